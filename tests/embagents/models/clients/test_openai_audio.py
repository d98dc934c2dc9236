"""OpenAITranscriptionClient against a real /v1/audio/transcriptions server (Whisper on sherpa-onnx)."""

from __future__ import annotations

import io
import json
import re
import socket
import wave
from collections.abc import Iterator
from email.parser import BytesParser
from email.policy import HTTP
from http.server import BaseHTTPRequestHandler
from typing import Any

import numpy as np
import pytest

pytest.importorskip("openai")
pytest.importorskip("sherpa_onnx")

from embagents.components import SpeechToText, SpeechToTextConfig  # noqa: E402
from embagents.models.backends.sherpa_stt import SherpaRecognizer  # noqa: E402
from embagents.models.clients.openai_audio import OpenAITranscriptionClient  # noqa: E402
from embagents.models.clients.openai_http import OpenAIHTTPError  # noqa: E402
from embagents.msgs import Audio, String  # noqa: E402
from embagents.topic import Topic  # noqa: E402
from tests.helpers import serve_http  # noqa: E402


def words(text: str) -> str:
    return " ".join(re.findall(r"[a-z']+", text.lower()))


def _form(handler: BaseHTTPRequestHandler) -> dict[str, Any]:
    body = handler.rfile.read(int(handler.headers["Content-Length"]))
    head = f"Content-Type: {handler.headers['Content-Type']}\r\n\r\n".encode()
    msg = BytesParser(policy=HTTP).parsebytes(head + body)
    return {part.get_param("name", header="content-disposition"): part.get_payload(decode=True)
            for part in msg.iter_parts()}


@pytest.fixture(scope="module")
def server(whisper_dir: str) -> Iterator[tuple[str, list[dict[str, Any]]]]:
    recognizer = SherpaRecognizer(whisper_dir)
    seen: list[dict[str, Any]] = []

    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args: Any) -> None:
            pass

        def do_POST(self) -> None:  # noqa: N802 - http.server's name
            form = _form(self)
            seen.append({k: v for k, v in form.items() if k != "file"})
            if form.get("model") == b"broken":
                self.send_response(500)
                payload = b'{"error": {"message": "model broken failed to load"}}'
            else:
                with wave.open(io.BytesIO(form["file"])) as w:
                    pcm = np.frombuffer(w.readframes(w.getnframes()), np.int16)
                    rate = w.getframerate()
                self.send_response(200)
                payload = json.dumps({"text": recognizer.transcribe(pcm, rate)}).encode()
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(payload)))
            self.end_headers()
            self.wfile.write(payload)

    with serve_http(Handler) as url:
        yield url, seen


def test_the_server_transcribes_what_the_client_sends(server: tuple, speech_clip: tuple) -> None:
    url, seen = server
    client = OpenAITranscriptionClient(url, model="whisper-tiny.en")
    out = client.transcribe(speech_clip[0][:44000].astype(np.float32) / 32768)
    assert words(out["text"]) == "ever tried ever failed" and out["seconds"] == 2.75
    assert seen[-1] == {"model": b"whisper-tiny.en", "language": b"en", "response_format": b"json"}


def test_the_component_can_use_the_server_instead_of_a_local_model(server: tuple, speech_clip: tuple) -> None:
    comp = SpeechToText(name="ears", inputs=[Topic("mic", Audio, keep="all")], outputs=[Topic("heard", String)],
                        model_client=OpenAITranscriptionClient(server[0]), config=SpeechToTextConfig(enable_vad=False))
    sent: list[Any] = []
    comp.attach(lambda topic, msg: sent.append(msg))
    comp.on_configure()
    comp.on_message("mic", Audio(data=speech_clip[0][:44000]))
    assert comp.execute() and [words(m.data) for m in sent] == ["ever tried ever failed"]


def test_server_errors_and_a_missing_server_are_named(server: tuple) -> None:
    with pytest.raises(OpenAIHTTPError, match="HTTP 500 .*model broken failed to load"):
        OpenAITranscriptionClient(server[0], model="broken").transcribe(np.zeros(1600, np.float32))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        free = s.getsockname()[1]
    with pytest.raises(ConnectionError, match=f"Cannot connect to http://127.0.0.1:{free}/v1/audio/transcriptions"):
        OpenAITranscriptionClient(f"http://127.0.0.1:{free}", timeout=5).transcribe(np.zeros(1600, np.float32))
    with pytest.raises(ValueError, match="dtype float64"):
        OpenAITranscriptionClient(server[0]).transcribe(np.zeros(1600))
