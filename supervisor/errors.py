"""Errors of the supervisor API; ``reason`` is OTP's error term.

Example::

    >>> try:
    ...     raise SupervisorError("running", "child 'cam' is running; terminate_child('cam') first")
    ... except SupervisorError as e:
    ...     e.reason
    'running'
"""

from __future__ import annotations

__all__ = ["StartError", "SupervisorError"]


class SupervisorError(Exception):
    """A supervisor call failed; ``reason`` is one of OTP's: "not_found",
    "running", "restarting", "already_present", "already_started",
    "simple_one_for_one", "shutdown", "start_failed"; or "expired": an
    operator's request whose deadline passed before its turn came."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


class StartError(SupervisorError):
    """A supervisor (or one child) could not start; ``detail`` says why."""

    def __init__(self, message: str, detail: str = "") -> None:
        super().__init__("start_failed", message)
        self.detail = detail
