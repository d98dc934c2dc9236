"""End of turn from the audio: Smart Turn v3 (Pipecat's open model, BSD-2-Clause) on onnxruntime.

The model reads the last 8 s of a user's speech (16 kHz mono; shorter audio is
zero-padded in front) as Whisper-style log-mel features (80 x 800) and says
how likely it is that the user has finished their turn: a falling "...please."
is finished, a "the cup that is on the..." trailing off mid-sentence is not,
however long the pause. The file is ``smart-turn-v3.2-cpu.onnx`` (8.7 MB) from
the ``pipecat-ai`` wheel (:func:`embagents.models.files.speech.smart_turn_path`: the
file only, not the package). The features follow the Whisper feature
extractor's recipe as Pipecat's ``_whisper_features.py`` computes it (its
input format): waveform normalised to zero mean and unit variance, a 400-point
periodic Hann STFT every 160 samples, a Slaney mel filterbank, log10, clipped
to 8 decades below the maximum, then ``(x + 4) / 4``.

Example::

    >>> turn = SmartTurn(smart_turn_path())              # doctest: +SKIP
    >>> turn.probability(question_samples) > 0.5          # doctest: +SKIP
    True
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["SmartTurn", "log_mel_features"]

RATE = 16000
SECONDS = 8
_N_FFT, _HOP, _N_MELS = 400, 160, 80


def _hz_to_mel(f: float | np.ndarray) -> np.ndarray:
    f = np.asarray(f, np.float64)
    return np.where(f >= 1000.0, 15.0 + np.log(np.maximum(f, 1e-9) / 1000.0) * 27.0 / np.log(6.4), 3.0 * f / 200.0)


def _mel_to_hz(m: np.ndarray) -> np.ndarray:
    m = np.asarray(m, np.float64)
    return np.where(m >= 15.0, 1000.0 * np.exp(np.log(6.4) / 27.0 * (m - 15.0)), 200.0 * m / 3.0)


def _filterbank() -> np.ndarray:
    """Slaney-normalised triangular mel filters, ``(n_fft // 2 + 1, 80)``."""
    edges = _mel_to_hz(np.linspace(_hz_to_mel(0.0), _hz_to_mel(RATE / 2), _N_MELS + 2))
    fft = np.linspace(0, RATE // 2, _N_FFT // 2 + 1)
    slopes = edges[None, :] - fft[:, None]
    down = -slopes[:, :-2] / np.diff(edges)[:-1]
    up = slopes[:, 2:] / np.diff(edges)[1:]
    return np.maximum(0.0, np.minimum(down, up)) * (2.0 / (edges[2:] - edges[:-2]))[None, :]


_FILTERS = _filterbank()
_WINDOW = np.hanning(_N_FFT + 1)[:-1]


def log_mel_features(audio: np.ndarray) -> np.ndarray:
    """``(80, 800)`` float32 features of the last 8 s of 16 kHz ``audio`` (zero-padded in front)."""
    n = RATE * SECONDS
    x = np.asarray(audio, np.float32).reshape(-1)[-n:]
    x = np.pad(x, (n - len(x), 0))
    x = (x - x.mean()) / np.sqrt(x.var() + 1e-7)
    padded = np.pad(x.astype(np.float64), (_N_FFT // 2, _N_FFT // 2), mode="reflect")
    frames = np.lib.stride_tricks.sliding_window_view(padded, _N_FFT)[::_HOP]
    power = np.abs(np.fft.rfft(frames * _WINDOW, axis=-1)) ** 2
    mel = np.log10(np.maximum(1e-10, power @ _FILTERS)).T[:, :-1]
    mel = np.maximum(mel, mel.max() - 8.0)
    return ((mel + 4.0) / 4.0).astype(np.float32)


class SmartTurn:
    """Smart Turn v3 on onnxruntime (see the module docstring); ``threads``: its intra-op threads."""

    def __init__(self, path: str, *, threads: int = 1) -> None:
        import onnxruntime as ort

        if not os.path.isfile(path):
            raise FileNotFoundError(f"Smart Turn model not found: {path!r}; use "
                                    "embagents.models.files.speech.smart_turn_path() (the file from PyPI's pipecat-ai wheel)")
        so = ort.SessionOptions()
        so.intra_op_num_threads = int(threads)
        so.inter_op_num_threads = 1
        self.session = ort.InferenceSession(path, sess_options=so, providers=["CPUExecutionProvider"])
        self.input = self.session.get_inputs()[0].name

    def probability(self, audio: np.ndarray) -> float:
        """How likely the user has finished, from the speech so far (16 kHz mono float32 or int16)."""
        x = np.asarray(audio)
        if x.dtype == np.int16:
            x = x.astype(np.float32) / 32768.0
        out = self.session.run(None, {self.input: log_mel_features(x)[None]})
        return float(np.asarray(out[0]).reshape(-1)[0])
