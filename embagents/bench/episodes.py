"""Whole-system measurements for ``embagents bench``: each runs ``embagents supervise`` on a small system.

- :func:`measure_fallback_once`: a worker fed at 200 Hz (its ``on_configure``
  takes ``configure_s``) poisons itself after a short healthy spell, then
  fails every step until its fallback (``restart()``, ``max_retries=3``)
  replaces it; ``episodes`` times in one run. Per episode: the restarts it
  caused (bar: 1, the worst episode) and the time from the first failure to
  the replacement's first healthy step (bar: p50 <= 3.5 s with a 3 s
  ``on_configure``).
- :func:`measure_startup_loss`: a source listed first publishes a keep-all
  topic at 1 kHz from its first step; its subscriber is listed last, after a
  component that takes 0.5 s to configure. Per start: the messages the
  subscriber never got (bar: 0 over 20 starts) and the time from the launch
  to the ready file.

Times come from ``time.monotonic`` written by the system's processes
(CLOCK_MONOTONIC is one clock for every process on Linux).

Example::

    >>> measure_fallback_once(2)["restarts_per_episode"]     # doctest: +SKIP
    1
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from typing import Any

from embagents.bench.registry import stop_process

__all__ = ["measure_fallback_once", "measure_startup_loss"]

FALLBACK_SYSTEM = '''
import os, time
from embagents.components import Component
from embagents.events import Fallback, restart
from embagents.msgs import String
from embagents.system import System
from embagents.topic import Topic

LOG = os.environ["BENCH_LOG"]
EPISODES = int(os.environ["BENCH_EPISODES"])
ticks = Topic("ticks", String)


def note(what):
    with open(LOG, "a") as f:
        f.write(f"{what} {os.getpid()} {time.monotonic():.6f}\\n")


class Feeder(Component):
    allowed_outputs = {"Required": [String]}

    def _execution_step(self, **inputs):
        self.publish(ticks, String(data="tick"))


class Worker(Component):
    allowed_inputs = {"Required": [String]}

    def on_configure(self):
        note("start")
        time.sleep(float(os.environ["BENCH_CONFIGURE_S"]))

    def on_activate(self):
        with open(LOG) as f:
            poisoned = sum(line.startswith("poison ") for line in f)
        self.poison_at = time.monotonic() + 0.3 if poisoned < EPISODES else None
        self.poisoned = False
        self.healthy = False

    def _execution_step(self, **inputs):
        if self.poisoned:
            raise RuntimeError("poisoned: every step of this incarnation fails")
        if self.poison_at is not None and time.monotonic() >= self.poison_at:
            self.poisoned = True
            note("poison")
            raise RuntimeError("poisoned: every step of this incarnation fails")
        if not self.healthy:
            self.healthy = True
            note("ok")


system = System([
    Feeder(name="feeder", outputs=[ticks], trigger=200.0),
    Worker(name="worker", inputs=[ticks], trigger=ticks,
           fallback=Fallback(on_algorithm_fail=restart(), max_retries=3)),
], name="bench_fallback_once")
'''

STARTUP_SYSTEM = '''
import json, os, time
from embagents.components import Component
from embagents.system import SYSTEM_STOP
from embagents.msgs import String
from embagents.system import System
from embagents.topic import Topic

OUT = os.environ["BENCH_OUT"]
N = int(os.environ["BENCH_N"])
seq = Topic("seq", String, queue_size=1000, keep="all")
stop = Topic(SYSTEM_STOP, String)


class Source(Component):
    allowed_outputs = {"Required": [String]}

    def on_activate(self):
        self.n = 0

    def _execution_step(self, **inputs):
        self.publish(seq, String(data=str(self.n)))
        self.n += 1


class Slow(Component):
    def on_configure(self):
        time.sleep(0.5)


class Sink(Component):
    allowed_inputs = {"Required": [String]}
    allowed_outputs = {"Optional": [String]}

    def on_activate(self):
        self.got = []

    def _execution_step(self, **inputs):
        self.got.append(int(inputs["seq"].data))
        if len(self.got) == N:
            with open(OUT, "w") as f:
                json.dump(self.got, f)
            self.publish(stop, String(data="done"))


system = System([
    Source(name="source", outputs=[seq], trigger=1000.0),
    Slow(name="slow", trigger=None),
    Sink(name="sink", inputs=[seq], outputs=[stop], trigger=seq),
], name="bench_startup_loss")
'''


def _supervise(folder: str, source: str, env: dict[str, str], *args: str) -> subprocess.Popen[bytes]:
    path = os.path.join(folder, "system.py")
    with open(path, "w") as f:
        f.write(textwrap.dedent(source))
    runs = os.path.join(folder, "runs")  # its own: `embagents` tools of other runs must not see it
    os.makedirs(runs, mode=0o700, exist_ok=True)
    return subprocess.Popen(
        [sys.executable, "-m", "embagents.cli", "supervise", path, *args],
        stdout=subprocess.DEVNULL, stderr=open(os.path.join(folder, "stderr.txt"), "wb"),  # noqa: SIM115
        env={**os.environ, "EMBAGENTS_RUNS_DIR": runs, **env},
    )


def _stderr_tail(folder: str) -> str:
    try:
        with open(os.path.join(folder, "stderr.txt"), "rb") as f:
            return f.read()[-2000:].decode(errors="replace")
    except OSError:
        return ""


def _notes(path: str) -> list[tuple[str, int, float]]:
    try:
        with open(path) as f:
            rows = [line.split() for line in f]
    except FileNotFoundError:
        return []
    return [(r[0], int(r[1]), float(r[2])) for r in rows if len(r) == 3]


def measure_fallback_once(episodes: int, configure_s: float = 3.0, timeout: float = 120.0) -> dict[str, Any]:
    """Run ``episodes`` failure episodes in one run; returns per-episode restarts and recovery times (s)."""
    with tempfile.TemporaryDirectory(prefix="bench-fallback-") as folder:
        log = os.path.join(folder, "worker.log")
        open(log, "w").close()
        proc = _supervise(folder, FALLBACK_SYSTEM, {"BENCH_LOG": log, "BENCH_EPISODES": str(episodes),
                                                    "BENCH_CONFIGURE_S": str(configure_s)})
        try:
            deadline = time.monotonic() + timeout + episodes * (configure_s + 1.0)
            while True:
                notes = _notes(log)
                poisons = [t for what, _, t in notes if what == "poison"]
                oks = [t for what, _, t in notes if what == "ok"]
                # Done: the last episode recovered, and 1 s more for a late (wrong) second restart to show.
                if len(poisons) >= episodes and oks and oks[-1] > poisons[-1] and time.monotonic() > oks[-1] + 1.0:
                    break
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"fallback_once: {len(poisons)} of {episodes} episodes, "
                                       f"{len(oks)} recoveries; the run said:\n{_stderr_tail(folder)}")
                time.sleep(0.1)
        finally:
            proc.terminate()  # a clean stop: every child is stopped in reverse order
            stop_process(proc, grace=10.0)
        notes = _notes(log)
    poisons = [t for what, _, t in notes if what == "poison"]
    starts = [t for what, _, t in notes if what == "start"]
    oks = [t for what, _, t in notes if what == "ok"]
    restarts, recovery = [], []
    for i, t in enumerate(poisons):
        end = poisons[i + 1] if i + 1 < len(poisons) else float("inf")
        restarts.append(sum(t < s < end for s in starts))
        recovery.append(min(o for o in oks if o > t) - t)
    return {"restarts": restarts, "recovery_s": recovery}


def measure_startup_loss(starts: int, n: int = 300, timeout: float = 60.0) -> dict[str, Any]:
    """``starts`` fresh runs; returns the messages lost in each and each run's launch -> ready time (s)."""
    lost, ready = [], []
    for _ in range(starts):
        with tempfile.TemporaryDirectory(prefix="bench-startup-") as folder:
            out, ready_file = os.path.join(folder, "got.json"), os.path.join(folder, "ready.json")
            launched = time.time()
            proc = _supervise(folder, STARTUP_SYSTEM, {"BENCH_OUT": out, "BENCH_N": str(n)}, "--ready-file", ready_file)
            try:
                while not os.path.exists(ready_file):
                    if proc.poll() is not None or time.time() > launched + timeout:
                        raise RuntimeError(f"startup_loss: the run was not ready within {timeout} s:\n"
                                           f"{_stderr_tail(folder)}")
                    time.sleep(0.01)
                with open(ready_file) as f:
                    ready.append(json.load(f)["ready_at"] - launched)
                code = proc.wait(timeout)  # the sink stops the run once it has n messages
            finally:
                stop_process(proc, grace=10.0)
            if code != 0 or not os.path.exists(out):
                raise RuntimeError(f"startup_loss: the run ended with {code} before the sink had {n} "
                                   f"messages:\n{_stderr_tail(folder)}")
            with open(out) as f:
                got = json.load(f)
        lost.append(got[-1] + 1 - len(got))  # the ones before its first, and gaps
    return {"lost": lost, "ready_s": ready}
