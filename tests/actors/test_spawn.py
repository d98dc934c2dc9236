"""Spawned actor processes (a fresh interpreter) and warm standbys at the actors layer."""

from __future__ import annotations

import os

import psutil
import pytest

from actors import ActorError, ActorRef, ActorSystem, Timeout
from tests.actors.workers import Echo
from tests.helpers import wait_until


def _standby(system: ActorSystem, name: str = "echo") -> object:
    system.rt.register(name, {"endpoint": system.rt.endpoint(name), "kind": "process"})
    info = system.start_process(system.make_spec(Echo, name, (), {}), standby=True)
    assert info.standing_by.wait(60), "the standby never said it was ready"
    return info


def test_a_standby_serves_nothing_until_it_takes_over(system: ActorSystem) -> None:
    info = _standby(system)
    assert info.method == "spawn" and psutil.Process(info.pid).ppid() == os.getpid()
    assert "echo" not in system.procs  # not the actor yet: no mailbox bound
    with pytest.raises(Timeout):
        ActorRef("echo").ask("pid", timeout=0.3).get()
    system.rt.on_client(lambda: system.take_over(info))
    system.wait_ready(info, 30)
    assert ActorRef("echo").ask("pid", timeout=10).get() == info.pid


def test_only_a_waiting_standby_can_take_over(system: ActorSystem) -> None:
    info = _standby(system)
    system.rt.on_client(lambda: system.take_over(info))
    with pytest.raises(ActorError, match="not a waiting standby"):
        system.rt.on_client(lambda: system.take_over(info))


def test_a_spawned_actor_serves_and_its_exit_is_seen(system: ActorSystem) -> None:
    system.rt.register("sp", {"endpoint": system.rt.endpoint("sp"), "kind": "process"})
    info = system.start_process(system.make_spec(Echo, "sp", (), {}), method="spawn")
    system.wait_ready(info, 60)
    assert ActorRef("sp").ask("hi", timeout=10).get() == "hi"
    system.signal("sp", 9)
    assert info.exited.wait(10) and info.exit_code == -9


def test_shutdown_leaves_no_spawned_process() -> None:
    system = ActorSystem()
    try:
        waiting = _standby(system)
        system.rt.register("sp", {"endpoint": system.rt.endpoint("sp"), "kind": "process"})
        serving = system.start_process(system.make_spec(Echo, "sp", (), {}), method="spawn")
        system.wait_ready(serving, 60)
    finally:
        system.shutdown()
    for pid in (waiting.pid, serving.pid):  # type: ignore[attr-defined]
        wait_until(lambda pid=pid: not psutil.pid_exists(pid), 5, f"exit of {pid}")


def test_a_bad_start_method_is_refused(system: ActorSystem) -> None:
    with pytest.raises(ValueError, match="'fork' or 'spawn'"):
        system.start_process(system.make_spec(Echo, "x", (), {}), method="forkserver")
