"""The supervisor's named values as enumerations that still are strings.

Each member is a ``str`` (``ChildStatus.RUNNING == "running"``), so
comparisons with plain strings, JSON and msgpack keep working, while type
checkers and readers see a closed set of values.

Example::

    >>> ChildStatus.RUNNING == "running", f"{ChildStatus.RUNNING}"
    (True, 'running')
    >>> ChildStatus("stopped") is ChildStatus.STOPPED
    True
"""

from __future__ import annotations

import enum

__all__ = ["ChildStatus", "StrEnum", "SupervisorState"]


class StrEnum(str, enum.Enum):
    """A ``str`` enumeration whose ``str()`` and format are its value (``enum.StrEnum`` needs 3.11)."""

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)


class ChildStatus(StrEnum):
    """Where a child of a supervisor is."""

    #: Its incarnation was started and is not ready yet.
    STARTING = "starting"
    #: Its incarnation is ready and serving.
    RUNNING = "running"
    #: It exited and waits for its restart (a backoff delay, or a sibling's restart).
    RESTARTING = "restarting"
    #: No incarnation: never started, terminated, or given up on.
    STOPPED = "stopped"


class SupervisorState(StrEnum):
    """Where a supervisor is."""

    NEW = "new"
    STARTING = "starting"
    RUNNING = "running"
    STOPPING = "stopping"
    STOPPED = "stopped"
