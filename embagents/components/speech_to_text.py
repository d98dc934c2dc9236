"""The SpeechToText component: the robot's ears. ``Audio`` in, the transcript (``String``) out.

Audio chunks (16 kHz mono; other rates and stereo are resampled, with a log
line) go through voice activity detection (Silero VAD on sherpa-onnx, in
this component's process: :class:`~embagents.components.vad.SpeechSegmenter`),
so the recognizer runs on utterances, not on silence. Each utterance goes to
the speech model's actor (:class:`~embagents.models.SpeechToTextModel` behind
a :class:`~embagents.models.LocalModelClient`: the samples cross through
shared memory), or to an OpenAI-compatible server
(:class:`~embagents.models.clients.openai_audio.OpenAITranscriptionClient`). The
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
from embagents.components.vad import SpeechOnset, SpeechSegmenter
from embagents.components.voice_stages import publish_stage
from embagents.config import (
    BaseComponentConfig,
    ConfigError,
    optional_positive_float,
    positive_float,
    positive_int,
    to_bool,
)
from embagents.models.protocol import ModelError, ModelUnavailable
from embagents.msgs import Audio, BargeIn, StreamingString, String, VoiceStage
from embagents.topic import Topic

__all__ = ["BACKCHANNELS", "SpeechToText", "SpeechToTextConfig", "is_backchannel", "strip_wake_phrase"]

#: What a listener says to show they follow, not to take the turn (Whisper's spellings included: tiny.en hears the
#: Piper voice's "Uh-huh, uh-huh." as "Uh", "ah", "ah ah ah ah"; its "Ah ha." as "Uh-huh."; "Hm." as "HM", "M";
#: "Aha, okay." as "ah ha okay"; a laugh as "Ha ha ha"). Compared word by word, lowercased, without punctuation
#: or hyphens (``"Mm-hmm."`` is ``mmhmm``).
BACKCHANNELS = ("mhm", "m", "mm", "hmm", "mmhmm", "mm-hmm", "uh-huh", "uh", "huh", "um", "hm", "ah", "oh", "yeah", "yes",
                "yep", "ok", "okay", "right", "all right", "sure", "alright", "i see", "got it", "aha", "ah-ha", "ha")

_WORD = re.compile(r"[\w']+")
#: A hum Whisper spells out in letters ("M-H-M.", "M H H", "Mmh"): no English word is made of m and h alone.
_HUM = re.compile(r"[mh]+", re.IGNORECASE)
_NOT_SPEECH = re.compile(r"\[[^\]]*\]?|\([^)]*\)?|\*[^*]*\*?")
_ECHO_TAIL_S = 0.25  # after the robot's last sound: its reverberation, a device's buffer


def _unit(value: object) -> float:
    out = positive_float(value)
    if not out < 1.0:
        raise ConfigError(f"a threshold (a probability) must be in (0, 1), got {value!r}")
    return out


def _optional_unit(value: object) -> float | None:
    return None if value is None or value == "" else _unit(value)


def _phrase(value: object) -> str | None:
    if value is None or value == "":
        return None
    if not isinstance(value, str) or not _WORD.search(value):
        raise ConfigError(f"wake_phrase must be a phrase of words (e.g. 'hey robot') or None, got {value!r}")
    return value


def _phrases(value: object) -> tuple[str, ...]:
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, (list, tuple)) or not all(isinstance(p, str) and _WORD.search(p) for p in items):
        raise ConfigError(f"backchannels must be a list of words or short phrases ('mhm', 'i see'), got {value!r}")
    return tuple(p.lower() for p in items)


def is_backchannel(text: str, backchannels: tuple[str, ...] = BACKCHANNELS) -> bool:
    """True when ``text`` says nothing but backchannels ("mhm", "yeah, okay") or nothing at all (a cough).

    >>> is_backchannel("Mm-hmm."), is_backchannel("Yeah, okay."), is_backchannel("Yeah, but stop.")
    (True, True, False)
    >>> is_backchannel("See."), is_backchannel("I see the cup.")
    (True, False)
    >>> is_backchannel(""), is_backchannel("[BLANK_AUDIO]"), is_backchannel("(coughs)")
    (True, True, True)
    >>> is_backchannel("M H H."), is_backchannel("Mmh, okay."), is_backchannel("Hm, move.")
    (True, True, False)
    """
    text = _NOT_SPEECH.sub(" ", text)  # Whisper's "[BLANK_AUDIO]", "(coughs)", "*sighs*": no words said
    # Word by word: the words of a backchannel phrase count alone too ("see" is "I see" misheard).
    known = {w.lower() for p in backchannels for w in _WORD.findall(p.replace("-", ""))}
    return all(w.lower() in known or _HUM.fullmatch(w) for w in _WORD.findall(text.replace("-", "")))


def _news(text: str, backchannels: tuple[str, ...]) -> int:
    """How many words of ``text`` are not backchannels (split as :func:`is_backchannel` splits them).

    >>> _news("M-H-M.", BACKCHANNELS), _news("M H H", BACKCHANNELS), _news("Uh-huh, stop.", BACKCHANNELS)
    (0, 0, 1)
    """
    # Hyphens out first: Whisper spells a hummed "mhm" "M-H-M.", which is one backchannel, not three words.
    return sum(not is_backchannel(w, backchannels) for w in _WORD.findall(_NOT_SPEECH.sub(" ", text).replace("-", "")))


def _optional_db(value: object) -> float | None:
    if value is None:
        return None
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        out = 1.0
    if isinstance(value, bool) or not -120.0 <= out <= 0.0:
        raise ConfigError(f"interrupt_level_db is a level in dBFS in [-120, 0] (e.g. -45) or None, got {value!r}")
    return out


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
    - ``playback_input``: the input topic that carries the Speaker's ``played``
      stream (what tells it the robot is speaking). With it and a ``BargeIn``
      output, barge-in is on: ``interrupt_onset_ms`` of speech while the robot
      speaks publishes ``pause`` (Silero's speech probability above
      ``interrupt_vad_threshold``: below the utterance threshold, as the echo
      canceller turns the start of speech over the robot's voice down, or
      twice as long at ``interrupt_level_db`` dBFS or above: the canceller
      leaves the robot's voice near the noise floor); once ``interrupt_min_speech_ms``
      of speech has ``interrupt_min_words`` words that are not ``backchannels``
      (mid-speech a short sound is often misheard), or an utterance that long
      ends with any such word, it publishes ``interrupt``; a backchannel or a noise (no words) publishes ``resume``, as does no decision
      within ``false_interruption_s``.
    - ``turn_silence_ms``: with a ``turn_model_client`` (an end-of-turn model,
      :class:`~embagents.models.TurnDetectorModel`), the pause after which it is
      asked whether the user has finished: yes ends the utterance there; no
      waits, and ``min_silence_ms`` (raise it, e.g. to 1000) stays the fallback
      and ``max_utterance_ms`` the hard maximum; ``turn_reask_ms``: after a no, ask
      again once the pause is this much longer (None: one verdict per pause, Pipecat's). ``turn_threshold``: the model's
      probability at or above which the turn is finished (0.5, Pipecat's; a
      higher one cuts fewer users off mid-sentence and leaves more turns to the
      silence fallback: see ``embagents bench --only turn_detection``).
    - ``text_turn_threshold``: with a ``text_turn_client`` (a chat model's actor,
      ``LocalModelClient(LlamaModel(name="turn_text"))``: LiveKit's text check), a
      turn the audio says is finished is finished only when the transcript's
      end-of-turn probability is at least this (4e-8: picked for the stock
      SmolLM2-135M-Instruct on 30 complete and 30 cut-off sentences that are not the
      bench's); below it the turn waits for more speech or the silence fallback.
    - ``turn_sure_threshold``: with both clients, a turn model probability at or
      above this ends the turn at once, without waiting for the transcript and the
      text check (the audio is sure); between ``turn_threshold`` and it the text
      check decides (None: it always does). The text check waits for Whisper's
      transcript (300-500 ms on 2 CPU cores): this puts the turns the audio is sure of
      at Smart Turn's speed (see ``embagents bench --only turn_detection``).
    - ``speculative_transcript``: with a turn model, start transcribing at the pause
      (in the speech model's actor, while the turn model decides): a turn that ends
      has its transcript already, one that goes on drops it. ``speculate_after_turn``:
      begin it only after the pause's first turn verdict, so the two do not share
      the CPU (the verdict sooner, the transcript later).

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
    playback_input: str | None = field(default=None, converter=_optional_path)
    interrupt_onset_ms: float = field(default=32.0, converter=positive_float)
    interrupt_vad_threshold: float = field(default=0.3, converter=_unit)
    interrupt_level_db: float | None = field(default=-45.0, converter=_optional_db)
    interrupt_min_speech_ms: float = field(default=500.0, converter=positive_float)
    interrupt_min_words: int = field(default=2, converter=positive_int)
    backchannels: tuple[str, ...] = field(default=BACKCHANNELS, converter=_phrases)
    false_interruption_s: float = field(default=2.0, converter=positive_float)
    turn_silence_ms: float = field(default=150.0, converter=positive_float)
    turn_threshold: float = field(default=0.5, converter=_unit)
    text_turn_threshold: float = field(default=4e-8, converter=_unit)
    turn_sure_threshold: float | None = field(default=None, converter=_optional_unit)
    turn_reask_ms: float | None = field(default=None, converter=optional_positive_float)
    speculative_transcript: bool = field(default=True, converter=to_bool)
    speculate_after_turn: bool = field(default=False, converter=to_bool)


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

    allowed_inputs = {"Required": [Audio], "Optional": [Audio]}  # the microphone; the Speaker's played stream
    allowed_outputs = {"Required": [String], "Optional": [StreamingString, BargeIn, VoiceStage]}
    config_class = SpeechToTextConfig
    client_methods = ("transcribe",)
    client_task = "transcribe"
    client_fix = "LocalModelClient(SpeechToTextModel(...)) or OpenAITranscriptionClient(url)"

    def __init__(self, *, name: str, turn_model_client: Any = None, text_turn_client: Any = None, **kw: Any) -> None:
        self.turn_client = turn_model_client  # an end-of-turn model (LocalModelClient(TurnDetectorModel(...)))
        self.text_turn_client = text_turn_client  # a chat model reading the transcript (LocalModelClient(LlamaModel))
        self._turn_vad: Any = None
        self._turn_due = 0.0  # the pause (ms) at which the turn model is asked next in this pause (inf: not again)
        # model: ended by the turn model(s); not_yet: the audio said the user goes on; text_not_yet: the audio said
        # finished, the transcript not.
        # sure: ended by the turn model alone at turn_sure_threshold, the text check not waited for.
        self.turns: dict[str, int] = {"model": 0, "silence": 0, "not_yet": 0, "text_not_yet": 0, "sure": 0}
        #: The text check's last probability that the user had finished (None: not asked yet).
        self.last_text_turn_probability: float | None = None
        self._spec: Any = None  # the pause's speech being transcribed (a PendingAnswer)
        self._spec_text: str | None = None  # its transcript, once taken
        self._spec_len = 0  # how many samples of the utterance it covers
        #: Transcripts begun at a pause: used for the turn, or dropped (the user went on).
        self.speculations: dict[str, int] = {"used": 0, "dropped": 0}
        #: The last turn's end-of-turn delay (s): end of speech -> the decision (``eou_delay``).
        self.last_eou_delay: float | None = None
        #: The last utterance's transcription delay (s): end of turn -> final transcript.
        self.last_transcription_delay: float | None = None
        self._turn_ended: float | None = None  # wall time the turn in progress was decided finished
        #: The turn model's last probability that the user had finished (None: not asked yet).
        self.last_turn_probability: float | None = None
        self._vad: Any = None
        self._wake_word: Any = None
        self._formats_seen: set[tuple[int, int]] = set()
        self._since_partial = 0  # samples since the last partial transcript
        self._utterances = 0
        self._awake_until = 0.0
        self._onset: Any = None  # barge-in's speech onset detector (None: barge-in off)
        self._played_until = 0.0  # wall time the robot's last played audio ends
        self._barge = ""  # "", "paused" (the robot held), "interrupted"
        self._barge_at = 0.0  # when the speech that paused it began
        self._last_voice = 0.0  # last window of speech (onset detector)
        self._checked_samples = 0  # the utterance's length at its last mid-speech check
        self.barge_ins: dict[str, int] = {"pause": 0, "resume": 0, "interrupt": 0}
        super().__init__(name=name, **kw)

    def default_trigger(self) -> Topic | None:
        return self.inputs[0] if self.inputs else None

    def validate(self) -> list[ComponentProblem]:
        problems = super().validate()
        if self.config.max_utterance_ms <= self.config.min_speech_ms:
            problems.append(("bad-config", f"{self._label()}: max_utterance_ms must be above min_speech_ms"))
        names = [t.name for t in self.inputs]
        playback = self.config.playback_input
        if playback is not None and playback not in names[1:]:
            problems.append(("bad-config", f"{self._label()}: playback_input {playback!r} is not one of its inputs "
                                           f"after the microphone ({', '.join(names[1:]) or 'none'}); add the "
                                           "Speaker's played topic to inputs"))
        if len(names) > 1 and playback is None:
            problems.append(("bad-config", f"{self._label()}: a second Audio input is the Speaker's played stream: "
                                           f"name it in playback_input (e.g. playback_input={names[1]!r})"))
        return problems

    def run_warmup(self) -> None:
        self.model_client.transcribe(np.zeros(1600, np.float32))

    # --- lifecycle --------------------------------------------------------------------------
    def on_configure(self) -> None:
        cfg = self.config
        if cfg.enable_vad:
            from embagents.models.files.speech import silero_vad_path  # lazy: a cycle

            self._vad = SpeechSegmenter(cfg.vad_model or silero_vad_path(), threshold=cfg.vad_threshold,
                                        min_silence_ms=cfg.min_silence_ms, min_speech_ms=cfg.min_speech_ms,
                                        max_utterance_ms=cfg.max_utterance_ms)
        if cfg.wake_word_model:
            self._wake_word = _load_wake_word(cfg.wake_word_model)
        for t in self.inputs:
            if t.keep != "all":  # a dropped chunk is a hole in a word
                self.logger.warning("%s: audio topic %r keeps only the latest messages: chunks may be dropped; "
                                    "declare it Topic(%r, Audio, keep='all')", self._label(), t.name, t.name)
        if (self.turn_client is not None or self.text_turn_client is not None) and self._vad is not None:
            from embagents.models.files.speech import silero_vad_path  # lazy: a cycle

            self._turn_vad = SpeechOnset(cfg.vad_model or silero_vad_path(), threshold=cfg.vad_threshold)
        if cfg.playback_input and self._barge_outputs and self._vad is not None:
            from embagents.models.files.speech import silero_vad_path  # lazy: a cycle

            self._onset = SpeechOnset(cfg.vad_model or silero_vad_path(), threshold=cfg.interrupt_vad_threshold,
                                      level_db=cfg.interrupt_level_db)
        super().on_configure()
        self.logger.info("%s: listening (VAD %s, wake phrase %r, barge-in %s, model client %s)", self._label(),
                         "on" if self._vad else "off", cfg.wake_phrase, "on" if self._onset else "off",
                         self.client_name)

    # --- steps ------------------------------------------------------------------------------
    @property
    def _partials(self) -> list[Topic]:
        return [t for t in self.outputs if t.msg_type is StreamingString]

    @property
    def _barge_outputs(self) -> list[Topic]:
        return [t for t in self.outputs if t.msg_type is BargeIn]

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if topic_name == self.config.playback_input and topic_name in self._subscribed:
            if isinstance(msg, Audio):  # what the robot plays: when it is speaking (an empty chunk: it stopped)
                if msg.data.size:
                    ends = msg.stamp + msg.data.size / max(1, msg.channels) / max(1, msg.sample_rate)
                    self._played_until = max(self._played_until, ends)
                else:
                    self._played_until = min(self._played_until, msg.stamp)
            return False
        return super().on_message(topic_name, msg, now)

    def _execution_step(self, **inputs: Any) -> None:
        topic = next((t for t in self.inputs if t.name in self.fresh_inputs and inputs.get(t.name) is not None
                      and t.name != self.config.playback_input), None)
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
            self.turns["silence"] += 1
            self.last_eou_delay = self.config.min_silence_ms / 1000
            self._turn_ended = time.time()
            self._finish(utterance)
        if self._turn_vad is not None:
            self._end_of_turn(samples)
        if self._onset is not None:
            self._barge_in(samples, msg.stamp or time.time())
        self._partial(samples)

    # --- end of turn -----------------------------------------------------------------------
    def _end_of_turn(self, samples: np.ndarray) -> None:
        """After ``turn_silence_ms`` of pause, ask the turn model (then the text check, on the transcript begun
        at the pause); a finished turn ends the utterance now."""

        vad = self._turn_vad
        vad.feed(samples)
        if vad.quiet == 0:
            self._turn_due = self.config.turn_silence_ms
            self._drop_speculation()  # the user goes on: what was said so far is not the turn
            return
        if not self._vad.speaking:
            return
        # speculate_after_turn: the pause's first turn verdict is not shared with the transcript's CPU
        first_verdict = self.turn_client is not None and self._turn_due <= self.config.turn_silence_ms
        if not (self.config.speculate_after_turn and first_verdict):
            self._speculate()
        pause_s = vad.quiet * vad.window / 16000
        if pause_s * 1000 < max(self._turn_due, self.config.turn_silence_ms):
            return
        self._turn_due = float("inf")  # one verdict per pause, unless a "not yet" is asked again
        began = time.monotonic()
        sure = False
        if self.turn_client is not None:
            try:
                verdict = self.turn_client.end_of_turn(self._vad.current())
            except (ModelError, ModelUnavailable, ConnectionError, TimeoutError) as exc:
                self.logger.warning("%s: the turn model did not answer (%s); silence ends the turn", self._label(), exc)
                return
            self._speculate()
            p = verdict.get("probability")
            self.last_turn_probability = None if p is None else float(p)
            if not (bool(verdict.get("complete")) if p is None else float(p) >= self.config.turn_threshold):
                self.turns["not_yet"] += 1
                if self.config.turn_reask_ms is not None:  # the probability rises as the pause grows: ask again
                    self._turn_due = pause_s * 1000 + self.config.turn_reask_ms
                return
            sure = p is not None and self.config.turn_sure_threshold is not None and (
                float(p) >= self.config.turn_sure_threshold)
        if sure and self.text_turn_client is not None:
            self.turns["sure"] += 1
        elif self.text_turn_client is not None and not self._text_says_finished():
            self.turns["text_not_yet"] += 1
            return
        self.turns["model"] += 1
        self.last_eou_delay = pause_s + time.monotonic() - began
        self._turn_ended = time.time()
        for utterance in self._vad.flush():
            self._finish(utterance)

    def _text_says_finished(self) -> bool:
        """The text check on the utterance's transcript (True when it cannot tell: no words, no answer)."""
        text = self._speculated()
        if text is None:  # nothing transcribed ahead (a client that cannot, or speculation off): now
            current = self._vad.current()
            text = self._transcribe(current)
            self._spec_text, self._spec_len = text, len(current)
        if not text or is_backchannel(text, ()):
            return True
        try:
            p = float(self.text_turn_client.end_of_turn_text(text)["probability"])
        except (ModelError, ModelUnavailable, ConnectionError, TimeoutError) as exc:
            self.logger.warning("%s: the text turn check did not answer (%s); the audio's verdict stands",
                                self._label(), exc)
            return True
        self.last_text_turn_probability = p
        if p >= self.config.text_turn_threshold:
            return True
        self.logger.info("%s: %r does not end a sentence (p %.1e): waiting for more", self._label(), text, p)
        return False

    # --- the transcript begun at the pause ---------------------------------------------------
    def _speculate(self) -> None:
        """Start transcribing the utterance so far (once per pause), when the speech model's client can answer later."""
        if (self._spec is not None or self._spec_text is not None or not self.config.speculative_transcript
                or not callable(getattr(self.model_client, "submit", None))):
            return
        current = self._vad.current()
        try:
            self._spec = self.model_client.submit("transcribe", {"audio": current})
        except (ModelError, ModelUnavailable, ConnectionError, TimeoutError) as exc:
            self.logger.warning("%s: could not start transcribing at the pause (%s)", self._label(), exc)
            return
        self._spec_len = len(current)

    def _speculated(self) -> str | None:
        """The transcript begun at the pause (waited for); None when there is none or it failed."""
        spec, self._spec = self._spec, None
        if spec is not None:
            try:
                self._spec_text = str(spec.result().get("text", "")).strip()
            except (ModelError, ModelUnavailable, ConnectionError, TimeoutError) as exc:
                self.logger.warning("%s: the transcript begun at the pause failed (%s)", self._label(), exc)
        return self._spec_text

    def _drop_speculation(self) -> None:
        if self._spec is not None:
            self._spec.cancel()
        if self._spec is not None or self._spec_text is not None:
            self.speculations["dropped"] += 1
        self._spec, self._spec_text = None, None

    def _take_speculation(self, utterance: np.ndarray) -> str | None:
        """The transcript begun at the pause when ``utterance`` is what it transcribed plus the pause; else None."""
        text = self._speculated() if len(utterance) >= self._spec_len > 0 else None
        if text is not None:
            self.speculations["used"] += 1
            self._spec_text = None
        self._drop_speculation()
        self._spec_len = 0
        return text

    # --- barge-in ---------------------------------------------------------------------------
    def _barge_publish(self, action: str, text: str = "") -> None:
        self.barge_ins[action] += 1
        self.logger.info("%s: barge-in: %s%s", self._label(), action, f" ({text!r})" if text else "")
        for t in self._barge_outputs:
            self.publish(t, BargeIn(action=action, text=text, stamp=self._barge_at))

    def _barge_in(self, samples: np.ndarray, now: float) -> None:
        """Speech while the robot speaks: pause it at once, then decide (see SpeechToTextConfig).

        ``now``: when the chunk's last sample was heard (its stamp): decisions go by the audio's time.
        """
        cfg = self.config
        run = self._onset.feed(samples)
        if run or self._onset.loud:
            self._last_voice = now
        if self._barge == "":
            # The robot is speaking: its sound is still playing, or ended so lately that its echo is about.
            speaking = now < self._played_until + _ECHO_TAIL_S
            # Speech, or sound well above the cancelled echo's floor for twice as long (a voice, a cough: the
            # decision below tells them apart).
            windows = max(run, self._onset.loud // 2)
            if windows * self._onset.window * 1000 >= cfg.interrupt_onset_ms * 16000 and speaking:
                self._barge = "paused"
                self._barge_at = now - windows * self._onset.window / 16000  # when the speech began
                self._checked_samples = 0
                self._barge_publish("pause")
            return
        if self._barge != "paused":
            return
        if self._vad.speaking:
            current = self._vad.current()
            grown = len(current) - self._checked_samples
            if len(current) * 1000 >= cfg.interrupt_min_speech_ms * 16000 and grown * 1000 >= 300 * 16000:
                self._checked_samples = len(current)
                text = self._transcribe(current)
                # Mid-speech, a word or two of a short sound is often misheard ("okay" as "and"): it takes
                # interrupt_min_words that are not backchannels; the utterance's end decides on any word.
                if text and _news(text, cfg.backchannels) >= cfg.interrupt_min_words:
                    self._barge = "interrupted"
                    self._barge_publish("interrupt", text)
        elif now - self._last_voice > cfg.min_silence_ms / 1000 or now - self._barge_at > cfg.false_interruption_s:
            self._barge = ""  # a noise too short to be an utterance, or no decision in time: play on
            self._barge_publish("resume")

    def _barge_heard(self, text: str, seconds: float) -> bool:
        """An utterance ended while barge-in holds the robot: True when it is passed on as a question.

        A short one (under interrupt_min_speech_ms) takes interrupt_min_words, as a partial does.
        """
        cfg = self.config
        if self._barge == "paused":
            self._barge = ""
            short = seconds * 1000 < cfg.interrupt_min_speech_ms
            if _news(text, cfg.backchannels) < (cfg.interrupt_min_words if short else 1):
                self._barge_publish("resume", text)
                return False
            self._barge_publish("interrupt", text)
        elif self._barge == "interrupted":
            self._barge = ""
        return True

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
        self._speculated()  # an answer is read only by the request waiting for it: take the pause's first
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
        began = time.monotonic()
        text = self._take_speculation(utterance)
        if text is None:
            text = self._transcribe(utterance)
        self.last_transcription_delay = time.monotonic() - began
        if text is None:
            return
        stream_id = self._stream_id()
        self._utterances += 1
        if not self._barge_heard(text, len(utterance) / 16000):
            self.logger.info("%s: %r was a backchannel or a noise: the robot speaks on", self._label(), text)
            return
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
            self._publish_stages()

    def _publish_stages(self) -> None:
        """The turn's stages on the VoiceStage outputs: end of speech, end of turn (its decision), transcript."""
        now = time.time()
        ended = self._turn_ended if self._turn_ended is not None else now - (self.last_transcription_delay or 0.0)
        self._turn_ended = None
        publish_stage(self, "end_of_speech", ended - (self.last_eou_delay or 0.0))
        publish_stage(self, "end_of_turn", ended)
        publish_stage(self, "transcript", now)

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
    def stats(self) -> dict[str, Any]:
        """The last turn's stage times (LiveKit's names, in ms) and counts (``embagents call ears stats``).

        ``eou_delay``: end of speech -> end-of-turn decision (the model's, or the silence's);
        ``transcription_delay``: that decision -> the final transcript; ``turn_probability``: the turn
        model's last answer (how likely the user had finished); ``text_turn_probability``: the text
        check's; ``turns``: how turns ended (``model``, ``silence``; ``not_yet``: the audio model said the
        user goes on; ``text_not_yet``: the audio said finished, the transcript not; ``sure``: the audio was
        sure, at ``turn_sure_threshold``, and the text check was not waited for); ``speculations``:
        transcripts begun at a pause, ``used`` for the turn or ``dropped``; ``barge_ins``: pauses,
        resumes and interruptions published.
        """
        def ms(s: float | None) -> float | None:
            return None if s is None else round(s * 1000, 1)

        return {"eou_delay": ms(self.last_eou_delay), "transcription_delay": ms(self.last_transcription_delay),
                "turn_probability": self.last_turn_probability,
                "text_turn_probability": self.last_text_turn_probability, "utterances": self._utterances,
                "turns": dict(self.turns),
                "speculations": dict(self.speculations), "barge_ins": dict(self.barge_ins)}

    def flush(self) -> int:
        """Transcribe the utterance in progress now (the end of a stream); returns how many ended."""
        if self._vad is None:
            return 0
        ended = self._vad.flush()
        for utterance in ended:
            self.last_eou_delay, self._turn_ended = 0.0, time.time()  # the stream's end ends the turn, now
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
