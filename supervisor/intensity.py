"""Restart intensity: at most ``intensity`` restarts within ``period`` seconds.

This is OTP's ``add_restart``: every restart a supervisor decides on (a
child's exit that its restart type says to restart, and every retry of a
restart whose start failed) is recorded with its time; restarts older than
``period`` seconds are forgotten; if more than ``intensity`` remain, the
supervisor gives up. With ``intensity=0`` the first restart is already one
too many.

Example::

    >>> clock = iter([0.0, 1.0, 2.0, 3700.0]).__next__
    >>> r = RestartIntensity(2, 3600.0, clock=clock)
    >>> [r.add(), r.add(), r.add()]          # the third within the hour: give up
    [True, True, False]
    >>> spaced = RestartIntensity(2, 3600.0, clock=iter([0.0, 3601.0, 7202.0]).__next__)
    >>> [spaced.add(), spaced.add(), spaced.add()]   # spaced beyond the period: fine
    [True, True, True]
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable

__all__ = ["RestartIntensity"]


class RestartIntensity:
    """The restart history of one supervisor (one incarnation of it)."""

    def __init__(self, intensity: int, period: float, *, clock: Callable[[], float] = time.monotonic) -> None:
        if intensity < 0:
            raise ValueError(f"intensity must be >= 0, not {intensity}")
        if period <= 0:
            raise ValueError(f"period must be > 0 seconds, not {period}")
        self.intensity = intensity
        self.period = period
        self.clock = clock
        self.restarts: deque[float] = deque()

    def add(self) -> bool:
        """Record a restart now; False if that exceeds the intensity (give up)."""
        now = self.clock()
        threshold = now - self.period
        while self.restarts and self.restarts[0] < threshold:
            self.restarts.popleft()
        self.restarts.append(now)
        return len(self.restarts) <= self.intensity

    def __len__(self) -> int:
        return len(self.restarts)
