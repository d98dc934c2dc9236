"""The manager loop as a supervised actor: ``manager_loop_jitter`` and ``manager_restart_resume``.

- ``manager_loop_jitter``: a Manager at 100 Hz whose handler keeps one call
  in flight to an agent doing 50 ms of pure-Python work per call; the tick
  period jitter (``|period - 10 ms|``) p99, with the agent isolated (its own
  process) and attached (a thread of the loop's process, sharing its GIL),
  one after the other. Fields ``p99_jitter_ms`` (isolated),
  ``attached_p99_jitter_ms`` and ``jitter_ratio`` (isolated / attached).
  Bars: isolated <= 2 ms and ratio <= 1/5.
- ``manager_restart_resume``: a Manager at 100 Hz runs a four-state
  pick-and-place cycle and publishes every tick (state, pid, stamp); the
  bench SIGKILLs it mid-mission, several times, reads the state the killed
  manager had reached from its snapshot, and checks that the new incarnation
  resumes in it. ``resume_ms`` = the worst time from the kill to that first
  tick (stamped by the manager itself; ``resume_p50_ms`` the median).
  Bar: <= 100 ms.
  The bench's manager has no handshake rules (a real one waits for its
  first camera frame again after a restart).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import tempfile
import threading
import time
from typing import Any

import numpy as np

from actors import ActorSystem
from actors.topics import Subscription
from embagents.bench.registry import BenchOptions, case
from embagents.manager import Agent, Handler, Manager, Node, State, StateMachineHandler
from embagents.msgs import String
from embagents.supervision import build_spec
from embagents.system import System, remember_system
from embagents.topic import Topic
from supervisor import start_supervisor
from supervisor.snapshot import read as read_snapshot

__all__ = ["BusyAgent"]

RATE_HZ = 100.0
WORK_S = 0.05


class BusyAgent:
    """An agent whose ``work(seconds)`` is pure Python: it holds the GIL the whole time."""

    def work(self, seconds: float) -> int:
        end, n = time.perf_counter() + seconds, 0
        while time.perf_counter() < end:
            n += 1
        return n


def _supervised(system: Any, key: str) -> Any:
    """A started ActorSystem and root supervisor running ``system`` (remembered under ``key``)."""

    remember_system(key, system)  # before the fork server starts: its children find the system in memory
    asys = ActorSystem()
    try:
        return asys, start_supervisor(asys, build_spec(system, key))
    except BaseException:
        asys.shutdown()
        raise


def _jitter_run(isolated: bool, ticks: int, out: str, nice: int | None = None) -> list[float]:
    agent = Agent("busy", BusyAgent, isolated=isolated, nice=nice)
    if os.path.exists(out):
        os.unlink(out)

    class Recorder(Handler):
        def __init__(self) -> None:
            super().__init__("recorder")
            self.fut: Any = None
            self.times: list[float] = []

        def on_tick(self, state: State, tick: int) -> None:
            self.times.append(time.monotonic())
            if self.fut is None or self.fut.done():
                self.fut = agent.call("work", WORK_S)
            if len(self.times) == ticks:
                with open(out + ".tmp", "w") as f:
                    json.dump(self.times, f)
                os.replace(out + ".tmp", out)

    manager = Manager(RATE_HZ, name="jitter", agents=[agent], handlers=[Recorder()], hang_timeout=10.0)
    system = System([], managers=[manager], name="bench_manager_jitter")
    asys, sup = _supervised(system, f"<bench manager_loop_jitter isolated={isolated}>")
    try:
        deadline = time.monotonic() + ticks / RATE_HZ * 3 + 30
        while not os.path.exists(out):
            if time.monotonic() > deadline:
                raise TimeoutError(f"the manager did not record {ticks} ticks in time")
            time.sleep(0.05)
        with open(out) as f:
            return list(json.load(f))
    finally:
        sup.stop()
        asys.shutdown()


def _jitter_s(times: list[float], skip: int) -> np.ndarray:
    """``|period - 1/rate|`` of every tick after the first ``skip``, in seconds."""
    return np.abs(np.diff(np.asarray(times[skip:])) - 1.0 / RATE_HZ)


def _p99_ms(jitter: np.ndarray) -> float:
    return round(float(np.percentile(jitter, 99)) * 1000, 3)


@case("manager_loop_jitter", transport="embagents", kind="manager")
def manager_loop_jitter(opts: BenchOptions) -> dict[str, Any]:
    ticks = 200 if opts.quick else 1050
    skip = 50  # the first half second: the run is still starting around the loop
    with tempfile.TemporaryDirectory(prefix="embagents-bench-") as tmp:
        iso = _jitter_s(_jitter_run(True, ticks, os.path.join(tmp, "isolated.json")), skip)
        att = _jitter_s(_jitter_run(False, ticks, os.path.join(tmp, "attached.json")), skip)
    isolated, attached = _p99_ms(iso), _p99_ms(att)
    return {
        # p50/p99: the isolated run's jitter, in microseconds.
        "p50_us": round(float(np.median(iso)) * 1e6, 2), "p99_us": round(float(np.percentile(iso, 99)) * 1e6, 2),
        "msgs_per_s": None,
        "p99_jitter_ms": isolated,
        "attached_p99_jitter_ms": attached,
        "jitter_ratio": round(isolated / attached, 3) if attached else None,
        "note": f"{ticks - skip} ticks at {RATE_HZ:g} Hz, one {WORK_S * 1000:g} ms pure-Python agent call always "
                "in flight; isolated agent vs attached; bars: isolated p99 <= 2 ms and <= 1/5 of attached",
    }


def _mission_system(first_ticks: str) -> Any:
    """The mission; each incarnation appends its first tick ``[pid, state, monotonic]`` to ``first_ticks``."""

    beats = Topic("mission_beats", String, queue_size=1000, keep="all")
    node = Node("beats", publish=[beats])

    class PickPlace(StateMachineHandler):
        transitions = {"approach": {"next": "grasp"}, "grasp": {"next": "lift"}, "lift": {"next": "place"},
                       "place": {"next": "approach"}}

        first = True  # a class attribute: True again in every new incarnation's process

        def on_tick(self, state: State, tick: int) -> None:
            if self.first:  # written by the manager itself: a topic's first messages may precede its subscriber
                PickPlace.first = False
                with open(first_ticks, "a") as f:
                    f.write(json.dumps([os.getpid(), self.current, time.monotonic()]) + "\n")
            super().on_tick(state, tick)
            steps = int(state.get("steps", 0)) + 1
            if steps >= 25:  # a quarter of a second in each state
                self.fire("next", state)
                steps = 0
            state["steps"] = steps
            node.publish(beats, String(data=json.dumps([os.getpid(), self.current, tick, time.monotonic()])))

    manager = Manager(RATE_HZ, name="mission", nodes=[node], handlers=[PickPlace()])
    return System([], managers=[manager], name="bench_manager_resume", supervision={"intensity": 100, "period": 10})


@case("manager_restart_resume", transport="embagents", kind="manager")
def manager_restart_resume(opts: BenchOptions) -> dict[str, Any]:
    kills = 3 if opts.quick else 15
    got: list[tuple[int, str, int, float]] = []
    cond = threading.Condition()

    def on_beat(msg: Any) -> None:
        with cond:
            got.append(tuple(json.loads(msg.data)))
            cond.notify_all()

    def wait_for(pred: Any, timeout: float, what: str) -> Any:
        with cond:
            if not cond.wait_for(lambda: pred(), timeout):
                raise TimeoutError(f"manager_restart_resume: no {what} within {timeout} s")
            return pred()

    tmp = tempfile.mkdtemp(prefix="embagents-bench-")
    first_ticks = os.path.join(tmp, "first_ticks.jsonl")
    asys, sup = _supervised(_mission_system(first_ticks), "<bench manager_restart_resume>")
    samples, states = [], []
    try:
        sub = asys.rt.on_client(lambda: Subscription(asys.rt, asys.loop, "mission_beats", on_beat, queue_size=1000,
                                                     keep="all"))
        wait_for(lambda: len(got) > 20, 10, "ticks")
        rng = np.random.default_rng(1)
        snap = os.path.join(asys.run_dir, "mission.snap")
        for _ in range(kills):
            time.sleep(0.1 + float(rng.random()) * 0.25)  # somewhere mid-state
            with cond:
                pid, seen = got[-1][0], len(got)
                t0 = time.monotonic()
                os.kill(pid, signal.SIGKILL)
            # The state at the kill: the killed manager's last completed tick, as its snapshot keeps it (read at
            # once: the new incarnation needs milliseconds to start). Its last beats may die with it, unsent.
            at_kill = dict(read_snapshot(snap)["handlers"])["PickPlace"]["current"]
            wait_for(lambda s=seen, p=pid: any(b[0] != p for b in got[s:]), 10, "tick of the new incarnation")
            with open(first_ticks) as f:
                new_pid, resumed_in, first_at = json.loads(f.read().splitlines()[-1])
            if new_pid == pid or resumed_in != at_kill:
                raise RuntimeError(f"the restarted manager resumed in {resumed_in!r}, not {at_kill!r} (pid {new_pid})")
            samples.append((first_at - t0) * 1000)
            states.append(at_kill)
        asys.rt.on_client(sub.close)
    finally:
        sup.stop()
        asys.shutdown()
        shutil.rmtree(tmp, ignore_errors=True)
    return {
        "p50_us": round(float(np.median(samples)) * 1000, 2), "p99_us": round(float(np.percentile(samples, 99)) * 1000, 2),
        "msgs_per_s": None,
        "resume_ms": round(max(samples), 2),
        "resume_p50_ms": round(float(np.median(samples)), 2),
        "note": f"{kills} SIGKILLs mid-mission (states {', '.join(sorted(set(states)))}); kill -> first tick of the "
                "new incarnation in the same state; resume_ms = worst; bar <= 100 ms",
    }
