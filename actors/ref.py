"""``ActorRef``: address an actor by name, from any thread of any process.

Example::

    >>> ref = system.ref("echo")                        # doctest: +SKIP
    >>> ref.tell({"cmd": "blink"})                      # doctest: +SKIP
    >>> ref.ask("ping", timeout=1.0).get()              # doctest: +SKIP
    'pong'
"""

from __future__ import annotations

import threading
import time
from typing import Any

import pykka

from actors import runtime as _rt
from actors import wire
from actors.errors import Timeout
from actors.link import Link, Pending

__all__ = ["ActorRef", "LinkFuture"]


class LinkFuture(pykka.Future):
    """A future answered over a link; ``get()`` drives the link's socket itself.

    Used when the asking thread is an IO loop thread (an actor's handler):
    waiting must not start the actor's next message, so only this link's
    sockets are served while it waits.
    """

    def __init__(self, link: Link, pending: Pending, default_timeout: float | None) -> None:
        super().__init__()
        self._link = link
        self._pending = pending
        self._default_timeout = default_timeout

    def get(self, *, timeout: float | None = None) -> Any:
        p = self._pending
        if not p.done:
            t = self._default_timeout if timeout is None else timeout
            if not self._link.wait(p, t):
                raise Timeout(f"no answer from actor {self._link.name!r} within {t} s")
        if p.ok:
            return p.value
        raise p.value

    def set(self, value: Any = None) -> None:  # pragma: no cover - pykka API shape
        self._pending.resolve(True, value)

    def set_exception(self, exc_info: Any = None) -> None:  # pragma: no cover
        self._pending.resolve(False, exc_info[1] if exc_info else RuntimeError("unknown"))


class _TimedThreadingFuture(pykka.ThreadingFuture):
    def __init__(self, default_timeout: float | None) -> None:
        super().__init__()
        self._default_timeout = default_timeout

    def get(self, *, timeout: float | None = None) -> Any:
        return super().get(timeout=self._default_timeout if timeout is None else timeout)


class ActorRef:
    """A handle on the actor ``name``; cheap to create, safe to share across threads."""

    __slots__ = ("name",)

    def __init__(self, name: str) -> None:
        self.name = wire.check_name(name)

    def __repr__(self) -> str:
        return f"<ActorRef {self.name}>"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ActorRef) and other.name == self.name

    def __hash__(self) -> int:
        return hash(("ActorRef", self.name))

    def tell(self, message: Any) -> None:
        """Send ``message``; it is kept until the actor (or its next incarnation) handles it."""
        rt = _rt.current()
        loop = rt.loop_here()
        if loop is not None:
            rt.link(self.name, loop).send(wire.TELL, message)
        else:
            rt.on_client(lambda: rt.link(self.name, rt.client_loop()).send(wire.TELL, message))

    def ask(self, message: Any, *, timeout: float | None = None) -> pykka.Future:
        """Send ``message`` and return a future of the answer.

        ``get()`` raises :class:`~actors.errors.RemoteError` if the handler
        raised, :class:`~actors.errors.ActorCrashed` if the actor died first,
        and ``pykka.Timeout`` after ``timeout`` seconds.
        """
        return self._ask(wire.ASK, message, timeout)

    def control(self, cmd: str, *args: Any, timeout: float | None = None) -> pykka.Future:
        """Send control command ``cmd`` (answered by the actor's host, not ``on_receive``); a future of its answer.

        A control command takes its turn in the mailbox like any message. The host answers "ping", "stop" and "stats"; host
        extensions add theirs (the supervisor's "lifecycle").
        """
        return self._ask(wire.CTRL, [cmd, list(args)], timeout)

    def _ask(self, kind: int, message: Any, timeout: float | None) -> pykka.Future:
        rt = _rt.current()
        loop = rt.loop_here()
        if loop is not None:
            link = rt.link(self.name, loop)
            pending = Pending()
            link.send(kind, message, pending)
            return LinkFuture(link, pending, timeout)
        fut = _TimedThreadingFuture(timeout)

        def settle(ok: bool, value: Any) -> None:
            if ok:
                fut.set(value)
            else:
                fut.set_exception((type(value), value, value.__traceback__))

        rt.on_client(lambda: rt.link(self.name, rt.client_loop()).send(kind, message, Pending(settle)))
        return fut

    def flush(self, timeout: float | None = None) -> bool:
        """Wait until every message this thread told the actor is acknowledged."""
        rt = _rt.current()
        loop = rt.loop_here()
        if loop is not None:
            link = rt.link(self.name, loop)
            return loop.run(until=lambda: not link.unacked, timeout=timeout)
        deadline = None if timeout is None else time.monotonic() + timeout
        done = threading.Event()

        def check() -> None:
            link = rt.link(self.name, rt.client_loop())
            if not link.unacked:
                done.set()
            elif deadline is None or time.monotonic() < deadline:
                rt.client_loop().call_later(0.005, check)
            else:
                done.set()

        rt.on_client(check)
        done.wait()
        return rt.on_client(lambda: not rt.link(self.name, rt.client_loop()).unacked)

    def backlog(self) -> int:
        """Messages from this process's client thread not yet acknowledged."""
        rt = _rt.current()
        loop = rt.loop_here() or rt.client_loop()
        return rt.link(self.name, loop).backlog
