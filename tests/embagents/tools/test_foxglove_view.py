"""`embagents view`: a real WebSocket client speaking the Foxglove protocol sees the run's topics."""

from __future__ import annotations

import asyncio
import json
import socket
import struct
import subprocess

import websockets

from embagents.tools.mcap_codec import decode
from tests.embagents.tools.conftest import Run
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
