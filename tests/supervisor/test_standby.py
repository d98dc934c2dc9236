"""Warm standbys (ChildSpec(standby=True)) and spawned actor processes (start_method="spawn")."""

from __future__ import annotations

import os
import signal
import threading
import time
from typing import Any

import psutil
import pytest

from actors import ActorSystem
from supervisor import ChildSpec, Command, SupervisorSpec, start_supervisor
from tests.helpers import wait_until
from tests.supervisor.conftest import EventLog, ask, gone, read_lines
from tests.supervisor.workers import KeepAllRecorder, SlowConfigure


def _slow(logfile: str, configure_s: float, **kw: object) -> SupervisorSpec:
    return SupervisorSpec(intensity=10, period=10, children=[
        ChildSpec("m", (SlowConfigure, (logfile, configure_s)), lifecycle="active", standby=True, **kw)])  # type: ignore[arg-type]


def test_a_standby_takes_over_a_killed_actor_with_its_state_and_its_messages(
        system: ActorSystem, events: EventLog, logfile: str) -> None:
    start_supervisor(system, _slow(logfile, 5.0), timeout=60)
    standby = events.wait("standby_ready", "m", timeout=60)["pid"]
    ref = system.ref("m")
    for _ in range(25):
        ref.tell("inc")
    assert ask(system, "m", "count") == 25
    os.kill(ask(system, "m"), signal.SIGKILL)
    for _ in range(10):  # told while no incarnation serves: kept by the sender, re-sent to the standby
        ref.tell("inc")
    assert ask(system, "m", timeout=3) == standby  # far sooner than the 5 s configure
    assert events.wait("restarted", "m")["standby"] is True
    assert ask(system, "m", "restored") == {"count": 25}  # the snapshot, restored into the standby
    assert ask(system, "m", "count") == 35
    assert f"on_configure {standby} ahead=True" in read_lines(logfile)
    again = events.wait("standby_ready", "m", n=2, timeout=60)["pid"]  # the next one, in the background
    assert again not in (standby, None)


def test_an_operator_restart_hands_over_to_the_standby(system: ActorSystem, events: EventLog, logfile: str) -> None:
    sup = start_supervisor(system, _slow(logfile, 1.0), timeout=60)
    standby = events.wait("standby_ready", "m", timeout=60)["pid"]
    assert sup.bounce("m") == standby


def test_a_standby_that_dies_is_replaced(system: ActorSystem, events: EventLog, logfile: str) -> None:
    start_supervisor(system, _slow(logfile, 0.5), timeout=60)
    first = events.wait("standby_ready", "m", timeout=60)["pid"]
    active = ask(system, "m")
    os.kill(first, signal.SIGKILL)
    lost = events.wait("standby_lost", "m")
    assert lost["pid"] == first and lost["exit_code"] == -signal.SIGKILL
    assert events.wait("standby_ready", "m", n=2, timeout=60)["pid"] != first
    assert ask(system, "m") == active  # the active one never noticed
    assert not events.of("restarted", "m")


def test_stopping_the_child_kills_its_standby(system: ActorSystem, events: EventLog, logfile: str) -> None:
    sup = start_supervisor(system, _slow(logfile, 0.5), timeout=60)
    standby = events.wait("standby_ready", "m", timeout=60)["pid"]
    sup.terminate_child("m")
    wait_until(lambda: gone(standby), 5, "the standby's exit")
    assert [r.pid for r in sup.which_children()] == [None]


def test_a_standby_still_configuring_takes_over_when_it_is_done(
        system: ActorSystem, events: EventLog, logfile: str) -> None:
    start_supervisor(system, _slow(logfile, 2.0), timeout=60)
    os.kill(ask(system, "m", timeout=30), signal.SIGKILL)  # the standby is still in on_standby
    restarted = events.wait("restarted", "m", timeout=30)
    assert restarted["standby"] is True
    assert ask(system, "m", "count") == 0


def test_a_spawned_actor_is_a_fresh_interpreter_and_restarts(system: ActorSystem, events: EventLog, logfile: str) -> None:
    start_supervisor(system, SupervisorSpec(children=[
        ChildSpec("m", (SlowConfigure, (logfile, 0.0)), lifecycle="active", start_method="spawn")]), timeout=60)
    pid = ask(system, "m", timeout=30)
    assert psutil.Process(pid).ppid() == os.getpid()  # not a child of the fork server
    assert psutil.Process(pid).cmdline()[-2:] == ["-m", "actors.spawn"]
    os.kill(pid, signal.SIGKILL)
    events.wait("restarted", "m", timeout=30, standby=False)
    assert ask(system, "m", timeout=30) != pid


def test_standby_and_start_method_are_checked_in_the_spec() -> None:
    with pytest.raises(ValueError, match="standby .* needs an actor child"):
        ChildSpec("cam", Command(["sleep", "1"]), standby=True)
    with pytest.raises(ValueError, match="start_method must be one of fork, spawn"):
        ChildSpec("m", SlowConfigure, start_method="forkserver")
    assert ChildSpec("m", SlowConfigure, standby=True).start_method == "spawn"


ROOT_SCRIPT = """
import sys, threading, time
from actors import ActorSystem
from supervisor import ChildSpec, SupervisorSpec, start_supervisor
from supervisor.rootio import on_root
from supervisor.tree import Tree
from tests.supervisor.workers import SlowConfigure

system = ActorSystem()
ready = []
got = threading.Event()
on_root(system, lambda: Tree.of(system).events.listeners.append(
    lambda ev: (ready.append(ev["pid"]), got.set()) if ev["event"] == "standby_ready" else None))
sup = start_supervisor(system, SupervisorSpec(children=[
    ChildSpec("m", (SlowConfigure, (sys.argv[1], 0.2)), lifecycle="active", standby=True)]), timeout=60)
got.wait(60)
print(sup.which_children()[0].pid, ready[0], flush=True)
time.sleep(600)
"""


def test_a_root_killed_by_sigkill_takes_its_spawned_active_and_standby_along(tmp_path: object, logfile: str) -> None:
    import subprocess
    import sys

    root = subprocess.Popen([sys.executable, "-c", ROOT_SCRIPT, logfile], stdout=subprocess.PIPE, text=True,
                            cwd=os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
    try:
        assert root.stdout is not None
        active, standby = (int(x) for x in root.stdout.readline().split())
        assert psutil.Process(standby).ppid() == root.pid
    finally:
        root.kill()
        root.wait()
    for pid in (active, standby):
        wait_until(lambda pid=pid: gone(pid), 5, f"exit of {pid} with its root")


def _numbers_across_kills(system: ActorSystem, events: EventLog, logfile: str, out: str, *, standby: bool,
                          kills: int = 2, rate_hz: float = 800.0) -> tuple[int, dict[int, list[int]], dict[str, Any]]:
    """Publish 0, 1, 2... at ``rate_hz`` on keep-all ``numbers`` while ``m`` (a KeepAllRecorder) is SIGKILLed ``kills`` times.

    Returns how many were published, what each incarnation (pid) recorded in order, and the last one's stats.
    """
    from actors.topics import Publisher, subscriber_pids

    configure_s = 1.0 if standby else 0.2
    start_supervisor(system, SupervisorSpec(intensity=10, period=10, children=[
        ChildSpec("m", (KeepAllRecorder, (logfile, configure_s, "numbers", out)), lifecycle="active",
                  standby=standby)]), timeout=60)
    pid = ask(system, "m", timeout=30)
    wait_until(lambda: pid in subscriber_pids(system.run_dir, "numbers"), 10, "the subscription")
    pub = system.rt.on_client(lambda: Publisher(system.rt, "numbers"))
    stop, sent = threading.Event(), [0]

    def send() -> None:
        n, period, t = 0, 1.0 / rate_hz, time.monotonic()
        while not stop.is_set():
            system.rt.on_client(lambda n=n: pub.publish(n))
            n += 1
            t += period
            time.sleep(max(0.0, t - time.monotonic()))
        sent[0] = n

    sender = threading.Thread(target=send)
    sender.start()
    try:
        for k in range(kills):
            if standby:
                events.wait("standby_ready", "m", n=k + 1, timeout=60)
            time.sleep(0.3)
            os.kill(pid, signal.SIGKILL)
            pid = wait_until(lambda old=pid: (p := ask(system, "m", timeout=30)) != old and p, 30, "the next incarnation")
        time.sleep(0.3)
    finally:
        stop.set()
        sender.join(30)

    def recorded() -> dict[int, list[int]]:
        got: dict[int, list[int]] = {}
        for line in read_lines(out):
            p, n = line.split()
            got.setdefault(int(p), []).append(int(n))
        return got

    wait_until(lambda: {n for ns in recorded().values() for n in ns} >= set(range(sent[0])), 20, "every number")
    stats = ask(system, "m", "sub")
    system.rt.on_client(pub.close)
    return sent[0], recorded(), stats


@pytest.mark.parametrize("standby", [False, True], ids=["restart", "standby"])
def test_a_keep_all_input_loses_nothing_when_its_actor_is_killed(
        system: ActorSystem, events: EventLog, logfile: str, tmp_path: Any, standby: bool) -> None:
    sent, got, stats = _numbers_across_kills(system, events, logfile, str(tmp_path / "numbers.txt"), standby=standby)
    assert len(got) == 3, got.keys()  # three incarnations recorded numbers
    for pid, ns in got.items():
        assert ns == sorted(set(ns)), f"incarnation {pid} got numbers twice or out of order"
    every = sorted(n for ns in got.values() for n in ns)
    assert set(every) == set(range(sent)), "lost: " + str(sorted(set(range(sent)) - set(every))[:20])
    # At-least-once: only what a dead incarnation had taken and not finished comes again, and is counted.
    assert len(every) - sent <= 2 * 100, len(every) - sent
    assert stats["dropped"] == 0, stats


def test_a_keep_all_message_its_actor_died_handling_is_delivered_again_and_counted(
        system: ActorSystem, events: EventLog, logfile: str, tmp_path: Any) -> None:
    from actors.topics import Publisher, subscriber_pids

    out = str(tmp_path / "numbers.txt")
    start_supervisor(system, SupervisorSpec(intensity=10, period=10, children=[
        ChildSpec("m", (KeepAllRecorder, (logfile, 0.0, "numbers", out, 5)), lifecycle="active")]), timeout=60)
    first = ask(system, "m", timeout=30)
    wait_until(lambda: first in subscriber_pids(system.run_dir, "numbers"), 10, "the subscription")
    pub = system.rt.on_client(lambda: Publisher(system.rt, "numbers"))
    try:
        for n in range(10):  # 5 kills the incarnation inside its callback: taken, not acknowledged
            system.rt.on_client(lambda n=n: pub.publish(n))
        again = wait_until(lambda: (p := ask(system, "m", timeout=30)) != first and p, 30, "the next incarnation")
        wait_until(lambda: again in subscriber_pids(system.run_dir, "numbers"), 10, "its subscription")
        system.rt.on_client(lambda: pub.publish(10))  # a publisher re-sends when it next publishes
        wait_until(lambda: len(read_lines(out)) >= 11, 10, "every number")
        assert [int(line.split()[1]) for line in read_lines(out)] == list(range(11))  # 5 once, in its place
        assert {int(line.split()[0]) for line in read_lines(out)[5:]} == {again}
        stats = ask(system, "m", "sub")
        assert stats["redelivered"] >= 1 and stats["dropped"] == 0, stats
        assert system.rt.on_client(lambda: pub.resent) >= 1
    finally:
        system.rt.on_client(pub.close)
