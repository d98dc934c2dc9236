"""Runs one actor: its mailbox, topics, heartbeat and extensions, in the current thread.

In an actor process the host owns the main thread; the same class hosts an
attached actor's IO in a thread of the spawning process. Its life:
``start()`` (extensions' ``before_start``, ``on_start``, extensions'
``after_start``), ``serve()`` until a stop is requested, ``stop()``
(``on_stop``, extensions' ``after_stop``), ``close()``. See
:mod:`actors.extension` for the order of the extension hooks.

Example::

    >>> host = ActorHost(rt, Loop(), "echo", Echo(), extensions=[(Snapshots, {})])  # doctest: +SKIP
    >>> host.start(); host.serve(); host.stop(); host.close()                      # doctest: +SKIP
"""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import msgpack

from actors import wire
from actors.actor import Actor, ActorContext
from actors.errors import UnknownMessage
from actors.extension import HostExtension, observes_messages, resolve
from actors.journal import Journal
from actors.loop import Loop
from actors.mailbox import Mailbox
from actors.runtime import Runtime
from actors.topics import Publisher, Subscription

__all__ = ["ActorHost", "load_class"]

log = logging.getLogger("actors.host")


def load_class(path: str) -> type[Actor]:
    """Import ``module:QualName`` and check it is an Actor subclass; a clear error if not."""
    cls = resolve(path, "actor class")
    if not (isinstance(cls, type) and issubclass(cls, Actor)):
        raise TypeError(f"{path!r} is {cls!r}, not an actors.Actor subclass")
    return cls


class ActorHost:
    """Hosts ``actor`` named ``name`` on ``loop``."""

    def __init__(
        self,
        rt: Runtime,
        loop: Loop,
        name: str,
        actor: Actor,
        *,
        heartbeat: float | None = 1.0,
        poison_limit: int = 3,
        extensions: Sequence[tuple[type[HostExtension], dict[str, Any]]] = (),
    ) -> None:
        self.rt = rt
        self.loop = loop
        self.name = name
        self.actor = actor
        self.journal = Journal(os.path.join(rt.run_dir, f"{name}.journal"))
        self.journal.on_restart()
        rt.beat = self.journal.beat
        self.incarnation = self.journal.incarnation
        # Only extensions that watch messages cost anything per message.
        self._observers: list[Callable[[int, bool], None]] = []
        observed = any(observes_messages(cls) for cls, _ in extensions)
        self.mailbox = Mailbox(
            rt, name, rt.endpoint(name), self._observed_dispatch() if observed else self._dispatch, self.journal,
            poison_limit=poison_limit, dead_letter=self._dead_letter,
            seen_path=os.path.join(rt.run_dir, f"{name}.seen"),
        )
        self.mailbox.loop = loop
        self.publishers: dict[str, Publisher] = {}
        self.thread_publishers: list[tuple[str, Publisher]] = []  # see thread_publisher
        self.subscriptions: list[Subscription] = []
        self.ctrl_handlers: dict[str, Callable[..., Any]] = {
            "ping": lambda: "pong",
            "stop": self._ctrl_stop,
            "stats": self.stats,
        }
        self.stop_requested = False
        actor.context = ActorContext(name, self)
        loop.add(self.mailbox.sock, self.mailbox.on_readable)
        loop.after_poll.append(self._after_poll)
        if heartbeat:
            loop.max_wait = heartbeat / 4
        self.journal.beat()
        self.extensions: list[HostExtension] = [cls(self, config) for cls, config in extensions]
        self._observers.extend(e.after_message for e in self.extensions if observes_messages(type(e)))
        for ext in self.extensions:
            self.ctrl_handlers.update(ext.controls())

    def extension(self, name: str) -> HostExtension | None:
        """The extension called ``name``, or None."""
        for ext in self.extensions:
            if ext.name == name:
                return ext
        return None

    # -- dispatch -----------------------------------------------------------
    def _dispatch(self, kind: int, body: Any) -> Any:
        if kind == wire.CTRL:
            cmd, args = body[0], body[1] if len(body) > 1 else []
            fn = self.ctrl_handlers.get(cmd)
            if fn is None:
                raise UnknownMessage(f"actor {self.name!r}", cmd, f"control commands: {', '.join(sorted(self.ctrl_handlers))}")
            return fn(*args)
        try:
            return self.actor.on_receive(body)
        except UnknownMessage:
            raise  # dead-lettered by the mailbox: the actor goes on, nothing failed
        except Exception:
            if kind == wire.TELL:
                self.actor.on_failure(*sys.exc_info())
            raise

    def _observed_dispatch(self) -> Callable[[int, Any], Any]:
        # A closure: on the message hot path, cell lookups are cheaper than attribute lookups.
        dispatch, observers = self._dispatch, self._observers

        def handler(kind: int, body: Any) -> Any:
            try:
                result = dispatch(kind, body)
            except Exception:
                for fn in observers:
                    fn(kind, False)
                raise
            for fn in observers:
                fn(kind, True)
            return result

        return handler

    def state_changed(self) -> None:
        """The actor's state changed outside a message: tell the extensions."""
        for ext in self.extensions:
            ext.state_changed()

    def _after_poll(self) -> None:
        self.journal.beat()
        self.mailbox.flush()
        if self.stop_requested:
            self.loop.stop()

    def _ctrl_stop(self) -> str:
        self.stop_requested = True
        return "stopping"

    def request_stop(self) -> None:
        self.stop_requested = True

    def _dead_letter(self, record: dict[str, Any]) -> None:
        with open(os.path.join(self.rt.run_dir, "deadletters.log"), "ab") as f:
            f.write(msgpack.packb(record))

    def stats(self) -> dict[str, Any]:
        mb = self.mailbox
        return {
            "name": self.name,
            "pid": os.getpid(),
            "incarnation": self.incarnation,
            "mailbox_depth": mb.depth,
            "received": mb.received,
            "handled": mb.handled,
            "dropped": mb.dropped,
            "dead_lettered": mb.dead_lettered,
            "busy_for": time.monotonic() - mb.busy_since if mb.busy_since else 0.0,
            "subscriptions": [sub.stats() for sub in self.subscriptions],
            "stalled": {t: p.stalled for t, p in [*self.publishers.items(), *self.thread_publishers] if p.stalled},
            "detail": getattr(self.actor, "status_detail", lambda: None)(),
        }

    # -- topics -------------------------------------------------------------
    def publisher(self, topic: str) -> Publisher:
        pub = self.publishers.get(topic)
        if pub is None:
            pub = self.publishers[topic] = Publisher(self.rt, topic)
        return pub

    def thread_publisher(self, topic: str, pub_id: int | None = None) -> Publisher:
        """A new publisher of ``topic`` for one other thread of this actor (closed with the actor)."""
        pub = Publisher(self.rt, topic, pub_id=pub_id)
        self.thread_publishers.append((topic, pub))
        return pub

    def close_thread_publisher(self, pub: Publisher) -> None:
        """Close one of :meth:`thread_publisher`'s before the actor stops (from the thread that uses it)."""
        self.thread_publishers = [(t, p) for t, p in self.thread_publishers if p is not pub]
        pub.close()

    def subscribe(self, topic: str, callback: Callable[[Any], None], **kw: Any) -> Subscription:
        if kw.get("keep") == "all" and "key" not in kw:
            # Durable across incarnations: the next one (a restart, the standby) gets what this one did not finish.
            same = sum(1 for s in self.subscriptions if s.keep == "all" and s.topic == topic.replace("/", "."))
            kw["key"] = f"{self.name}#{same}"
        sub = Subscription(self.rt, self.loop, topic, callback, **kw)
        self.subscriptions.append(sub)
        return sub

    # -- life ---------------------------------------------------------------
    def start(self) -> None:
        """Extensions' ``before_start``, the actor's ``on_start``, extensions' ``after_start``."""
        for ext in self.extensions:
            ext.before_start()
        self.actor.on_start()
        for ext in self.extensions:
            ext.after_start()

    def serve(self) -> None:
        """Handle messages until a stop is requested; a told message that raises propagates."""
        self.mailbox.on_readable()  # messages may have queued before we polled
        while not self.stop_requested:
            self.loop.run()

    def stop(self) -> None:
        """The actor's ``on_stop``, then extensions' ``after_stop`` in reverse order (also if it raised)."""
        try:
            self.actor.on_stop()
        finally:
            for ext in reversed(self.extensions):
                ext.after_stop()

    def close(self) -> None:
        for sub in self.subscriptions:
            sub.close()
        for pub in [*self.publishers.values(), *(p for _, p in self.thread_publishers)]:
            pub.close()
        self.loop.remove(self.mailbox.sock)
        self.mailbox.close()
        self.journal.end()
        self.journal.close()


