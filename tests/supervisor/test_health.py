"""Fault injection with real processes: SIGSEGV, a GIL-holding hang, memory and CPU limits."""

from __future__ import annotations

import signal
import time

import psutil

from actors import ActorSystem
from supervisor import ChildSpec, Command, SupervisorSpec, start_supervisor
from tests.supervisor.conftest import EventLog, ask, gone
from tests.supervisor.workers import Echo


def sup_of(*children: ChildSpec):
    return SupervisorSpec(intensity=5, period=60, children=list(children))


def test_sigsegv_from_native_code_is_a_crash_and_restarts(system: ActorSystem, events: EventLog) -> None:
    start_supervisor(system, sup_of(ChildSpec("n", Echo, poison_limit=1)))
    old = ask(system, "n")
    system.ref("n").tell("segv")
    ev = events.wait("crashed", "n")
    assert ev["reason"] == "error" and ev["exit_code"] == -signal.SIGSEGV and "SIGSEGV" in ev["detail"]
    events.wait("restarted", "n")
    assert ask(system, "n") != old


def test_a_hang_holding_the_gil_is_detected_and_restarted(system: ActorSystem, events: EventLog) -> None:
    deadline = 0.5
    start_supervisor(system, sup_of(ChildSpec("h", Echo, heartbeat=deadline, poison_limit=1)))
    old = ask(system, "h")
    system.ref("h").tell("hang")  # sum(range(10**13)): one C call, the GIL held throughout
    hang = events.wait("hang_detected", "h")
    assert hang["pid"] == old
    assert deadline <= hang["silent_for"] < deadline + 1.0  # the bench holds the exact +100 ms bar
    crash = events.wait("crashed", "h")
    assert crash["reason"] == "error" and crash["detail"].startswith("hang")
    events.wait("restarted", "h")
    assert ask(system, "h") != old  # and the hanging message was dead-lettered, not replayed


def test_a_slow_start_is_not_a_hang(system: ActorSystem, events: EventLog) -> None:
    # The first beat comes before on_start; being ready counts as a beat.
    start_supervisor(system, sup_of(ChildSpec("s", Echo, heartbeat=0.3)))
    assert ask(system, "s", "hello") == "hello"
    time.sleep(0.8)
    assert not events.of("hang_detected")


def test_memory_blow_up_hits_the_rss_limit(system: ActorSystem, events: EventLog) -> None:
    start_supervisor(system, sup_of(ChildSpec("m", Echo, max_rss_mb=150, poison_limit=1)))
    old = ask(system, "m")
    system.ref("m").tell("alloc")
    ev = events.wait("limit_exceeded", "m")
    assert ev["limit"] == "rss" and ev["value"] > 150
    assert events.wait("crashed", "m")["detail"].startswith("limit: rss")
    events.wait("restarted", "m")
    assert ask(system, "m") != old


def test_sustained_cpu_hits_the_cpu_limit(system: ActorSystem, events: EventLog) -> None:
    start_supervisor(system, sup_of(ChildSpec("c", Echo, max_cpu_percent=20, cpu_window=1.0, poison_limit=1)))
    system.ref("c").tell("spin")
    ev = events.wait("limit_exceeded", "c")
    assert ev["limit"] == "cpu" and ev["value"] > 20
    events.wait("restarted", "c")


def test_nice_and_cpu_affinity_apply_to_actors_and_commands(system: ActorSystem) -> None:
    sup = start_supervisor(system, sup_of(
        ChildSpec("a", Echo, nice=5, cpu_affinity=[0]),
        ChildSpec("x", Command(["sleep", "60"]), nice=7, cpu_affinity=[0]),
    ))
    kids = {c.id: c.pid for c in sup.which_children()}
    base = psutil.Process().nice()
    a, x = psutil.Process(kids["a"]), psutil.Process(kids["x"])
    assert a.nice() == base + 5 and a.cpu_affinity() == [0]
    assert x.nice() == base + 7 and x.cpu_affinity() == [0]
    sup.stop()
    assert gone(kids["x"]) and gone(kids["a"])


def test_an_exception_storm_reaches_the_intensity_and_escalates(system: ActorSystem, events: EventLog) -> None:
    inner = SupervisorSpec(intensity=2, period=60, children=[ChildSpec("storm", Echo, poison_limit=100)])
    root = start_supervisor(system, SupervisorSpec(intensity=0, children=[ChildSpec("inner", inner)]))
    system.ref("storm").tell("crash")  # replayed after every restart: a storm
    events.wait("gave_up", supervisor="root/inner")
    events.wait("escalated", supervisor="root/inner")
    events.wait("gave_up", supervisor="root")
    assert root.wait(10).reason == "shutdown"
    assert len(events.of("crashed", "storm")) == 3
