"""Exponential backoff with jitter between restarts (Akka's formula).

The n-th consecutive restart of a child (n = 0 for the first) waits::

    min(max_backoff, min_backoff * 2**n) * (1 + random() * random_factor)

so with ``random_factor=0.2`` the delay lies between the capped exponential
value and 20 % above it (the jitter keeps many children that failed
together from restarting in lockstep). The count goes back to 0 once the
child has stayed up ``reset_after`` seconds (default: ``min_backoff``, as
Akka's automatic reset).

Example::

    >>> backoff_delay(0, 300.0, 420.0, 0.0)     # 5 min, capped at 7 min
    300.0
    >>> backoff_delay(2, 5.0, 7.0, 0.0)
    7.0
    >>> Backoff(min=0.1, max=2.0, random_factor=0.0).delay(3)
    0.8
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["Backoff", "backoff_delay"]


def backoff_delay(
    restart_count: int,
    min_backoff: float,
    max_backoff: float,
    random_factor: float = 0.0,
    *,
    rand: Callable[[], float] = random.random,
) -> float:
    """Seconds to wait before restart number ``restart_count`` (0-based)."""
    if restart_count < 0:
        raise ValueError(f"restart_count must be >= 0, not {restart_count}")
    try:
        grown = min_backoff * math.pow(2.0, restart_count)
    except OverflowError:  # 2**n beyond float range: the cap applies anyway
        grown = math.inf
    return min(max_backoff, grown) * (1.0 + rand() * random_factor)


@dataclass(frozen=True)
class Backoff:
    """Backoff policy of one child spec (seconds)."""

    min: float = 0.1
    max: float = 10.0
    random_factor: float = 0.2
    reset_after: float | None = None

    def __post_init__(self) -> None:
        if not 0 < self.min <= self.max:
            raise ValueError(f"Backoff needs 0 < min <= max, got min={self.min}, max={self.max}")
        if self.random_factor < 0:
            raise ValueError(f"Backoff.random_factor must be >= 0, not {self.random_factor}")
        if self.reset_after is not None and self.reset_after < 0:
            raise ValueError(f"Backoff.reset_after must be >= 0, not {self.reset_after}")

    def delay(self, restart_count: int, rand: Callable[[], float] = random.random) -> float:
        return backoff_delay(restart_count, self.min, self.max, self.random_factor, rand=rand)

    @property
    def reset_window(self) -> float:
        """Uptime after which the restart count starts again from 0."""
        return self.min if self.reset_after is None else self.reset_after
