"""Real audio made offline for the voice benches and tests: the robot's Piper voice through a simulated room.

- :func:`robot_says`: 16 kHz int16 of the Piper voice joe saying a line (made
  once with the real TTS, then cached: :func:`~embagents.components.audio_io.spoken_clip_path`),
  without the clip's leading and trailing pauses.
- :func:`room_impulse_response`: a synthetic room impulse response (a direct
  path after ``delay_ms``, then exponentially decaying diffuse reflections
  with reverberation time ``rt60_s``), seeded, made with numpy.
- :func:`echo_of`: what a microphone hears of what the speaker played through
  that room, at ``level_db`` (RMS, dBFS).

Example::

    >>> h = room_impulse_response(16000, delay_ms=30, rt60_s=0.3, seed=1)
    >>> int(np.argmax(np.abs(h)))
    480
"""

from __future__ import annotations

import numpy as np

from embagents.components.audio_io import read_wav, spoken_clip_path

__all__ = ["ROBOT_LINES", "USER_BACKCHANNELS", "USER_INTERRUPTIONS", "echo_of", "mix_at", "robot_says",
           "room_impulse_response", "rms_db"]

RATE = 16000
#: What the robot says in the voice benches (answers of a few seconds).
ROBOT_LINES = (
    "The red cup is on the kitchen table, next to the blue plate and the bread.",
    "Paris is the capital of France, and it is known for the Eiffel Tower and its museums.",
    "I will bring the box to the living room, and then I will charge my battery for an hour.",
    "The weather today is sunny and warm, with a light wind from the west in the afternoon.",
    "Your meeting starts at three o'clock in the small room on the second floor of the building.",
)
#: Short things a listener says while the robot speaks that must not interrupt it. ("Mhm" and "uh-huh" are
#: not among them: the Piper voice says them as no word Whisper knows, "and make an", "I heard".)
USER_BACKCHANNELS = ("Yeah.", "Okay.", "Right.", "I see.", "Sure.")
#: Things a listener says to interrupt the robot.
USER_INTERRUPTIONS = (
    "Wait, stop, I meant the green cup.",
    "No, tell me about Berlin instead.",
    "Hold on, put the box in the kitchen.",
    "Sorry, what time is the meeting?",
    "Stop talking and come here please.",
)


def robot_says(text: str) -> np.ndarray:
    """16 kHz int16 of the Piper voice joe saying ``text`` (cached), trimmed to the speech."""

    samples, _, _ = read_wav(spoken_clip_path(text, progress=False))
    loud = np.flatnonzero(np.abs(samples) > 300)
    return samples[loud[0]:loud[-1] + 1] if loud.size else samples


def room_impulse_response(rate: int = RATE, *, delay_ms: float = 30.0, rt60_s: float = 0.3,
                          length_ms: float = 300.0, seed: int = 0) -> np.ndarray:
    """A synthetic room impulse response, peak-normalised to 1 (see the module docstring)."""
    rng = np.random.default_rng(seed)
    n = int(rate * length_ms / 1000)
    t = np.arange(n) / rate
    tail = rng.standard_normal(n) * np.exp(-6.9 * t / rt60_s) * 0.3  # -60 dB after rt60
    tail[0] = 1.0  # the direct path
    return np.concatenate([np.zeros(int(rate * delay_ms / 1000)), tail])


def rms_db(x: np.ndarray) -> float:
    """RMS level of int16 or float [-1, 1] samples in dBFS."""
    f = x.astype(np.float64) / (32768.0 if x.dtype == np.int16 else 1.0)
    return float(10 * np.log10(np.mean(f * f) + 1e-12))


def echo_of(played: np.ndarray, h: np.ndarray, level_db: float = -26.0) -> np.ndarray:
    """``played`` (int16) through the room ``h`` at RMS ``level_db``: float64 in [-1, 1], as long as ``played``."""
    from scipy.signal import fftconvolve

    x = played.astype(np.float64) / 32768.0
    y = fftconvolve(x, h)[:len(x)]
    speech = y[np.abs(x) > 0.01]
    return y * (10 ** (level_db / 20) / (np.sqrt(np.mean(speech ** 2)) + 1e-12))


def mix_at(base: np.ndarray, other: np.ndarray, at: int, level_db: float | None = None) -> np.ndarray:
    """``base`` (float) with ``other`` (int16 or float) added from sample ``at`` (at RMS ``level_db`` if given)."""
    o = other.astype(np.float64) / (32768.0 if other.dtype == np.int16 else 1.0)
    if level_db is not None:
        o = o * 10 ** ((level_db - rms_db(o)) / 20)
    out = base.astype(np.float64).copy()
    end = min(len(out), at + len(o))
    out[at:end] += o[:end - at]
    return out


def to_int16(x: np.ndarray) -> np.ndarray:
    return np.clip(np.round(x * 32768.0), -32768, 32767).astype(np.int16)
