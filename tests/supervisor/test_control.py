"""The control endpoint and the discovery file."""

from __future__ import annotations

import json
import os
import threading

import pytest

from actors import ActorSystem
from supervisor import ChildSpec, Command, SupervisorSpec, start_supervisor
from supervisor.client import request
from supervisor.control import ControlServer, runs_dir
from tests.helpers import wait_until
from tests.supervisor.conftest import EventLog, ask
from tests.supervisor.workers import Echo


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


def test_garbage_on_the_control_socket_is_answered_and_the_root_goes_on(system: ActorSystem) -> None:
    import msgpack
    import zmq

    tree(system)
    control = ControlServer(system, "demo")
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVTIMEO, 5000)
    try:
        sock.connect(f"ipc://{system.run_dir}/_control")
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
        assert answers == [{"ok": True, "ready": True}]
        with open(control.discovery) as f:
            assert json.load(f)["ready"] is True
        assert request(system.run_dir, {"cmd": "wait_ready"}) == {"ok": True, "ready": True}  # at once now
    finally:
        control.close()


def test_wait_ready_is_told_when_the_run_ends_before_it_was_ready(system: ActorSystem) -> None:
    from supervisor.client import ControlError

    tree(system)
    control = ControlServer(system, "demo")
    control.hold_ready()
    errors: list[str] = []

    def wait() -> None:
        try:
            request(system.run_dir, {"cmd": "wait_ready"}, 30)
        except ControlError as exc:
            errors.append(str(exc))

    waiter = threading.Thread(target=wait)
    waiter.start()
    wait_until(lambda: control._waiting, 10, "the wait_ready request held")
    control.close()
    waiter.join(10)
    assert errors == ["the run stopped before it was ready"]
