"""Speech-to-text on an OpenAI-compatible server: ``POST /v1/audio/transcriptions`` (``openai`` package).

The remote alternative to a local :class:`~embagents.models.SpeechToTextModel`:
:meth:`OpenAITranscriptionClient.transcribe` takes the same 16 kHz samples and
answers the same ``{"text", "seconds"}``, so a :class:`~embagents.components.SpeechToText`
component can use either (and switch between them). The samples are sent as a
16-bit WAV file. Works with OpenAI (``whisper-1``), speaches / faster-whisper-server,
LocalAI and vLLM's audio endpoint.

Example::

    >>> client = OpenAITranscriptionClient("http://127.0.0.1:8000", model="whisper-1")
    >>> client.url
    'http://127.0.0.1:8000/v1/audio/transcriptions'
"""

from __future__ import annotations

import io
import wave
from typing import Any

import numpy as np

from embagents.clients.openai_http import OpenAIHTTPClient

__all__ = ["OpenAITranscriptionClient", "wav_bytes"]


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

        Raises ``ConnectionError`` / ``TimeoutError`` / :class:`~embagents.clients.openai_http.OpenAIHTTPError`
        with the URL and what to check.
        """
        from embagents.models.backends.sherpa_stt import check_samples

        samples = np.asarray(audio)
        check_samples(samples)  # a clear error here, not an HTTP 400 from the server
        extra = {"language": self.language} if self.language else {}
        with self._errors(self.url):
            result = self._client().audio.transcriptions.create(
                model=self.model, file=("speech.wav", wav_bytes(samples, sample_rate), "audio/wav"),
                response_format="json", **extra)
        text = result if isinstance(result, str) else getattr(result, "text", "")
        return {"text": str(text).strip(), "seconds": len(samples) / float(sample_rate)}
