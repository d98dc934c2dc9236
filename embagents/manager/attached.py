"""Attached resources: nodes and agents that share the manager's process.

Anything with ``start()`` and ``stop()`` can be attached: it starts at once
and is stopped at shutdown in reverse order of attachment, so a resource
can rely on everything attached before it. Agents are pykka actors living
as threads here; heavy or blocking work belongs in its own actor process.

Example::

    >>> import logging, pykka
    >>> class Echo(pykka.ThreadingActor):
    ...     def on_receive(self, message):
    ...         return message
    >>> class Lidar(AttachedNode):
    ...     def start(self):
    ...         print("lidar on")
    ...     def stop(self):
    ...         print("lidar off")
    >>> attached = Attachments(logging.getLogger("demo"))
    >>> lidar = attached.attach(Lidar())
    lidar on
    >>> echo = attached.attach_actor(Echo)
    >>> echo.ask("ping")
    'ping'
    >>> attached.names
    ('Lidar', 'Echo')
    >>> attached.close()
    lidar off
    >>> echo.is_alive()
    False
"""

from __future__ import annotations

import logging
import threading
from typing import Any, Protocol, TypeVar, runtime_checkable

import pykka

__all__ = ["AttachedActor", "AttachedNode", "Attachments", "Resource"]

#: Seconds an attached actor gets to finish its mailbox at shutdown.
ACTOR_STOP_TIMEOUT = 5.0


@runtime_checkable
class Resource(Protocol):
    """What can be attached: anything with ``start()`` and ``stop()``."""

    def start(self) -> object: ...

    def stop(self) -> object: ...


R = TypeVar("R", bound=Resource)


class AttachedNode:
    """Base for a node in the manager's process: override the two hooks."""

    def __init__(self, name: str | None = None) -> None:
        self.name = name or type(self).__name__

    def start(self) -> None:
        """Acquire resources (open a device, start a thread). Runs at attach time."""

    def stop(self) -> None:
        """Release them. Runs at shutdown, even if a handler raised."""


class AttachedActor:
    """A pykka actor class as a resource: started on attach, stopped at shutdown."""

    def __init__(
        self,
        actor_class: type[pykka.Actor],
        *args: Any,
        stop_timeout: float | None = ACTOR_STOP_TIMEOUT,
        **kwargs: Any,
    ) -> None:
        if not (isinstance(actor_class, type) and issubclass(actor_class, pykka.Actor)):
            raise TypeError(f"expected a pykka Actor class, got {actor_class!r}")
        self.name = actor_class.__name__
        self.actor_class = actor_class
        self.args = args
        self.kwargs = kwargs
        self.stop_timeout = stop_timeout
        self.ref: pykka.ActorRef[Any] | None = None

    def start(self) -> pykka.ActorRef[Any]:
        self.ref = self.actor_class.start(*self.args, **self.kwargs)
        return self.ref

    def stop(self) -> None:
        if self.ref is not None:
            # Returns False (no error) if the actor had already stopped itself.
            self.ref.stop(block=True, timeout=self.stop_timeout)


class Attachments:
    """The ordered set of started resources that one manager owns."""

    def __init__(self, logger: logging.Logger) -> None:
        self._logger = logger
        self._lock = threading.Lock()
        self._items: list[tuple[str, Resource]] = []
        self._closed = False

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the attached resources, in attachment order."""
        with self._lock:
            return tuple(name for name, _ in self._items)

    def attach(self, resource: R, *, name: str | None = None) -> R:
        """Start ``resource`` now and own it; returns it unchanged."""
        if not isinstance(resource, Resource):
            raise TypeError(f"cannot attach {resource!r}: it needs start() and stop() methods")
        name = name or getattr(resource, "name", None) or type(resource).__name__
        with self._lock:
            if self._closed:
                raise RuntimeError(f"cannot attach {name!r}: the manager has shut down")
            # Not registered if start() raises: there is nothing to stop.
            resource.start()
            self._items.append((name, resource))
        self._logger.debug("attached %s", name)
        return resource

    def attach_actor(
        self, actor_class: type[pykka.Actor], *args: Any, **kwargs: Any
    ) -> pykka.ActorRef[Any]:
        """Start a pykka actor and own it; returns its ref."""
        agent = self.attach(AttachedActor(actor_class, *args, **kwargs))
        assert agent.ref is not None
        return agent.ref

    def close(self) -> None:
        """Stop every resource, newest first; errors are logged, not raised."""
        with self._lock:
            self._closed = True
            items, self._items = self._items, []
        for name, resource in reversed(items):
            try:
                resource.stop()
            except Exception:
                # Keep going: every other resource still has to be released.
                self._logger.exception("stopping attached %s failed", name)
            else:
                self._logger.debug("stopped %s", name)
