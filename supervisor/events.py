"""Supervisor events: logged, published on ``_supervisor.events``, handed to listeners.

Every event is a plain dict with at least ``event`` (its kind), ``time``
(wall clock, seconds) and ``supervisor`` (the path of the supervisor that
saw it, e.g. "root/sensors"); most also carry ``child`` and ``pid``.

=================  ==========================================================
event              extra fields
=================  ==========================================================
started            child, pid, type
restarted          child, pid, restarts (how many so far), downtime (s), standby
                   (True: a warm standby took over)
standby_ready      child, pid, prepare_s: a warm standby waits (supervisor.standby)
standby_lost       child, pid, exit_code, detail: a standby died; another follows
exited             child, pid, reason, detail   (a normal end)
crashed            child, pid, reason, detail, exit_code, phase ("run"/"start")
restarting         child, delay (s): a backoff delay before the restart
stopped            child, pid, reason, detail   (its supervisor stopped it)
hang_detected      child, pid, silent_for (s), deadline (s)
limit_exceeded     child, pid, limit ("rss"/"cpu"), value, max
gave_up            child (the last one to fail), restarts, intensity, period
escalated          parent: the supervisor this one's exit goes to
=================  ==========================================================

Subscribe from any actor with ``self.context.subscribe("_supervisor.events", fn)``.

Example::

    events = Events(system)
    events.listeners.append(print)
    events.emit("crashed", supervisor="root", child="llm", reason="killed")
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

from actors import ActorSystem
from actors.topics import Publisher

__all__ = ["TOPIC", "Events"]

TOPIC = "_supervisor.events"

log = logging.getLogger("supervisor")

_LEVELS = {
    "crashed": logging.ERROR,
    "gave_up": logging.ERROR,
    "escalated": logging.ERROR,
    "hang_detected": logging.WARNING,
    "limit_exceeded": logging.WARNING,
}


def _describe(rec: dict[str, Any]) -> str:
    skip = {"event", "time", "supervisor", "child"}
    extra = " ".join(f"{k}={v}" for k, v in rec.items() if k not in skip and v is not None)
    who = f"{rec.get('supervisor', '?')}/{rec['child']}" if rec.get("child") else rec.get("supervisor", "?")
    return f"{rec['event']} {who} {extra}".rstrip()


class Events:
    """The event stream of one supervision tree; use on the root IO thread only."""

    def __init__(self, system: ActorSystem) -> None:
        self.system = system
        self.listeners: list[Callable[[dict[str, Any]], None]] = []
        self._pub: Publisher | None = None

    def emit(self, event: str, **fields: Any) -> dict[str, Any]:
        rec: dict[str, Any] = {"event": event, "time": time.time(), **fields}
        log.log(_LEVELS.get(event, logging.INFO), "%s", _describe(rec))
        try:
            if self._pub is None:
                self._pub = Publisher(self.system.rt, TOPIC)
            self._pub.publish(rec)
        except Exception as exc:  # the run may be closing; events must never break supervision
            log.debug("could not publish a supervisor event: %s", exc)
        for fn in list(self.listeners):
            try:
                fn(rec)
            except Exception:
                log.exception("a supervisor event listener failed")
        return rec

    def close(self) -> None:
        if self._pub is not None:
            self._pub.close()
            self._pub = None
