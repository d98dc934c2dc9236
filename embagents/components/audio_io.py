"""Audio from and to WAV files: a source that plays a file as a microphone would, a sink that writes utterances.

``WavFileSource`` publishes a WAV file's samples (int16, its own rate and
channels) in chunks of ``chunk_ms`` at real-time pace (run it with
``trigger`` = 1000 / chunk_ms Hz), then one empty ``Audio``: the end of the
stream (SpeechToText transcribes what it holds there). ``loop=True`` starts
again after it.

``WavFileSink`` writes each utterance it receives (the ``Audio`` up to an
empty one, as TextToSpeech ends each utterance) to its own file,
``<folder>/<prefix>-<n>.wav`` (16-bit PCM at the audio's rate), and
publishes the file's path on an optional ``String`` output when the file is
complete.

Example::

    >>> from embagents.msgs import Audio, String
    >>> from embagents.topic import Topic
    >>> sink = WavFileSink(name="ear_file", inputs=[Topic("speaker", Audio, keep="all")],
    ...                    outputs=[Topic("written", String)], config=WavFileSinkConfig(folder="/tmp/said"))
    >>> sink.config.prefix
    'utterance'
"""

from __future__ import annotations

import os
import time
import wave
from typing import Any

import numpy as np
from attrs import define, field

from embagents.components.audio_format import TARGET_RATE, to_mono_16k
from embagents.components.component import Component
from embagents.components.echo_cancel import EchoCancelling
from embagents.config import BaseComponentConfig, ConfigError, positive_float, to_bool
from embagents.models.files.wheels import cache_dir
from embagents.msgs import Audio, String

__all__ = ["AudioSink", "WavFileSink", "WavFileSinkConfig", "WavFileSource", "WavFileSourceConfig", "read_wav", "spoken_clip_path"]


def non_negative_float(value: object) -> float:
    """A number >= 0 (a delay), or ConfigError."""
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        out = -1.0
    if isinstance(value, bool) or not out >= 0.0:
        raise ConfigError(f"expected a number >= 0, got {value!r}")
    return out


def _path(value: object) -> str:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"expected a file or folder path, got {value!r}")
    return value


def read_wav(path: str) -> tuple[np.ndarray, int, int]:
    """``(int16 interleaved samples, rate, channels)`` of a 16-bit PCM WAV file (a clear error otherwise)."""
    if not os.path.isfile(path):
        raise FileNotFoundError(f"WAV file not found: {path!r}; give the path of a 16-bit PCM .wav file")
    try:
        with wave.open(path) as w:
            if w.getsampwidth() != 2:
                raise ValueError(f"{path!r} has {8 * w.getsampwidth()}-bit samples; convert it to 16-bit PCM "
                                 "(e.g. `ffmpeg -i in.wav -acodec pcm_s16le out.wav`)")
            return np.frombuffer(w.readframes(w.getnframes()), "<i2").astype(np.int16), w.getframerate(), w.getnchannels()
    except wave.Error as exc:
        raise ValueError(f"{path!r} is not a PCM WAV file ({exc}); convert it to 16-bit PCM WAV") from None


def spoken_clip_path(text: str, *, progress: bool = True) -> str:
    """A 16 kHz mono WAV of the voice joe saying ``text``: made once with the real TTS, then cached.

    For examples and benches that need a spoken question of their choosing (the
    clip in :func:`embagents.models.files.speech.speech_clip_path` says only Beckett's lines), to
    play with a :class:`WavFileSource`. Loads espeak-ng (GPL-3.0) in the calling process, once per text.
    """
    import hashlib

    from embagents.models.backends.sherpa_tts import SherpaSpeaker  # lazy: a cycle
    from embagents.models.clients.openai_audio import wav_bytes  # lazy: a cycle
    from embagents.models.files.speech import piper_joe_dir  # lazy: a cycle

    dest = cache_dir() / "prepared" / "spoken" / f"{hashlib.sha256(text.encode()).hexdigest()[:16]}.wav"
    if dest.is_file():
        return str(dest)
    speaker = SherpaSpeaker(piper_joe_dir(progress=progress))
    pause = np.zeros(speaker.sample_rate // 2, np.float32)
    samples = np.concatenate([pause] + [np.concatenate([a, pause]) for a, _, _ in speaker.speak(text)])
    clip, _ = to_mono_16k(Audio(data=samples, sample_rate=speaker.sample_rate))
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.with_suffix(f".part{os.getpid()}")
    tmp.write_bytes(wav_bytes(clip, TARGET_RATE))
    os.replace(tmp, dest)
    return str(dest)


@define(kw_only=True)
class WavFileSourceConfig(BaseComponentConfig):
    """``path``: the WAV file; ``chunk_ms``: audio per message; ``loop``: start again at the end.

    With the Speaker's ``played`` stream as input, echo is cancelled (see
    :mod:`~embagents.components.echo_cancel`): ``echo_cancellation`` (on),
    ``echo_delay_ms`` (the canceller's delay hint), ``noise_suppression`` (WebRTC's, off).
    """

    path: str = field(default="", converter=_path)
    chunk_ms: float = field(default=100.0, converter=positive_float)
    loop: bool = field(default=False, converter=to_bool)
    echo_cancellation: bool = field(default=True, converter=to_bool)
    echo_delay_ms: float = field(default=0.0, converter=non_negative_float)
    noise_suppression: bool = field(default=False, converter=to_bool)


class WavFileSource(EchoCancelling, Component):
    """Plays a WAV file as ``Audio`` chunks, then an empty ``Audio`` (see the module docstring).

    Each chunk is stamped with the wall time it is published (its last sample "heard" then).
    """

    allowed_inputs = {"Optional": [Audio]}  # the Speaker's played stream: the echo reference
    allowed_outputs = {"Required": [Audio]}
    config_class = WavFileSourceConfig

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if topic_name in self._subscribed:
            self._aec_reference(topic_name, msg)  # at once, every chunk: not only the latest at a step
        return super().on_message(topic_name, msg, now)

    def on_configure(self) -> None:
        self.samples, self.rate, self.channels = read_wav(self.config.path)
        self._aec_setup(self.rate, self.channels)
        self.step_samples = max(1, int(self.rate * self.config.chunk_ms / 1000)) * self.channels
        self.at = 0
        self.finished = False
        self.logger.info("%s: playing %s (%.1f s at %d Hz, %d channels)", self._label(), self.config.path,
                         len(self.samples) / self.channels / self.rate, self.rate, self.channels)

    def _execution_step(self, **inputs: Any) -> None:
        if self.finished:
            if not self.config.loop:
                return
            self.at, self.finished = 0, False
        chunk = self.samples[self.at:self.at + self.step_samples]
        self.at += self.step_samples
        self.finished = chunk.size == 0  # the empty chunk is the end-of-stream marker
        stamp = time.time()
        chunk = self._aec_process(chunk, stamp)
        if chunk.size == 0 and not self.finished:
            return  # less than one 10 ms frame so far: it goes out with the next chunk
        for t in self.outputs:
            self.publish(t, Audio(data=chunk, sample_rate=self.rate, channels=self.channels, stamp=stamp))


@define(kw_only=True)
class WavFileSinkConfig(BaseComponentConfig):
    """``folder``: where the files go (made if missing); ``prefix``: their names' start."""

    folder: str = field(default="audio_out", converter=_path)
    prefix: str = field(default="utterance", converter=_path)


class AudioSink(Component):
    """Base of the components that take every ``Audio`` chunk in order (a file, a speaker): a step per message.

    The runtime keeps only the latest message of a topic for a step; a sink
    keeps them all (:meth:`take`), as one dropped chunk is a hole in a word.
    """

    allowed_inputs = {"Required": [Audio]}

    def __init__(self, *, name: str, **kw: Any) -> None:
        self._received: list[Audio] = []
        super().__init__(name=name, **kw)

    def default_trigger(self) -> list[Any]:
        return list(self.inputs)

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if topic_name in self._subscribed and isinstance(msg, Audio):
            self._received.append(msg)
        return super().on_message(topic_name, msg, now)

    def take(self) -> list[Audio]:
        """The chunks received since the last call, oldest first."""
        received, self._received = self._received, []
        return received


class WavFileSink(AudioSink):
    """Writes each utterance to a WAV file (see the module docstring)."""

    allowed_outputs = {"Optional": [String]}
    config_class = WavFileSinkConfig

    def __init__(self, *, name: str, **kw: Any) -> None:
        self._file: wave.Wave_write | None = None
        self._path = ""
        self._format: tuple[int, int] = (0, 0)
        self.written: list[str] = []
        super().__init__(name=name, **kw)

    def _execution_step(self, **inputs: Any) -> None:
        for msg in self.take():
            if msg.data.size == 0:
                self._close()
                continue
            if msg.data.dtype not in (np.int16, np.float32):
                self.logger.error("%s: skipped Audio of dtype %s; send int16 PCM or float32 in [-1, 1]",
                                  self._label(), msg.data.dtype)
                self.set_algorithm_failure(f"bad audio dtype {msg.data.dtype}")
                continue
            if self._file is not None and self._format != (msg.sample_rate, msg.channels):
                self._close()  # a new format is a new file
            if self._file is None:
                self._open(msg.sample_rate, msg.channels)
            pcm = msg.data if msg.data.dtype == np.int16 else np.clip(msg.data * 32767.0, -32768, 32767).astype(np.int16)
            assert self._file is not None
            self._file.writeframes(pcm.astype("<i2").tobytes())

    def _open(self, rate: int, channels: int) -> None:
        os.makedirs(self.config.folder, exist_ok=True)
        self._path = os.path.abspath(os.path.join(self.config.folder, f"{self.config.prefix}-{len(self.written) + 1}.wav"))
        self._file = wave.open(self._path, "wb")
        self._file.setnchannels(channels)
        self._file.setsampwidth(2)
        self._file.setframerate(rate)
        self._format = (rate, channels)

    def _close(self) -> None:
        if self._file is None:
            return
        frames = self._file.getnframes()
        self._file.close()
        self._file = None
        self.written.append(self._path)
        self.logger.info("%s: wrote %s (%.2f s)", self._label(), self._path, frames / self._format[0])
        for t in self.outputs:
            self.publish(t, String(data=self._path))

    def on_shutdown(self) -> None:
        self._close()
        super().on_shutdown()
