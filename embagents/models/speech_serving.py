"""Speech behind the inference protocol: ``transcribe`` (speech to text) and ``speak`` (text to speech).

A request carries ``{"audio": 1-D 16 kHz samples}`` (float32 in [-1, 1] or
int16; arrays of 64 KB and more cross through shared memory); the answer is
``{"text": str, "seconds": float}`` (the audio's length). Audio of another
shape, dtype or rate is refused at once with what to do about it; empty
audio is answered with ``""``.

Example::

    >>> serving = SpeechToTextServing(whisper_tiny_en_dir(), {})            # doctest: +SKIP
    >>> next(serving.run("transcribe", {"audio": samples}, {}))["text"]      # doctest: +SKIP
    'Ever tried, ever failed.'
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from embagents.models.backends.sherpa_stt import SherpaRecognizer, check_samples
from embagents.models.backends.sherpa_tts import SherpaSpeaker
from embagents.models.backends.smart_turn import SmartTurn
from embagents.models.protocol import BadRequest
from embagents.models.sentences import speakable

__all__ = ["SPEAK_OPTIONS", "TRANSCRIBE_OPTIONS", "SpeechToTextServing", "TextToSpeechServing", "TurnServing"]

#: Options a ``transcribe`` request may carry.
TRANSCRIBE_OPTIONS = ("sample_rate",)


class SpeechToTextServing:
    """A :class:`~embagents.models.backends.sherpa_stt.SherpaRecognizer` behind the ``transcribe`` task."""

    batchable = False

    def __init__(self, path: str, options: dict[str, Any]) -> None:
        self.path, self.options = path, {k: v for k, v in options.items() if v is not None}
        self.recognizer: Any = None

    def load(self) -> None:
        self.recognizer = SherpaRecognizer(self.path, **self.options)

    def warmup(self) -> None:
        self.recognizer.transcribe(np.zeros(8000, np.float32))

    def check(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> None:
        if task != "transcribe":
            raise BadRequest(f"a speech-to-text model serves task 'transcribe', not {task!r}")
        unknown = sorted(set(options) - set(TRANSCRIBE_OPTIONS))
        if unknown:
            raise BadRequest(f"unknown option(s) {', '.join(unknown)}; this model takes {', '.join(TRANSCRIBE_OPTIONS)}")
        rate = options.get("sample_rate", 16000)
        if rate != 16000:
            raise BadRequest(f"audio must be 16000 Hz, got sample_rate={rate!r}; resample it first "
                             "(the SpeechToText component does)")
        try:
            check_samples(inputs.get("audio"))
        except ValueError as exc:
            raise BadRequest(str(exc)) from None

    def run(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> Iterator[dict[str, Any]]:
        audio = inputs["audio"]
        yield {"text": self.recognizer.transcribe(audio), "seconds": len(audio) / 16000.0, "done": True}

    def run_batch(self, task: str, batch: list[dict[str, Any]], options: dict[str, Any]) -> list[dict[str, Any]]:
        raise NotImplementedError("the recognizer serves one utterance at a time")

    def close(self) -> None:
        self.recognizer = None


#: Options a ``speak`` request may carry.
SPEAK_OPTIONS = ("speed",)


class TextToSpeechServing:
    """A :class:`~embagents.models.backends.sherpa_tts.SherpaSpeaker` behind the ``speak`` task.

    A request carries ``{"text": str}``; the answer streams one chunk per
    sentence, ``{"audio": float32 samples, "sample_rate": int, "text": phonemes}``,
    then ``{"done": True, "seconds": total}``. A client that cancels stops it
    at the next sentence. Text with nothing to say is refused at once.
    """

    batchable = False

    def __init__(self, path: str, options: dict[str, Any]) -> None:
        self.path, self.options = path, {k: v for k, v in options.items() if v is not None}
        self.speaker: Any = None

    def load(self) -> None:
        self.speaker = SherpaSpeaker(self.path, **self.options)

    def warmup(self) -> None:
        for _ in self.speaker.speak("Ready."):
            pass

    def check(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> None:
        if task != "speak":
            raise BadRequest(f"a text-to-speech model serves task 'speak', not {task!r}")
        unknown = sorted(set(options) - set(SPEAK_OPTIONS))
        if unknown:
            raise BadRequest(f"unknown option(s) {', '.join(unknown)}; this model takes {', '.join(SPEAK_OPTIONS)}")
        text = inputs.get("text")
        if not isinstance(text, str):
            raise BadRequest(f"text must be a str, got {type(text).__name__}")
        if not speakable(text):
            raise BadRequest(f"text {text[:60]!r} has no speakable characters (no letters or digits); send words")
        speed = options.get("speed", 1.0)
        if not isinstance(speed, (int, float)) or not 0.25 <= speed <= 4.0:
            raise BadRequest(f"speed must be a number in [0.25, 4], got {speed!r}")

    def run(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> Iterator[dict[str, Any]]:
        seconds = 0.0
        for samples, rate, phonemes in self.speaker.speak(inputs["text"], speed=options.get("speed")):
            seconds += len(samples) / rate
            yield {"audio": samples, "sample_rate": rate, "text": phonemes}
        yield {"done": True, "seconds": seconds}

    def run_batch(self, task: str, batch: list[dict[str, Any]], options: dict[str, Any]) -> list[dict[str, Any]]:
        raise NotImplementedError("the synthesizer speaks one text at a time")

    def close(self) -> None:
        self.speaker = None


class TurnServing:
    """Smart Turn v3 (:class:`~embagents.models.backends.smart_turn.SmartTurn`) behind the ``end_of_turn`` task.

    A request carries ``{"audio": 1-D 16 kHz samples}`` (the user's speech so far; the last 8 s count);
    the answer is ``{"probability": float, "complete": bool}`` (complete: probability > 0.5).
    """

    batchable = False

    def __init__(self, path: str, options: dict[str, Any]) -> None:
        self.path, self.options = path, {k: v for k, v in options.items() if v is not None}
        self.model: Any = None

    def load(self) -> None:
        self.model = SmartTurn(self.path, **self.options)

    def warmup(self) -> None:
        self.model.probability(np.zeros(16000, np.float32))

    def check(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> None:
        if task != "end_of_turn":
            raise BadRequest(f"a turn model serves task 'end_of_turn', not {task!r}")
        if options:
            raise BadRequest(f"unknown option(s) {', '.join(sorted(options))}; a turn model takes none")
        try:
            check_samples(inputs.get("audio"))
        except ValueError as exc:
            raise BadRequest(str(exc)) from None

    def run(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> Iterator[dict[str, Any]]:
        p = self.model.probability(inputs["audio"])
        yield {"probability": p, "complete": p > 0.5, "done": True}

    def run_batch(self, task: str, batch: list[dict[str, Any]], options: dict[str, Any]) -> list[dict[str, Any]]:
        raise NotImplementedError("one turn at a time")

    def close(self) -> None:
        self.model = None
