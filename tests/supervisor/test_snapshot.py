"""snapshot()/restore(): a restarted actor keeps what it knew."""

from __future__ import annotations

import os
import signal
import time

from actors import ActorSystem
from supervisor import ChildSpec, SupervisorSpec, start_supervisor
from supervisor.snapshot import read
from tests.helpers import wait_until
from tests.supervisor.conftest import EventLog, ask
from tests.supervisor.workers import Managed


def test_state_survives_a_sigkill(system: ActorSystem, events: EventLog, logfile: str) -> None:
    start_supervisor(system, SupervisorSpec(children=[ChildSpec("m", (Managed, (logfile,)))]))
    ref = system.ref("m")
    for _ in range(25):
        ref.tell("inc")
    assert ask(system, "m", "count") == 25
    os.kill(ask(system, "m"), signal.SIGKILL)
    events.wait("restarted", "m")
    assert ask(system, "m", "restored") == {"count": 25}
    assert ask(system, "m", "count") == 25  # restored before on_start
    assert read(os.path.join(system.run_dir, "m.snap")) == {"count": 25}


def test_snapshots_are_throttled_and_the_last_one_is_written_on_stop(system: ActorSystem, logfile: str) -> None:
    sup = start_supervisor(system, SupervisorSpec(children=[ChildSpec("m", (Managed, (logfile,)), snapshot_interval=0.3)]))
    path = os.path.join(system.run_dir, "m.snap")
    for _ in range(50):
        system.ref("m").tell("inc")
    assert ask(system, "m", "count") == 50
    wait_until(lambda: os.path.exists(path) and read(path) == {"count": 50}, 5, "the delayed snapshot")
    time.sleep(0.05)
    system.ref("m").tell("inc")
    assert ask(system, "m", "count") == 51
    sup.terminate_child("m")
    assert read(path) == {"count": 51}
    sup.restart_child("m")
    assert ask(system, "m", "count") == 51


def test_an_unreadable_snapshot_is_set_aside(system: ActorSystem, logfile: str) -> None:
    with open(os.path.join(system.run_dir, "m.snap"), "wb") as f:
        f.write(b"\xc1 not msgpack")
    start_supervisor(system, SupervisorSpec(children=[ChildSpec("m", (Managed, (logfile,)))]))
    assert ask(system, "m", "restored") is None
    assert os.path.exists(os.path.join(system.run_dir, "m.snap.bad"))


def test_delete_child_removes_the_snapshot(system: ActorSystem, logfile: str) -> None:
    sup = start_supervisor(system, SupervisorSpec(children=[ChildSpec("m", (Managed, (logfile,)))]))
    system.ref("m").tell("inc")
    assert ask(system, "m", "count") == 1
    sup.terminate_child("m")
    sup.delete_child("m")
    assert not os.path.exists(os.path.join(system.run_dir, "m.snap"))
    assert not os.path.exists(os.path.join(system.run_dir, "m.journal"))
