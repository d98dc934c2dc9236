"""Supervision cases: ``crash_detect``, ``restart_ready`` and ``hang_detect``.

- crash_detect: SIGKILL an actor; time until the supervisor's exit listener
  runs (the fork server reaps it on SIGCHLD; nothing polls). Bar: p50 <= 5 ms.
- restart_ready: SIGKILL a light actor under a one_for_one supervisor; time
  until an ask answers again. Bar: p50 <= 50 ms (a fresh rclpy node takes
  ~364 ms to start here; Sugarcoat respawns through a ROS launch process).
- hang_detect: an actor holds the GIL in a C call; time from the moment its
  heartbeat deadline passed until the supervisor killed it. Bar: <= 100 ms.
- fallback_once: 10 failure episodes of a component fed at 200 Hz whose
  replacement takes 3 s in ``on_configure`` (:mod:`embagents.bench.episodes`).
  Bars: restarts per episode == 1 (the worst episode), recovery p50 <= 3.5 s.
- startup_loss: 20 starts of a system whose keep-all source is listed first
  and publishes at 1 kHz from its first step. Bar: lost == 0.
- standby_takeover: a component whose on_configure takes 5 s (a CUDA model's
  start: 6.7 s measured on an H200) is SIGKILLed 10 times while numbers are
  told to it and published on its keep-all input at 200/s; time until it
  answers again, with ``standby=True`` and (``no_standby_p50_ms``) without.
  Bars: p50 <= 100 ms; ``lost`` (keep-all input numbers never recorded, with
  the standby) == 0; beside: ``lost_no_standby``, ``redelivered`` (numbers
  recorded twice: at-least-once) and ``mailbox_lost`` (the told numbers).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from embagents.bench.registry import BenchOptions, case


def _row(samples_s: list[float], note: str) -> dict[str, Any]:
    us = np.asarray(samples_s, dtype=np.float64) * 1e6
    p50, p99 = np.percentile(us, [50, 99])
    return {"p50_us": round(float(p50), 1), "p99_us": round(float(p99), 1), "msgs_per_s": None,
            "samples": len(samples_s), "note": note}


@case("crash_detect", transport="embagents", kind="supervision")
def crash_detect(opts: BenchOptions) -> dict[str, Any]:
    from embagents.bench.faults import measure_crash_detect  # lazy: a cycle

    return _row(measure_crash_detect(20 if opts.quick else 100), "SIGKILL -> exit seen by the supervisor; bar p50 <= 5 ms")


@case("restart_ready", transport="embagents", kind="supervision")
def restart_ready(opts: BenchOptions) -> dict[str, Any]:
    from embagents.bench.faults import measure_restart_ready  # lazy: a cycle

    return _row(measure_restart_ready(20 if opts.quick else 100),
                "SIGKILL -> the restarted actor answers an ask; bar p50 <= 50 ms")


@case("hang_detect", transport="embagents", kind="supervision")
def hang_detect(opts: BenchOptions) -> dict[str, Any]:
    from embagents.bench.faults import measure_hang_detect  # lazy: a cycle

    deadline = 0.5
    late = [t - deadline for t in measure_hang_detect(deadline, 3 if opts.quick else 8)]
    return _row(late, f"time past a {deadline} s heartbeat deadline until the hung actor was killed; bar <= 100 ms")


@case("fallback_once", transport="embagents", kind="supervision")
def fallback_once(opts: BenchOptions) -> dict[str, Any]:
    from embagents.bench.episodes import measure_fallback_once  # lazy: a cycle

    episodes, configure_s = (2, 1.0) if opts.quick else (10, 3.0)
    res = measure_fallback_once(episodes, configure_s=configure_s)
    row = _row(res["recovery_s"], f"{episodes} failure episodes of a worker fed at 200 Hz, {configure_s:g} s "
                                  "on_configure: first failure -> the replacement's first healthy step; bars: "
                                  "restarts per episode == 1 (worst), recovery p50 <= 3.5 s (with 3 s)")
    recovery = sorted(res["recovery_s"])
    row.update(restarts_per_episode=max(res["restarts"]), restarts=res["restarts"], episodes=episodes,
               recovery_s=round(float(np.percentile(recovery, 50)), 3), recovery_max_s=round(recovery[-1], 3))
    return row


@case("startup_loss", transport="embagents", kind="supervision")
def startup_loss(opts: BenchOptions) -> dict[str, Any]:
    from embagents.bench.episodes import measure_startup_loss  # lazy: a cycle

    starts = 3 if opts.quick else 20
    res = measure_startup_loss(starts)
    row = _row(res["ready_s"], f"{starts} starts: a source listed first publishes a keep-all topic at 1 kHz from "
                               "its first step, its subscriber listed last; p50/p99: launch -> ready file; "
                               "bar: lost == 0")
    row.update(lost=sum(res["lost"]), lost_per_start=res["lost"], starts=starts)
    return row


@case("standby_takeover", transport="embagents", kind="supervision")
def standby_takeover(opts: BenchOptions) -> dict[str, Any]:
    from embagents.bench.faults import measure_standby_takeover  # lazy: a cycle

    kills, configure_s = (2, 1.0) if opts.quick else (10, 5.0)  # a quick run: a shorter configure, same code
    warm = measure_standby_takeover(kills, standby=True, configure_s=configure_s)
    cold = measure_standby_takeover(kills, standby=False, configure_s=configure_s)
    row = _row(warm["samples"], f"SIGKILL -> serving again, a {configure_s:g} s on_configure, {kills} kills, numbers "
                                "told and published on its keep-all input at 200/s; standby=True vs none "
                                "(no_standby_p50_ms); bars p50 <= 100 ms, lost (keep-all input, standby) == 0")
    # lost: the keep-all topic input with the standby (the bar); without it, a 5 s configure blocks the
    # new incarnation's reads past the publisher's window and stall bound (lost_no_standby).
    row.update(p50_ms=round(row["p50_us"] / 1000, 1), p99_ms=round(row["p99_us"] / 1000, 1),
               no_standby_p50_ms=round(float(np.percentile(cold["samples"], 50)) * 1000, 1),
               lost=warm["topic_lost"], lost_no_standby=cold["topic_lost"],
               redelivered=warm["topic_again"], redelivered_no_standby=cold["topic_again"],
               mailbox_lost=warm["lost"] + cold["lost"], sent=warm["sent"] + cold["sent"])
    return row
