"""Microphone and Speaker: each owns a sound device (PortAudio, through ``sounddevice``) in its own process.

``Microphone`` publishes what a capture device hears as ``Audio`` chunks of
``chunk_ms`` (int16 by default, ``sample_rate`` Hz, ``channels``
interleaved). It runs at its trigger rate (default ``1000 / chunk_ms`` Hz)
and each step takes every whole chunk the device has buffered: no busy
wait, nothing dropped while a step is late by less than ``buffer_ms``.

``Speaker`` plays the ``Audio`` it receives (int16 or float32, any rate and
channels: converted to the device's with :func:`~embagents.components.audio_format.to_pcm16`,
logged once per format). An empty ``Audio`` ends an utterance, as
TextToSpeech sends it. It writes only what the device has room for and comes
back when there is room again, so an idle speaker (its stream stopped once
the last audio has played) costs nothing; the ``stop_playback()`` action
drops what is queued and silences the device at once.

``device`` is a PortAudio device index, a substring of its name (``"USB"``,
``"pulse"``), or ``None`` for the system's default; ``python -m sounddevice``
lists them. A device that is missing or busy, PortAudio's library that is
not installed, or a stream that fails mid-way is reported on health as
SYSTEM_FAILURE naming the device and the fix, and tried again with
exponential backoff (``retry_s`` doubling up to ``retry_max_s``, PortAudio's
device list read anew each time, so a device plugged in later is found);
the process and the system keep running.

Example::

    >>> from embagents.msgs import Audio, BargeIn, VoiceStage
    >>> from embagents.topic import Topic
    >>> mic = Microphone(name="mic", outputs=[Topic("mic", Audio, keep="all")],
    ...                  config=MicrophoneConfig(device="USB", chunk_ms=50))
    >>> mic.rate_hz, mic.config.sample_rate, mic.config.dtype
    (20.0, 16000, 'int16')
    >>> Speaker(name="speaker", inputs=[Topic("said", Audio, keep="all")]).config.buffer_ms
    200.0
"""

from __future__ import annotations

import collections
import time
from types import ModuleType
from typing import Any

import numpy as np
from attrs import define, field

from embagents.components.audio_format import AudioFormatError, to_pcm16
from embagents.components.audio_io import AudioSink, non_negative_float
from embagents.components.component import Component
from embagents.components.device_retry import DeviceRetry
from embagents.components.echo_cancel import EchoCancelling
from embagents.components.voice_stages import publish_stage
from embagents.config import (
    BaseComponentConfig,
    ConfigError,
    int_at_least,
    one_of,
    positive_float,
    positive_int,
    to_bool,
)
from embagents.msgs import Audio, BargeIn, StreamingString, VoiceStage

__all__ = ["Microphone", "MicrophoneConfig", "PacedOutput", "Speaker", "SpeakerConfig", "input_device_present"]

LIST_HINT = ("list the devices with `python -m sounddevice` (ALSA's own view: `arecord -l`, `aplay -l`); "
             "check it is plugged in and that the user is in group 'audio' (`sudo usermod -aG audio $USER`, "
             "then log in again)")
BUSY_HINT = ("another program holds it (`fuser -v /dev/snd/*` names it): close that program, or use a device "
             "that mixes ('default', 'pulse' or 'pipewire')")
# PortAudio's error codes (portaudio.h) that say what to fix.
_PA_INVALID_CHANNELS, _PA_INVALID_RATE, _PA_DEVICE_UNAVAILABLE = -9998, -9997, -9985


class DeviceUnavailable(Exception):
    """A sound device cannot be used now; the message says what is wrong and how to fix it."""


class PacedOutput:
    """A speaker with no sound device (``SpeakerConfig(simulated=True)``): an output stream that plays into
    nothing at the pace a device would, so that what the Speaker publishes as played is stamped as a
    real one's (offline demos and tests of echo cancellation and barge-in; examples/voice.py).

    What is written is "heard" from when the frames before it have been (or, when it ran dry, after its
    ``latency``, as the Speaker stamps it); it takes up to twice ``latency`` ahead of the wall clock, as a
    device's buffer does. The Speaker uses it as it uses a ``sounddevice.OutputStream``.

    >>> out = PacedOutput(16000, 1, 0.2)
    >>> out.start(); out.write_available
    6400
    >>> out.write(np.zeros(1600, np.int16))  # heard from 0.2 s on, until 0.3 s: 0.1 s more fits
    >>> 1600 <= out.write_available < 1700
    True
    """

    class PortAudioError(Exception):
        """Never raised: there is no device to fail (the Speaker catches this type of its backend)."""

    def __init__(self, samplerate: int, channels: int, latency: float) -> None:
        self.samplerate, self.channels, self.latency = samplerate, channels, latency
        self.active = False
        self._end = 0.0  # wall time the last frame written is heard

    @property
    def write_available(self) -> int:
        ahead = max(0.0, self._end - time.time())
        return max(0, int((2 * self.latency - ahead) * self.samplerate))

    def write(self, frames: np.ndarray) -> None:
        now = time.time()
        start = self._end if self._end >= now else now + self.latency
        self._end = start + len(frames) / self.samplerate

    def start(self) -> None:
        self.active = True

    def stop(self) -> None:
        self.active = False  # a device plays out what it holds before stopping: the Speaker stops once it has

    def abort(self) -> None:
        self.active, self._end = False, 0.0  # what it held is not heard

    def close(self) -> None:
        self.abort()


def portaudio() -> ModuleType:
    """The ``sounddevice`` module, or :class:`DeviceUnavailable` naming the install that is missing."""
    try:
        import sounddevice
    except ModuleNotFoundError:
        raise DeviceUnavailable("the sounddevice package is not installed; `pip install sounddevice` "
                                "(it is in embagents' speech extra)") from None
    except OSError as exc:  # sounddevice found no libportaudio.so
        raise DeviceUnavailable(f"PortAudio's library is missing ({exc}); install it: "
                                "`sudo apt install libportaudio2` (Debian, Ubuntu), `dnf install portaudio`") from None
    return sounddevice


def _rescan(sd: ModuleType) -> None:
    """Read PortAudio's device list anew (it is read once, at initialisation): finds devices added since.

    sounddevice has no public call for it; its own ``_terminate``/``_initialize`` pair is the known way.
    Only called while this component holds no stream (PortAudio's terminate closes them all).
    """
    while sd._initialized > 0:
        sd._terminate()
    sd._initialize()


def input_device_present(device: int | str | None = None) -> bool:
    """True when PortAudio finds an input device (``device``, or the default one); never raises.

    PortAudio is shut again afterwards, so a process that forks components after asking starts them clean.
    """
    try:
        sd = portaudio()
        _rescan(sd)
        try:
            return bool(sd.query_devices(device, "input")["max_input_channels"] > 0)
        finally:
            while sd._initialized > 0:
                sd._terminate()
    except Exception:  # no library, no device, no default: not present
        return False


def _seconds(chunks: list[Audio]) -> float:
    return sum(m.data.size / max(1, m.channels) / max(1, m.sample_rate) for m in chunks)


def _device(value: object) -> int | str | None:
    if value is None or (isinstance(value, int) and not isinstance(value, bool) and value >= 0):
        return value
    if isinstance(value, str) and value.strip():
        return int(value) if value.strip().isdigit() else value
    raise ConfigError(f"device is a PortAudio device index (0), part of its name ('USB'), or None for the "
                      f"default; got {value!r} (`python -m sounddevice` lists them)")


def _optional_int(value: object) -> int | None:
    return None if value is None else int_at_least(1)(value)


@define(kw_only=True)
class _DeviceConfig(BaseComponentConfig):
    device: int | str | None = field(default=None, converter=_device)
    retry_s: float = field(default=0.5, converter=positive_float)
    retry_max_s: float = field(default=10.0, converter=positive_float)


def _dtype(value: object) -> str:
    return one_of("dtype", "int16", "float32")(value)


@define(kw_only=True)
class MicrophoneConfig(_DeviceConfig):
    """Settings of :class:`Microphone`; ``buffer_ms``: audio the device holds between two steps.

    >>> MicrophoneConfig(device="2").device
    2
    """

    sample_rate: int = field(default=16000, converter=positive_int)
    channels: int = field(default=1, converter=positive_int)
    chunk_ms: float = field(default=100.0, converter=positive_float)
    dtype: str = field(default="int16", converter=_dtype)
    buffer_ms: float = field(default=500.0, converter=positive_float)
    echo_cancellation: bool = field(default=True, converter=to_bool)
    echo_delay_ms: float = field(default=0.0, converter=non_negative_float)
    noise_suppression: bool = field(default=False, converter=to_bool)


@define(kw_only=True)
class SpeakerConfig(_DeviceConfig):
    """Settings of :class:`Speaker`; ``sample_rate`` / ``channels`` ``None``: the device's own (at most 2 channels).

    ``simulated``: no sound device, nor PortAudio: it plays into nothing in real time (:class:`PacedOutput`;
    16 kHz mono unless ``sample_rate`` / ``channels`` say otherwise), publishing what it plays as a device would.

    >>> SpeakerConfig(sample_rate=48000).channels is None
    True
    """

    sample_rate: int | None = field(default=None, converter=_optional_int)
    channels: int | None = field(default=None, converter=_optional_int)
    buffer_ms: float = field(default=200.0, converter=positive_float)
    simulated: bool = field(default=False, converter=to_bool)


class _SoundDevice(Component):
    """What a microphone and a speaker share: open the stream, report and retry a device that fails."""

    kind = "input"  # PortAudio's word for the direction

    def __init__(self, *, name: str, **kw: Any) -> None:
        self._sd: Any = None
        self._stream: Any = None
        self._retry = DeviceRetry()
        self._reported = ""
        super().__init__(name=name, **kw)

    def _describe(self) -> str:
        what = "microphone" if self.kind == "input" else "speaker"
        device = self.config.device
        if getattr(self.config, "simulated", False):
            return f"the simulated {what}"
        return f"the default {what}" if device is None else f"{what} {device!r}"

    def _make_stream(self, sd: ModuleType) -> Any:
        raise NotImplementedError

    def _open(self) -> bool:
        """Open and start the stream; False (reported, retry scheduled) when it cannot be had."""
        sd: Any
        try:
            if getattr(self.config, "simulated", False):  # a Speaker with no device (SpeakerConfig.simulated)
                sd = self._sd = PacedOutput  # stands for the module where the Speaker looks: PortAudioError
            else:
                sd = self._sd = portaudio()
                _rescan(sd)
            stream = self._make_stream(sd)
        except DeviceUnavailable as exc:
            self._lost(str(exc))
            return False
        except ValueError as exc:  # sounddevice: no device of that name or index
            self._lost(f"is not there ({exc}); {LIST_HINT}")
            return False
        except Exception as exc:  # sounddevice.PortAudioError: cannot be opened
            self._lost(self._open_error(exc))
            return False
        self._stream = stream
        self._retry.opened()
        self._reported = ""
        self.logger.info("%s: opened %s: %s", self._label(), self._describe(), self._format())
        self.set_healthy()
        return True

    def _open_error(self, exc: Exception) -> str:
        code = exc.args[1] if len(exc.args) > 1 else None
        if code == _PA_DEVICE_UNAVAILABLE or "busy" in str(exc).lower():
            return f"is busy or unavailable ({exc}); {BUSY_HINT}"
        if code in (_PA_INVALID_RATE, _PA_INVALID_CHANNELS):
            return (f"does not take this format ({exc}); set sample_rate and channels to what it takes "
                    "(`python -m sounddevice` shows its default rate and channels), or use the 'default', "
                    "'pulse' or 'pipewire' device, which convert")
        if "querying device -1" in str(exc):
            return f"is not there: PortAudio has no default {self.kind} device; {LIST_HINT}"
        return f"cannot be opened ({exc}); {LIST_HINT}"

    def _format(self) -> str:
        return ""

    def _lost(self, what: str) -> None:
        """Report ``what`` (with its fix) as SYSTEM_FAILURE and wait before trying again."""
        self._close(abort=True)
        delay = self._retry.failed(self.config.retry_s, self.config.retry_max_s)
        if what != self._reported:  # the log says each new problem once; health says it every time
            self._reported = what
            self.logger.warning("%s: %s %s; retrying with backoff", self._label(), self._describe(), what)
        self.set_system_failure(f"{self._describe()} {what}; retrying in {delay:.1f} s")

    def _close(self, abort: bool = False) -> None:
        stream, self._stream = self._stream, None
        if stream is not None:
            try:
                stream.abort() if abort else stream.stop()
                stream.close()
            except Exception:  # a stream whose device is gone may fail to close: it is dropped all the same
                self.logger.debug("%s: closing the stream failed", self._label(), exc_info=True)

    def on_reconfigure(self, old_config: Any) -> None:
        # Another device or format: close this one and try the new one at the next chance, without waiting.
        device_fields = ("device", "sample_rate", "channels", "dtype", "buffer_ms")
        if any(getattr(old_config, f, None) != getattr(self.config, f, None) for f in device_fields):
            self._close()
            self._retry.opened()
            self._reported = ""
            self._reopen()

    def _reopen(self) -> None:
        """After a reconfigure: a microphone opens at its next step; a speaker opens at once (see Speaker)."""

    def on_deactivate(self) -> None:
        self._close()

    def on_shutdown(self) -> None:
        self._close()


class Microphone(EchoCancelling, _SoundDevice):
    """Publishes what a capture device hears as ``Audio`` chunks (see the module docstring).

    Its optional input is the Speaker's ``played`` stream: wired, the echo of
    what the robot says is cancelled before anything is published (see
    :mod:`~embagents.components.echo_cancel`; ``echo_cancellation``,
    ``echo_delay_ms``, ``noise_suppression`` in its config).
    """

    allowed_inputs = {"Optional": [Audio]}
    allowed_outputs = {"Required": [Audio]}
    config_class = MicrophoneConfig
    kind = "input"

    def __init__(self, *, name: str, **kw: Any) -> None:
        self.chunks = 0
        self.overflows = 0
        self._overflows_said = 0
        super().__init__(name=name, **kw)

    def default_trigger(self) -> float:
        return 1000.0 / self.config.chunk_ms

    def on_configure(self) -> None:
        self._aec_setup(self.config.sample_rate, self.config.channels)
        super().on_configure()

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if topic_name in self._subscribed:
            self._aec_reference(topic_name, msg)  # at once, every chunk: not only the latest at a step
        return super().on_message(topic_name, msg, now)

    @property
    def _frames(self) -> int:
        return max(1, round(self.config.sample_rate * self.config.chunk_ms / 1000))

    def _make_stream(self, sd: ModuleType) -> Any:
        c = self.config
        # Blocking mode: the device buffers between steps and a step reads what is there (no callback thread).
        stream = sd.InputStream(device=c.device, samplerate=c.sample_rate, channels=c.channels, dtype=c.dtype,
                                latency=c.buffer_ms / 1000)
        stream.start()
        return stream

    def _format(self) -> str:
        c = self.config
        return f"{c.sample_rate} Hz, {c.channels} channel(s), {c.dtype}, chunks of {c.chunk_ms:g} ms"

    def _execution_step(self, **inputs: Any) -> None:
        if self._stream is None and (self._retry.waiting() or not self._open()):
            self._health_set_in_step = True  # the failure stands between retries
            return
        c, frames = self.config, self._frames
        try:
            available = self._stream.read_available
            chunks = []
            for _ in range(available // frames):
                data, overflowed = self._stream.read(frames)
                self.overflows += bool(overflowed)
                chunks.append(data)
        except self._sd.PortAudioError as exc:
            self._end_of_stream()
            self._lost(f"stopped giving audio ({exc}); {LIST_HINT}")
            return
        if self.overflows and self.overflows != self._overflows_said:
            self._overflows_said = self.overflows  # a step late by more than buffer_ms: audio was lost
            self.logger.warning("%s: the device's buffer overflowed (%d times so far): audio was lost; raise "
                                "buffer_ms (now %g) or give this process more CPU", self._label(), self.overflows,
                                c.buffer_ms)
        now = time.time()
        for i, data in enumerate(chunks):
            ends = now - (available - (i + 1) * frames) / c.sample_rate  # when this chunk's last sample was heard
            samples = self._aec_process(np.ascontiguousarray(data).reshape(-1), ends)
            msg = Audio(data=samples, sample_rate=c.sample_rate, channels=c.channels, stamp=ends)
            for t in self.outputs:
                self.publish(t, msg)
            self.chunks += 1

    def stats(self) -> dict[str, float]:
        """Chunks published and reads that found the device's buffer overflowed (``embagents call mic stats``)."""
        return {"chunks": self.chunks, "overflows": self.overflows, "open": self._stream is not None}

    def _end_of_stream(self) -> None:
        # An empty Audio: a listener (SpeechToText) transcribes what it holds instead of waiting for silence.
        if self.chunks:
            for t in self.outputs:
                self.publish(t, Audio(data=np.zeros(0, self.config.dtype), sample_rate=self.config.sample_rate,
                                      channels=self.config.channels))


@define
class _Sentence:
    """A sentence the Speaker was given (``Audio.text``), on its timeline of frames queued: its words, told or not."""

    stream_id: str
    words: list[str]
    start: int  # the frame it begins at, counted over all the audio queued
    end: int
    told: int = 0  # words published as played
    closed: bool = False  # nothing more of it comes: the next sentence, other audio or the utterance's end came
    last: bool = False  # the utterance ended after it


class Speaker(_SoundDevice, AudioSink):
    """Plays the ``Audio`` it receives on an output device (see the module docstring).

    Its optional ``Audio`` output is what it plays (the echo reference of a
    Microphone, and what tells SpeechToText the robot is speaking): int16 at the
    device's rate and channels, each chunk stamped with the wall time its first
    sample leaves the speaker; an empty chunk stamped ``t`` says nothing plays from ``t`` on
    (after :meth:`pause` or :meth:`stop_playback`).

    Its optional ``StreamingString`` output is what has been said aloud: the words of the audio it
    got with a ``text`` (TextToSpeech's sentences), published as they are heard (the audio's
    share of its sentence spread evenly over the words), with the ``stream_id`` of the text they
    were made from, and ``done`` once that utterance has played to its end or was cut short (a
    :meth:`stop_playback`, a barge-in). Words still in the device's buffer at a :meth:`pause` are
    not heard: they come when it resumes. Wired into the LLM, an answer cut short is kept in its
    chat history as the words the user heard.

    Its optional ``BargeIn`` input (SpeechToText's) acts at once, between two
    writes: ``pause`` -> :meth:`pause`, ``resume`` -> :meth:`resume`,
    ``interrupt`` -> :meth:`stop_playback`, and what still comes of the utterance in progress (a sentence the
    voice was making) is dropped up to its end.
    """

    allowed_inputs = {"Required": [Audio], "Optional": [BargeIn]}
    allowed_outputs = {"Optional": [Audio, VoiceStage, StreamingString]}
    config_class = SpeakerConfig
    kind = "output"

    def __init__(self, *, name: str, **kw: Any) -> None:
        self._queue: collections.deque[np.ndarray | None] = collections.deque()  # None: an utterance ends
        self._rate = self._channels = 0
        self._notes: set[str] = set()
        self._pump_due = False
        self._last_write = 0.0
        self._play_clock = 0.0  # wall time the device will be done with what it was given
        self._recent: collections.deque[np.ndarray] = collections.deque()  # written lately: re-queued by pause()
        self._paused = False
        self._started = False  # the utterance in progress has reached the device (its speaker_start is out)
        self._receiving = False  # audio of an utterance has come whose end (an empty Audio) has not
        self._drop_rest = False  # stopped mid-utterance: what comes of it until its end is not played
        # The words played (the StreamingString output): frames of audio queued and given to the device, counted
        # over the speaker's life (a pause takes back what the device had not played), and the sentences in them.
        self._fed = self._given = 0
        self._dry_at = 0  # frames given when the device last ran dry: what it holds after that is audio
        self._sentences: collections.deque[_Sentence] = collections.deque()
        self._told_stream = ""  # the stream whose words were told last (the next of its words: after a space)
        self.played_s = 0.0
        self.dropped_s = 0.0
        self.utterances = 0
        super().__init__(name=name, **kw)

    def on_activate(self) -> None:
        self._open()  # health says at once whether the speaker is there, before anything is said

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if isinstance(msg, BargeIn) and topic_name in self._subscribed:
            act = {"pause": self.pause, "resume": self.resume, "interrupt": self._interrupted}.get(msg.action)
            if act is None:
                self.logger.warning("%s: BargeIn action %r ignored; it is pause, resume or interrupt",
                                    self._label(), msg.action)
            else:
                act()
            return False
        return super().on_message(topic_name, msg, now)

    def _make_stream(self, sd: ModuleType) -> Any:
        c = self.config
        if c.simulated:
            self._rate, self._channels = c.sample_rate or 16000, c.channels or 1
            return PacedOutput(self._rate, self._channels, c.buffer_ms / 1000)
        info = sd.query_devices(c.device, "output")
        self._rate = c.sample_rate or int(info["default_samplerate"])
        self._channels = c.channels or min(2, int(info["max_output_channels"]))
        # Opened, not started: a stopped stream costs nothing; it starts when there is audio to play.
        return sd.OutputStream(device=c.device, samplerate=self._rate, channels=self._channels, dtype="int16",
                               latency=c.buffer_ms / 1000)

    def _format(self) -> str:
        return f"{self._rate} Hz, {self._channels} channel(s), int16"

    def _reopen(self) -> None:
        self._drop(self._queue_s(), "the speaker was reconfigured")
        self._open()

    def stats(self) -> dict[str, float]:
        """Seconds played, dropped and queued, and utterances ended (``embagents call speaker stats``)."""
        return {"played_s": self.played_s, "dropped_s": self.dropped_s, "queued_s": self._queue_s(),
                "utterances": self.utterances, "open": self._stream is not None}

    def _lost(self, what: str) -> None:
        super()._lost(what)
        self._drop(self._queue_s(), "the speaker is not there")
        self._later(self._retry.wait_s())  # try again even when nothing more is sent

    def _execution_step(self, **inputs: Any) -> None:
        received = self.take()
        if self._stream is None and (self._retry.waiting() or not self._open()):
            self._drop(_seconds(received), "the speaker is not there")
            self._health_set_in_step = True
            return
        for msg in received:
            if msg.data.size == 0:
                self._receiving = False
                if self._drop_rest:  # the end of the utterance stop_playback() cut: the next one plays
                    self._drop_rest = False
                else:
                    self._queue.append(None)
                    if self._sentences and not self._sentences[-1].closed:
                        self._sentences[-1].closed = self._sentences[-1].last = True
                continue
            self._receiving = True
            if self._drop_rest:
                self.dropped_s += _seconds([msg])  # made before the voice heard the stop (a sentence in progress)
                continue
            try:
                frames, note = to_pcm16(msg, self._rate, self._channels)
            except AudioFormatError as exc:
                self.logger.error("%s: skipped Audio: %s", self._label(), exc)
                self.set_algorithm_failure(f"skipped Audio: {exc}")
                continue
            if note and note not in self._notes:
                self._notes.add(note)
                self.logger.info("%s: %s", self._label(), note)
            self._queue.append(frames)
            self._queued_words(msg, len(frames))
        self._pump()

    def _queued_words(self, msg: Audio, frames: int) -> None:
        """Keep which frames ``msg``'s words (``Audio.text``, its ``stream_id``) are, to tell them once played."""
        last = self._sentences[-1] if self._sentences else None
        if msg.text and self._text_outputs:
            if last is not None:
                last.closed = True
            self._sentences.append(_Sentence(msg.stream_id, msg.text.split(), self._fed, self._fed + frames))
        elif last is not None and not last.closed and msg.stream_id == last.stream_id and last.end == self._fed:
            last.end += frames  # the sentence goes on in this chunk
        elif last is not None:
            last.closed = True
        self._fed += frames

    @property
    def _text_outputs(self) -> list[Any]:
        return [t for t in self.outputs if t.msg_type is StreamingString]

    def _unheard(self, now: float) -> int:
        """Frames given to the device that it has not played by ``now`` (not the silence before them)."""
        ahead = max(0.0, self._play_clock - now) if self._play_clock else 0.0
        return min(int(ahead * self._rate), self._given - self._dry_at)

    def _tell_words(self, cut: bool = False) -> None:
        """Publish the words heard since the last call; ``cut``: the rest is not played (``done``)."""
        if not self._sentences:
            return
        heard = self._given - self._unheard(time.time())
        ended: list[str] = []
        while self._sentences:
            s = self._sentences[0]
            share = (heard - s.start) / max(1, s.end - s.start)
            k = len(s.words) if heard >= s.end and s.closed else min(len(s.words), max(0, round(len(s.words) * share)))
            if k > s.told:
                space = " " if s.told or self._told_stream == s.stream_id else ""
                words = space + " ".join(s.words[s.told:k])
                s.told, self._told_stream = k, s.stream_id
                for t in self._text_outputs:
                    self.publish(t, StreamingString(data=words, done=False, stream_id=s.stream_id))
            if not cut and (s.told < len(s.words) or not s.closed):
                break
            self._sentences.popleft()
            if (cut or s.last) and s.stream_id not in ended:
                ended.append(s.stream_id)
        for stream_id in ended:
            self._told_stream = ""
            for t in self._text_outputs:
                self.publish(t, StreamingString(data="", done=True, stream_id=stream_id))

    def _pump(self) -> None:
        """Write what the device has room for; come back when it has room again, or to stop it once played."""
        self._pump_due = False
        if self._paused:
            return  # resume() pumps again
        if self._stream is None:
            if self._retry.waiting():
                self._later(self._retry.wait_s())
                return
            if not self._open():
                return  # reported; _lost scheduled the next try
        stream = self._stream
        try:
            while self._queue and self._queue[0] is None:
                self._queue.popleft()
                self.utterances += 1
                self._started = False
            if self._queue:
                if not stream.active:
                    stream.start()
                room = stream.write_available
                while room > 0 and self._queue:
                    frames = self._queue[0]
                    if frames is None:
                        self._queue.popleft()
                        self.utterances += 1
                        self._started = False
                        continue
                    n = min(room, len(frames))
                    stream.write(frames[:n])  # never blocks: there is room for n frames
                    self._played(frames[:n], stream)
                    room -= n
                    self.played_s += n / self._rate
                    self._last_write = time.monotonic()
                    if n == len(frames):
                        self._queue.popleft()
                    else:
                        self._queue[0] = frames[n:]
            self._tell_words()
            buffered_s = self.config.buffer_ms / 1000
            if self._queue:
                self._later(buffered_s / 2)
            elif stream.active:
                played_out = self._last_write + buffered_s + 0.05
                if time.monotonic() >= played_out:
                    stream.stop()  # all of it has played: an idle stream costs nothing
                else:
                    self._later(played_out - time.monotonic())
            if not self._queue and self._sentences and self._unheard(time.time()):
                self._later(self._play_clock - time.time() + 0.01)  # its last words, once heard
        except self._sd.PortAudioError as exc:
            self._lost(f"stopped playing ({exc}); {LIST_HINT}")

    def _played(self, frames: np.ndarray, stream: Any) -> None:
        """Publish what was just given to the device, stamped with when it will be heard; keep it for pause()."""
        now = time.time()
        if self._play_clock < now:  # the device ran dry: this plays after its output latency
            self._play_clock = now + float(getattr(stream, "latency", 0.0) or 0.0)
            self._dry_at = self._given
        stamp = self._play_clock
        self._play_clock += len(frames) / self._rate
        self._given += len(frames)
        if not self._started:
            self._started = True
            publish_stage(self, "speaker_start", stamp)  # when the utterance's first sound will be heard
        self._recent.append(frames)
        while len(self._recent) > 1 and sum(len(f) for f in self._recent) - len(self._recent[0]) > self._rate:
            self._recent.popleft()  # a second is more than any device buffer holds
        for t in self._audio_outputs:
            self.publish(t, Audio(data=np.ascontiguousarray(frames).reshape(-1), sample_rate=self._rate,
                                  channels=self._channels, stamp=stamp))

    def _silenced(self) -> None:
        """Nothing plays from now on: say so on the played stream (an empty chunk), forget the clock."""
        now = time.time()
        self._play_clock = 0.0
        self._recent.clear()
        for t in self._audio_outputs:
            self.publish(t, Audio(data=np.zeros(0, np.int16), sample_rate=self._rate or 16000,
                                  channels=self._channels or 1, stamp=now))

    @property
    def _audio_outputs(self) -> list[Any]:
        return [t for t in self.outputs if t.msg_type is Audio]

    def pause(self) -> float:
        """Stop the sound at once but keep what was not heard yet, to :meth:`resume` where it stopped.

        For barge-in: user speech pauses the robot at once; a backchannel ("mhm") resumes it. Returns the
        seconds held. What arrives while paused is queued behind it.
        """
        if self._paused:
            return self._queue_s()
        self._paused = True
        n = self._unheard(time.time())
        if n and self._recent:
            tail = np.concatenate(list(self._recent))[-n:]
            self._queue.appendleft(tail)  # what the device held is played again on resume
            self._given -= len(tail)
        if self._stream is not None and self._stream.active:
            self._stream.abort()  # abort, not stop: what the device holds is not played
        self._silenced()
        self._tell_words()  # the words heard until now
        self.logger.info("%s: paused; %.2f s held", self._label(), self._queue_s())
        return self._queue_s()

    def resume(self) -> float:
        """Play on from where :meth:`pause` stopped; returns the seconds queued."""
        if not self._paused:
            return self._queue_s()
        self._paused = False
        self.logger.info("%s: resumed; %.2f s queued", self._label(), self._queue_s())
        self._pump()
        return self._queue_s()

    def _later(self, delay: float) -> None:
        if not self._pump_due and self._call_later is not None:
            self._pump_due = True
            self.call_later(delay, self._pump)

    def _queue_s(self) -> float:
        return sum(len(f) for f in self._queue if f is not None) / max(1, self._rate)

    def _drop(self, seconds: float, why: str) -> None:
        self._queue.clear()
        self._fed = self._given
        self._tell_words(cut=True)
        if seconds > 0:
            self.dropped_s += seconds
            self.logger.warning("%s: dropped %.2f s of audio: %s", self._label(), seconds, why)

    def _interrupted(self) -> float:
        """A barge-in ``interrupt``: :meth:`stop_playback`, and the rest of the utterance in progress is dropped
        when it comes, until its end (an empty ``Audio``): the voice stops that answer too, but a sentence it
        was making when the interrupt came is sent after."""
        for msg in self._received:  # received, not yet taken: stop_playback drops them
            self._receiving = msg.data.size > 0
        self._drop_rest = self._receiving
        return self.stop_playback()

    def stop_playback(self) -> float:
        """Stop at once: drop what is queued and what the device still holds; returns the seconds dropped."""
        taken = self.take()
        dropped = self._queue_s() + _seconds(taken)
        self._queue.clear()
        self._given -= self._unheard(time.time())  # what the device held is not heard: not told
        self._fed = self._given
        self._paused = False
        self._started = False  # the utterance's end was dropped with it: what comes next is a new one
        if self._stream is not None and self._stream.active:
            self._stream.abort()  # abort, not stop: what the device holds is not played
        self._silenced()
        self._tell_words(cut=True)
        self.logger.info("%s: stopped; %.2f s of audio dropped", self._label(), dropped)
        return dropped
