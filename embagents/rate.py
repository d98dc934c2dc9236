"""The one rate rule of embagents: a component's rate trigger and the manager loop both follow it.

Deadlines are absolute: tick *n* is due at ``start + n * period``, so the
rate does not drift. When a tick ends after the next one was due, that next
tick runs at once (late, but not lost), and the deadlines it overran beyond
it are dropped (no burst of catch-up ticks), so the phase is kept. rclpy's
timers behave the same way.

Example::

    >>> next_deadline(1.0, 0.25, now=1.1)    # on time: the next tick is due at 1.25
    (1.25, False)
    >>> next_deadline(1.0, 0.25, now=1.8)    # overran: run at once (1.75 <= now), then 2.0, 2.25, ...
    (1.75, True)
"""

from __future__ import annotations

import math

__all__ = ["next_deadline"]


def next_deadline(deadline: float, period: float, now: float) -> tuple[float, bool]:
    """The deadline of the tick after the one due at ``deadline``, and whether that one overran.

    When it overran (``now`` past the next deadline), the result is the
    latest deadline on the phase that is not after ``now``: due at once.
    """
    nxt = deadline + period
    if now <= nxt:
        return nxt, False
    return nxt + math.floor((now - nxt) / period) * period, True
