"""Real audio made offline for the voice benches and tests: the robot's Piper voice through a simulated room.

- :func:`robot_says`: 16 kHz int16 of the Piper voice joe saying a line (made
  once with the real TTS, then cached: :func:`~embagents.components.audio_io.spoken_clip_path`),
  without the clip's leading and trailing pauses.
- :func:`room_impulse_response`: a synthetic room impulse response (a direct
  path after ``delay_ms``, then exponentially decaying diffuse reflections
  with reverberation time ``rt60_s``), seeded, made with numpy.
- :func:`echo_of`: what a microphone hears of what the speaker played through
  that room, at ``level_db`` (RMS, dBFS).
- :func:`said_with_a_pause`: a question spoken in one go with a pause cut in
  between two of its words, as a person who stops mid-sentence sounds: the
  words before the pause keep the level tone of a sentence going on, not the
  falling end of one. The break between the two words is found by aligning
  (dynamic time warping on log spectra) the whole question with its two parts
  spoken apart, then taking the quietest 20 ms near it.

Example::

    >>> h = room_impulse_response(16000, delay_ms=30, rt60_s=0.3, seed=1)
    >>> int(np.argmax(np.abs(h)))
    480
"""

from __future__ import annotations

import numpy as np

from embagents.components.audio_io import read_wav, spoken_clip_path

__all__ = ["ROBOT_LINES", "USER_BACKCHANNELS", "USER_INTERRUPTIONS", "echo_of", "mix_at", "robot_says",
           "room_impulse_response", "rms_db", "said_with_a_pause"]

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


def _spectra(x: np.ndarray) -> np.ndarray:
    """Unit-norm log spectra (40 bands up to 8 kHz) every 10 ms of 16 kHz int16 ``x``, ``(frames, 40)``."""
    f = np.pad(x.astype(np.float64) / 32768.0, (200, 200))
    frames = np.lib.stride_tricks.sliding_window_view(f, 400)[::160] * np.hanning(400)
    power = (np.abs(np.fft.rfft(frames, axis=-1)) ** 2)[:, :200].reshape(len(frames), 40, 5).sum(-1)
    s = np.log(power + 1e-10)
    s -= s.mean(axis=1, keepdims=True)
    return s / (np.linalg.norm(s, axis=1, keepdims=True) + 1e-9)


def _aligned(x: np.ndarray, y: np.ndarray) -> list[tuple[int, int]]:
    """The dynamic time warping path between frames ``x`` and ``y`` (cosine distance), start to end."""
    cost = 1.0 - x @ y.T
    n, m = cost.shape
    d = np.full((n + 1, m + 1), np.inf)
    d[0, 0] = 0.0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            d[i, j] = cost[i - 1, j - 1] + min(d[i - 1, j - 1], d[i - 1, j], d[i, j - 1])
    i, j, path = n, m, []
    while i > 0 and j > 0:
        path.append((i - 1, j - 1))
        step = int(np.argmin((d[i - 1, j - 1], d[i - 1, j], d[i, j - 1])))
        i, j = (i - 1, j - 1) if step == 0 else (i - 1, j) if step == 1 else (i, j - 1)
    return path[::-1]


def said_with_a_pause(first: str, rest: str, pause_s: float) -> tuple[np.ndarray, int]:
    """``(speech, cut)``: the voice saying ``first rest`` in one go with ``pause_s`` of silence after ``first``.

    ``cut``: where the pause starts (samples). The two parts are the one
    utterance's audio (:func:`robot_says` of the whole text), cut at the break
    between ``first``'s last word and ``rest``'s first (see the module
    docstring), each faded over 5 ms so the cut does not click.
    """

    whole, a, b = robot_says(f"{first} {rest}"), robot_says(first), robot_says(rest)
    fa = len(_spectra(a))
    path = _aligned(np.concatenate([_spectra(a), _spectra(b)]), _spectra(whole))
    ends = max(j for i, j in path if i == fa - 1) * 160  # where first's last frame lands in the whole
    starts = min(j for i, j in path if i == fa) * 160  # and rest's first
    win, hop = 320, 80
    lo, hi = max(0, min(ends, starts) - 640), min(len(whole) - win, max(ends, starts) + 320)
    at = list(range(lo, max(lo + 1, hi), hop))
    cut = at[int(np.argmin([np.square(whole[k:k + win].astype(np.float64)).mean() for k in at]))] + win // 2
    fade = np.linspace(1.0, 0.0, RATE // 200)
    head, tail = whole[:cut].astype(np.float64), whole[cut:].astype(np.float64)
    head[-len(fade):] *= fade
    tail[:len(fade)] *= fade[::-1]
    pause = np.zeros(int(round(pause_s * RATE)))
    return np.concatenate([head, pause, tail]).astype(np.int16), cut


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
