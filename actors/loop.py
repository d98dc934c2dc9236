"""A small poll loop over ZeroMQ sockets and file descriptors.

One loop per IO thread: an actor process's main thread, or the client IO
thread of any other process. It blocks in ``zmq.Poller.poll`` until a
socket is readable, a timer is due or another thread wakes it, so an idle
loop costs nothing (no busy polling).

Example::

    >>> loop = Loop()
    >>> timer = loop.call_later(0.01, loop.stop)
    >>> loop.run()          # returns when the timer stops it (no ``until`` given)
    False
    >>> loop.close()
"""

from __future__ import annotations

import heapq
import itertools
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import zmq

__all__ = ["Loop"]

Handler = Callable[[], None]


class Loop:
    """Poll loop with timers, idle hooks and a thread-safe ``call_soon``."""

    def __init__(self) -> None:
        self._poller = zmq.Poller()
        self._handlers: dict[Any, Handler] = {}
        self._timers: list[tuple[float, int, Handler]] = []
        self._cancelled: set[int] = set()
        self._ids = itertools.count()
        self._calls: deque[Handler] = deque()
        self._wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self.add(self._wake_fd, self._drain_calls)
        self.after_poll: list[Handler] = []  # flush acks / releases, beat the heartbeat
        self.max_wait: float | None = None  # upper bound on one poll (heartbeat interval)
        self.thread_id = threading.get_ident()
        self._stopping = False
        self._restricted: dict[tuple[int, ...], zmq.Poller] = {}  # pollers of run(only=...)

    def add(self, sock: Any, handler: Handler) -> None:
        self._handlers[sock] = handler
        self._poller.register(sock, zmq.POLLIN)

    def remove(self, sock: Any) -> None:
        if self._handlers.pop(sock, None) is not None:
            self._poller.unregister(sock)
            self._restricted = {k: p for k, p in self._restricted.items() if id(sock) not in k}

    def call_later(self, delay: float, fn: Handler) -> int:
        tid = next(self._ids)
        heapq.heappush(self._timers, (time.monotonic() + delay, tid, fn))
        return tid

    def cancel(self, tid: int) -> None:
        self._cancelled.add(tid)

    def call_soon_threadsafe(self, fn: Handler) -> None:
        self._calls.append(fn)
        os.eventfd_write(self._wake_fd, 1)

    def _drain_calls(self) -> None:
        try:
            os.eventfd_read(self._wake_fd)
        except BlockingIOError:
            pass
        while self._calls:
            self._calls.popleft()()

    def stop(self) -> None:
        self._stopping = True

    def _run_timers(self) -> float | None:
        timers = self._timers
        if not timers:
            return None
        now = time.monotonic()
        if timers[0][0] <= now:
            while timers and timers[0][0] <= now:
                _, tid, fn = heapq.heappop(timers)
                if tid in self._cancelled:
                    self._cancelled.discard(tid)
                    continue
                fn()
            if not timers:
                return None
            now = time.monotonic()
        return max(0.0, timers[0][0] - now)

    def run(
        self,
        until: Callable[[], bool] | None = None,
        timeout: float | None = None,
        only: list[Any] | None = None,
    ) -> bool:
        """Run until ``stop()``, ``until()`` is true or ``timeout`` passes.

        ``only`` restricts the loop to some sockets (a handler waiting for a
        reply must not start the next message). Returns ``until()``'s last value.
        """
        deadline = None if timeout is None else time.monotonic() + timeout
        poller = self._poller
        if only is not None:
            key = tuple(id(s) for s in only)
            restricted = self._restricted.get(key)
            if restricted is None:
                restricted = self._restricted[key] = zmq.Poller()
                for s in only:
                    restricted.register(s, zmq.POLLIN)
            poller = restricted
        self._stopping = False
        # zmq_poll on the Poller's own item list: Poller.poll() only adds argument checks.
        items, handlers, hooks = poller.sockets, self._handlers, self.after_poll
        while not self._stopping:
            if until is not None and until():
                return True
            wait = self._run_timers() if only is None else None
            if self._stopping:  # a timer asked us to stop
                break
            if until is not None and until():
                return True
            bound = self.max_wait
            if bound is not None and (wait is None or bound < wait):
                wait = bound
            if deadline is not None:
                left = deadline - time.monotonic()
                if left <= 0:
                    return until() if until is not None else False
                if wait is None or left < wait:
                    wait = left
            for sock, _ in zmq.zmq_poll(items, -1 if wait is None else int(wait * 1000 + 0.999)):
                h = handlers.get(sock)
                if h is not None:
                    h()
            for hook in hooks:
                hook()
        return until() if until is not None else False

    def close(self) -> None:
        os.close(self._wake_fd)
