"""External commands as supervised children."""

from __future__ import annotations

import logging
import os
import signal
import sys

import pytest

from actors import ActorSystem
from supervisor import ChildSpec, Command, StartError, SupervisorSpec, start_supervisor
from tests.helpers import wait_until
from tests.supervisor.conftest import EventLog, gone

PRINTER = [sys.executable, "-c", "import sys, time; print('hello out', flush=True); "
           "print('hello err', file=sys.stderr, flush=True); time.sleep(60)"]


def test_output_lines_are_logged_under_the_child_name(system: ActorSystem, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="supervisor.child.printer")
    start_supervisor(system, SupervisorSpec(children=[ChildSpec("printer", Command(PRINTER))]))

    def lines() -> dict[str, int]:
        return {r.getMessage(): r.levelno for r in caplog.records if r.name == "supervisor.child.printer"}

    wait_until(lambda: len(lines()) == 2, 10, "both lines")
    assert lines() == {"hello out": logging.INFO, "hello err": logging.WARNING}


def test_a_killed_command_is_restarted_and_a_stop_is_a_shutdown(system: ActorSystem, events: EventLog) -> None:
    sup = start_supervisor(system, SupervisorSpec(children=[ChildSpec("sl", Command(["sleep", "60"]), shutdown=2)]))
    old = sup.which_children()[0].pid
    os.kill(old, signal.SIGKILL)
    assert events.wait("crashed", "sl")["reason"] == "killed"
    new = events.wait("restarted", "sl")["pid"]
    assert new != old and sup.which_children()[0].pid == new
    sup.terminate_child("sl")
    assert events.wait("stopped", "sl")["reason"] == "shutdown"
    assert gone(new)


def test_exit_codes_follow_the_restart_type(system: ActorSystem, events: EventLog) -> None:
    spec = SupervisorSpec(intensity=5, period=60, children=[
        ChildSpec("ok", Command(["true"]), restart="transient"),
        ChildSpec("bad", Command(["sh", "-c", "sleep 0.2; exit 3"]), restart="transient"),
    ])
    sup = start_supervisor(system, spec)
    assert events.wait("exited", "ok")["reason"] == "normal"
    ev = events.wait("crashed", "bad")
    assert ev["exit_code"] == 3 and ev["detail"] == "exit code 3"
    events.wait("restarted", "bad")
    assert sup.which_children()[0].pid is None


def test_a_missing_program_fails_to_start(system: ActorSystem) -> None:
    with pytest.raises(StartError, match="cannot start 'no-such-program-xyz'"):
        start_supervisor(system, SupervisorSpec(children=[ChildSpec("x", Command(["no-such-program-xyz"]))]))


def test_stop_reaches_the_whole_process_group(system: ActorSystem, tmp_path) -> None:
    pidfile = tmp_path / "grandchild"
    script = f"sleep 60 & echo $! > {pidfile}; wait"
    sup = start_supervisor(system, SupervisorSpec(children=[ChildSpec("sh", Command(["sh", "-c", script]))]))
    wait_until(lambda: pidfile.exists() and pidfile.read_text().strip(), 5, "the grandchild's pid")
    grandchild = int(pidfile.read_text())
    sup.stop()
    wait_until(lambda: gone(grandchild), 5, "the grandchild's exit")
