"""`embagents view`: a real WebSocket client speaking the Foxglove protocol sees the run's topics."""

from __future__ import annotations

import asyncio
import json
import socket
import struct
import subprocess

import websockets

from embagents.tools.mcap_codec import decode
from tests.embagents.fixtures.live_run import Run
from tests.helpers import free_port, wait_until

SUBPROTOCOL = "foxglove.sdk.v1"  # what foxglove-sdk's server speaks (the Foxglove WebSocket protocol)


async def _first_messages(port: int, topics: list[str]) -> tuple[dict[str, dict], dict[str, bytes]]:
    async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL]) as ws:  # type: ignore[list-item]
        channels: dict[str, dict] = {}
        while not set(topics) <= set(channels):
            msg = json.loads(await ws.recv())
            if msg["op"] == "advertise":
                channels.update({c["topic"]: c for c in msg["channels"]})
        subs = [{"id": i, "channelId": channels[t]["id"]} for i, t in enumerate(topics)]
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
        got: dict[str, bytes] = {}
        while len(got) < len(topics):
            frame = await asyncio.wait_for(ws.recv(), 20)
            if isinstance(frame, bytes) and frame[0] == 0x01:  # message data: opcode, sub id, time, payload
                (sub_id,) = struct.unpack_from("<I", frame, 1)
                got.setdefault(topics[sub_id], frame[13:])
        return channels, got


def test_foxglove_client_subscribes_and_receives(live_run: Run) -> None:
    port = free_port()
    view = live_run.popen("view", "--port", str(port), "--duration", "60")
    try:
        wait_until(lambda: socket.socket().connect_ex(("127.0.0.1", port)) == 0, 30, "the Foxglove server")
        topics = ["chatter", "camera/image", "dets/annotations"]
        channels, got = asyncio.run(_first_messages(port, topics))
        assert channels["camera/image"]["schemaName"] == "foxglove.RawImage"
        assert channels["dets/annotations"]["schemaName"] == "foxglove.ImageAnnotations"
        assert "_supervisor.events" in channels
        assert json.loads(got["chatter"])["data"].startswith("hello")
        assert decode("foxglove.RawImage", got["camera/image"]).data.shape == (240, 320, 3)
    finally:
        view.terminate()
        assert view.wait(20) == 0


def test_a_taken_port_says_which_and_how_to_choose_another(live_run: Run) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        out = live_run.cli("view", "--port", str(port), "--duration", "1")
    assert out.returncode == 1
    assert f"127.0.0.1:{port}" in out.stderr and "choose another with --port" in out.stderr
    assert isinstance(out, subprocess.CompletedProcess)


async def _handshake(port: int, origin: str | None, path: str = "/") -> int:
    """The HTTP status of a Foxglove WebSocket handshake with this ``Origin`` (101: it went through)."""
    try:
        async with websockets.connect(f"ws://127.0.0.1:{port}{path}", origin=origin,  # type: ignore[arg-type]
                                      subprotocols=[SUBPROTOCOL]) as ws:  # type: ignore[list-item]
            assert json.loads(await asyncio.wait_for(ws.recv(), 20))["op"] == "serverInfo"
            return 101
    except websockets.InvalidStatus as exc:
        return exc.response.status_code


def test_a_page_of_a_foreign_origin_is_refused_and_the_app_or_an_allowed_one_is_not(live_run: Run) -> None:
    port = free_port()
    view = live_run.popen("view", "--port", str(port), "--duration", "60", "--allow-origin", "http://localhost:8080")
    try:
        assert view.stdout is not None
        said = view.stdout.readline() + view.stdout.readline()
        token_url = said.split("pages of origins other than ", 1)[1].split(": ", 1)[1].strip()
        assert token_url.startswith(f"ws://127.0.0.1:{port}/?token=")
        assert asyncio.run(_handshake(port, "http://evil.example")) == 403
        assert asyncio.run(_handshake(port, "null")) == 403
        assert asyncio.run(_handshake(port, "http://evil.example", "/?token=wrong")) == 403
        assert asyncio.run(_handshake(port, None)) == 101  # the desktop app sends no Origin
        assert asyncio.run(_handshake(port, "https://app.foxglove.dev")) == 101
        assert asyncio.run(_handshake(port, "http://localhost:8080")) == 101  # --allow-origin
        assert asyncio.run(_handshake(port, "http://evil.example", token_url[len(f"ws://127.0.0.1:{port}"):])) == 101
        with socket.create_connection(("127.0.0.1", port), timeout=20) as raw:  # a client still there at the end
            raw.sendall(f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                        f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Key: MDEyMzQ1Njc4OWFiY2RlZg==\r\n"
                        f"Sec-WebSocket-Protocol: {SUBPROTOCOL}\r\n\r\n".encode())
            assert raw.recv(4096).startswith(b"HTTP/1.1 101")
            view.terminate()
            assert view.wait(20) == 0
            while raw.recv(1 << 16):  # the view closed it on its way out
                pass
    finally:
        view.terminate()
        assert view.wait(20) == 0
    assert view.stderr is not None
    refused = view.stderr.read()
    assert refused.count("refused a page of origin http://evil.example") == 1 and "--allow-origin ORIGIN" in refused


def test_on_every_address_it_warns_and_a_bad_origin_is_named(live_run: Run) -> None:
    port = free_port()
    out = live_run.cli("view", "--host", "0.0.0.0", "--port", str(port), "--duration", "0.5")
    assert out.returncode == 0, out.stderr
    assert "warning: embagents view listens on 0.0.0.0" in out.stderr and "--host 127.0.0.1" in out.stderr
    bad = live_run.cli("view", "--port", str(port), "--allow-origin", "app.foxglove.dev", "--duration", "0.5")
    assert bad.returncode == 1 and "--allow-origin 'app.foxglove.dev' is not an origin" in bad.stderr
