"""Speech synthesis with sherpa-onnx's offline TTS on a Piper/VITS or a Kokoro voice.

A Piper voice folder holds ``model.onnx`` (with sherpa-onnx's metadata),
``tokens.txt`` and the Piper config ``voice.json``
(:func:`embagents.models.convert.piper.prepare_piper_voice` makes one from a Piper
release; :func:`embagents.models.files.speech.piper_joe_dir` is the offline default).
A Kokoro folder (sherpa-onnx's ``kokoro-en-v0_19`` or
``kokoro-multi-lang-v1_0`` releases, EmbodiedAgents' default voice) holds
``model.onnx``, ``voices.bin`` and ``tokens.txt``; its espeak-ng data and
lexicons are not needed. Which one a folder is: ``voices.bin`` says Kokoro.
Text is phonemized by espeak-ng (:mod:`embagents.models.backends.phonemes`, in this process:
the model actor's) and synthesized sentence by sentence, so a caller can
play the first sentence while the next is being made.

Example::

    >>> voice = SherpaSpeaker(piper_joe_dir())                                       # doctest: +SKIP
    >>> [(len(a) > 0, sr) for a, sr, _ in voice.speak("Hello. I am a robot.")]       # doctest: +SKIP
    [(True, 22050), (True, 22050)]
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from typing import Any

import numpy as np

from embagents.models.backends.phonemes import phonemize
from embagents.models.files.speech import PIPER_PREPARE_HINT
from embagents.models.sentences import speakable

__all__ = ["KOKORO_FILES", "SherpaSpeaker", "TTSModelError", "check_voice_dir", "speakable", "voice_family"]

_PIPER = ("model.onnx", "tokens.txt", "voice.json")
_KOKORO = KOKORO_FILES = ("model.onnx", "voices.bin", "tokens.txt")


def voice_family(folder: str) -> str:
    """``"kokoro"`` if ``folder`` has a ``voices.bin`` (Kokoro's speaker styles), else ``"piper"``."""
    return "kokoro" if os.path.isfile(os.path.join(folder, "voices.bin")) else "piper"


class TTSModelError(FileNotFoundError):
    """A voice folder lacks a file (the message names it and how to get the default voice)."""


def check_voice_dir(path: str) -> str:
    """``path`` (expanded) if it is a complete Piper voice folder; else :class:`TTSModelError` naming what is missing."""

    folder = os.path.abspath(os.path.expanduser(path))
    if not os.path.isdir(folder):
        raise TTSModelError(f"text-to-speech voice folder not found: {path!r}; give a Piper voice folder "
                            f"({', '.join(_PIPER)}) or a Kokoro one ({', '.join(_KOKORO)}), or {PIPER_PREPARE_HINT}")
    if voice_family(folder) == "kokoro":
        missing = [f for f in _KOKORO if not os.path.isfile(os.path.join(folder, f))]
        if missing:
            raise TTSModelError(f"Kokoro voice folder {path!r} lacks {', '.join(missing)} (a Kokoro folder holds "
                                f"{', '.join(_KOKORO)}, as in sherpa-onnx's kokoro-en-v0_19 release)")
        return folder
    missing = [f for f in _PIPER if not os.path.isfile(os.path.join(folder, f))]
    if missing:
        raise TTSModelError(f"voice folder {path!r} lacks {', '.join(missing)} (a Piper voice folder holds "
                            f"{', '.join(_PIPER)}: make one from a Piper .onnx + .onnx.json with "
                            f"embagents.models.convert.piper.prepare_piper_voice; a Kokoro one holds {', '.join(_KOKORO)}; "
                            f"or {PIPER_PREPARE_HINT})")
    return folder


class SherpaSpeaker:
    """One Piper/VITS or Kokoro voice on sherpa-onnx; :meth:`speak` yields each sentence's samples."""

    def __init__(self, path: str, *, threads: int = 1, provider: str = "cpu", speed: float = 1.0,
                 speaker_id: int = 0) -> None:
        import sherpa_onnx

        self.path = check_voice_dir(path)
        self.family = voice_family(self.path)
        self.speed, self.speaker_id = speed, speaker_id
        model, tokens = os.path.join(self.path, "model.onnx"), os.path.join(self.path, "tokens.txt")
        if self.family == "kokoro":
            # Phonemes are ours (espeak-ng, as Kokoro v0.19 was trained on): no espeak data or lexicon here.
            family = {"kokoro": sherpa_onnx.OfflineTtsKokoroModelConfig(
                model=model, voices=os.path.join(self.path, "voices.bin"), tokens=tokens)}
            self.voice_config: dict[str, Any] = {}
        else:
            family = {"vits": sherpa_onnx.OfflineTtsVitsModelConfig(model=model, tokens=tokens)}
            with open(os.path.join(self.path, "voice.json"), encoding="utf-8") as f:
                self.voice_config = json.load(f)
        config = sherpa_onnx.OfflineTtsConfig(
            model=sherpa_onnx.OfflineTtsModelConfig(**family, num_threads=threads, provider=provider))
        self.tts = sherpa_onnx.OfflineTts(config)
        self.sample_rate = int(self.tts.sample_rate)
        speakers = int(self.tts.num_speakers)
        if speakers > 1 and not 0 <= speaker_id < speakers:
            raise ValueError(f"speaker_id {speaker_id} is not one of this voice's {speakers} speakers "
                             f"(0..{speakers - 1}): {self.path}")
        # Piper: the voice's own espeak voice; Kokoro: the model's "voice" metadata (en-us by default).
        self.espeak_voice = (self.voice_config.get("espeak", {}).get("voice") if self.family == "piper"
                             else self.tts.lang) or "en-us"

    def speak(self, text: str, *, speed: float | None = None) -> Iterator[tuple[np.ndarray, int, str]]:
        """``(samples, sample_rate, phonemes)`` per sentence of ``text``: float32 mono in [-1, 1]."""
        import sherpa_onnx


        for sentence in phonemize(text, self.espeak_voice):
            gen = sherpa_onnx.GenerationConfig()
            gen.sid, gen.speed = self.speaker_id, float(speed or self.speed)
            gen.phoneme_codepoints = [[ord(ch) for ch in sentence]]
            audio = self.tts.generate("", gen)
            samples = np.asarray(audio.samples, np.float32)
            if samples.size:
                yield samples, self.sample_rate, sentence

    def describe(self) -> dict[str, Any]:
        return {"sample_rate": self.sample_rate, "voice": self.espeak_voice, "path": self.path,
                "family": self.family, "speakers": int(self.tts.num_speakers)}
