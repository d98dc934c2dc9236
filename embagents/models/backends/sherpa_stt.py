"""Speech-to-text on sherpa-onnx's offline recognizer: Whisper, Moonshine, Paraformer, transducer.

A model is a directory in sherpa-onnx's layout; its family is found from its
files (:func:`detect_stt_model`):

- ``joiner``: a transducer (``*encoder*.onnx``, ``*decoder*.onnx``, ``*joiner*.onnx``);
- ``preprocess``: Moonshine v1 (``preprocess``, ``encode``, ``uncached_decode``, ``cached_decode``);
- ``merged_decode``: Moonshine v2 (``encoder``/``encode``, ``merged_decode``);
- ``encoder`` + ``decoder``: Whisper;
- one ``model.onnx``: Paraformer;

each with ``tokens.txt``. Where several files match (``model.onnx`` and
``model.int8.onnx``), the full-precision one is taken. A directory that
misses a file raises :class:`SpeechModelError` naming that file.

Example::

    >>> stt = SherpaRecognizer(whisper_tiny_en_dir())                      # doctest: +SKIP
    >>> stt.transcribe(samples_16k_float32)                               # doctest: +SKIP
    'Ever tried, ever failed. No matter, try again.'
"""

from __future__ import annotations

import glob
import logging
import os
import re
from typing import Any

import numpy as np

from embagents.models.files.speech import WHISPER_PREPARE_HINT

__all__ = ["STT_FAMILIES", "SherpaRecognizer", "SpeechModelError", "check_samples", "detect_stt_model"]

log = logging.getLogger("embagents.stt")

#: The model families a sherpa-onnx model directory can hold.
STT_FAMILIES = ("whisper", "moonshine", "moonshine_v2", "paraformer", "transducer")
SAMPLE_RATE = 16000
#: Whisper's longest piece of audio here (its window is 30 s, sherpa-onnx keeps 0.5 s of it for padding).
WHISPER_PIECE_S = 28.0
_ANNOTATION = re.compile(r"\[[^\]]*\]|\([^)]*\)|\*[^*]*\*")

# Per family: role -> glob patterns (first that matches wins).
_LAYOUTS: dict[str, dict[str, tuple[str, ...]]] = {
    "transducer": {"encoder": ("*encoder*.onnx",), "decoder": ("*decoder*.onnx",), "joiner": ("*joiner*.onnx",)},
    "moonshine": {"preprocessor": ("*preprocess*.onnx",), "encoder": ("*encode*.onnx",),
                  "uncached_decoder": ("*uncached_decode*.onnx",), "cached_decoder": ("*cached_decode*.onnx",)},
    "moonshine_v2": {"encoder": ("*encode*.onnx",), "decoder": ("*merged_decode*.onnx",)},
    "whisper": {"encoder": ("*encoder*.onnx",), "decoder": ("*decoder*.onnx",)},
    "paraformer": {"paraformer": ("model.onnx", "model.int8.onnx", "*.onnx")},
}


class SpeechModelError(FileNotFoundError):
    """A speech model directory that is missing, or misses a file (the message names which, and the fix)."""


def _find(folder: str, patterns: tuple[str, ...], exclude: tuple[str, ...] = ()) -> str | None:
    for pattern in patterns:
        hits = [h for h in sorted(glob.glob(os.path.join(folder, pattern)))
                if not any(x in os.path.basename(h) for x in exclude)]
        if hits:  # full precision first: int8 files are smaller, and less exact
            return sorted(hits, key=lambda h: ".int8." in h)[0]
    return None


def _family_of(folder: str, names: list[str]) -> str:
    has = lambda part: any(part in n for n in names if n.endswith(".onnx"))  # noqa: E731
    if has("joiner"):
        return "transducer"
    if has("preprocess"):
        return "moonshine"
    if has("merged_decode"):
        return "moonshine_v2"
    if has("encoder") or has("decoder"):
        return "whisper"
    if any(n.endswith(".onnx") for n in names):
        return "paraformer"
    raise SpeechModelError(f"{folder} holds no .onnx model file; give a sherpa-onnx model directory "
                           f"({', '.join(STT_FAMILIES)}), or {_hint()}")


def _listing(names: list[str]) -> str:
    shown = ", ".join(names[:12]) or "nothing"
    return shown + (f" and {len(names) - 12} more" if len(names) > 12 else "")


def _hint() -> str:
    return WHISPER_PREPARE_HINT


def detect_stt_model(folder: str, family: str | None = None) -> tuple[str, dict[str, str]]:
    """``(family, {role: path})`` of the sherpa-onnx model in ``folder`` (``family`` forces one).

    Raises :class:`SpeechModelError` naming the missing file and how to get the default model.
    """
    folder = os.path.abspath(os.path.expanduser(folder))
    if not os.path.isdir(folder):
        raise SpeechModelError(f"speech model directory not found: {folder!r}; {_hint()}")
    names = sorted(os.listdir(folder))
    if family is not None and family not in STT_FAMILIES:
        raise ValueError(f"speech model family {family!r} is not known; use one of {', '.join(STT_FAMILIES)}")
    family = family or _family_of(folder, names)
    files: dict[str, str] = {}
    for role, patterns in _LAYOUTS[family].items():
        exclude: tuple[str, ...] = ("uncached",) if role == "cached_decoder" else ("merged",) if family == "moonshine" else ()
        if family == "moonshine" and role == "encoder":
            exclude = ("decode", "preprocess")
        if family == "moonshine_v2" and role == "encoder":
            exclude = ("decode",)
        found = _find(folder, patterns, exclude)
        if found is None:
            raise SpeechModelError(f"the {family} model in {folder} misses its {role} file ({' or '.join(patterns)}); "
                                   f"it has {_listing(names)}. Copy the whole model directory, or "
                                   f"{_hint()}")
        files[role] = found
    tokens = os.path.join(folder, "tokens.txt")
    if not os.path.isfile(tokens):
        found_tokens = _find(folder, ("*tokens.txt",))
        if found_tokens is None:
            raise SpeechModelError(f"the {family} model in {folder} misses its tokens file (tokens.txt); it has "
                                   f"{_listing(names)}. Copy the whole model directory, or {_hint()}")
        tokens = found_tokens
    files["tokens"] = tokens
    return family, files


def check_samples(samples: object) -> np.ndarray:
    """``samples`` as a 1-D float32 array in [-1, 1] (int16 is scaled), or ``ValueError`` saying what it is.

    >>> check_samples(np.array([16384], np.int16))
    array([0.5], dtype=float32)
    """
    if not isinstance(samples, np.ndarray):
        raise ValueError(f"audio must be a numpy array, got {type(samples).__name__}")
    if samples.ndim != 1:
        raise ValueError(f"audio must be 1-D mono samples, got shape {samples.shape}; mix the channels down first")
    if samples.dtype == np.int16:
        return samples.astype(np.float32) / 32768.0
    if samples.dtype != np.float32:
        raise ValueError(f"audio must be float32 in [-1, 1] or int16 samples, got dtype {samples.dtype}; "
                         "convert it (e.g. samples.astype(np.float32) / 32768 for int32 PCM >> 16)")
    return samples


def _quietest(audio: np.ndarray, start: int, end: int, rate: int) -> int:
    """The start of the quietest 100 ms window of ``audio[start:end]`` (a pause, where a cut splits no word)."""
    hop = rate // 10
    energy = [float(np.square(audio[i:i + hop]).sum()) for i in range(start, end - hop + 1, hop)]
    return start + hop * int(np.argmin(energy))


class SherpaRecognizer:
    """One sherpa-onnx offline recognizer on the model in ``path`` (see the module docstring).

    ``language``/``task``: Whisper's (``"en"``, ``"transcribe"``); ``threads``:
    onnxruntime threads; ``provider``: ``cpu``, ``cuda`` or ``coreml``.
    """

    def __init__(self, path: str, *, family: str | None = None, threads: int = 1, language: str = "en",
                 task: str = "transcribe", provider: str = "cpu") -> None:
        try:
            import sherpa_onnx
        except ImportError as exc:
            raise ModuleNotFoundError("speech-to-text needs sherpa-onnx: pip install 'embagents[speech]'") from exc
        self.family, self.files = detect_stt_model(path, family)
        f, common = self.files, {"tokens": self.files["tokens"], "num_threads": int(threads), "provider": provider}
        make = sherpa_onnx.OfflineRecognizer
        try:
            if self.family == "whisper":
                self.recognizer = make.from_whisper(encoder=f["encoder"], decoder=f["decoder"], language=language,
                                                    task=task, **common)
            elif self.family == "moonshine":
                self.recognizer = make.from_moonshine(preprocessor=f["preprocessor"], encoder=f["encoder"],
                                                      uncached_decoder=f["uncached_decoder"],
                                                      cached_decoder=f["cached_decoder"], **common)
            elif self.family == "moonshine_v2":
                self.recognizer = make.from_moonshine_v2(encoder=f["encoder"], decoder=f["decoder"], **common)
            elif self.family == "paraformer":
                self.recognizer = make.from_paraformer(paraformer=f["paraformer"], **common)
            else:
                self.recognizer = make.from_transducer(encoder=f["encoder"], decoder=f["decoder"],
                                                       joiner=f["joiner"], **common)
        except Exception as exc:  # sherpa-onnx raises RuntimeError (or exits) on files it cannot read
            raise ValueError(f"sherpa-onnx could not load the {self.family} model in {path}: {exc}") from exc
        log.info("loaded %s model from %s (%d threads, %s)", self.family, path, threads, provider)

    def transcribe(self, samples: Any, sample_rate: int = SAMPLE_RATE) -> str:
        """The text said in ``samples`` (mono, float32 in [-1, 1] or int16); "" for silence.

        Whisper hears at most 30 s at once: longer audio is transcribed in pieces of
        :data:`WHISPER_PIECE_S` seconds (cut where it is quietest near the end of each).
        """
        audio = check_samples(samples)
        if audio.size == 0:
            return ""
        piece = int(WHISPER_PIECE_S * sample_rate)
        if self.family == "whisper" and len(audio) > piece:
            cut = _quietest(audio, piece - 3 * sample_rate, piece, sample_rate)
            return " ".join(t for t in (self.transcribe(audio[:cut], sample_rate),
                                        self.transcribe(audio[cut:], sample_rate)) if t)
        stream = self.recognizer.create_stream()
        stream.accept_waveform(int(sample_rate), audio)
        self.recognizer.decode_stream(stream)
        text = str(stream.result.text)
        if self.family == "whisper":  # Whisper names what is not speech ("[ Silence ]", "(music)"): not words
            text = _ANNOTATION.sub("", text)
        return " ".join(text.split())
