"""Two runs linked by their Zenoh bridges over loopback: a component on one publishes, one on the other receives."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.embagents.zenoh.runs import RECEIVER, SENDER, Run, free_port, linked, wait_for, write

pytest.importorskip("zenoh")


def test_a_topic_crosses_from_one_run_to_the_other_in_order(tmp_path: Path) -> None:
    port = free_port()
    runs = str(tmp_path / "runs")
    a = Run(write(tmp_path, "robot_a", SENDER, f"listen=['tcp/127.0.0.1:{port}']"), runs)
    b = Run(write(tmp_path, "gpu_b", RECEIVER, f"connect=['tcp/127.0.0.1:{port}']"), runs)
    try:
        wait_for(lambda: len(b.got()) >= 20, 60, "20 messages on run B: " + "".join(b.all[-20:]))
        got = b.got()
        assert got == list(range(got[0], got[0] + len(got)))  # in order, none twice, none missing
        detail = wait_for(lambda: b.bridge(), 30, "the bridge's status detail")
        link = detail["links"][0]
        assert (link["endpoint"], link["role"], link["state"]) == (f"tcp/127.0.0.1:{port}", "connect", "up")
        assert detail["counts"]["msgs_in"] >= 20 and detail["health"] == "HEALTHY"
        sender = wait_for(lambda: a.bridge(), 30, "run A's bridge detail")
        assert sender["links"][0]["state"] == "up" and sender["counts"]["msgs_out"] >= 20

        # Garbage on the Zenoh port: refused by Zenoh, the bridge stays up and the link keeps flowing.
        import os
        import socket

        for _ in range(3):
            with socket.create_connection(("127.0.0.1", port)) as s:
                s.sendall(os.urandom(4096) + b"\xff" * 4096)
        n = len(b.got())
        wait_for(lambda: len(b.got()) >= n + 20, 30, "messages after the garbage")
        rows = {r["name"]: r for r in a.status()["rows"]}  # type: ignore[index]
        assert rows["_zenoh_bridge"]["restarts"] == 0 and rows["_zenoh_bridge"]["status"] == "running"
        got = b.got()
        assert got == list(range(got[0], got[0] + len(got)))

        import subprocess
        import sys

        topics = subprocess.run([sys.executable, "-m", "embagents.cli", "topic", "list", "--run", "gpu_b"],
                                capture_output=True, text=True, timeout=60, env=b.env).stdout
        assert "(remote robot*/chatter)" in topics  # the remote topic names its host's key
    finally:
        codes = b.stop(), a.stop()  # both stopped before either is judged: nothing left running
        assert codes == (0, 0), "".join(b.all[-30:] + a.all[-30:])


def test_a_link_that_never_came_up_is_an_error_in_status_and_the_log(tmp_path: Path) -> None:
    port = free_port()  # nobody listens there
    runs = str(tmp_path / "runs")
    b = Run(write(tmp_path, "lonely", RECEIVER, f"connect=['tcp/127.0.0.1:{port}']", link_down_s=1.0), runs)
    try:
        def failing() -> dict | None:
            d = b.bridge()
            return d if d and d["health"] == "SYSTEM_FAILURE" and d["links"][0]["last_error"] else None

        detail = wait_for(failing, 60, "SYSTEM_FAILURE on the bridge: " + "".join(b.all[-20:]))
        link = detail["links"][0]
        assert link["state"] == "never up"
        assert "Connection refused" in link["last_error"] and f"127.0.0.1:{port}" in link["last_error"]
        assert "never came up" in detail["health_text"]
        wait_for(lambda: any("never came up" in x and "start the other side" in x for x in b.all), 30, "the log line")
        import subprocess
        import sys

        table = subprocess.run([sys.executable, "-m", "embagents.cli", "status", "--run", "lonely"],
                               capture_output=True, text=True, timeout=60, env=b.env).stdout
        assert f"_zenoh_bridge: zenoh connect tcp/127.0.0.1:{port}: never up for" in table
        assert "last error: Connection refused" in table
    finally:
        assert b.stop() == 0, "".join(b.all[-30:])


def test_the_two_hosts_example_brings_detections_back_to_the_robot(tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    pytest.importorskip("skimage")
    import os

    root = Path(__file__).resolve().parents[3]
    runs = str(tmp_path / "runs")
    os.environ["EMBAGENTS_ZENOH_PORT"] = str(free_port())
    os.environ["EMBAGENTS_TWO_HOSTS_N"] = "3"
    try:
        gpu = Run(str(root / "examples/two_hosts/gpu_box.py"), runs)
        robot = Run(str(root / "examples/two_hosts/robot.py"), runs)
    finally:
        del os.environ["EMBAGENTS_ZENOH_PORT"], os.environ["EMBAGENTS_TWO_HOSTS_N"]
    try:
        assert robot.proc.wait(timeout=180) == 0, "".join(robot.all[-30:])
        found = [x for x in robot.all if x.startswith("from the GPU box: ")]
        assert len(found) >= 3 and all("face 1.00" in x for x in found), "".join(robot.all[-30:])
    finally:
        codes = robot.stop(), gpu.stop()
        assert codes[1] == 0, "".join(gpu.all[-30:])


def test_an_lz4_compressed_topic_arrives_whole(tmp_path: Path) -> None:
    with linked(tmp_path, "lz", compress="lz4") as (a, b):
        wait_for(lambda: len(b.got()) >= 10, 60, "lz4 messages on run B")
        got = b.got()
        assert got == list(range(got[0], got[0] + len(got)))
        assert b.bridge()["counts"]["refused"] == 0  # type: ignore[index]


def test_a_killed_bridge_is_restarted_and_the_topic_flows_again(tmp_path: Path) -> None:
    with linked(tmp_path, "kill") as (a, b):
        wait_for(lambda: len(b.got()) >= 10, 60, "messages on run B")
        a.kill_bridge(1)
        n = len(b.got())
        wait_for(lambda: len(b.got()) >= n + 20, 60, "messages after the restart")
        got = b.got()
        assert len(set(got)) == len(got) and got == sorted(got)  # none twice, in order
        # What the killed bridge had taken but not got out (if anything) is counted on the other side.
        missing = set(range(got[0], got[-1] + 1)) - set(got)
        assert b.bridge()["counts"]["lost"] == len(missing)  # type: ignore[index]


def test_a_peer_bridge_restarted_again_and_again_leaves_no_publishers_behind_on_the_other_side(tmp_path: Path) -> None:
    import time

    from embagents.zenoh.bridge_actor import KEEP_SOURCES

    with linked(tmp_path, "again", rate=50.0) as (a, b):
        wait_for(lambda: len(b.got()) >= 10, 60, "messages on run B")
        kills = KEEP_SOURCES + 2
        for i in range(1, kills + 1):  # each incarnation of A's bridge is a new Zenoh source for B's
            time.sleep(2.0)  # kills apart: 3 restarts in 5 s is the root supervisor's intensity
            a.kill_bridge(i)
            n = len(b.got())
            wait_for(lambda n=n: len(b.got()) >= n + 10, 60, f"messages after restart {i}")  # type: ignore[misc]
        got = b.got()
        assert len(set(got)) == len(got) and got == sorted(got)  # none twice, in order
        detail = b.bridge()
        assert detail is not None
        # The current source and the KEEP_SOURCES before it; without the limit, one per incarnation (kills + 1).
        assert detail["source_publishers"] == KEEP_SOURCES + 1


def test_a_killed_receiving_bridge_delivers_each_message_once_and_counts_the_replay(tmp_path: Path) -> None:
    # 200 Hz: a live sample often reaches the restarted bridge before the replies to its history query (zenoh-ext
    # then drops them as old; the bridge fetches them): 4 runs in 14 had a gap before it did, 1 in 12 at 50 Hz.
    with linked(tmp_path, "rkill", rate=200.0) as (a, b):
        wait_for(lambda: len(b.got()) >= 20, 60, "messages on run B")
        b.kill_bridge(1)
        n = len(b.got())
        wait_for(lambda: len(b.got()) >= n + 50, 60, "messages after the restart")
        got = b.got()
        # The new bridge's subscriber gets the publisher's whole cache again: what the killed one had
        # forwarded is dropped and counted; what was sent while it was down arrives. Once, in order, no gap.
        assert got == list(range(got[0], got[0] + len(got)))
        detail = b.bridge()
        assert detail is not None and detail["counts"]["replayed"] >= 20 and detail["counts"]["lost"] == 0
        assert any("replayed" in line for line in detail["lines"])


def test_a_peers_frames_go_on_as_they_came_and_its_garbage_or_forged_handles_are_dropped_and_counted(
        tmp_path: Path) -> None:
    # A bare Zenoh peer (no bridge) puts on run B's import: frames without arrays go on to the component
    # undecoded (its subscription refuses garbage), a forged array handle is refused by the bridge itself.
    import json

    import msgpack
    import zenoh

    import embagents.msgs  # noqa: F401 - registers String
    from actors.codec import Codec
    from embagents.msgs import String
    from embagents.zenoh.bridge_actor import _HEAD, MAGIC

    def payload(body: bytes) -> bytes:
        return _HEAD.pack(MAGIC, len(body), 0) + body

    port = free_port()
    conf = zenoh.Config()
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    runs = str(tmp_path / "runs")
    with zenoh.open(conf) as session:
        b = Run(write(tmp_path, "peer_b", RECEIVER, f"connect=['tcp/127.0.0.1:{port}']"), runs)
        try:
            codec = Codec()

            def put(n: int) -> list[int]:
                session.put("robot1/chatter", payload(codec.encode(String(data=str(n)))[0]))
                return b.got()

            wait_for(lambda: put(1), 60, "a peer's message on run B: " + "".join(b.all[-20:]))
            session.put("robot1/chatter", payload(b"\xc1\xc1 no msgpack"))
            session.put("robot1/chatter", payload(msgpack.packb(msgpack.ExtType(3, msgpack.packb([0, 8, "|u1", [8]])))))
            wait_for(lambda: 7 in put(7), 30, "a message after the garbage")
            assert b.got()[-1] == 7 and set(b.got()) == {1, 7}
            detail = b.bridge()
            assert detail is not None and detail["counts"]["refused"] == 1  # the forged handle
            wait_for(lambda: any("dropped a corrupt frame" in x for x in b.all), 10, "the receiver's log line")
            rows = {r["name"]: r for r in b.status()["rows"]}  # type: ignore[index]
            assert rows["_zenoh_bridge"]["restarts"] == 0 and rows["_zenoh_bridge"]["status"] == "running"
            assert rows["printer"]["restarts"] == 0
        finally:
            assert b.stop() == 0, "".join(b.all[-30:])
