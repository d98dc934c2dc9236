"""OpenAISpeechClient against a real /v1/audio/speech server (the Piper voice on sherpa-onnx)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler
from typing import Any

import numpy as np
import pytest

pytest.importorskip("openai")
pytest.importorskip("sherpa_onnx")
pytest.importorskip("espeakng_loader")

from embagents.components import TextToSpeech  # noqa: E402
from embagents.models.backends.sherpa_stt import SherpaRecognizer  # noqa: E402
from embagents.models.backends.sherpa_tts import SherpaSpeaker  # noqa: E402
from embagents.models.clients import OpenAISpeechClient  # noqa: E402
from embagents.models.clients.openai_audio import wav_bytes  # noqa: E402
from embagents.models.clients.openai_http import OpenAIHTTPError  # noqa: E402
from embagents.msgs import Audio, String  # noqa: E402
from embagents.topic import Topic  # noqa: E402
from tests.helpers import serve_http  # noqa: E402


@pytest.fixture(scope="module")
def server(piper_dir: str) -> Iterator[tuple[str, list[dict[str, Any]]]]:
    speaker = SherpaSpeaker(piper_dir)
    seen: list[dict[str, Any]] = []

    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args: Any) -> None:
            pass

        def do_POST(self) -> None:  # noqa: N802 - http.server's name
            body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
            seen.append(body)
            if body.get("model") == "broken":
                self.send_response(500)
                kind, payload = "application/json", b'{"error": {"message": "voice broken failed to load"}}'
            elif body.get("model") == "mp3-only":
                self.send_response(200)
                kind, payload = "audio/mpeg", b"ID3\x03not a wav"
            else:
                audio = np.concatenate([a for a, _, _ in speaker.speak(body["input"], speed=body.get("speed"))])
                self.send_response(200)
                kind, payload = "audio/wav", wav_bytes(audio, speaker.sample_rate)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(payload)))
            self.end_headers()
            self.wfile.write(payload)

    with serve_http(Handler) as url:
        yield url, seen


def test_the_server_speaks_each_sentence_and_a_recognizer_hears_it(server: tuple, whisper_dir: str) -> None:
    url, seen = server
    chunks = list(OpenAISpeechClient(url, model="piper", voice="joe").speak("Hello robot. Bring me the cup."))
    assert [c.get("text") for c in chunks[:-1]] == ["Hello robot.", "Bring me the cup."]
    assert seen[-1] == {"model": "piper", "voice": "joe", "input": "Bring me the cup.", "response_format": "wav"}
    assert chunks[-1]["done"] and chunks[-1]["seconds"] > 1.0
    from scipy.signal import resample_poly

    quiet = np.zeros(8000, np.float32)  # Whisper hears a sentence best with a pause around it
    speech = np.concatenate([quiet, resample_poly(chunks[1]["audio"], 320, 441).astype(np.float32), quiet])
    heard = SherpaRecognizer(whisper_dir).transcribe(speech)
    assert "cup" in heard.lower(), heard


def test_the_tts_component_speaks_through_the_server(server: tuple) -> None:
    url, _ = server
    comp = TextToSpeech(name="voice", inputs=[Topic("answer", String)], outputs=[Topic("speaker", Audio, keep="all")],
                        model_client=OpenAISpeechClient(url, model="piper", voice="joe"))
    sent: list[Audio] = []
    comp.attach(lambda topic, msg: sent.append(msg), None, lambda delay, fn: fn())
    comp.on_configure()
    comp.on_message("answer", String(data="It is done."))
    assert comp.execute()
    assert [a.data.size > 0 for a in sent] == [True, False] and sent[0].sample_rate == 22050


def test_server_errors_and_bad_answers_are_named(server: tuple) -> None:
    url, _ = server
    with pytest.raises(OpenAIHTTPError, match="voice broken failed to load"):
        list(OpenAISpeechClient(url, model="broken").speak("Hello."))
    with pytest.raises(ValueError, match="not a 16-bit PCM WAV file.*response_format='wav'"):
        list(OpenAISpeechClient(url, model="mp3-only").speak("Hello."))
    with pytest.raises(ValueError, match="no speakable characters"):
        list(OpenAISpeechClient(url).speak("?!"))
    with pytest.raises(ConnectionError):
        list(OpenAISpeechClient("http://127.0.0.1:9", timeout=2).speak("Hello."))
