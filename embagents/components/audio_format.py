"""Audio messages as the recognizers want them: 16 kHz mono float32 samples.

Example::

    >>> from embagents.msgs import Audio
    >>> out, note = to_mono_16k(Audio(data=np.zeros(4800, np.int16), sample_rate=48000, channels=2))
    >>> out.shape, out.dtype, note
    ((800,), dtype('float32'), 'audio at 48000 Hz, 2 channels: mixed down and resampled to 16 kHz mono')
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["AudioFormatError", "TARGET_RATE", "to_mono_16k"]

TARGET_RATE = 16000


class AudioFormatError(ValueError):
    """An Audio message that cannot be read as samples (the message says what it is and what to send)."""


def to_mono_16k(msg: object) -> tuple[np.ndarray, str | None]:
    """``(samples, note)``: 1-D float32 in [-1, 1] at 16 kHz; ``note`` says what was converted (None: nothing).

    Raises :class:`AudioFormatError` for a dtype other than int16/float32, a
    rate that is not a positive integer, or samples that do not divide into
    the channels.
    """
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
    samples = flat.astype(np.float32) / 32768.0 if flat.dtype == np.int16 else flat
    if channels > 1:
        samples = samples.reshape(-1, channels).mean(axis=1, dtype=np.float32)
    if rate != TARGET_RATE and samples.size:
        from scipy.signal import (
            resample_poly,  # polyphase: filters before it decimates (no aliasing)
        )

        g = math.gcd(rate, TARGET_RATE)
        samples = resample_poly(samples, TARGET_RATE // g, rate // g).astype(np.float32)
    done = [d for d, yes in (("mixed down", channels > 1), ("resampled", rate != TARGET_RATE)) if yes]
    note = f"audio at {rate} Hz, {channels} channels: {' and '.join(done)} to 16 kHz mono" if done else None
    return np.ascontiguousarray(samples, np.float32), note
