"""Running code on the root IO thread, where the whole supervision tree lives.

Every supervisor, child record and timer is touched only on that thread
(the one ``system.exit_listeners`` are called on), so none of it needs a
lock. Other threads hand work over with :func:`on_root`.

Example::

    >>> rows = on_root(system, lambda: len(system.procs))   # doctest: +SKIP
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

from actors import ActorSystem
from actors.system import ProcessInfo

__all__ = ["in_root", "on_root", "start_process"]

T = TypeVar("T")


def in_root(system: ActorSystem) -> bool:
    """True when called on the root IO thread."""
    return threading.get_ident() == system.loop.thread_id


def on_root(system: ActorSystem, fn: Callable[[], T]) -> T:
    """Run ``fn`` on the root IO thread and return its result (inline if already there)."""
    if in_root(system):
        return fn()
    return system.rt.on_client(fn)


def start_process(system: ActorSystem, spec: dict[str, Any]) -> ProcessInfo:
    """``system.start_process(spec)``, callable from the root IO thread itself.

    ``ActorSystem.start_process`` hands its work to the IO thread through
    ``Runtime.on_client`` and waits, which deadlocks when called from that
    thread. Until ``on_client`` runs inline on its own thread, this does the
    same steps here. (Reported upstream; see the supervisor README notes.)
    """
    if not in_root(system):
        return system.start_process(spec)
    name = spec["name"]
    info = ProcessInfo(name, spec)
    token = next(system._tokens)
    system.procs[name] = info
    system._spawning[token] = info
    info.started_at = time.monotonic()
    system.forkserver.send(["spawn", token, spec])
    return info
