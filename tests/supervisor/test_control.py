"""The control endpoint and the discovery file."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from actors import ActorSystem
from supervisor import ChildSpec, Command, SupervisorSpec, start_supervisor
from supervisor.client import request
from supervisor.control import ControlServer, runs_dir
from tests.helpers import wait_until
from tests.supervisor.conftest import EventLog, ask
from tests.supervisor.workers import Echo, SlowStop


def tree(system: ActorSystem):
    inner = SupervisorSpec(children=[ChildSpec("deep", Echo)])
    return start_supervisor(system, SupervisorSpec(children=[
        ChildSpec("a", Echo, lifecycle="active"), ChildSpec("x", Command(["sleep", "60"])), ChildSpec("in", inner)]))


def test_status_lists_every_child_with_its_numbers(system: ActorSystem) -> None:
    tree(system)
    control = ControlServer(system, "demo")
    try:
        for _ in range(10):
            system.ref("a").tell("hi")
        ask(system, "a", "sync")
        reply = request(system.run_dir, {"cmd": "status"})
        assert reply["system"] == "demo" and reply["run_id"] == system.run_id and reply["pid"] == os.getpid()
        rows = {r["name"]: r for r in reply["rows"]}
        assert list(rows) == ["a", "x", "in", "deep"]
        a = rows["a"]
        assert a["status"] == "running" and a["supervisor"] == "root" and a["kind"] == "actor"
        assert a["lifecycle"] == "active" and a["restarts"] == 0 and a["pid"] > 0
        assert a["mailbox"] == 0 and a["handled"] >= 11 and a["rate"] is not None
        assert a["drops"] == 0 and a["subscriptions"] == [] and a["stalled"] == {}  # per-subscription counts
        assert rows["deep"]["supervisor"] == "root/in"
        assert rows["x"]["kind"] == "command" and rows["x"]["mailbox"] is None
        wait_until(lambda: request(system.run_dir, {"cmd": "status"})["rows"][0]["rss_mb"], 5, "an rss sample")
    finally:
        control.close()


def test_restart_by_name_anywhere_in_the_tree(system: ActorSystem, events: EventLog) -> None:
    tree(system)
    control = ControlServer(system, "demo")
    try:
        old = ask(system, "deep")
        reply = request(system.run_dir, {"cmd": "restart", "name": "deep"})
        assert reply["pid"] != old and ask(system, "deep") == reply["pid"]
        rows = {r["name"]: r for r in request(system.run_dir, {"cmd": "status"})["rows"]}
        assert rows["deep"]["restarts"] == 1
        bad = request_error(system, {"cmd": "restart", "name": "nobody"})
        assert "no child named 'nobody'" in bad and "known: a, deep, in, x" in bad  # names the known ones
        assert "unknown command" in request_error(system, {"cmd": "dance"})
    finally:
        control.close()


def test_a_command_added_by_the_layer_above_is_served_and_listed(system: ActorSystem) -> None:
    tree(system)
    control = ControlServer(system, "demo")
    try:
        control.add_command("echo", lambda msg: {"ok": True, "said": msg["text"]})
        assert request(system.run_dir, {"cmd": "echo", "text": "hi"})["said"] == "hi"
        assert "one of: status, restart, stop, wait_ready, echo" in request_error(system, {"cmd": "dance"})
        assert "KeyError" in request_error(system, {"cmd": "echo"})  # a failing handler is an answer
        with pytest.raises(ValueError, match="already served"):
            control.add_command("status", lambda msg: {"ok": True})
    finally:
        control.close()


def request_error(system: ActorSystem, msg: dict) -> str:
    from supervisor.client import ControlError

    try:
        request(system.run_dir, msg)
    except ControlError as exc:
        return str(exc)
    raise AssertionError("the request should have failed")


def test_stop_answers_then_calls_on_stop(system: ActorSystem) -> None:
    tree(system)
    stopped = threading.Event()
    control = ControlServer(system, "demo", on_stop=stopped.set)
    try:
        assert request(system.run_dir, {"cmd": "stop"})["stopping"] is True
        assert stopped.wait(5)
    finally:
        control.close()


def test_the_discovery_file_lives_as_long_as_the_endpoint(system: ActorSystem) -> None:
    control = ControlServer(system, "demo")
    path = os.path.join(runs_dir(), f"{system.run_id}.json")
    with open(path) as f:
        info = json.load(f)
    assert info["run_dir"] == system.run_dir and info["pid"] == os.getpid() and info["system"] == "demo"
    assert oct(os.stat(runs_dir()).st_mode & 0o777) == "0o700"
    control.close()
    assert not os.path.exists(path)


def _dealer(system: ActorSystem) -> Any:
    """A raw DEALER on the run's control endpoint (frames as a client in any language sends them)."""
    import zmq

    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVTIMEO, 5000)
    sock.connect(f"ipc://{system.run_dir}/_control")
    return sock


def test_garbage_on_the_control_socket_is_answered_and_the_root_goes_on(system: ActorSystem) -> None:
    import msgpack

    tree(system)
    control = ControlServer(system, "demo")
    sock = _dealer(system)
    try:
        for junk in [b"\xc1", msgpack.packb([1, 2]), msgpack.packb({"cmd": 7}), msgpack.packb({"cmd": "restart", "name": ["x"]})]:
            sock.send_multipart([b"", junk])
            reply = msgpack.unpackb(sock.recv_multipart()[-1])
            assert reply["ok"] is False and reply["error"], reply
        assert request(system.run_dir, {"cmd": "status"})["ok"]
    finally:
        sock.close()
        control.close()


def test_wait_ready_is_answered_when_the_run_is_ready_and_status_keeps_being_served(system: ActorSystem) -> None:
    tree(system)
    control = ControlServer(system, "demo")
    try:
        control.hold_ready()
        answers: list[dict] = []
        waiter = threading.Thread(target=lambda: answers.append(request(system.run_dir, {"cmd": "wait_ready"}, 30)))
        waiter.start()
        # The held request blocks neither the endpoint nor the other requests.
        assert request(system.run_dir, {"cmd": "status"})["ready"] is False
        with open(control.discovery) as f:
            assert json.load(f)["ready"] is False
        assert answers == []
        control.mark_ready()
        waiter.join(10)
        assert [(a["ok"], a["ready"]) for a in answers] == [(True, True)]
        with open(control.discovery) as f:
            assert json.load(f)["ready"] is True
        assert request(system.run_dir, {"cmd": "wait_ready"})["ready"] is True  # at once now
    finally:
        control.close()


# -- serving side by side, and deadlines --------------------------------------
def test_a_slow_command_does_not_hold_up_status(system: ActorSystem) -> None:
    tree(system)
    control = ControlServer(system, "demo")
    release = threading.Event()
    control.add_command("slow", lambda msg: {"ok": release.wait(30)})
    answers: list[dict] = []
    slow = threading.Thread(target=lambda: answers.append(request(system.run_dir, {"cmd": "slow"}, 30)))
    try:
        slow.start()
        # One request at a time would leave this one waiting behind "slow": no answer within 5 s.
        assert request(system.run_dir, {"cmd": "status"}, 5)["rows"]
        assert not answers  # "slow" is still in flight
        release.set()
        slow.join(10)
        assert answers[0]["ok"] is True
    finally:
        release.set()
        control.close()


def test_a_late_answer_to_an_abandoned_request_is_not_taken_for_the_next_one(system: ActorSystem) -> None:
    from supervisor.client import ControlClient, ControlError

    tree(system)
    control = ControlServer(system, "demo")
    release = threading.Event()
    control.add_command("slow", lambda msg: {"ok": True, "slow": release.wait(30)})
    try:
        with ControlClient(system.run_dir) as client:
            with pytest.raises(ControlError, match="no answer .* within 0.2 s"):
                client.request({"cmd": "slow"}, 0.2)
            release.set()  # its answer comes now, to a request nobody waits for
            reply = client.request({"cmd": "status"})
            assert "rows" in reply and "slow" not in reply
    finally:
        release.set()
        control.close()


def test_a_request_whose_deadline_passed_is_answered_and_not_carried_out(system: ActorSystem) -> None:
    import time

    import msgpack

    tree(system)
    control = ControlServer(system, "demo")
    sock = _dealer(system)
    try:
        pid = ask(system, "a")
        late = {"cmd": "restart", "name": "a", "deadline": time.monotonic() - 1.0, "id": 7}
        sock.send_multipart([b"", msgpack.packb(late)])
        reply = msgpack.unpackb(sock.recv_multipart()[-1])
        assert reply["ok"] is False and reply["expired"] is True and reply["id"] == 7
        assert "restart not carried out: its deadline passed" in reply["error"]
        assert ask(system, "a") == pid
        assert {r["name"]: r for r in request(system.run_dir, {"cmd": "status"})["rows"]}["a"]["restarts"] == 0
    finally:
        sock.close()
        control.close()


def test_a_restart_whose_deadline_passes_behind_a_slow_restart_is_not_carried_out(
        system: ActorSystem, tmp_path: Path) -> None:
    from supervisor.client import ControlError

    stopping = str(tmp_path / "stopping")
    start_supervisor(system, SupervisorSpec(children=[
        ChildSpec("slow", (SlowStop, (3.0, None, False, stopping)), shutdown=20), ChildSpec("a", Echo),
        ChildSpec("b", Echo)]))
    control = ControlServer(system, "demo")
    try:
        pid = ask(system, "a")
        slow = threading.Thread(target=request, args=(system.run_dir, {"cmd": "restart", "name": "slow"}, 30))
        slow.start()
        wait_until(lambda: os.path.exists(stopping), 10, "the slow child to begin stopping")
        with pytest.raises(ControlError, match="no answer"):  # queued behind slow's restart in the supervisor
            request(system.run_dir, {"cmd": "restart", "name": "a"}, 0.5)
        slow.join(30)
        request(system.run_dir, {"cmd": "restart", "name": "b"}, 30)  # a's job, queued before it, has had its turn
        assert ask(system, "a") == pid  # reported as failed: it never happened
        assert {r["name"]: r for r in request(system.run_dir, {"cmd": "status"})["rows"]}["a"]["restarts"] == 0
    finally:
        control.close()


def test_wait_ready_is_told_when_the_run_ends_before_it_was_ready(system: ActorSystem) -> None:
    tree(system)
    control = ControlServer(system, "demo")
    control.hold_ready()
    try:
        assert control.handle({"cmd": "wait_ready", "deadline": time.monotonic() + 0.05}) == {
            "ok": False, "ready": False, "error": "the run is not ready yet"}  # its deadline passed
    finally:
        control.close()
    assert control.handle({"cmd": "wait_ready"}) == {"ok": False, "error": "the run stopped before it was ready"}


def test_requests_beyond_the_limit_are_refused_at_once(system: ActorSystem, monkeypatch: pytest.MonkeyPatch) -> None:
    import supervisor.control

    monkeypatch.setattr(supervisor.control, "MAX_IN_FLIGHT", 2)
    tree(system)
    control = ControlServer(system, "demo")
    release = threading.Event()
    started = threading.Semaphore(0)
    control.add_command("slow", lambda msg: {"ok": started.release() or release.wait(30)})
    waiting = [threading.Thread(target=request, args=(system.run_dir, {"cmd": "slow"}, 30)) for _ in range(2)]
    try:
        for t in waiting:
            t.start()
        for _ in waiting:
            assert started.acquire(timeout=10)
        assert "serving 2 control requests already" in request_error(system, {"cmd": "status"})
        release.set()
        for t in waiting:
            t.join(10)
        assert request(system.run_dir, {"cmd": "status"})["rows"]
    finally:
        release.set()
        control.close()
