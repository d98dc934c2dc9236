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

import glob
import os
import signal
import tempfile
import threading
import time
from functools import partial
from typing import Any

from actors import Actor, ActorCrashed, ActorSystem, Timeout
from actors.topics import Publisher
from embagents.bench.registry import scoped_environ
from embagents.bench.standby_system import NUMBERS
from embagents.msgs import String
from embagents.requests import Call
from embagents.supervision import build_spec
from embagents.system import load_system, remember_system
from supervisor.spec import ChildSpec, SupervisorSpec
from supervisor.supervisor import start_supervisor
from supervisor.tree import Tree

__all__ = ["Light", "measure_crash_detect", "measure_hang_detect", "measure_restart_ready", "measure_standby_takeover"]


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


def measure_standby_takeover(kills: int, standby: bool, configure_s: float = 5.0,
                             rate_hz: float = 200.0) -> dict[str, Any]:
    """SIGKILL the :mod:`embagents.bench.standby_system` component ``kills`` times while numbers flow.

    Returns ``samples`` (seconds from each SIGKILL until a ``Call("pid")`` ask
    is answered by another process), ``sent`` and ``lost`` (numbers told at
    ``rate_hz`` and never recorded: the mailbox, at-least-once),
    ``topic_lost`` (the same numbers published on the component's
    ``keep="all"`` input and not recorded, from the first one heard on: the
    publisher keeps what the dead incarnation had not acknowledged, within its
    window, for the next one) and ``topic_again`` (numbers recorded more than
    once: taken by an incarnation that died before acknowledging them).
    With ``standby``, each kill waits until the next standby is ready.
    """
    with tempfile.TemporaryDirectory(prefix="standby-bench-") as out, scoped_environ({
        "EMBAGENTS_BENCH_OUT": out, "EMBAGENTS_BENCH_CONFIGURE_S": str(configure_s),
        "EMBAGENTS_BENCH_STANDBY": "1" if standby else "0",  # read by the system file, in every process
    }):
        samples, sent = _kill_and_time(kills, standby, configure_s, rate_hz)
        seen: dict[str, set[int]] = {"T": set(), "S": set()}
        again = 0
        for f in glob.glob(os.path.join(out, "rec-*.log")):
            with open(f) as fh:
                for how, n in (line.split() for line in fh):
                    again += how == "S" and int(n) in seen["S"]
                    seen[how].add(int(n))
    first = min(seen["S"], default=sent)
    return {"samples": samples, "sent": sent, "lost": sum(1 for n in range(sent) if n not in seen["T"]),
            "topic_lost": sum(1 for n in range(first, sent) if n not in seen["S"]), "topic_again": again}


def _kill_and_time(kills: int, standby: bool, configure_s: float, rate_hz: float) -> tuple[list[float], int]:
    path = os.path.join(os.path.dirname(__file__), "standby_system.py")
    system_decl = load_system(path)
    remember_system(path, system_decl)
    spec = build_spec(system_decl, path)
    spec.intensity, spec.period = 1_000_000, 1.0
    samples: list[float] = []
    sent = [0]
    with ActorSystem() as system:
        tree = Tree.of(system)
        ready = threading.Event()
        tree.events.listeners.append(lambda ev: ready.set() if ev["event"] == "standby_ready" else None)
        sup = start_supervisor(system, spec, "bench")
        stop = threading.Event()

        numbers = system.rt.on_client(lambda: Publisher(system.rt, NUMBERS.name))

        def send() -> None:
            ref = system.ref("slow")
            n = 0
            while not stop.wait(1.0 / rate_hz):
                ref.tell(Call("record", [n]))
                system.rt.on_client(partial(numbers.publish, String(data=str(n))))
                n += 1
            sent[0] = n
            ref.ask(Call("pid"), timeout=60).get()  # in order: every tell before it was handled

        ref = system.ref("slow")
        pid = ref.ask(Call("pid"), timeout=60).get()
        sender = threading.Thread(target=send, name="standby-bench-sender")
        sender.start()
        try:
            for _ in range(kills):
                if standby and not ready.wait(configure_s + 60):
                    raise TimeoutError("no standby got ready")
                ready.clear()
                time.sleep(0.05)  # the senders' links settle on the serving incarnation
                t0 = time.perf_counter()
                os.kill(pid, signal.SIGKILL)
                pid = _other_pid(ref, pid, t0 + configure_s + 60)
                samples.append(time.perf_counter() - t0)
            # The flow goes on past the last takeover: a publisher re-sends what a dead incarnation held at its
            # next publish, so stopping at the takeover itself would count the kept messages as lost.
            time.sleep(1.0)
        finally:
            stop.set()
            sender.join(120)
        sup.stop()
        system.rt.on_client(numbers.close)
        tree.close()
    return samples, sent[0]


def _other_pid(ref: Any, old: int, deadline: float) -> int:
    """Ask ``Call("pid")`` until a process other than ``old`` answers."""

    while time.perf_counter() < deadline:
        try:
            pid = ref.ask(Call("pid"), timeout=1.0).get()
        except (ActorCrashed, Timeout):
            continue
        if pid != old:
            return int(pid)
    raise TimeoutError("the component did not come back")
