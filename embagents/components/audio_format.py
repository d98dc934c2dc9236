"""Audio messages as the recognizers want them (16 kHz mono float32) and as sound cards take them (int16 frames).

Example::

    >>> from embagents.msgs import Audio
    >>> out, note = to_mono_16k(Audio(data=np.zeros(4800, np.int16), sample_rate=48000, channels=2))
    >>> out.shape, out.dtype, note
    ((800,), dtype('float32'), 'audio at 48000 Hz, 2 channels: mixed down and resampled to 16 kHz mono')
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["AudioFormatError", "TARGET_RATE", "to_mono_16k", "to_pcm16"]

TARGET_RATE = 16000


class AudioFormatError(ValueError):
    """An Audio message that cannot be read as samples (the message says what it is and what to send)."""


def _checked(msg: object) -> tuple[np.ndarray, int, int]:
    """``(flat samples, rate, channels)`` of an Audio message, or :class:`AudioFormatError` saying what to send."""
    data = getattr(msg, "data", None)
    rate, channels = getattr(msg, "sample_rate", None), getattr(msg, "channels", None)
    if not isinstance(data, np.ndarray):
        raise AudioFormatError(f"Audio.data must be a numpy array, got {type(data).__name__}")
    if data.dtype not in (np.int16, np.float32):
        raise AudioFormatError(f"Audio.data has dtype {data.dtype}; send int16 PCM or float32 samples in [-1, 1] "
                               "(e.g. data.astype(np.float32))")
    if not isinstance(rate, int) or isinstance(rate, bool) or rate <= 0:
        raise AudioFormatError(f"Audio.sample_rate must be a positive integer (Hz), got {rate!r}")
    if not isinstance(channels, int) or isinstance(channels, bool) or channels < 1:
        raise AudioFormatError(f"Audio.channels must be an integer >= 1, got {channels!r}")
    flat = data.reshape(-1)
    if flat.size % channels:
        raise AudioFormatError(f"Audio.data has {flat.size} samples, not a multiple of its {channels} channels; "
                               "send whole frames (interleaved samples, one per channel)")
    return flat, rate, channels


def _resample(samples: np.ndarray, rate: int, target: int) -> np.ndarray:
    """float32 ``samples`` (frames along axis 0) from ``rate`` to ``target`` Hz."""
    if rate == target or not samples.size:
        return samples
    from scipy.signal import resample_poly  # polyphase: filters before it decimates (no aliasing)

    g = math.gcd(rate, target)
    return resample_poly(samples, target // g, rate // g, axis=0).astype(np.float32)


def _note(rate: int, channels: int, target_rate: int, target_channels: int, what: str) -> str | None:
    done = [d for d, yes in (("mixed down" if target_channels < channels else "spread", channels != target_channels),
                             ("resampled", rate != target_rate)) if yes]
    return f"audio at {rate} Hz, {_channels(channels)}: {' and '.join(done)} to {what}" if done else None


def _channels(n: int) -> str:
    return "1 channel" if n == 1 else f"{n} channels"


def to_mono_16k(msg: object) -> tuple[np.ndarray, str | None]:
    """``(samples, note)``: 1-D float32 in [-1, 1] at 16 kHz; ``note`` says what was converted (None: nothing).

    Raises :class:`AudioFormatError` for a dtype other than int16/float32, a
    rate that is not a positive integer, or samples that do not divide into
    the channels.
    """
    flat, rate, channels = _checked(msg)
    samples = flat.astype(np.float32) / 32768.0 if flat.dtype == np.int16 else flat
    if channels > 1:
        samples = samples.reshape(-1, channels).mean(axis=1, dtype=np.float32)
    samples = _resample(samples, rate, TARGET_RATE)
    return np.ascontiguousarray(samples, np.float32), _note(rate, channels, TARGET_RATE, 1, "16 kHz mono")


def to_pcm16(msg: object, rate: int, channels: int) -> tuple[np.ndarray, str | None]:
    """``(frames, note)``: int16 frames of shape (n, ``channels``) at ``rate`` Hz, as a sound card takes them.

    int16 audio already at ``rate`` keeps its exact samples; mono is copied to
    every channel, more channels than asked are mixed down. Raises
    :class:`AudioFormatError` as :func:`to_mono_16k` does.

    >>> from embagents.msgs import Audio
    >>> frames, note = to_pcm16(Audio(data=np.array([0.5, -1.0], np.float32), sample_rate=16000), 16000, 2)
    >>> frames.tolist(), note
    ([[16384, 16384], [-32767, -32767]], 'audio at 16000 Hz, 1 channel: spread to 16000 Hz, 2 channels')
    """
    flat, src_rate, src_channels = _checked(msg)
    frames = flat.reshape(-1, src_channels)
    if frames.dtype != np.int16 or src_rate != rate or src_channels not in (1, channels):
        x = frames.astype(np.float32) / 32768.0 if frames.dtype == np.int16 else frames
        if src_channels != channels and src_channels > 1:
            x = x.mean(axis=1, keepdims=True, dtype=np.float32)
        x = _resample(x, src_rate, rate)
        frames = np.clip(np.rint(x * 32767.0), -32768, 32767).astype(np.int16)
    if frames.shape[1] != channels:
        frames = np.repeat(frames[:, :1], channels, axis=1)
    note = _note(src_rate, src_channels, rate, channels, f"{rate} Hz, {_channels(channels)}")
    return np.ascontiguousarray(frames, np.int16), note
