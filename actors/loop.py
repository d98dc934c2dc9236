"""A small poll loop over ZeroMQ sockets and file descriptors.

One loop per IO thread: an actor process's main thread, or the client IO
thread of any other process. It blocks in ``zmq.Poller.poll`` until a
socket is readable, a timer is due or another thread wakes it, so an idle
loop costs nothing (no busy polling).

Example::

    >>> loop = Loop()
    >>> loop.call_later(0.01, loop.stop)
    >>> loop.run()
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
        now = time.monotonic()
        while self._timers and self._timers[0][0] <= now:
            _, tid, fn = heapq.heappop(self._timers)
            if tid in self._cancelled:
                self._cancelled.discard(tid)
                continue
            fn()
        if not self._timers:
            return None
        return max(0.0, self._timers[0][0] - time.monotonic())

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
            poller = self._restricted.get(key)
            if poller is None:
                poller = self._restricted[key] = zmq.Poller()
                for s in only:
                    poller.register(s, zmq.POLLIN)
        self._stopping = False
        while not self._stopping:
            if until is not None and until():
                return True
            wait = self._run_timers() if only is None else None
            if self._stopping:  # a timer asked us to stop
                break
            if until is not None and until():
                return True
            for bound in (self.max_wait, None if deadline is None else deadline - time.monotonic()):
                if bound is not None:
                    wait = bound if wait is None else min(wait, bound)
            if wait is not None and wait <= 0 and deadline is not None and time.monotonic() >= deadline:
                return until() if until is not None else False
            events = poller.poll(None if wait is None else max(0, int(wait * 1000 + 0.999)))
            for sock, _ in events:
                h = self._handlers.get(sock)
                if h is not None:
                    h()
            for hook in self.after_poll:
                hook()
        return until() if until is not None else False

    def close(self) -> None:
        os.close(self._wake_fd)
