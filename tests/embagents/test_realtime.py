"""The one rate rule (components' rate triggers and the manager loop): absolute deadlines, a late tick at once."""

from __future__ import annotations

import pytest

from embagents.realtime import next_deadline


def test_on_time_the_next_deadline_is_one_period_on() -> None:
    assert next_deadline(2.0, 0.5, now=2.1) == (2.5, False)
    assert next_deadline(2.0, 0.5, now=2.5) == (2.5, False)  # exactly due is not late


@pytest.mark.parametrize(("now", "due"), [(2.6, 2.5), (3.2, 3.0), (4.9, 4.5)])
def test_after_an_overrun_the_next_tick_is_due_at_once_on_the_phase(now: float, due: float) -> None:
    # Not skipped (due <= now: it runs at once), not a burst (one tick, then back on the 0.5 s grid).
    nxt, overran = next_deadline(2.0, 0.5, now=now)
    assert overran and nxt == due and nxt <= now < nxt + 0.5
    assert next_deadline(nxt, 0.5, now=now) == (due + 0.5, False)


def test_the_phase_never_drifts_over_many_ticks() -> None:
    deadline, period = 0.0, 0.125
    for _ in range(1000):
        deadline, overran = next_deadline(deadline, period, now=deadline + period * 0.9)
        assert not overran
    assert deadline == 1000 * period
