"""Voice activity detection: Silero VAD on sherpa-onnx, cutting a sample stream into utterances.

Samples go in as they arrive (any chunk size, 16 kHz mono float32); whole
utterances come out once the speaker has been silent ``min_silence_ms``, or
when one grows to ``max_utterance_ms`` (it is cut there, so a long talk
still reaches the recognizer). The model is ``silero_vad.onnx`` (2.3 MB, from
the ``silero-vad`` wheel: :func:`embagents.models.files.speech.silero_vad_path`).

Example::

    >>> vad = SpeechSegmenter(silero_vad_path())                 # doctest: +SKIP
    >>> [len(u) / 16000 for u in vad.feed(samples) + vad.flush()]  # doctest: +SKIP
    [2.1, 1.4]
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["SpeechSegmenter"]

SAMPLE_RATE = 16000


class SpeechSegmenter:
    """Silero VAD through ``sherpa_onnx.VoiceActivityDetector`` (see the module docstring).

    ``threshold``: speech probability above which a window is speech;
    ``min_silence_ms``: silence that ends an utterance; ``min_speech_ms``:
    shorter blips are dropped; ``max_utterance_ms``: longer speech is cut.
    """

    def __init__(self, model: str, *, threshold: float = 0.5, min_silence_ms: float = 500.0,
                 min_speech_ms: float = 250.0, max_utterance_ms: float = 20000.0, threads: int = 1) -> None:
        import sherpa_onnx

        if not os.path.isfile(model):
            raise FileNotFoundError(f"Silero VAD model not found: {model!r}; use "
                                    "embagents.models.files.speech.silero_vad_path() (fetched once from PyPI's silero-vad)")
        if not 0.0 < threshold < 1.0:
            raise ValueError(f"VAD threshold must be in (0, 1), got {threshold!r}")
        if min_silence_ms <= 0 or max_utterance_ms <= min_speech_ms:
            raise ValueError(f"VAD needs min_silence_ms > 0 and max_utterance_ms > min_speech_ms, got "
                             f"{min_silence_ms}, {max_utterance_ms}, {min_speech_ms}")
        config = sherpa_onnx.VadModelConfig()
        config.silero_vad.model = model
        config.silero_vad.threshold = float(threshold)
        config.silero_vad.min_silence_duration = float(min_silence_ms) / 1000.0
        config.silero_vad.min_speech_duration = float(min_speech_ms) / 1000.0
        config.silero_vad.max_speech_duration = float(max_utterance_ms) / 1000.0
        config.sample_rate = SAMPLE_RATE
        config.num_threads = int(threads)
        self.window = int(config.silero_vad.window_size)
        self.vad = sherpa_onnx.VoiceActivityDetector(config, buffer_size_in_seconds=max_utterance_ms / 1000.0 + 30)
        self._pending = np.zeros(0, np.float32)  # less than one VAD window, kept for the next chunk
        #: Where each utterance the last feed/flush returned starts (samples from the stream's start).
        self.last_starts: list[int] = []

    @property
    def speaking(self) -> bool:
        """True while an utterance is going on."""
        return bool(self.vad.is_speech_detected())

    def current(self) -> np.ndarray:
        """The utterance going on so far (from where the VAD saw it start); empty between utterances."""
        if not self.speaking:
            return np.zeros(0, np.float32)
        return np.asarray(self.vad.current_segment.samples, np.float32)

    def feed(self, samples: np.ndarray) -> list[np.ndarray]:
        """Give 16 kHz mono float32 samples; returns the utterances that ended in them."""
        buf = np.concatenate([self._pending, samples.astype(np.float32, copy=False)])
        whole = len(buf) - len(buf) % self.window
        if whole:
            self.vad.accept_waveform(buf[:whole])
        self._pending = buf[whole:]
        return self._take()

    def flush(self) -> list[np.ndarray]:
        """The end of the stream: an utterance still going on comes out too."""
        if len(self._pending):
            self.vad.accept_waveform(np.pad(self._pending, (0, self.window - len(self._pending))))
            self._pending = np.zeros(0, np.float32)
        self.vad.flush()
        out = self._take()
        self.vad.reset()
        return out

    def _take(self) -> list[np.ndarray]:
        out, self.last_starts = [], []
        while not self.vad.empty():
            out.append(np.asarray(self.vad.front.samples, np.float32))
            self.last_starts.append(int(self.vad.front.start))
            self.vad.pop()
        return out


class SpeechOnset:
    """The first moments of speech, window by window (32 ms), for barge-in: faster than a whole segment.

    Silero VAD's per-window decision (``sherpa_onnx.VadModel.is_speech``, the same model file as
    :class:`SpeechSegmenter`); :meth:`feed` returns how many windows in a row, up to the last one fed, are
    speech (0 after a silent window); :attr:`loud` counts the windows in a row whose level is at least
    ``level_db`` (dBFS RMS; None: not counted), a faster sign of the user where the echo canceller has
    taken the robot's voice down to its noise floor but turns the start of the user's speech over it down too.
    """

    def __init__(self, model: str, *, threshold: float = 0.5, level_db: float | None = None,
                 threads: int = 1) -> None:
        import sherpa_onnx

        if not os.path.isfile(model):
            raise FileNotFoundError(f"Silero VAD model not found: {model!r}; use "
                                    "embagents.models.files.speech.silero_vad_path() (fetched once from PyPI's silero-vad)")
        config = sherpa_onnx.VadModelConfig()
        config.silero_vad.model = model
        config.silero_vad.threshold = float(threshold)
        # The model's own smoothing (its defaults: 250 ms of speech before it says so) is what this replaces.
        config.silero_vad.min_speech_duration = 0.0
        config.silero_vad.min_silence_duration = 0.0
        config.sample_rate = SAMPLE_RATE
        config.num_threads = int(threads)
        self.model = sherpa_onnx.VadModel.create(config)
        self.window = int(self.model.window_size())
        self._pending = np.zeros(0, np.float32)
        self.run = 0  # speech windows in a row
        self.quiet = 0  # silent windows in a row
        self.loud = 0  # windows in a row at level_db or above
        self.level = None if level_db is None else 10 ** (level_db / 10)  # mean square
        self.windows = 0  # windows seen so far

    def feed(self, samples: np.ndarray) -> int:
        """Give 16 kHz mono float32 samples; returns the speech windows in a row so far."""
        buf = np.concatenate([self._pending, samples.astype(np.float32, copy=False)])
        w = self.window
        whole = len(buf) - len(buf) % w
        for i in range(0, whole, w):
            self.windows += 1
            window = buf[i:i + w]
            speech = self.model.is_speech(window)
            self.run = self.run + 1 if speech else 0
            self.quiet = 0 if speech else self.quiet + 1
            if self.level is not None:
                self.loud = self.loud + 1 if float(np.mean(window * window)) >= self.level else 0
        self._pending = buf[whole:]
        return self.run
