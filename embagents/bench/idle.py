"""Idle cost: ten actors that receive nothing, their total CPU over a window.

``cpu_percent`` is the sum over the ten actor processes (psutil, user +
system time) divided by the window, as a percentage of one core; the bar
is under 2 %. psutil counts in 10 ms ticks, so ``cpu_percent_schedstat``
gives the same from the scheduler's nanosecond counters as a cross-check. The window is 10 s (2 s with ``quick``). Right after it the
root asks each actor once more: ``p50_us`` / ``p99_us`` are those round
trips (an idle actor must still answer at once).

Example::

    >>> from embagents.bench.registry import BenchOptions
    >>> idle_case(BenchOptions(quick=True))["cpu_percent"] < 2        # doctest: +SKIP
    True
"""

from __future__ import annotations

import time
from typing import Any

import psutil

from embagents.bench.cases_actors import actor_system
from embagents.bench.registry import BenchOptions, case, percentiles
from embagents.bench.workers import Echo

__all__ = ["IDLE_ACTORS", "idle_case"]

IDLE_ACTORS = 10
_SETTLE_S = 0.5


def _schedstat_seconds(pids: list[int]) -> float | None:
    """On-CPU time from /proc/<pid>/schedstat (nanoseconds, finer than psutil's 10 ms ticks)."""
    total = 0
    try:
        for pid in pids:
            with open(f"/proc/{pid}/schedstat") as f:
                total += int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    return total / 1e9


def _cpu_seconds(procs: list[psutil.Process]) -> float:
    total = 0.0
    for p in procs:
        t = p.cpu_times()
        total += t.user + t.system
    return total


@case("idle_10_actors", transport="embagents", payload_bytes=0, kind="idle")
def idle_case(opts: BenchOptions) -> dict[str, Any]:
    """Ten idle actor processes: CPU over ``opts.idle_seconds``, then one ask each."""
    window = opts.idle_seconds
    with actor_system() as system:
        refs = [system.spawn(Echo, f"idle{i}") for i in range(IDLE_ACTORS)]
        for ref in refs:  # every actor is up and serving
            ref.ask(b"ping", timeout=10).get()
        procs = [psutil.Process(system.procs[ref.name].pid) for ref in refs]
        root = psutil.Process()
        time.sleep(_SETTLE_S)
        pids = [p.pid for p in procs]
        c0, s0, r0, t0 = _cpu_seconds(procs), _schedstat_seconds(pids), root.cpu_times(), time.monotonic()
        time.sleep(window)
        c1, s1, r1, t1 = _cpu_seconds(procs), _schedstat_seconds(pids), root.cpu_times(), time.monotonic()
        lat = []
        clock = time.perf_counter_ns
        for _ in range(3):
            for ref in refs:
                s = clock()
                ref.ask(b"ping", timeout=10).get()
                lat.append(clock() - s)
    elapsed = t1 - t0
    res: dict[str, Any] = percentiles(lat)
    res["msgs_per_s"] = None
    res["cpu_percent"] = round(100.0 * (c1 - c0) / elapsed, 3)
    if s0 is not None and s1 is not None:
        res["cpu_percent_schedstat"] = round(100.0 * (s1 - s0) / elapsed, 3)
    res["root_cpu_percent"] = round(100.0 * (r1.user + r1.system - r0.user - r0.system) / elapsed, 3)
    res["window_s"] = round(elapsed, 2)
    res["actors"] = IDLE_ACTORS
    res["note"] = (
        f"CPU of {IDLE_ACTORS} idle actor processes over {elapsed:.1f} s, % of one core; "
        "p50/p99 = asks from the root right after"
    )
    return res
