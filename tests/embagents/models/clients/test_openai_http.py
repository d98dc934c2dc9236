"""OpenAIHTTPClient against llama-cpp-python's own OpenAI-compatible server (a real subprocess)."""

from __future__ import annotations

import contextlib
import importlib.util
import os
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import msgpack
import pytest

from embagents.models.clients.openai_http import OpenAIHTTPClient, OpenAIHTTPError
from tests.helpers import wait_until

SERVER_MODULES = (
    "llama_cpp",
    "fastapi",
    "uvicorn",
    "sse_starlette",
    "starlette_context",
    "pydantic_settings",
)
_missing = [m for m in SERVER_MODULES if importlib.util.find_spec(m) is None]
SKIP_REASON = (
    f"llama-cpp-python server extras not installed (missing: {', '.join(_missing)}); "
    "pip install fastapi uvicorn sse-starlette starlette-context pydantic-settings"
)

HELLO = [{"role": "user", "content": "hello"}]
# llama_cpp.server defaults repeat_penalty to 1.1, in-process llama-cpp-python to 1.0.
SAME_AS_INPROCESS = {"repeat_penalty": 1.0}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def _llama_server(args: list[str], log_path: Path) -> Iterator[str]:
    """Base URL of ``python -m llama_cpp.server ARGS`` on a free loopback port, stopped afterwards."""
    if _missing:
        pytest.skip(SKIP_REASON)
    port = _free_port()
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "llama_cpp.server", *args, "--host", "127.0.0.1", "--port", str(port),
             "--n_ctx", "512"],
            stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )  # fmt: skip
    base_url = f"http://127.0.0.1:{port}"
    try:
        client = OpenAIHTTPClient(base_url, timeout=5.0)

        def answering() -> bool:
            if proc.poll() is not None:
                pytest.fail(f"llama_cpp.server exited with {proc.returncode}:\n{log_path.read_text()[-3000:]}")
            try:
                client.list_models()
            except ConnectionError:
                return False
            return True

        try:
            wait_until(answering, 60.0, "llama_cpp.server answering", interval=0.1)
        except AssertionError as exc:
            pytest.fail(f"{exc}:\n{log_path.read_text()[-3000:]}")
        yield base_url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)


@pytest.fixture(scope="module")
def server(tiny_gguf: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """Base URL of a running ``python -m llama_cpp.server`` on the tiny model."""
    with _llama_server(["--model", tiny_gguf], tmp_path_factory.mktemp("server") / "server.log") as url:
        yield url


@pytest.mark.llama_in_process  # see tests/conftest.py
def test_chat_matches_inprocess_backend(server: str, tiny_gguf: str) -> None:
    from embagents.models.backends.llama import LlamaBackend

    reply = OpenAIHTTPClient(server).chat(HELLO, max_tokens=20, extra=SAME_AS_INPROCESS)
    assert reply["finish_reason"] == "length"
    assert reply["tool_calls"] is None
    backend = LlamaBackend(tiny_gguf, n_ctx=512)
    try:
        expected = backend.chat(HELLO, max_tokens=20)["content"]
    finally:
        backend.close()
    assert reply["content"] == expected and len(expected) > 10


def test_chat_stream_yields_deltas_then_done(server: str) -> None:
    chunks = list(OpenAIHTTPClient(server + "/v1/").chat_stream(HELLO, max_tokens=16))
    deltas, final = chunks[:-1], chunks[-1]
    assert len(deltas) >= 5
    assert all(set(c) == {"delta"} and c["delta"] for c in deltas)
    assert final["done"] is True and final["finish_reason"] == "length"
    assert final["usage"]["completion_tokens"] >= 5
    assert final["timing"]["first_token_s"] <= final["timing"]["total_s"]
    assert msgpack.unpackb(msgpack.packb(chunks)) == chunks


def test_stop_string_over_http(server: str) -> None:
    client = OpenAIHTTPClient(server)
    full = client.chat(HELLO, max_tokens=24)["content"]
    stop = full[-6:-3]
    cut = full.find(stop)
    assert cut > 0, f"pick another stop string for {full!r}"
    reply = client.chat(HELLO, max_tokens=24, stop=[stop])
    assert reply["content"] == full[:cut] and reply["finish_reason"] == "stop"


def test_connection_refused_names_the_url() -> None:
    url = f"http://127.0.0.1:{_free_port()}"
    with pytest.raises(ConnectionError, match="connection refused") as info:
        OpenAIHTTPClient(url, timeout=5.0).chat(HELLO)
    assert f"{url}/v1/chat/completions" in str(info.value)


def test_http_errors_carry_status_and_body(server: str) -> None:
    with pytest.raises(OpenAIHTTPError) as info:
        OpenAIHTTPClient(server + "/no/such/prefix").chat(HELLO)
    assert info.value.status == 404 and "HTTP 404" in str(info.value)
    assert "/no/such/prefix/v1/chat/completions" in str(info.value)
    with pytest.raises(OpenAIHTTPError) as info:
        OpenAIHTTPClient(server).chat(HELLO, extra={"max_tokens": "many"})
    assert info.value.status is not None and info.value.status >= 400
    assert "max_tokens" in info.value.body  # the server's validation message, excerpted


def test_bad_base_url_and_messages_fail_before_any_request() -> None:
    with pytest.raises(ValueError, match="http://"):
        OpenAIHTTPClient("127.0.0.1:8000")
    with pytest.raises(ValueError, match="non-empty list"):
        OpenAIHTTPClient("http://127.0.0.1:9").chat([])


# --- protocol corners, against a stdlib HTTP server with canned replies -------------

_TOOL_STREAM = [
    {"choices": [{"delta": {"role": "assistant"}}]},
    {"choices": [{"delta": {"tool_calls": [{"index": 0, "id": "c9", "function": {"name": "move", "arguments": '{"direc'}}]}}]},
    {"choices": [{"delta": {"tool_calls": [{"index": 0, "function": {"arguments": 'tion": "left"}'}}]}, "finish_reason": "tool_calls"}]},
    {"choices": [], "usage": {"prompt_tokens": 7, "completion_tokens": 3, "total_tokens": 10}},
]  # fmt: skip
_JSON_REPLY = {
    "choices": [{"message": {"role": "assistant", "content": "Hi there"}, "finish_reason": "stop"}],
    "usage": {"prompt_tokens": 2, "completion_tokens": 2, "total_tokens": 4},
}


@pytest.fixture(scope="module")
def canned() -> Iterator[str]:
    import json
    import threading
    from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args: object) -> None:
            pass

        def do_POST(self) -> None:
            self.rfile.read(int(self.headers["Content-Length"]))
            kind = self.path.split("/")[1]
            if kind == "json":  # a server that ignores stream=true
                body = json.dumps(_JSON_REPLY).encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)
                return
            events = (
                _TOOL_STREAM if kind == "tools" else [{"choices": [{"delta": {"content": "Hel"}}]}]
            )
            self.send_response(200)
            self.send_header("Content-Type", "text/event-stream")
            self.end_headers()
            for event in events:
                self.wfile.write(f"data: {json.dumps(event)}\r\n\r\n".encode())
            if kind == "tools":
                self.wfile.write(b": keep-alive comment\n\ndata: [DONE]\n\n")
            self.close_connection = True  # "partial": the body just ends

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}"
    httpd.shutdown()
    httpd.server_close()


def test_streamed_tool_call_fragments_and_usage(canned: str) -> None:
    tools = [{"type": "function", "function": {"name": "move", "parameters": {}}}]
    chunks = list(OpenAIHTTPClient(canned + "/tools").chat_stream(HELLO, tools=tools))
    (final,) = chunks
    assert final["finish_reason"] == "tool_calls"
    assert final["tool_calls"] == [{"id": "c9", "name": "move", "arguments": {"direction": "left"}}]
    assert final["usage"] == {"prompt_tokens": 7, "completion_tokens": 3, "total_tokens": 10}


def test_non_streaming_json_reply_is_accepted(canned: str) -> None:
    reply = OpenAIHTTPClient(canned + "/json").chat(HELLO)
    assert reply["content"] == "Hi there" and reply["finish_reason"] == "stop"
    assert reply["usage"]["total_tokens"] == 4


def test_truncated_stream_is_an_error_not_a_short_reply(canned: str) -> None:
    stream = OpenAIHTTPClient(canned + "/partial").chat_stream(HELLO)
    assert next(stream) == {"delta": "Hel"}
    with pytest.raises(ConnectionError, match="ended before the reply was complete"):
        next(stream)


@pytest.fixture(scope="module")
def vlm_server(tiny_vlm: tuple[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    """llama_cpp.server with the tiny LLaVA-style model (its clip model path and llava-1-5 format), and its log."""
    log = tmp_path_factory.mktemp("vlm-server") / "server.log"
    args = ["--model", tiny_vlm[0], "--clip_model_path", tiny_vlm[1], "--chat_format", "llava-1-5"]
    with _llama_server(args, log) as url:
        yield url, log


def test_images_reach_a_vision_server_as_image_url_parts(vlm_server: tuple[str, Path]) -> None:
    import numpy as np

    url, log = vlm_server
    client = OpenAIHTTPClient(url)

    def encoded() -> int:  # the server's llama.cpp logs each image its projector encodes
        return log.read_text(errors="replace").count("encoding image slice")

    before = encoded()
    frame = np.full((48, 64, 3), 100, np.uint8)
    reply = client.chat([{"role": "user", "content": "what do you see?"}], images=[frame, frame], max_tokens=4)
    assert reply["finish_reason"] == "length" and reply["content"]
    wait_until(lambda: encoded() - before == 2, 5.0, "two images encoded by the server")
    with pytest.raises(ValueError, match=r"\(H, W, 3\) uint8 RGB array, got shape \(48, 64\)"):
        client.chat([{"role": "user", "content": "what?"}], images=[frame[:, :, 0]], max_tokens=2)
