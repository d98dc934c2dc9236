"""Running code on the root IO thread, where the whole supervision tree lives.

Every supervisor, child record and timer is touched only on that thread
(the one ``system.exit_listeners`` are called on), so none of it needs a
lock. Other threads hand work over with :func:`on_root`.

Example::

    >>> rows = on_root(system, lambda: len(system.procs))   # doctest: +SKIP
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TypeVar

from actors import ActorSystem

__all__ = ["in_root", "on_root"]

T = TypeVar("T")


def in_root(system: ActorSystem) -> bool:
    """True when called on the root IO thread."""
    return threading.get_ident() == system.loop.thread_id


def on_root(system: ActorSystem, fn: Callable[[], T]) -> T:
    """Run ``fn`` on the root IO thread and return its result (inline if already there)."""
    return system.rt.on_client(fn)
