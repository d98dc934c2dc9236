"""The SpeechToText component: the robot's ears. ``Audio`` in, the transcript (``String``) out.

Audio chunks (16 kHz mono; other rates and stereo are resampled, with a log
line) go through voice activity detection (Silero VAD on sherpa-onnx, in
this component's process: :class:`~embagents.models.backends.sherpa_vad.SpeechSegmenter`),
so the recognizer runs on utterances, not on silence. Each utterance goes to
the speech model's actor (:class:`~embagents.models.SpeechToTextModel` behind
a :class:`~embagents.models.LocalModelClient`: the samples cross through
shared memory), or to an OpenAI-compatible server
(:class:`~embagents.clients.openai_audio.OpenAITranscriptionClient`). The
transcript is published on the ``String`` output. When a ``StreamingString``
output is wired, the utterance in progress is transcribed every
``partial_interval_ms`` and each hypothesis is published on it (``data`` is
the whole hypothesis so far, ``done=False``), the final one with ``done=True``:
a live view of what is heard, not gated by the wake phrase.

A wake phrase (``wake_phrase="hey robot"``) gates what is passed on: a
transcript that says it is passed on from after the phrase; one that is only
the phrase opens the gate for the next utterance within ``wake_window_s``;
anything else is logged and dropped. ``wake_word_model`` (an openWakeWord
``.onnx`` file; ``pip install openwakeword``) opens the same gate from the
audio instead.

An ``Audio`` with no samples marks the end of a stream (a WAV file's end):
the utterance in progress is transcribed at once. ``flush()`` does the same
as an action.

Example::

    >>> from embagents.models import LocalModelClient, SpeechToTextModel
    >>> from embagents.msgs import Audio, String
    >>> from embagents.topic import Topic
    >>> ears = SpeechToText(name="ears", inputs=[Topic("mic", Audio, keep="all")],
    ...                     outputs=[Topic("heard", String)],
    ...                     model_client=LocalModelClient(SpeechToTextModel(name="whisper")),
    ...                     config=SpeechToTextConfig(wake_phrase="hey robot"))
    >>> ears.config.min_silence_ms
    500.0
"""

from __future__ import annotations

import re
import time
from typing import Any

import numpy as np
from attrs import define, field

from embagents.components.audio_format import AudioFormatError, to_mono_16k
from embagents.components.component import ComponentProblem
from embagents.components.model_component import ModelComponent
from embagents.config import BaseComponentConfig, ConfigError, positive_float, to_bool
from embagents.msgs import Audio, StreamingString, String
from embagents.topic import Topic

__all__ = ["SpeechToText", "SpeechToTextConfig", "strip_wake_phrase"]

_WORD = re.compile(r"[\w']+")


def _unit(value: object) -> float:
    out = positive_float(value)
    if not out < 1.0:
        raise ConfigError(f"vad_threshold must be in (0, 1), got {value!r}")
    return out


def _phrase(value: object) -> str | None:
    if value is None or value == "":
        return None
    if not isinstance(value, str) or not _WORD.search(value):
        raise ConfigError(f"wake_phrase must be a phrase of words (e.g. 'hey robot') or None, got {value!r}")
    return value


def _optional_path(value: object) -> str | None:
    if value is None or value == "":
        return None
    if not isinstance(value, str):
        raise ConfigError(f"expected a file path or None, got {value!r}")
    return value


@define(kw_only=True)
class SpeechToTextConfig(BaseComponentConfig):
    """Settings of :class:`SpeechToText`.

    - ``enable_vad``: cut the audio into utterances with Silero VAD (else each
      Audio message is one utterance); ``vad_model``: its .onnx file (None: the
      ``silero-vad`` wheel's); ``vad_threshold``: speech probability;
      ``min_silence_ms``: the pause that ends an utterance; ``min_speech_ms``:
      shorter blips are dropped; ``max_utterance_ms``: longer speech is cut.
    - ``partial_interval_ms``: how often the utterance in progress is
      transcribed for the StreamingString output (when one is wired).
    - ``wake_phrase``: words a transcript must contain to be passed on (None:
      everything is); ``wake_window_s``: how long the phrase alone keeps the
      gate open; ``wake_word_model``/``wake_word_threshold``: an openWakeWord model instead.

    >>> SpeechToTextConfig(vad_threshold="0.6").vad_threshold
    0.6
    """

    enable_vad: bool = field(default=True, converter=to_bool)
    vad_model: str | None = field(default=None, converter=_optional_path)
    vad_threshold: float = field(default=0.5, converter=_unit)
    min_silence_ms: float = field(default=500.0, converter=positive_float)
    min_speech_ms: float = field(default=250.0, converter=positive_float)
    max_utterance_ms: float = field(default=20000.0, converter=positive_float)
    partial_interval_ms: float = field(default=1000.0, converter=positive_float)
    wake_phrase: str | None = field(default=None, converter=_phrase)
    wake_window_s: float = field(default=8.0, converter=positive_float)
    wake_word_model: str | None = field(default=None, converter=_optional_path)
    wake_word_threshold: float = field(default=0.5, converter=_unit)


def strip_wake_phrase(text: str, phrase: str) -> str | None:
    """What ``text`` says after ``phrase`` (case and punctuation ignored); None when it does not say it.

    >>> strip_wake_phrase("Hey, robot! Bring me the cup.", "hey robot")
    'Bring me the cup.'
    >>> strip_wake_phrase("Bring me the cup.", "hey robot") is None
    True
    """
    want = [w.lower() for w in _WORD.findall(phrase)]
    words = list(_WORD.finditer(text))
    said = [m.group().lower() for m in words]
    for i in range(len(said) - len(want) + 1):
        if said[i:i + len(want)] == want:
            return text[words[i + len(want) - 1].end():].lstrip(" ,.!?;:-").strip()
    return None


class SpeechToText(ModelComponent):
    """Transcribes speech with a speech-to-text model (see the module docstring)."""

    allowed_inputs = {"Required": [Audio]}
    allowed_outputs = {"Required": [String], "Optional": [StreamingString]}
    config_class = SpeechToTextConfig

    def __init__(self, *, name: str, **kw: Any) -> None:
        self._vad: Any = None
        self._wake_word: Any = None
        self._formats_seen: set[tuple[int, int]] = set()
        self._since_partial = 0  # samples since the last partial transcript
        self._utterances = 0
        self._awake_until = 0.0
        super().__init__(name=name, **kw)

    def _add_client(self, key: str, client: Any) -> str:
        if not callable(getattr(client, "transcribe", None)):
            self._client_problems.append(("bad-client", f"model client {client!r} cannot transcribe (it has no "
                                                        "transcribe()); give it LocalModelClient(SpeechToTextModel(...))"
                                                        " or OpenAITranscriptionClient(url)"))
            return key
        self.clients.setdefault(key, client)
        return key

    def default_trigger(self) -> Topic | None:
        return self.inputs[0] if self.inputs else None

    def validate(self) -> list[ComponentProblem]:
        problems = super().validate()
        if self.config.max_utterance_ms <= self.config.min_speech_ms:
            problems.append(("bad-config", f"{self._label()}: max_utterance_ms must be above min_speech_ms"))
        return problems

    def run_warmup(self) -> None:
        self.model_client.transcribe(np.zeros(1600, np.float32))

    # --- lifecycle --------------------------------------------------------------------------
    def on_configure(self) -> None:
        cfg = self.config
        if cfg.enable_vad:
            from embagents.models.backends.sherpa_vad import SpeechSegmenter
            from embagents.speechfiles import silero_vad_path

            self._vad = SpeechSegmenter(cfg.vad_model or silero_vad_path(), threshold=cfg.vad_threshold,
                                        min_silence_ms=cfg.min_silence_ms, min_speech_ms=cfg.min_speech_ms,
                                        max_utterance_ms=cfg.max_utterance_ms)
        if cfg.wake_word_model:
            self._wake_word = _load_wake_word(cfg.wake_word_model)
        for t in self.inputs:
            if t.keep != "all":  # a dropped chunk is a hole in a word
                self.logger.warning("%s: audio topic %r keeps only the latest messages: chunks may be dropped; "
                                    "declare it Topic(%r, Audio, keep='all')", self._label(), t.name, t.name)
        super().on_configure()
        self.logger.info("%s: listening (VAD %s, wake phrase %r, model client %s)", self._label(),
                         "on" if self._vad else "off", cfg.wake_phrase, self.client_name)

    # --- steps ------------------------------------------------------------------------------
    @property
    def _partials(self) -> list[Topic]:
        return [t for t in self.outputs if t.msg_type is StreamingString]

    def _execution_step(self, **inputs: Any) -> None:
        topic = next((t for t in self.inputs if t.name in self.fresh_inputs and inputs.get(t.name) is not None), None)
        if topic is None:
            return
        try:
            samples, note = to_mono_16k(inputs[topic.name])
        except AudioFormatError as exc:
            self.logger.error("%s: skipped an Audio message on %s: %s", self._label(), topic.name, exc)
            self.set_algorithm_failure(f"bad audio on {topic.name}: {exc}")
            return
        msg = inputs[topic.name]
        if note and (msg.sample_rate, msg.channels) not in self._formats_seen:
            self._formats_seen.add((msg.sample_rate, msg.channels))
            self.logger.info("%s: %s", self._label(), note)
        if samples.size == 0:  # the end of a stream
            self.flush()
            return
        if self._wake_word is not None:
            self._listen_for_wake_word(samples)
        if self._vad is None:
            self._finish(samples)
            return
        for utterance in self._vad.feed(samples):
            self._finish(utterance)
        self._partial(samples)

    def _partial(self, samples: np.ndarray) -> None:
        if not self._partials or not self._vad.speaking:
            self._since_partial = 0
            return
        self._since_partial += len(samples)
        if self._since_partial * 1000 >= self.config.partial_interval_ms * 16000:
            self._since_partial = 0
            text = self._transcribe(self._vad.current())
            if text:
                for t in self._partials:
                    self.publish(t, StreamingString(data=text, done=False, stream_id=self._stream_id()))

    def _stream_id(self) -> str:
        return f"{self.name}-{self._utterances + 1}"

    def _transcribe(self, samples: np.ndarray) -> str | None:
        from embagents.models.protocol import ModelError, ModelUnavailable

        try:
            return str(self.model_client.transcribe(samples).get("text", "")).strip()
        except (ModelError, ModelUnavailable, ConnectionError, TimeoutError) as exc:
            self.logger.error("%s: %.1f s of speech not transcribed: %s", self._label(), len(samples) / 16000, exc)
            self.set_algorithm_failure(f"transcription failed: {exc}")
            return None

    def _finish(self, utterance: np.ndarray) -> None:
        """Transcribe one whole utterance and pass it on (through the wake gate)."""
        self._since_partial = 0
        if utterance.size == 0:
            self.logger.info("%s: skipped an empty utterance", self._label())
            return
        text = self._transcribe(utterance)
        if text is None:
            return
        stream_id = self._stream_id()
        self._utterances += 1
        if not text:
            self.logger.info("%s: heard nothing in %.1f s of audio (no words)", self._label(), len(utterance) / 16000)
            return
        passed = self._gate(text)
        for t in self._partials:
            self.publish(t, StreamingString(data=text, done=True, stream_id=stream_id))
        if passed:
            self.logger.info("%s: heard %r", self._label(), passed)
            for t in self.outputs:
                if t.msg_type is String:
                    self.publish(t, String(data=passed))

    def _gate(self, text: str) -> str | None:
        cfg = self.config
        if cfg.wake_phrase is None and self._wake_word is None:
            return text
        now = time.monotonic()
        awake, self._awake_until = now < self._awake_until, 0.0
        rest = strip_wake_phrase(text, cfg.wake_phrase) if cfg.wake_phrase else None
        if rest:  # the phrase, then what is asked
            return rest
        if rest == "":  # the phrase alone: the next utterance is for us
            self._awake_until = now + cfg.wake_window_s
            self.logger.info("%s: wake phrase heard; listening for %.0f s", self._label(), cfg.wake_window_s)
            return None
        if awake:
            return text
        self.logger.info("%s: not for me (no wake %s): %r", self._label(),
                         f"phrase {cfg.wake_phrase!r}" if cfg.wake_phrase else "word", text)
        return None

    def _listen_for_wake_word(self, samples: np.ndarray) -> None:
        pcm = np.clip(samples * 32768.0, -32768, 32767).astype(np.int16)
        scores = self._wake_word.predict(pcm)
        if max(scores.values(), default=0.0) >= self.config.wake_word_threshold:
            self._awake_until = time.monotonic() + self.config.wake_window_s
            self.logger.info("%s: wake word heard (%s); listening", self._label(), scores)

    # --- actions ----------------------------------------------------------------------------
    def flush(self) -> int:
        """Transcribe the utterance in progress now (the end of a stream); returns how many ended."""
        if self._vad is None:
            return 0
        ended = self._vad.flush()
        for utterance in ended:
            self._finish(utterance)
        return len(ended)


def _load_wake_word(path: str) -> Any:
    import os

    if not os.path.isfile(path):
        raise FileNotFoundError(f"openWakeWord model not found: {path!r}; give the path of a wake word .onnx file "
                                "(openWakeWord ships none on PyPI), or use wake_phrase='hey robot' instead")
    try:
        import openwakeword
    except ImportError as exc:
        raise ModuleNotFoundError("wake_word_model needs openWakeWord: pip install openwakeword "
                                  "(or use wake_phrase, matched on transcripts)") from exc
    return openwakeword.Model(wakeword_models=[path], inference_framework="onnx")
