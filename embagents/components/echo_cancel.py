"""Acoustic echo cancellation: what the robot's speaker played, taken out of what its microphone hears.

On a robot the speaker and the microphone share one body: without this the
recognizer hears the robot's own answers (and barge-in interrupts itself).
:class:`EchoCanceller` wraps the WebRTC audio processing module (AEC3, with
its own delay estimator) of the ``livekit`` wheel (``livekit.rtc.AudioProcessingModule``;
it runs offline, no LiveKit server), in the process of the component that
owns the microphone, before voice activity detection.

The reference is the Speaker's ``played`` stream: ``Audio`` chunks stamped
with the wall-clock time their first sample leaves the speaker. Microphone
chunks are stamped with the time their last sample was heard. Both are laid
on one timeline, so the reference that goes with each 10 ms microphone frame
is the one played at that moment; ``delay_ms`` is the canceller's hint of how
much later the echo arrives than the stamps say (device buffers the stamps do
not see, the air). With no reference (nothing played), frames pass through
the canceller all the same, so its state stays continuous.

Example::

    >>> aec = EchoCanceller(16000)                                   # doctest: +SKIP
    >>> aec.reference(played, 16000, stamp=t0)                       # doctest: +SKIP
    >>> clean = aec.process(mic_chunk, stamp=t0 + 0.1)               # doctest: +SKIP
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from embagents.components.audio_format import _resample
from embagents.msgs import Audio

__all__ = ["APM_RATES", "EchoCanceller", "erle_db", "livekit_rtc"]

#: The sample rates the WebRTC module takes.
APM_RATES = (8000, 16000, 32000, 48000)
_KEEP_S = 3.0  # reference kept behind the microphone's position (the delay estimator looks back ~0.5 s)


def livekit_rtc() -> Any:
    """``livekit.rtc``, or an error naming the install (it is in embagents' speech extra)."""
    try:
        from livekit import rtc
    except ModuleNotFoundError:
        raise ModuleNotFoundError("echo cancellation needs the livekit package (the WebRTC audio processing "
                                  "module): `pip install livekit` (it is in embagents' speech extra), or turn "
                                  "echo_cancellation off") from None
    return rtc


def erle_db(before: np.ndarray, after: np.ndarray) -> float:
    """Echo return loss enhancement: how much quieter the echo is after cancellation, in dB.

    >>> round(erle_db(np.full(100, 1000.0), np.full(100, 10.0)), 1)
    40.0
    """
    p_in = float(np.mean(np.square(before.astype(np.float64)))) + 1e-9
    p_out = float(np.mean(np.square(after.astype(np.float64)))) + 1e-9
    return 10.0 * math.log10(p_in / p_out)


class EchoCanceller:
    """Cancels the played reference out of microphone chunks (see the module docstring).

    ``rate``: the microphone's sample rate (one of :data:`APM_RATES`), mono;
    ``delay_ms``: the delay hint; ``noise_suppression``: WebRTC's noise suppressor too.
    """

    def __init__(self, rate: int, *, delay_ms: float = 0.0, noise_suppression: bool = False) -> None:
        if rate not in APM_RATES:
            raise ValueError(f"echo cancellation takes audio at {', '.join(map(str, APM_RATES))} Hz, got {rate} Hz; "
                             "set the microphone's sample_rate to one of them")
        if delay_ms < 0:
            raise ValueError(f"echo delay_ms must be >= 0, got {delay_ms!r}")
        self.rtc = livekit_rtc()
        self.rate = rate
        self.frame = rate // 100  # the module takes exactly 10 ms frames
        self.apm = self.rtc.AudioProcessingModule(echo_cancellation=True, noise_suppression=noise_suppression,
                                                  high_pass_filter=True)
        self.apm.set_stream_delay_ms(int(delay_ms))
        self._t0: float | None = None  # wall time of sample 0 of the timeline
        self._ref = np.zeros(0, np.int16)  # the reference from timeline sample _ref_start on
        self._ref_start = 0
        self._pending = np.zeros(0, np.int16)  # microphone samples short of a whole frame
        self.reference_s = 0.0  # seconds of reference received
        self.played_until = 0.0  # wall time the last reference sample is played

    # --- the timeline -----------------------------------------------------------------------
    def _index(self, stamp: float) -> int:
        if self._t0 is None:
            self._t0 = stamp
        return round((stamp - self._t0) * self.rate)

    def reference(self, samples: np.ndarray, rate: int, stamp: float, channels: int = 1) -> None:
        """What the speaker plays from wall time ``stamp`` on (int16 or float32, any rate and channels)."""

        x = samples.reshape(-1).astype(np.float32)
        if samples.dtype == np.int16:
            x /= 32768.0
        if channels > 1:
            x = x.reshape(-1, channels).mean(axis=1)
        x = _resample(x, rate, self.rate)
        pcm = np.clip(x * 32768.0, -32768, 32767).astype(np.int16)
        at = self._index(stamp) - self._ref_start
        if not pcm.size:  # the speaker stopped at ``stamp``: what it had announced after it is not played
            self._ref[max(at, 0):] = 0
            self.played_until = min(self.played_until, stamp)
            return
        if at < 0:  # older than what is kept: only its newer part counts
            pcm, at = pcm[-at:], 0
        end = at + len(pcm)
        if end > len(self._ref):
            self._ref = np.concatenate([self._ref, np.zeros(end - len(self._ref), np.int16)])
        self._ref[at:end] = pcm
        self.reference_s += len(pcm) / self.rate
        self.played_until = max(self.played_until, stamp + len(pcm) / self.rate)

    def _reference_for(self, start: int, n: int) -> np.ndarray:
        out = np.zeros(n, np.int16)
        a, b = start - self._ref_start, start - self._ref_start + n
        lo, hi = max(a, 0), min(b, len(self._ref))
        if hi > lo:
            out[lo - a:hi - a] = self._ref[lo:hi]
        return out

    def _trim(self, position: int) -> None:
        drop = position - int(_KEEP_S * self.rate) - self._ref_start
        if drop > 0:
            self._ref = self._ref[drop:]
            self._ref_start += drop

    # --- the microphone ---------------------------------------------------------------------
    def process(self, samples: np.ndarray, stamp: float) -> np.ndarray:
        """Cancel the echo out of int16 mono ``samples`` whose last sample was heard at ``stamp``.

        Returns the cancelled samples of every whole 10 ms frame so far (a remainder waits for the next chunk).
        """
        if samples.dtype != np.int16:
            samples = np.clip(samples.astype(np.float32) * 32768.0, -32768, 32767).astype(np.int16)
        buf = np.concatenate([self._pending, samples.reshape(-1)])
        whole = len(buf) - len(buf) % self.frame
        end = self._index(stamp) - (len(buf) - whole)  # the timeline index just after the last whole frame
        start = end - whole
        ref = self._reference_for(start, whole)
        out = np.empty(whole, np.int16)
        rtc, f = self.rtc, self.frame
        for i in range(0, whole, f):
            self.apm.process_reverse_stream(rtc.AudioFrame(ref[i:i + f].tobytes(), self.rate, 1, f))
            frame = rtc.AudioFrame(buf[i:i + f].tobytes(), self.rate, 1, f)
            self.apm.process_stream(frame)  # in place
            out[i:i + f] = np.frombuffer(frame.data, np.int16)
        self._pending = buf[whole:].copy()
        self._trim(end)
        return out

    def playing(self, now: float) -> bool:
        """True while reference audio is being played at wall time ``now``."""
        return now < self.played_until


class EchoCancelling:
    """What a microphone-like component (Microphone, WavFileSource) adds for echo cancellation.

    Its optional ``Audio`` input is the Speaker's ``played`` stream: wired, the
    chunks it publishes are cancelled (``echo_cancellation`` in its config, on
    by default); not wired (no speaker in the system), nothing changes.
    """

    config: Any
    inputs: tuple[Any, ...]
    logger: Any
    _aec: EchoCanceller | None = None  # set by _aec_setup (on_configure)

    def _aec_setup(self, rate: int, channels: int) -> None:
        self._aec = None
        wired = [t for t in self.inputs if t.msg_type is not None]
        if not wired or not self.config.echo_cancellation:
            return
        if channels != 1:
            raise ValueError(f"echo cancellation takes one channel, this source has {channels}; set channels=1 "
                             "or echo_cancellation=False")
        self._aec = EchoCanceller(rate, delay_ms=self.config.echo_delay_ms,
                                  noise_suppression=self.config.noise_suppression)
        for t in wired:
            if t.keep != "all":  # a dropped reference chunk is echo let through
                self.logger.warning("reference topic %r keeps only the latest messages: declare it "
                                    "Topic(%r, Audio, keep='all')", t.name, t.name)

    def _aec_reference(self, topic_name: str, msg: Any) -> None:
        # An empty chunk too: the speaker stopped (a pause, a barge-in) and what it had announced is not played.
        if self._aec is not None and isinstance(msg, Audio):
            self._aec.reference(msg.data, msg.sample_rate, msg.stamp, msg.channels)

    def _aec_process(self, samples: np.ndarray, stamp: float) -> np.ndarray:
        """``samples`` with the echo taken out (int16, the source's dtype otherwise), or as they were."""
        if self._aec is None or not samples.size:
            return samples
        out = self._aec.process(samples, stamp)
        return out if samples.dtype == np.int16 else out.astype(np.float32) / 32768.0
