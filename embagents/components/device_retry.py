"""When to try a device again: exponential backoff between attempts, shared by the device components.

A camera, microphone or speaker that cannot be opened (or is lost) is tried
again after ``first_s``, then twice as long each time up to ``max_s``
(:func:`supervisor.backoff.backoff_delay`, the supervisor's own formula,
without jitter: one process, one device). A success starts the count again.

Example::

    >>> r = DeviceRetry()
    >>> r.failed(0.5, 10.0), r.failed(0.5, 10.0), r.failed(0.5, 1.5)
    (0.5, 1.0, 1.5)
    >>> r.waiting()
    True
    >>> r.opened()
    >>> r.waiting(), r.failures
    (False, 0)
"""

from __future__ import annotations

import time

from supervisor.backoff import backoff_delay

__all__ = ["DeviceRetry"]


class DeviceRetry:
    """Counts consecutive failures to open a device and says when the next try is due."""

    def __init__(self) -> None:
        self.failures = 0
        self.retry_at = 0.0

    def failed(self, first_s: float, max_s: float) -> float:
        """One more failure: the delay in seconds before the next try (it is also remembered)."""
        delay = backoff_delay(self.failures, first_s, max_s)
        self.failures += 1
        self.retry_at = time.monotonic() + delay
        return delay

    def opened(self) -> None:
        """The device works again: the next failure waits ``first_s`` again."""
        self.failures, self.retry_at = 0, 0.0

    def waiting(self) -> bool:
        """True while the delay of the last failure has not passed."""
        return time.monotonic() < self.retry_at

    def wait_s(self) -> float:
        """Seconds until the next try is due (0: now)."""
        return max(0.0, self.retry_at - time.monotonic())
