"""Futures and tasks on one :class:`actors.loop.Loop` (the root IO thread).

A supervisor is sequential logic ("stop these in reverse order, each with
its timeout, then start those in order, each until it is ready") that must
never block the thread it runs on: exits, ready notes and timers all
arrive on that same thread. So supervisor jobs are coroutines, and this
module is the smallest driver for them: no asyncio, no second thread.

Callbacks always run from the loop's next turn, never inside the code that
resolved the future, so a job can never be re-entered or cancelled while it
is executing.

Example::

    >>> from actors.loop import Loop
    >>> loop = Loop()
    >>> async def job():
    ...     await sleep(loop, 0.01)
    ...     return "done"
    >>> task = Task(loop, job())
    >>> task.future.add_done_callback(lambda f: stop(loop))
    >>> loop.run()
    False
    >>> task.future.result()
    'done'
"""

from __future__ import annotations

import functools
import weakref
from collections import deque
from collections.abc import Callable, Coroutine, Generator
from typing import Any, Generic, TypeVar

from actors.loop import Loop

__all__ = ["Cancelled", "Future", "Task", "sleep", "soon", "stop", "wait_for"]

T = TypeVar("T")


class Cancelled(Exception):
    """The task was cancelled (its supervisor is shutting down)."""


class _Soon:
    """A FIFO of calls for the loop's next turn (one timer per batch, not per call)."""

    def __init__(self, loop: Loop) -> None:
        self.loop = weakref.ref(loop)
        self.calls: deque[Callable[[], None]] = deque()
        self.armed = False

    def add(self, fn: Callable[[], None]) -> None:
        self.calls.append(fn)
        self._arm()

    def _arm(self) -> None:
        loop = self.loop()
        if not self.armed and loop is not None:
            self.armed = True
            loop.call_later(0, self.run)

    def run(self) -> None:
        self.armed = False
        # Only what is queued now: calls added meanwhile wait a turn, so IO is never starved.
        for _ in range(len(self.calls)):
            self.calls.popleft()()
        if self.calls:
            self._arm()


_queues: weakref.WeakKeyDictionary[Loop, _Soon] = weakref.WeakKeyDictionary()


def soon(loop: Loop, fn: Callable[[], None]) -> None:
    """Call ``fn`` on ``loop``'s next turn (must be called on the loop's thread)."""
    q = _queues.get(loop)
    if q is None:
        q = _queues[loop] = _Soon(loop)
    q.add(fn)


class Future(Generic[T]):
    """A value that arrives later, on the loop's thread; ``await`` it in a :class:`Task`."""

    __slots__ = ("loop", "_done", "_value", "_error", "_callbacks")

    def __init__(self, loop: Loop) -> None:
        self.loop = loop
        self._done = False
        self._value: Any = None
        self._error: BaseException | None = None
        self._callbacks: list[Callable[[Future[T]], None]] = []

    def done(self) -> bool:
        return self._done

    def result(self) -> T:
        if not self._done:
            raise RuntimeError("the future is not done yet")
        if self._error is not None:
            raise self._error
        return self._value

    def exception(self) -> BaseException | None:
        return self._error

    def set_result(self, value: T) -> None:
        if not self._done:
            self._done, self._value = True, value
            self._schedule()

    def set_exception(self, error: BaseException) -> None:
        if not self._done:
            self._done, self._error = True, error
            self._schedule()

    def add_done_callback(self, fn: Callable[[Future[T]], None]) -> None:
        if self._done:
            soon(self.loop, lambda: fn(self))
        else:
            self._callbacks.append(fn)

    def _schedule(self) -> None:
        cbs, self._callbacks = self._callbacks, []
        for fn in cbs:
            soon(self.loop, functools.partial(fn, self))

    def __await__(self) -> Generator[Future[T], None, T]:
        if not self._done:
            yield self
        return self.result()


class Task:
    """Drives coroutine ``coro`` on ``loop``; its outcome lands in :attr:`future`."""

    def __init__(self, loop: Loop, coro: Coroutine[Any, Any, Any]) -> None:
        self.loop = loop
        self.future: Future[Any] = Future(loop)
        self._coro = coro
        self._cancelled = False
        self._running = False
        soon(loop, lambda: self._step(None, None))

    def _step(self, value: Any, error: BaseException | None) -> None:
        if self._cancelled:
            return
        self._running = True
        try:
            waited = self._coro.throw(error) if error is not None else self._coro.send(value)
        except StopIteration as stop:
            self.future.set_result(stop.value)
            return
        except BaseException as exc:  # handed to whoever awaits the task
            self.future.set_exception(exc)
            return
        finally:
            self._running = False
        if self._cancelled:  # it cancelled itself during this step
            self._coro.close()
            return
        waited.add_done_callback(self._wake)

    def _wake(self, fut: Future[Any]) -> None:
        err = fut.exception()
        self._step(None if err is not None else fut.result(), err)

    def cancel(self) -> None:
        """Stop the coroutine at its current ``await``; its ``finally`` blocks run."""
        if self._cancelled or self.future.done():
            return
        self._cancelled = True
        if not self._running:
            self._coro.close()
        self.future.set_exception(Cancelled())


def stop(loop: Loop) -> None:
    """Stop ``loop.run()`` from a callback on that loop.

    ``Loop.stop()`` alone is only seen after the next poll returns, so a
    stop from a timer with nothing else pending would wait forever: wake it.
    """
    loop.stop()
    loop.call_soon_threadsafe(lambda: None)


def sleep(loop: Loop, delay: float) -> Future[None]:
    fut: Future[None] = Future(loop)
    loop.call_later(max(0.0, delay), lambda: fut.set_result(None))
    return fut


def wait_for(loop: Loop, fut: Future[Any], timeout: float | None) -> Future[bool]:
    """A future of True once ``fut`` is done, or False after ``timeout`` seconds (None: never)."""
    out: Future[bool] = Future(loop)
    if fut.done():
        out.set_result(True)
        return out
    if timeout is None:
        fut.add_done_callback(lambda _: out.set_result(True))
        return out

    def expire() -> None:
        out.set_result(False)

    tid = loop.call_later(max(0.0, timeout), expire)

    def done(_: Future[Any]) -> None:
        if not out.done():  # cancelling a timer that already ran would leak its id in the loop
            loop.cancel(tid)
        out.set_result(True)

    fut.add_done_callback(done)
    return out
