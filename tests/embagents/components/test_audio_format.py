"""Audio messages become 16 kHz mono float32: resampled without aliasing, channels mixed, bad ones named."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("scipy")

from embagents.components.audio_format import AudioFormatError, to_mono_16k  # noqa: E402
from embagents.msgs import Audio  # noqa: E402


def tone(hz: float, rate: int, seconds: float = 1.0) -> np.ndarray:
    t = np.arange(int(rate * seconds)) / rate
    return (0.5 * np.sin(2 * np.pi * hz * t)).astype(np.float32)


def peak_hz(samples: np.ndarray, rate: int = 16000) -> float:
    spectrum = np.abs(np.fft.rfft(samples))
    return float(np.fft.rfftfreq(len(samples), 1 / rate)[int(np.argmax(spectrum))])


def test_48_khz_keeps_a_tone_below_8_khz_and_drops_one_above_instead_of_folding_it() -> None:
    out, note = to_mono_16k(Audio(data=tone(1000, 48000), sample_rate=48000))
    assert out.dtype == np.float32 and len(out) == 16000 and abs(peak_hz(out) - 1000) < 2
    assert note == "audio at 48000 Hz, 1 channel: resampled to 16 kHz mono"
    high, _ = to_mono_16k(Audio(data=tone(10000, 48000), sample_rate=48000))  # would alias to 6 kHz
    assert np.abs(high[800:-800]).max() < 0.01  # filtered out (past the filter's edges), not folded into speech


def test_stereo_int16_is_mixed_down_and_scaled() -> None:
    left = np.full(160, 16384, np.int16)
    right = np.zeros(160, np.int16)
    out, note = to_mono_16k(Audio(data=np.column_stack([left, right]).reshape(-1), sample_rate=16000, channels=2))
    assert out.tolist() == [0.25] * 160 and note == "audio at 16000 Hz, 2 channels: mixed down to 16 kHz mono"
    same, note = to_mono_16k(Audio(data=tone(440, 16000)))
    assert note is None and np.array_equal(same, tone(440, 16000))


@pytest.mark.parametrize(("msg", "says"), [
    (Audio(data=np.zeros(10, np.float64)), "dtype float64; send int16 PCM or float32"),
    (Audio(data=np.zeros(10, np.int16), sample_rate=-1), "sample_rate must be a positive integer"),
    (Audio(data=np.zeros(10, np.int16), channels=0), "channels must be an integer >= 1"),
    (Audio(data=np.zeros(9, np.int16), channels=2), "9 samples, not a multiple of its 2 channels"),
])
def test_audio_that_cannot_be_read_is_named(msg: Audio, says: str) -> None:
    with pytest.raises(AudioFormatError, match=says):
        to_mono_16k(msg)
