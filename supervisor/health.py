"""Hang detection (heartbeat) and resource limits (psutil), on the root IO loop.

**Hangs.** An actor's loop writes a CLOCK_MONOTONIC timestamp into its
journal at least every ``heartbeat/4`` s when idle and after every message.
A started actor whose last beat is older than its ``heartbeat`` deadline is
alive but silent (a C call holding the GIL, a deadlock, a handler that
never returns): it is killed (SIGKILL) and its supervisor handles the exit
as a crash with reason "error" (hang). No polling: one timer per actor,
set for the moment its deadline would pass given its last beat, so a hang
is seen within about a millisecond of the deadline.

**Limits.** Every ``interval`` s the monitor samples each running child
process (RSS and CPU % since the previous sample). RSS above ``max_rss_mb``,
or CPU above ``max_cpu_percent`` in every sample for ``cpu_window`` s,
kills it (SIGKILL; a leaking process may not have time for a clean stop)
and it is restarted per its restart type. The samples also feed ``status``.

Example::

    >>> ChildSpec("llm", LLM, heartbeat=5.0, max_rss_mb=4000,       # doctest: +SKIP
    ...           max_cpu_percent=190, cpu_window=30)
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

import psutil

from supervisor.exits import Exit, Reason

if TYPE_CHECKING:
    from actors.journal import Journal
    from supervisor.procs import Incarnation
    from supervisor.tree import Tree

__all__ = ["ResourceMonitor", "watch_heartbeat"]

log = logging.getLogger("supervisor.health")


def watch_heartbeat(tree: Tree, inc: Incarnation, journal: Journal, deadline: float) -> None:
    """Kill ``inc`` once its journal's heartbeat is older than ``deadline`` seconds."""

    def check() -> None:
        if inc.exited.done() or inc.stopping:
            return
        # Being ready counts as a beat: on_start may have run longer than the deadline.
        last = max(journal.last_beat(), inc.ready_at or 0.0)
        now = time.monotonic()
        due = last + deadline
        if now < due:
            tree.loop.call_later(due - now, check)
            return
        silent = now - last
        tree.events.emit(
            "hang_detected", supervisor=inc.path, child=inc.name, pid=inc.pid,
            silent_for=round(silent, 3), deadline=deadline,
        )
        inc.kill(Exit(Reason.ERROR, None, f"hang: no heartbeat for {silent:.2f} s (deadline {deadline} s)"))

    check()


class ResourceMonitor:
    """Samples the tree's running processes; enforces ``max_rss_mb`` and ``max_cpu_percent``."""

    def __init__(self, tree: Tree, interval: float = 0.5) -> None:
        self.tree = tree
        self.interval = interval
        self.watched: dict[int, Incarnation] = {}
        self._timer: int | None = None

    def watch(self, inc: Incarnation) -> None:
        if inc.pid is None:
            return
        try:
            inc.ps = psutil.Process(inc.pid)
            inc.ps.cpu_percent(None)  # the first call only sets the baseline
        except psutil.Error:
            return
        self.watched[id(inc)] = inc
        if self._timer is None:
            self._timer = self.tree.loop.call_later(self.interval, self._tick)

    def _tick(self) -> None:
        self._timer = None
        now = time.monotonic()
        for key, inc in list(self.watched.items()):
            if inc.exited.done():
                del self.watched[key]
                continue
            self._sample(inc, now)
        if self.watched:
            self._timer = self.tree.loop.call_later(self.interval, self._tick)

    def _sample(self, inc: Incarnation, now: float) -> None:
        u = inc.usage
        try:
            with inc.ps.oneshot():
                u.rss_mb = inc.ps.memory_info().rss / 1e6
                u.cpu_percent = inc.ps.cpu_percent(None)
        except psutil.Error:
            return  # it is exiting; the exit listener will say so
        u.at = now
        spec = inc.spec
        if inc.stopping:
            return
        if spec.max_rss_mb is not None and u.rss_mb > spec.max_rss_mb:
            self._exceeded(inc, "rss", round(u.rss_mb, 1), spec.max_rss_mb, f"rss {u.rss_mb:.0f} MB > {spec.max_rss_mb} MB")
            return
        if spec.max_cpu_percent is not None:
            if u.cpu_percent <= spec.max_cpu_percent:
                u.cpu_over_since = None
            elif u.cpu_over_since is None:
                u.cpu_over_since = now - self.interval  # the sample covers the past interval
            elif now - u.cpu_over_since >= spec.cpu_window:
                self._exceeded(
                    inc, "cpu", round(u.cpu_percent, 1), spec.max_cpu_percent,
                    f"cpu above {spec.max_cpu_percent} % for {now - u.cpu_over_since:.1f} s",
                )

    def _exceeded(self, inc: Incarnation, limit: str, value: float, cap: float, detail: str) -> None:
        self.tree.events.emit(
            "limit_exceeded", supervisor=inc.path, child=inc.name, pid=inc.pid, limit=limit, value=value, max=cap
        )
        inc.kill(Exit(Reason.ERROR, None, f"limit: {detail}"))
        self.watched.pop(id(inc), None)

    def close(self) -> None:
        if self._timer is not None:
            self.tree.loop.cancel(self._timer)
            self._timer = None
        self.watched.clear()
