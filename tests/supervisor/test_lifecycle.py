"""Managed lifecycle: transitions, hooks, and a restart that returns to the same state."""

from __future__ import annotations

import os
import signal

import pytest

from actors import ActorCrashed, ActorSystem, RemoteError
from supervisor import ChildSpec, SupervisorSpec, lifecycle, start_supervisor
from tests.supervisor.conftest import EventLog, ask, read_lines
from tests.supervisor.workers import Managed


def start(system: ActorSystem, log: str, **kw: object):
    spec = SupervisorSpec(intensity=5, period=60, children=[ChildSpec("m", (Managed, (log,)), **kw)])  # type: ignore[arg-type]
    return start_supervisor(system, spec)


def status_of(sup) -> str:
    return [r for r in lifecycle_rows(sup) if r["name"] == "m"][0]["lifecycle"]


def lifecycle_rows(sup):
    from supervisor.rootio import on_root

    return on_root(sup.system, sup._rows)


def test_transitions_call_the_hooks_in_order(system: ActorSystem, logfile: str) -> None:
    sup = start(system, logfile)
    assert lifecycle.state(system, "m") == "unconfigured"
    assert lifecycle.transition(system, "m", "configure") == "inactive"
    assert lifecycle.transition(system, "m", "activate") == "active"
    assert status_of(sup) == "active"  # the supervisor reads it from the journal
    assert lifecycle.transition(system, "m", "deactivate") == "inactive"
    assert lifecycle.transition(system, "m", "cleanup") == "unconfigured"
    assert read_lines(logfile)[1:] == ["on_configure", "on_activate", "on_deactivate", "on_cleanup"]


def test_a_transition_from_the_wrong_state_is_refused(system: ActorSystem, logfile: str) -> None:
    start(system, logfile)
    with pytest.raises(RemoteError, match="cannot activate actor 'm': it is unconfigured"):
        lifecycle.transition(system, "m", "activate")
    with pytest.raises(RemoteError, match="unknown transition 'jump'"):
        lifecycle.transition(system, "m", "jump")
    assert lifecycle.state(system, "m") == "unconfigured"


def test_a_hook_returning_false_fails_the_transition(system: ActorSystem, tmp_path) -> None:
    log = str(tmp_path / "l")
    spec = SupervisorSpec(children=[ChildSpec("m", (Managed, (log, True)))])
    start_supervisor(system, spec)
    lifecycle.transition(system, "m", "configure")
    with pytest.raises(RemoteError, match="returned False; it stays inactive"):
        lifecycle.transition(system, "m", "activate")
    assert lifecycle.state(system, "m") == "inactive"


def test_a_restart_replays_the_state_it_was_in(system: ActorSystem, events: EventLog, logfile: str) -> None:
    start(system, logfile, lifecycle="active")  # a fresh actor goes to its target
    assert lifecycle.state(system, "m") == "active"
    assert read_lines(logfile) == ["on_start count=0", "on_configure", "on_activate"]
    lifecycle.transition(system, "m", "deactivate")
    os.kill(ask(system, "m"), signal.SIGKILL)
    events.wait("restarted", "m")
    assert lifecycle.state(system, "m") == "inactive"  # where it was, not its spec's target
    assert read_lines(logfile)[-2:] == ["on_start count=0", "on_configure"]


def test_shutdown_finalizes_and_ends_a_transient_actor(system: ActorSystem, events: EventLog, logfile: str) -> None:
    sup = start(system, logfile, restart="transient", lifecycle="inactive")
    try:
        assert lifecycle.transition(system, "m", "shutdown") == "finalized"
    except ActorCrashed:
        pass  # the reply can be lost as the actor stops: a runtime issue (ZMQ_IMMEDIATE), reported
    assert events.wait("exited", "m")["reason"] == "normal"
    assert read_lines(logfile)[-1] == "on_shutdown"
    # Started again by hand, a finalized actor starts fresh, at its target.
    sup.restart_child("m")
    assert ask(system, "m", "pid") and lifecycle.state(system, "m") == "inactive"


def test_a_failing_replay_fails_the_start(system: ActorSystem, events: EventLog, tmp_path) -> None:
    log = str(tmp_path / "l")
    spec = SupervisorSpec(intensity=2, period=60, children=[ChildSpec("m", (Managed, (log, True)), lifecycle="active")])
    with pytest.raises(Exception, match="failed to start child 'm'"):
        start_supervisor(system, spec)
