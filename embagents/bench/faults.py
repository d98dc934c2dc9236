"""Fault measurements of the supervisor for ``embagents bench`` (each runs its own actor system).

- :func:`measure_crash_detect`: SIGKILL of an actor process -> the root's exit
  listener runs (the fork server's SIGCHLD path). Bar: p50 <= 5 ms.
- :func:`measure_restart_ready`: SIGKILL of a light actor under a one_for_one
  supervisor -> an ask answers again, from the new incarnation. Bar: p50 <= 50 ms.
- :func:`measure_hang_detect`: an actor stuck in one C call holding the GIL
  (its loop cannot beat) -> killed; returns how long it had been silent when
  it was killed. Bar: <= its heartbeat deadline + 100 ms.

Times are seconds, measured with ``time.perf_counter`` from just before the
fault. Call from a process that has no ActorSystem running.

Example::

    >>> import statistics
    >>> statistics.median(measure_crash_detect(20)) < 0.005     # doctest: +SKIP
    True
"""

from __future__ import annotations

import os
import signal
import threading
import time
from typing import Any

from actors import Actor, ActorCrashed, ActorSystem, Timeout
from supervisor.spec import ChildSpec, SupervisorSpec
from supervisor.supervisor import start_supervisor
from supervisor.tree import Tree

__all__ = ["Light", "measure_crash_detect", "measure_hang_detect", "measure_restart_ready"]


class Light(Actor):
    """The lightest useful actor: answers "pid", hangs on "hang"."""

    def on_receive(self, message: Any) -> Any:
        if message == "hang":
            sum(range(10**13))  # one C call holding the GIL
        return os.getpid() if message == "pid" else message


def _tree(system: ActorSystem, **child: Any) -> Any:
    spec = SupervisorSpec(strategy="one_for_one", intensity=1_000_000, period=1.0,
                          children=[ChildSpec("light", Light, **child)])
    return start_supervisor(system, spec, "bench")


def _pid(system: ActorSystem, old: int | None = None, timeout: float = 10.0) -> tuple[int, float]:
    """Ask until the actor answers with a pid other than ``old``; returns (pid, when)."""
    ref = system.ref("light")
    deadline = time.perf_counter() + timeout
    while time.perf_counter() < deadline:
        try:
            pid = ref.ask("pid", timeout=1.0).get()
        except (ActorCrashed, Timeout):
            continue
        if pid != old:
            return pid, time.perf_counter()
    raise TimeoutError("the actor did not come back")


def measure_crash_detect(n: int = 50) -> list[float]:
    """Seconds from SIGKILL to the exit listener, ``n`` times."""
    out: list[float] = []
    with ActorSystem() as system:
        seen = threading.Event()
        stamp: list[float] = []

        def on_exit(info: Any) -> None:
            stamp.append(time.perf_counter())
            seen.set()

        system.exit_listeners.append(on_exit)
        sup = _tree(system)
        pid, _ = _pid(system)
        for _ in range(n):
            seen.clear()
            stamp.clear()
            t0 = time.perf_counter()
            os.kill(pid, signal.SIGKILL)
            if not seen.wait(5):
                raise TimeoutError("no exit seen within 5 s")
            out.append(stamp[0] - t0)
            pid, _ = _pid(system, pid)
        sup.stop()
        Tree.of(system).close()
    return out


def measure_restart_ready(n: int = 50) -> list[float]:
    """Seconds from SIGKILL until an ask is answered by the new incarnation, ``n`` times."""
    out: list[float] = []
    with ActorSystem() as system:
        sup = _tree(system)
        pid, _ = _pid(system)
        for _ in range(n):
            time.sleep(0.02)  # let the previous restart settle (links connected)
            t0 = time.perf_counter()
            os.kill(pid, signal.SIGKILL)
            pid, t1 = _pid(system, pid)
            out.append(t1 - t0)
        sup.stop()
        Tree.of(system).close()
    return out


def measure_hang_detect(deadline: float = 0.5, n: int = 5) -> list[float]:
    """Seconds the hung actor had been silent when killed (the bar: ``deadline`` + 0.1), ``n`` times."""
    out: list[float] = []
    with ActorSystem() as system:
        got = threading.Event()
        silent: list[float] = []

        def on_event(ev: dict[str, Any]) -> None:
            if ev["event"] == "hang_detected":
                silent.append(ev["silent_for"])
                got.set()

        tree = Tree.of(system)
        tree.events.listeners.append(on_event)
        sup = _tree(system, heartbeat=deadline, poison_limit=1)  # the hang message is not replayed
        pid, _ = _pid(system)
        for _ in range(n):
            got.clear()
            system.ref("light").tell("hang")
            if not got.wait(deadline + 10):
                raise TimeoutError("the hang was not detected")
            pid, _ = _pid(system, pid)
            out.append(silent[-1])
        sup.stop()
        tree.close()
    return out
