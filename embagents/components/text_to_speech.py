"""The TextToSpeech component: the robot's voice. ``String`` or ``StreamingString`` in, ``Audio`` out.

Text goes to a voice's model actor (:class:`~embagents.models.TextToSpeechModel`
behind a :class:`~embagents.models.LocalModelClient`: sherpa-onnx on a Piper
voice, phonemized by espeak-ng in that actor's process, not this one) or to an
OpenAI-compatible ``/audio/speech`` server
(:class:`~embagents.models.clients.openai_audio.OpenAISpeechClient`), one sentence
at a time. Each sentence's audio is published as soon as it is made
(float32 mono at the voice's rate), and an empty ``Audio`` follows the last
sentence of each utterance: the end of the utterance (a WAV sink closes its
file there, as SpeechToText ends an utterance on one). The first chunk of each
sentence carries the sentence (``Audio.text``) and every chunk the
``stream_id`` of the text it speaks, so that a Speaker can say which words it
has played (and an LLM keep only those of an answer cut short).

A ``StreamingString`` (an LLM's token deltas, closed by ``done=True``) is
spoken sentence by sentence as it arrives: the first sentence is heard while
the model is still writing the rest.

Sentences wait in a queue and are spoken one per turn of the component's
loop, so the actions come in between: ``say(text)`` drops what is queued,
ends the utterance in progress and speaks ``text``; ``stop_playback()`` drops
what is queued and ends it. A ``BargeIn`` input (SpeechToText's) with
``interrupt`` stops it as ``stop_playback()`` does: the rest of that answer
is not spoken.

Example::

    >>> from embagents.models import LocalModelClient, TextToSpeechModel
    >>> from embagents.msgs import Audio, String
    >>> from embagents.topic import Topic
    >>> voice = TextToSpeech(name="voice", inputs=[Topic("answer", String)],
    ...                      outputs=[Topic("speaker", Audio, keep="all")],
    ...                      model_client=LocalModelClient(TextToSpeechModel(name="joe")))
    >>> voice.config.max_queue_sentences
    50
"""

from __future__ import annotations

import re
import time
from collections import deque
from typing import Any

import numpy as np
from attrs import define, field

from embagents.components.model_component import ModelComponent
from embagents.components.voice_stages import publish_stage
from embagents.config import BaseComponentConfig, ConfigError
from embagents.models.protocol import ModelError, ModelUnavailable
from embagents.models.sentences import speakable
from embagents.msgs import Audio, BargeIn, StreamingString, String, VoiceStage
from embagents.topic import Topic

__all__ = ["TextToSpeech", "TextToSpeechConfig", "take_sentences"]

# A sentence ends at . ! ? ; or a newline, followed by white space (so "3.5" and "e.g." mid-word stay whole).
_END = re.compile(r"[.!?;]+[\"')\]]*\s+|\n+")


def _positive_int(value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"expected an integer >= 1, got {value!r}")
    return value


@define(kw_only=True)
class TextToSpeechConfig(BaseComponentConfig):
    """Settings of :class:`TextToSpeech`.

    - ``max_queue_sentences``: sentences waiting beyond this are dropped (logged);
    - ``speed``: passed to the voice (1.0: its own pace; None: the model's setting).

    >>> TextToSpeechConfig(max_queue_sentences=5).max_queue_sentences
    5
    """

    max_queue_sentences: int = field(default=50, converter=_positive_int)
    speed: float | None = None


def take_sentences(buffer: str) -> tuple[list[str], str]:
    """The whole sentences at the start of ``buffer``, and what is left of it.

    >>> take_sentences("The cup is red. It is on the tab")
    (['The cup is red.'], 'It is on the tab')
    >>> take_sentences("Pi is 3.14 or so")
    ([], 'Pi is 3.14 or so')
    """
    out, start = [], 0
    for m in _END.finditer(buffer):
        sentence = buffer[start:m.end()].strip()
        if sentence:
            out.append(sentence)
        start = m.end()
    return out, buffer[start:]


class TextToSpeech(ModelComponent):
    """Speaks text with a text-to-speech model (see the module docstring)."""

    allowed_inputs = {"Required": [[String, StreamingString]], "Optional": [String, StreamingString, BargeIn]}
    allowed_outputs = {"Required": [Audio], "Optional": [VoiceStage]}
    config_class = TextToSpeechConfig
    client_methods = ("speak",)
    client_task = "speak"
    client_fix = "LocalModelClient(TextToSpeechModel(...)) or OpenAISpeechClient(url)"

    def __init__(self, *, name: str, **kw: Any) -> None:
        self._received: list[Any] = []
        self._queue: deque[tuple[str, bool, str]] = deque()  # (sentence, ends the utterance, its stream_id)
        self._streams: dict[str, str] = {}  # stream_id -> text not yet a whole sentence
        self._muted: set[str] = set()  # streams cut short by say() or stop_playback()
        self._pumping = False
        self._in_utterance = False
        self.spoken = 0  # sentences spoken (for tests and status)
        super().__init__(name=name, **kw)

    @property
    def _audio_outputs(self) -> list[Topic]:
        return [t for t in self.outputs if t.msg_type is Audio]

    def default_trigger(self) -> list[Any]:
        return list(self.inputs)  # a message on any input is text to speak

    def missing_inputs(self, now: float | None = None, inputs: Any = None) -> list[str]:
        return []  # every message is queued by on_message: a step never waits for another topic

    def run_warmup(self) -> None:
        for _ in self.model_client.speak("Ready."):
            pass

    def on_configure(self) -> None:
        for t in self._audio_outputs:
            if t.keep != "all":  # a dropped chunk is a hole in a word
                self.logger.warning("%s: audio topic %r keeps only the latest messages: sentences may be dropped; "
                                    "declare it Topic(%r, Audio, keep='all')", self._label(), t.name, t.name)
        super().on_configure()

    # --- input ------------------------------------------------------------------------------
    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if isinstance(msg, BargeIn):
            if msg.action == "interrupt" and topic_name in self._subscribed:
                # Chunks of the answer received but not yet taken belong to it too: not spoken either.
                self._muted.update(m.stream_id for m in self._received if isinstance(m, StreamingString) and not m.done)
                self._received = [m for m in self._received if not isinstance(m, StreamingString)]
                self.stop_playback()
            return False
        if topic_name in self._subscribed:
            self._received.append(msg)  # every chunk of a stream, not only the latest
        return super().on_message(topic_name, msg, now)

    def _execution_step(self, **inputs: Any) -> None:
        received, self._received = self._received, []
        for msg in received:
            if isinstance(msg, String):
                self._enqueue_text(msg.data)
            elif isinstance(msg, StreamingString):
                self._stream_chunk(msg)
        if not self._pumping:  # else the scheduled turn speaks next, in order
            self._pump()

    def _stream_chunk(self, msg: StreamingString) -> None:
        if msg.stream_id in self._muted:  # stopped: the rest of that stream is not spoken
            if msg.done:
                self._muted.discard(msg.stream_id)
            return
        buffer = self._streams.pop(msg.stream_id, "") + msg.data
        sentences, rest = take_sentences(buffer)
        if msg.done:
            sentences += [rest.strip()] if rest.strip() else []
            self._enqueue(sentences, ends=True, stream_id=msg.stream_id)
        else:
            self._streams[msg.stream_id] = rest
            self._enqueue(sentences, ends=False, stream_id=msg.stream_id)

    def _enqueue_text(self, text: str) -> None:
        sentences, rest = take_sentences(text + "\n")
        self._enqueue(sentences + ([rest.strip()] if rest.strip() else []), ends=True)

    def _enqueue(self, sentences: list[str], *, ends: bool, stream_id: str = "") -> None:
        said = [s for s in sentences if speakable(s)]
        for s in sentences:
            if not speakable(s):
                self.logger.info("%s: skipped %r: nothing to say (no letters or digits)", self._label(), s)
        for i, s in enumerate(said):
            if len(self._queue) >= self.config.max_queue_sentences:
                self.logger.warning("%s: %d sentences queued already; dropped %r", self._label(), len(self._queue), s)
                self.set_algorithm_failure("speech queue full: sentences dropped")
                break
            self._queue.append((s, ends and i == len(said) - 1, stream_id))
        if ends and not said and self._in_utterance:
            self._end_utterance()

    # --- speaking ---------------------------------------------------------------------------
    def _pump(self) -> None:
        """Speak the next sentence; come back for the one after it (actions get in between)."""
        self._pumping = False
        if not self._queue:
            return
        sentence, ends, stream_id = self._queue.popleft()
        self._speak(sentence, stream_id)
        if ends:
            self._end_utterance()
        if self._queue:
            self._pumping = True
            self.call_later(0.0, self._pump)

    def _speak(self, sentence: str, stream_id: str = "") -> None:
        options = {"speed": self.config.speed} if self.config.speed is not None else {}
        text = sentence  # on the sentence's first chunk: the Speaker tells which words were played
        try:
            for chunk in self.model_client.speak(sentence, **options):
                audio = chunk.get("audio")
                if isinstance(audio, np.ndarray) and audio.size:
                    if not self._in_utterance:
                        publish_stage(self, "tts_first_audio")
                    self._in_utterance = True
                    for t in self._audio_outputs:
                        self.publish(t, Audio(data=np.ascontiguousarray(audio, np.float32),
                                              sample_rate=int(chunk["sample_rate"]), stamp=time.time(), text=text,
                                              stream_id=stream_id))
                    text = ""
        except (ModelError, ModelUnavailable, ConnectionError, TimeoutError) as exc:
            self.logger.error("%s: could not speak %r: %s", self._label(), sentence, exc)
            self.set_algorithm_failure(f"speech failed: {exc}")
            return
        self.spoken += 1
        self.logger.info("%s: said %r", self._label(), sentence)

    def _end_utterance(self) -> None:
        self._in_utterance = False
        for t in self._audio_outputs:
            self.publish(t, Audio(data=np.zeros(0, np.float32), sample_rate=22050, stamp=time.time()))

    # --- actions ----------------------------------------------------------------------------
    def say(self, text: str) -> int:
        """Speak ``text`` now: what was queued is dropped and the utterance in progress ends. Returns its sentences."""
        if not isinstance(text, str):
            raise TypeError(f"say() takes the text to speak as a str, got {type(text).__name__}")
        self.stop_playback()
        self._enqueue_text(text)
        queued = len(self._queue)
        if queued and not self._pumping:
            self._pumping = True
            self.call_later(0.0, self._pump)
        return queued

    def stop_playback(self) -> int:
        """Stop speaking: drop the queued sentences (returned: how many) and end the utterance in progress."""
        dropped = len(self._queue)
        self._queue.clear()
        self._muted.update(self._streams)
        self._streams.clear()
        if self._in_utterance:
            self._end_utterance()
        if dropped:
            self.logger.info("%s: stopped; %d queued sentences dropped", self._label(), dropped)
        return dropped

