"""OTP's supervisor_SUITE, the applicable cases, with real processes."""

from __future__ import annotations

import os
import signal
import time

import pytest

from actors import ActorSystem
from supervisor import (
    Backoff,
    ChildSpec,
    StartError,
    SupervisorError,
    SupervisorSpec,
    start_supervisor,
)
from tests.helpers import wait_until
from tests.supervisor.conftest import EventLog, ask, gone, read_lines
from tests.supervisor.workers import Echo, FailStart, SlowStop


def pids(sup) -> dict[str, object]:
    return {c.id: c.pid for c in sup.which_children()}


def ask_pid(system: ActorSystem, name: str) -> int:
    return ask(system, name, "pid")


def C(name: str, start: object, **kw: object) -> ChildSpec:
    """A child spec whose killing message is dead-lettered at once instead of replayed."""
    kw.setdefault("poison_limit", 1)
    return ChildSpec(name, start, **kw)  # type: ignore[arg-type]


def one_for_one(*children: ChildSpec, intensity: int = 3, period: float = 60, strategy: str = "one_for_one") -> SupervisorSpec:
    return SupervisorSpec(strategy=strategy, intensity=intensity, period=period, children=list(children))


# -- start and stop order -----------------------------------------------------
def test_children_start_in_order_and_stop_in_reverse(system: ActorSystem, logfile: str) -> None:
    sup = start_supervisor(system, one_for_one(*(C(n, (Echo, (logfile,))) for n in "abc")))
    assert [c.id for c in sup.which_children()] == ["a", "b", "c"]
    assert sup.count_children() == {"specs": 3, "active": 3, "supervisors": 0, "workers": 3}
    ex = sup.stop()
    assert ex is not None and ex.reason == "shutdown"
    names = [line.split()[:2] for line in read_lines(logfile)]
    assert names == [["start", "a"], ["start", "b"], ["start", "c"], ["stop", "c"], ["stop", "b"], ["stop", "a"]]


def test_a_child_that_fails_to_start_stops_the_earlier_ones(system: ActorSystem, events: EventLog) -> None:
    spec = one_for_one(C("ok", Echo), C("bad", FailStart), C("never", Echo))
    with pytest.raises(StartError, match="failed to start child 'bad'.*RuntimeError: cannot start"):
        start_supervisor(system, spec)
    started = events.of("started")
    assert [e["child"] for e in started] == ["ok"]
    assert events.wait("stopped", "ok")["reason"] == "shutdown"
    assert gone(started[0]["pid"])
    assert not events.of("started", "never")


# -- shutdown modes -----------------------------------------------------------
def test_shutdown_timeout_kills_a_child_that_does_not_stop(system: ActorSystem, events: EventLog, logfile: str) -> None:
    sup = start_supervisor(system, one_for_one(C("slow", (SlowStop, (30.0, logfile)), shutdown=0.3)))
    t0 = time.monotonic()
    sup.terminate_child("slow")
    assert time.monotonic() - t0 < 10
    assert events.wait("stopped", "slow")["reason"] == "killed"
    assert read_lines(logfile) == []  # on_stop never finished
    assert pids(sup) == {"slow": None}


def test_shutdown_timeout_lets_a_clean_stop_finish(system: ActorSystem, events: EventLog, logfile: str) -> None:
    sup = start_supervisor(system, one_for_one(C("slow", (SlowStop, (0.2, logfile)), shutdown=10)))
    sup.terminate_child("slow")
    assert events.wait("stopped", "slow")["reason"] == "shutdown"
    assert read_lines(logfile) == ["stopped slow"]


def test_shutdown_brutal_kill(system: ActorSystem, events: EventLog, logfile: str) -> None:
    sup = start_supervisor(system, one_for_one(C("b", (SlowStop, (0.0, logfile)), shutdown="brutal_kill")))
    sup.terminate_child("b")
    assert events.wait("stopped", "b")["reason"] == "killed"
    assert read_lines(logfile) == []  # no on_stop: killed outright


def test_shutdown_infinity_waits_as_long_as_it_takes(system: ActorSystem, events: EventLog, logfile: str) -> None:
    sup = start_supervisor(system, one_for_one(C("inf", (SlowStop, (1.5, logfile)), shutdown="infinity")))
    sup.terminate_child("inf")
    assert events.wait("stopped", "inf")["reason"] == "shutdown"
    assert read_lines(logfile) == ["stopped inf"]


def test_shutdown_timeout_kills_a_child_stuck_holding_the_gil(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, one_for_one(C("stuck", Echo, shutdown=0.3)))
    system.ref("stuck").tell("hang")
    time.sleep(0.1)
    sup.terminate_child("stuck")
    assert events.wait("stopped", "stuck")["reason"] == "killed"


# -- restart types x exit reasons ------------------------------------------------
EXITS = {
    "normal": "stop",  # the actor stops itself: exit 0
    "shutdown": "sigterm",  # it dies of SIGTERM
    "abnormal": "crash",  # an exception in a told message: exit 1
}


@pytest.mark.parametrize("restart", ["permanent", "transient", "temporary"])
@pytest.mark.parametrize("why", ["normal", "shutdown", "abnormal"])
def test_restart_type_and_exit_reason(system: ActorSystem, events: EventLog, restart: str, why: str) -> None:
    sup = start_supervisor(system, one_for_one(C("c", Echo, restart=restart), C("other", Echo)))
    old = ask_pid(system, "c")
    system.ref("c").tell(EXITS[why])
    ev = events.wait("crashed" if why == "abnormal" else "exited", "c")
    assert ev["reason"] == {"normal": "normal", "shutdown": "shutdown", "abnormal": "error"}[why]
    restarted = restart == "permanent" or (restart == "transient" and why == "abnormal")
    if restarted:
        events.wait("restarted", "c")
        assert ask_pid(system, "c") != old
    else:
        time.sleep(0.2)
        assert not events.of("restarted", "c")
        kids = pids(sup)
        if restart == "temporary":
            assert "c" not in kids  # a temporary child's spec is dropped
        else:
            assert kids["c"] is None  # a transient one keeps its spec
    assert gone(old)


def test_a_sigterm_from_outside_is_a_clean_stop(system: ActorSystem, events: EventLog, logfile: str) -> None:
    sup = start_supervisor(system, one_for_one(C("t", (Echo, (logfile,)), restart="transient")))
    os.kill(ask_pid(system, "t"), signal.SIGTERM)  # the actor's handler: on_stop, exit 0
    assert events.wait("exited", "t")["reason"] == "normal"
    assert read_lines(logfile)[-1].startswith("stop t")
    time.sleep(0.2)
    assert pids(sup) == {"t": None}


# -- restart intensity ----------------------------------------------------------
def test_one_for_one_intensity_third_exit_in_period_takes_the_supervisor_down(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, one_for_one(C("a", Echo), C("b", Echo), intensity=2, period=3600))
    b_pid = ask_pid(system, "b")
    for n in (1, 2):
        system.ref("a").tell("crash")
        events.wait("restarted", "a", n=n)
    system.ref("a").tell("crash")
    gave_up = events.wait("gave_up", supervisor="root")
    assert gave_up["child"] == "a" and gave_up["restarts"] == 3
    ex = sup.wait(10)
    assert ex is not None and ex.reason == "shutdown" and ex.normal
    assert events.wait("stopped", "b")["reason"] == "shutdown"
    wait_until(lambda: gone(b_pid), 5, "b's exit")


def test_restarts_spaced_beyond_the_period_are_fine(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, one_for_one(C("a", Echo), intensity=1, period=0.4))
    for n in (1, 2, 3):
        system.ref("a").tell("crash")
        events.wait("restarted", "a", n=n)
        time.sleep(0.5)
    assert sup.running and not events.of("gave_up")


def test_intensity_zero_gives_up_at_the_first_restart(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, one_for_one(C("a", Echo), intensity=0))
    system.ref("a").tell("crash")
    assert sup.wait(10).reason == "shutdown"


def test_a_restart_whose_start_fails_is_retried_through_the_same_accounting(
    system: ActorSystem, events: EventLog, tmp_path
) -> None:
    flag = str(tmp_path / "fail")
    sup = start_supervisor(system, one_for_one(C("f", (FailStart, (flag,))), intensity=3, period=60))
    open(flag, "w").close()  # from now on, every start fails
    os.kill(pids(sup)["f"], signal.SIGKILL)
    assert sup.wait(15).reason == "shutdown"
    starts = [e for e in events.of("crashed", "f") if e["phase"] == "start"]
    assert len(starts) == 3  # the crash + 3 failed retries = 4 restarts > 3
    assert events.of("gave_up")[0]["restarts"] == 4


def test_a_failed_restart_succeeds_when_the_cause_is_gone(system: ActorSystem, events: EventLog, tmp_path) -> None:
    flag = str(tmp_path / "fail")
    sup = start_supervisor(system, one_for_one(C("f", (FailStart, (flag,)), backoff=Backoff(0.2, 0.2, 0.0)),
                                               intensity=10, period=60))
    open(flag, "w").close()
    os.kill(pids(sup)["f"], signal.SIGKILL)
    events.wait("crashed", "f", phase="start")
    assert pids(sup)["f"] == "restarting"
    os.unlink(flag)
    events.wait("restarted", "f")
    assert isinstance(pids(sup)["f"], int)


# -- strategies ----------------------------------------------------------------------
def test_one_for_all_restarts_everyone_and_leaves_no_old_pid(system: ActorSystem, events: EventLog, logfile: str) -> None:
    sup = start_supervisor(system, one_for_one(*(C(n, (Echo, (logfile,))) for n in "abc"), strategy="one_for_all"))
    old = pids(sup)
    os.kill(old["b"], signal.SIGKILL)
    for n in "abc":
        events.wait("restarted", n)
    new = pids(sup)
    assert all(isinstance(new[n], int) and new[n] != old[n] for n in "abc")
    assert all(gone(p) for p in old.values())
    lines = [line.split()[:2] for line in read_lines(logfile)][3:]
    assert lines == [["stop", "c"], ["stop", "a"], ["start", "a"], ["start", "b"], ["start", "c"]]


def test_one_for_all_also_starts_children_that_had_been_stopped(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, one_for_one(C("a", Echo), C("b", Echo), strategy="one_for_all"))
    sup.terminate_child("b")
    assert pids(sup)["b"] is None
    system.ref("a").tell("crash")
    events.wait("restarted", "b")
    assert isinstance(pids(sup)["b"], int)


def test_rest_for_one_restarts_the_child_and_those_after_it(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, one_for_one(*(C(n, Echo) for n in "abcd"), strategy="rest_for_one"))
    old = pids(sup)
    os.kill(old["b"], signal.SIGKILL)
    events.wait("restarted", "d")
    new = pids(sup)
    assert new["a"] == old["a"]
    assert all(new[n] != old[n] for n in "bcd")


def test_temporary_bystander_is_dropped_when_a_sibling_restart_kills_it(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, one_for_one(C("p", Echo), C("t", Echo, restart="temporary"),
                                               strategy="one_for_all"))
    t_pid = pids(sup)["t"]
    system.ref("p").tell("crash")
    events.wait("restarted", "p")
    assert [c.id for c in sup.which_children()] == ["p"]
    assert gone(t_pid)


def test_simple_one_for_one(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, SupervisorSpec(strategy="simple_one_for_one", intensity=5, period=60,
                                                  children=[C("w", Echo, restart="transient")]))
    assert sup.which_children() == []
    a = sup.start_child()
    b = sup.start_child(name="worker-b")
    assert (a, b) == ("w.1", "worker-b")
    assert system.ref(b).ask("hi", timeout=5).get() == "hi"
    system.ref(a).tell("crash")  # transient: restarted after an abnormal exit
    events.wait("restarted", a)
    system.ref(a).tell("stop")  # and dropped after a normal one
    events.wait("exited", a)
    wait_until(lambda: [c.id for c in sup.which_children()] == [b], 5, "a dropped")
    for call in (sup.restart_child, sup.delete_child):
        with pytest.raises(SupervisorError) as err:
            call(b)
        assert err.value.reason == "simple_one_for_one"
    sup.terminate_child(b)
    assert sup.count_children()["specs"] == 0


# -- nested supervisors and escalation ----------------------------------------------------
def nested(restart: str = "permanent") -> SupervisorSpec:
    mid = SupervisorSpec(strategy="one_for_one", intensity=1, period=60, children=[C("w", Echo)])
    return one_for_one(C("mid", mid, restart=restart), C("side", Echo), intensity=3)


def test_escalation_restarts_a_permanent_child_supervisor(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, nested())
    assert sup.count_children() == {"specs": 2, "active": 2, "supervisors": 1, "workers": 1}
    side = ask_pid(system, "side")
    w0 = ask_pid(system, "w")
    system.ref("w").tell("crash")
    w1 = (events.wait("restarted", "w"), ask_pid(system, "w"))[1]
    system.ref("w").tell("crash")  # the second within the period: mid gives up
    events.wait("gave_up", supervisor="root/mid")
    assert events.wait("escalated", supervisor="root/mid")["parent"] == "root"
    events.wait("restarted", "mid")
    w2 = ask_pid(system, "w")
    assert len({w0, w1, w2}) == 3 and gone(w0) and gone(w1)
    assert ask_pid(system, "side") == side  # one_for_one at the root
    assert sup.child("mid").which_children()[0].pid == w2


def test_a_transient_child_supervisor_that_gave_up_is_not_restarted(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, nested("transient"))
    for _ in range(2):
        system.ref("w").tell("crash")
        time.sleep(0.15)
    events.wait("gave_up", supervisor="root/mid")
    assert events.wait("exited", "mid")["reason"] == "shutdown"
    time.sleep(0.2)
    assert pids(sup)["mid"] is None and not events.of("restarted", "mid")


def test_an_exception_storm_escalates_to_the_root(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, SupervisorSpec(intensity=0, children=[C("mid", nested().children[0].start)]))
    for _ in range(2):
        system.ref("w").tell("crash")
        time.sleep(0.15)
    events.wait("gave_up", supervisor="root/mid")
    events.wait("gave_up", supervisor="root")
    assert sup.wait(10).reason == "shutdown"


def test_brutal_kill_of_a_child_supervisor_kills_everything_below_it(system: ActorSystem, events: EventLog, logfile: str) -> None:
    inner = SupervisorSpec(children=[C(n, (SlowStop, (0.0, logfile))) for n in ("i1", "i2")])
    sup = start_supervisor(system, one_for_one(C("in", inner, shutdown="brutal_kill")))
    below = [ask_pid(system, n) for n in ("i1", "i2")]
    sup.terminate_child("in")
    assert events.wait("stopped", "in")["reason"] == "killed"
    assert all(gone(p) for p in below) and read_lines(logfile) == []  # no on_stop below


def test_a_child_supervisor_that_does_not_stop_in_time_is_killed(system: ActorSystem, events: EventLog, logfile: str) -> None:
    inner = SupervisorSpec(children=[C("slow", (SlowStop, (30.0, logfile)), shutdown="infinity")])
    sup = start_supervisor(system, one_for_one(C("in", inner, shutdown=0.3)))
    pid = ask_pid(system, "slow")
    t0 = time.monotonic()
    sup.terminate_child("in")
    assert time.monotonic() - t0 < 10
    assert events.wait("stopped", "in")["reason"] == "killed"
    assert gone(pid)


def test_nested_supervisor_children_stop_in_reverse_order(system: ActorSystem, logfile: str) -> None:
    inner = SupervisorSpec(children=[C(n, (Echo, (logfile,))) for n in ("i1", "i2")])
    sup = start_supervisor(system, one_for_one(C("o1", (Echo, (logfile,))), C("in", inner),
                                               C("o2", (Echo, (logfile,)))))
    sup.stop()
    order = [line.split()[:2] for line in read_lines(logfile)]
    assert order == [["start", "o1"], ["start", "i1"], ["start", "i2"], ["start", "o2"],
                     ["stop", "o2"], ["stop", "i2"], ["stop", "i1"], ["stop", "o1"]]


# -- the API --------------------------------------------------------------------------------
def test_terminate_restart_delete_and_start_child(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, one_for_one(C("a", Echo)))
    with pytest.raises(SupervisorError) as err:
        sup.delete_child("a")
    assert err.value.reason == "running"
    with pytest.raises(SupervisorError) as err:
        sup.restart_child("a")
    assert err.value.reason == "running"
    sup.terminate_child("a")
    assert pids(sup) == {"a": None}
    assert sup.count_children()["active"] == 0
    pid = sup.restart_child("a")
    assert pid == ask_pid(system, "a")
    with pytest.raises(SupervisorError) as err:
        sup.start_child(C("a", Echo))
    assert err.value.reason == "already_started"
    sup.terminate_child("a")
    with pytest.raises(SupervisorError) as err:
        sup.start_child(C("a", Echo))
    assert err.value.reason == "already_present"
    sup.delete_child("a")
    assert sup.which_children() == []
    assert sup.start_child(C("a", Echo)) == "a"
    assert sup.start_child(C("b", Echo)) == "b"
    assert [c.id for c in sup.which_children()] == ["a", "b"]
    with pytest.raises(SupervisorError) as err:
        sup.terminate_child("nope")
    assert err.value.reason == "not_found"
    with pytest.raises(StartError):
        sup.start_child(C("bad", FailStart))
    assert [c.id for c in sup.which_children()] == ["a", "b"]


def test_names_are_unique_in_the_run(system: ActorSystem) -> None:
    sup = start_supervisor(system, one_for_one(C("a", Echo)))
    with pytest.raises(SupervisorError) as err:
        sup.start_child(C("a", SlowStop))
    assert err.value.reason == "already_started"
    system.spawn(Echo, "spawned")
    with pytest.raises(SupervisorError, match="already exists"):
        sup.start_child(C("spawned", Echo))


def test_backoff_delays_the_restart(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, one_for_one(C("a", Echo, backoff=Backoff(min=0.5, max=5, random_factor=0))))
    system.ref("a").tell("crash")
    assert events.wait("restarting", "a")["delay"] == 0.5
    assert pids(sup)["a"] == "restarting"
    assert sup.count_children()["active"] == 0
    ev = events.wait("restarted", "a")
    assert ev["downtime"] >= 0.5
    system.ref("a").tell("crash")  # the second consecutive restart waits twice as long
    assert events.wait("restarting", "a", n=2)["delay"] == 1.0


def test_calls_from_the_root_io_thread_are_refused(system: ActorSystem) -> None:
    from supervisor.rootio import on_root

    sup = start_supervisor(system, one_for_one(C("a", Echo)))
    with pytest.raises(RuntimeError, match="root IO thread"):
        on_root(system, lambda: sup.terminate_child("a"))
