"""Restart intensity, as OTP counts it."""

from __future__ import annotations

import pytest

from supervisor.intensity import RestartIntensity


def clock(*times: float):
    return iter(times).__next__


def test_more_than_intensity_within_the_period_gives_up() -> None:
    r = RestartIntensity(2, 3600, clock=clock(0, 10, 20))
    assert [r.add(), r.add(), r.add()] == [True, True, False]


def test_restarts_older_than_the_period_are_forgotten() -> None:
    r = RestartIntensity(2, 10, clock=clock(0, 5, 11, 16, 17))
    assert [r.add() for _ in range(5)] == [True, True, True, True, False]
    assert len(r) == 3


def test_a_restart_exactly_one_period_ago_still_counts() -> None:
    r = RestartIntensity(1, 10, clock=clock(0, 10))
    assert [r.add(), r.add()] == [True, False]


def test_intensity_zero() -> None:
    assert RestartIntensity(0, 5, clock=clock(0)).add() is False


def test_bad_values() -> None:
    with pytest.raises(ValueError):
        RestartIntensity(-1, 5)
    with pytest.raises(ValueError):
        RestartIntensity(1, 0)
