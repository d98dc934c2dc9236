"""Speech on an OpenAI-compatible server: ``POST /v1/audio/transcriptions`` and ``/v1/audio/speech`` (``openai``).

The remote alternative to a local :class:`~embagents.models.SpeechToTextModel`:
:meth:`OpenAITranscriptionClient.transcribe` takes the same 16 kHz samples and
answers the same ``{"text", "seconds"}``, so a :class:`~embagents.components.SpeechToText`
component can use either (and switch between them). The samples are sent as a
16-bit WAV file. Works with OpenAI (``whisper-1``), speaches / faster-whisper-server,
LocalAI and vLLM's audio endpoint.

:class:`OpenAISpeechClient` is the remote alternative to a local
:class:`~embagents.models.TextToSpeechModel`: :meth:`OpenAISpeechClient.speak`
yields the same chunks (one per sentence, then ``{"done": True}``), asking the
server for a WAV of each sentence, so a :class:`~embagents.components.TextToSpeech`
component can use either. Works with OpenAI (``tts-1``), speaches, LocalAI, Kokoro-FastAPI.

Example::

    >>> client = OpenAITranscriptionClient("http://127.0.0.1:8000", model="whisper-1")
    >>> client.url
    'http://127.0.0.1:8000/v1/audio/transcriptions'
"""

from __future__ import annotations

import io
import wave
from collections.abc import Iterator
from typing import Any

import numpy as np

from embagents.models.backends.sherpa_stt import check_samples
from embagents.models.clients.openai_http import OpenAIHTTPClient
from embagents.models.sentences import speakable, split_sentences

__all__ = ["OpenAISpeechClient", "OpenAITranscriptionClient", "wav_bytes"]


def wav_bytes(samples: np.ndarray, sample_rate: int = 16000) -> bytes:
    """Mono samples (float32 in [-1, 1] or int16) as the bytes of a 16-bit PCM WAV file.

    >>> wav_bytes(np.zeros(16, np.float32))[:4]
    b'RIFF'
    """
    pcm = samples if samples.dtype == np.int16 else np.clip(samples * 32768.0, -32768, 32767).astype(np.int16)
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(int(sample_rate))
        w.writeframes(pcm.tobytes())
    return buf.getvalue()


class OpenAITranscriptionClient(OpenAIHTTPClient):
    """Transcribes with an OpenAI-compatible server (see the module docstring).

    ``base_url`` may or may not end in ``/v1``; ``model`` is the server's
    model id; ``language`` (ISO 639-1) is sent when given.
    """

    def __init__(self, base_url: str, model: str = "whisper-1", api_key: str | None = None, timeout: float = 60.0,
                 language: str | None = "en") -> None:
        super().__init__(base_url, model=model, api_key=api_key, timeout=timeout)
        self.url = self.api_root + "/audio/transcriptions"
        self.language = language
        self.name = f"openai-stt:{model}"

    def transcribe(self, audio: Any, sample_rate: int = 16000) -> dict[str, Any]:
        """The text said in ``audio`` (1-D float32 or int16 samples): ``{"text", "seconds"}``.

        Raises ``ConnectionError`` / ``TimeoutError`` / :class:`~embagents.models.clients.openai_http.OpenAIHTTPError`
        with the URL and what to check.
        """

        samples = np.asarray(audio)
        check_samples(samples)  # a clear error here, not an HTTP 400 from the server
        extra = {"language": self.language} if self.language else {}
        with self._errors(self.url):
            result = self._client().audio.transcriptions.create(
                model=self.model, file=("speech.wav", wav_bytes(samples, sample_rate), "audio/wav"),
                response_format="json", **extra)
        text = result if isinstance(result, str) else getattr(result, "text", "")
        return {"text": str(text).strip(), "seconds": len(samples) / float(sample_rate)}


class OpenAISpeechClient(OpenAIHTTPClient):
    """Speaks with an OpenAI-compatible server (see the module docstring).

    ``model`` and ``voice`` are the server's (e.g. ``tts-1`` and ``alloy``); ``speed`` is sent when given.

    >>> OpenAISpeechClient("http://127.0.0.1:8000/v1", voice="joe").url
    'http://127.0.0.1:8000/v1/audio/speech'
    """

    def __init__(self, base_url: str, model: str = "tts-1", voice: str = "alloy", api_key: str | None = None,
                 timeout: float = 60.0) -> None:
        super().__init__(base_url, model=model, api_key=api_key, timeout=timeout)
        self.url = self.api_root + "/audio/speech"
        self.voice = voice
        self.name = f"openai-tts:{model}/{voice}"

    def speak(self, text: str, speed: float | None = None) -> Iterator[dict[str, Any]]:
        """A chunk per sentence, ``{"audio": float32 samples, "sample_rate", "text"}``, then ``{"done": True, "seconds"}``.

        Raises ``ValueError`` for text with nothing to say, ``ConnectionError`` /
        ``TimeoutError`` / :class:`~embagents.models.clients.openai_http.OpenAIHTTPError` naming the URL,
        and ``ValueError`` when the server's answer is not a WAV file.
        """

        if not speakable(text):
            raise ValueError(f"text {str(text)[:60]!r} has no speakable characters (no letters or digits); send words")
        extra = {"speed": speed} if speed is not None else {}
        seconds = 0.0
        for sentence in (s for s in split_sentences(text) if speakable(s)):
            with self._errors(self.url):
                answer = self._client().audio.speech.create(model=self.model, voice=self.voice, input=sentence,
                                                            response_format="wav", **extra)
            samples, rate = _read_wav_bytes(answer.content, self.url)
            seconds += len(samples) / rate
            yield {"audio": samples, "sample_rate": rate, "text": sentence}
        yield {"done": True, "seconds": seconds}


def _read_wav_bytes(data: bytes, url: str) -> tuple[np.ndarray, int]:
    try:
        with wave.open(io.BytesIO(data)) as w:
            if w.getsampwidth() != 2:
                raise wave.Error(f"{8 * w.getsampwidth()}-bit samples")
            pcm = np.frombuffer(w.readframes(w.getnframes()), "<i2")
            channels, rate = w.getnchannels(), w.getframerate()
    except (wave.Error, EOFError) as exc:
        raise ValueError(f"{url} answered {len(data)} bytes that are not a 16-bit PCM WAV file ({exc}); "
                         "check that the server supports response_format='wav'") from None
    samples = pcm.astype(np.float32) / 32768.0
    if channels > 1:
        samples = samples.reshape(-1, channels).mean(axis=1, dtype=np.float32)
    return samples, rate
