"""The bench helpers run and meet their bars loosely (the exact numbers are the benchmark's)."""

from __future__ import annotations

import statistics

from embagents.bench.faults import measure_crash_detect, measure_hang_detect, measure_restart_ready


def test_crash_detect() -> None:
    xs = measure_crash_detect(5)
    assert len(xs) == 5 and statistics.median(xs) < 0.5


def test_restart_ready() -> None:
    xs = measure_restart_ready(5)
    assert len(xs) == 5 and statistics.median(xs) < 1.0


def test_hang_detect() -> None:
    xs = measure_hang_detect(0.3, 2)
    assert len(xs) == 2 and all(0.3 <= x < 0.3 + 1.0 for x in xs)
