"""Akka's backoff formula, with Akka's own test vectors."""

from __future__ import annotations

import pytest

from supervisor.backoff import Backoff, backoff_delay

MIN, DAY = 60.0, 86400.0


@pytest.mark.parametrize(
    ("n", "lo", "hi", "expected"),
    [
        (0, 5 * MIN, 7 * MIN, 5 * MIN),
        (2, 5.0, 7.0, 7.0),
        (2, 5.0, 7 * DAY, 20.0),
        (29, 5 * MIN, 10 * MIN, 10 * MIN),
    ],
)
def test_akka_vectors_without_randomness(n: int, lo: float, hi: float, expected: float) -> None:
    assert backoff_delay(n, lo, hi, 0.0) == expected


def test_huge_restart_counts_stay_at_the_cap() -> None:
    assert backoff_delay(5000, 1.0, 30.0, 0.0) == 30.0


def test_jitter_stays_within_the_random_factor() -> None:
    assert backoff_delay(1, 1.0, 10.0, 0.5, rand=lambda: 0.0) == 2.0
    assert backoff_delay(1, 1.0, 10.0, 0.5, rand=lambda: 1.0) == 3.0
    values = {backoff_delay(3, 0.1, 10.0, 0.2) for _ in range(50)}
    assert all(0.8 <= v <= 0.96 for v in values) and len(values) > 1


def test_policy_object() -> None:
    b = Backoff(min=0.5, max=4.0, random_factor=0.0)
    assert [b.delay(n) for n in range(5)] == [0.5, 1.0, 2.0, 4.0, 4.0]
    assert b.reset_window == 0.5 and Backoff(reset_after=9).reset_window == 9
    with pytest.raises(ValueError, match="min <= max"):
        Backoff(min=2, max=1)
    with pytest.raises(ValueError):
        backoff_delay(-1, 1, 2)
