"""A Piper voice made into a sherpa-onnx VITS model directory, once.

A Piper voice is an ``.onnx`` graph and an ``.onnx.json`` config. sherpa-onnx
wants the graph with its metadata (``model_type=vits``, ``comment=piper``,
sample rate, speakers, language) and a ``tokens.txt`` mapping each phoneme to
its id; :func:`prepare_piper_voice` writes them (and a copy of the config as
``voice.json``) into a folder, atomically, with a progress bar.

Example::

    >>> d = prepare_piper_voice("en_US-joe-medium.onnx", "en_US-joe-medium.onnx.json", "/tmp/joe")  # doctest: +SKIP
    >>> sorted(os.listdir(d))                                                                     # doctest: +SKIP
    ['model.onnx', 'tokens.txt', 'voice.json']
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

from embagents.models.progress import progress_bar

__all__ = ["PIPER_FILES", "PREPARER_VERSION", "PiperVoiceError", "piper_config", "prepare_piper_voice"]

#: What a prepared voice folder holds.
PIPER_FILES = ("model.onnx", "tokens.txt", "voice.json")
#: Bumped when the prepared files change (the cache folder is named after it).
PREPARER_VERSION = 1


class PiperVoiceError(ValueError):
    """A Piper voice's files are missing or not what a Piper voice holds."""


def piper_config(json_path: str) -> dict[str, Any]:
    """The voice's ``.onnx.json``, checked for what synthesis needs."""
    if not os.path.isfile(json_path):
        raise PiperVoiceError(f"Piper voice config not found: {json_path!r}; a Piper voice is an .onnx file and the "
                              ".onnx.json next to it (both from the voice's release)")
    with open(json_path, encoding="utf-8") as f:
        config = json.load(f)
    missing = [k for k in ("phoneme_id_map", "audio") if k not in config]
    if missing or "sample_rate" not in config.get("audio", {}):
        raise PiperVoiceError(f"{json_path!r} is not a Piper voice config: it lacks {', '.join(missing) or 'audio.sample_rate'}")
    return config


def prepare_piper_voice(onnx_path: str, json_path: str, dest: str, *, progress: bool = True) -> str:
    """Write :data:`PIPER_FILES` for the voice into ``dest`` (kept if already complete); returns ``dest``."""
    import onnx

    if all(os.path.isfile(os.path.join(dest, f)) for f in PIPER_FILES):
        return dest
    if not os.path.isfile(onnx_path):
        raise PiperVoiceError(f"Piper voice model not found: {onnx_path!r}")
    config = piper_config(json_path)
    show = progress_bar(f"preparing Piper voice {Path(onnx_path).stem} for sherpa-onnx", progress)
    tmp = Path(f"{dest}.part{os.getpid()}")
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        show(0, 3)
        model = onnx.load(onnx_path)
        show(1, 3)
        lang = config.get("language", {})
        meta = {
            "model_type": "vits", "comment": "piper", "language": lang.get("name_english", "English"),
            "voice": config.get("espeak", {}).get("voice", "en-us"), "has_espeak": 1,
            "n_speakers": config.get("num_speakers", 1), "sample_rate": config["audio"]["sample_rate"],
        }
        del model.metadata_props[:]
        for key, value in meta.items():
            prop = model.metadata_props.add()
            prop.key, prop.value = key, str(value)
        onnx.save(model, str(tmp / "model.onnx"))
        show(2, 3)
        with open(tmp / "tokens.txt", "w", encoding="utf-8") as f:
            for symbol, ids in config["phoneme_id_map"].items():
                f.write(f"{symbol} {ids[0]}\n")
        shutil.copyfile(json_path, tmp / "voice.json")
        if os.path.isdir(dest):  # a folder that lost a file: replaced whole
            shutil.rmtree(dest)
        os.makedirs(os.path.dirname(os.path.abspath(dest)), exist_ok=True)
        os.replace(tmp, dest)
        show(3, 3)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return dest
