"""The ``Actor`` base class: hooks in the style of pykka.

Subclass it, override :meth:`Actor.on_receive`, and spawn it with
:meth:`actors.ActorSystem.spawn`; it then runs in its own process (or, with
``attached=True``, as a pykka thread in the spawning process) behind the
same :class:`~actors.ActorRef` API.

Example::

    >>> class Echo(Actor):
    ...     def on_receive(self, message):
    ...         return message
    >>> ref = system.spawn(Echo, "echo")               # doctest: +SKIP
    >>> ref.ask("hi", timeout=1).get()                 # doctest: +SKIP
    'hi'
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from types import TracebackType
from typing import TYPE_CHECKING, Any, TypedDict

from actors.ref import ActorRef

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from actors.extension import HostExtension
    from actors.host import ActorHost
    from actors.topics import Publisher, Subscription

__all__ = ["Actor", "ActorContext"]


class SubscribeOptions(TypedDict, total=False):
    """The options of :class:`actors.topics.Subscription` (its defaults: 10, "latest", any type)."""

    queue_size: int
    keep: str  # "latest" or "all"
    msg_type: type | None
    raw: bool  # the callback gets undecoded frames (a relay's; see Subscription)


class ActorContext:
    """What the runtime offers an actor: its name, refs, topics, stopping."""

    def __init__(self, name: str, host: ActorHost) -> None:
        self.name = name
        self._host = host

    def ref(self, name: str) -> ActorRef:
        """A ref to another actor of the run (raises ActorNotFound if unknown)."""
        self._host.rt.lookup(name)
        return ActorRef(name)

    def publish(self, topic: str, message: Any) -> None:
        self._host.publisher(topic).publish(message)

    def thread_publisher(self, topic: str, pub_id: int | None = None) -> Publisher:
        """A publisher of ``topic`` for one thread of the actor's own (a driver's receive thread).

        ``publish`` hands a message to this actor's thread; a driver thread that
        publishes with its own publisher saves that wake-up (70-200 us on a busy
        machine). Only one thread at a time may use it (ZeroMQ sockets are not
        thread-safe); a publish may wait, as on the actor's thread, for a slow
        ``keep="all"`` subscriber. It counts in the actor's stats and is closed
        with the actor, after ``on_stop``: stop the thread there. ``pub_id``: see
        :class:`~actors.topics.Publisher` (a relay's, whose messages are numbered by their source).
        """
        return self._host.thread_publisher(topic, pub_id)

    def close_thread_publisher(self, pub: Publisher) -> None:
        """Close a :meth:`thread_publisher` before the actor stops, from the thread that uses it.

        For a relay that makes one per source it forwards (the Zenoh bridge):
        one whose source is gone for good does not keep its sockets for the
        actor's whole life.
        """
        self._host.close_thread_publisher(pub)

    def thread_loop(self) -> AbstractContextManager[Any]:
        """Inside it, one thread of the actor's own asks other actors on links of its own.

        For a driver thread that asks and waits (the ROS bridge's service
        thread): ``ref.ask(...).get()`` there blocks on its own socket instead
        of handing the ask to the process's client IO thread and its answer
        back (see :meth:`actors.runtime.Runtime.thread_loop`). Leave it before
        the actor stops: stop the thread in ``on_stop``.
        """
        return self._host.rt.thread_loop()

    def subscribe(self, topic: str, callback: Callable[[Any], None], **options: Unpack[SubscribeOptions]) -> Subscription:
        """Call ``callback(message)`` on this actor's thread for each message on ``topic``.

        Returns the :class:`~actors.topics.Subscription`; its ``stats()`` count what it
        received, dropped and refused. A ``keep="all"`` subscription outlives this
        process: publishers keep what its callback did not finish and re-send it to the
        actor's next incarnation (at-least-once; see :mod:`actors.topics`).
        """
        return self._host.subscribe(topic, callback, **options)

    def call_later(self, delay: float, fn: Callable[[], None]) -> int:
        """Run ``fn`` on this actor's thread after ``delay`` seconds (timers, rates)."""
        return self._host.loop.call_later(delay, fn)

    @property
    def run_dir(self) -> str:
        return self._host.rt.run_dir

    def cancel(self, timer: int) -> None:
        """Cancel a timer from :meth:`call_later`."""
        self._host.loop.cancel(timer)

    def call_soon_threadsafe(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` on this actor's thread, from any thread (e.g. a driver's callback thread)."""
        self._host.loop.call_soon_threadsafe(fn)

    def watch(self, sock: object, handler: Callable[[], None]) -> None:
        """Serve another socket (or fd) on this actor's loop."""
        self._host.loop.add(sock, handler)

    def extension(self, name: str) -> HostExtension | None:
        """The host extension named ``name`` (e.g. the supervisor's "lifecycle"), or None."""
        return self._host.extension(name)

    def changed(self) -> None:
        """Say that state worth keeping changed outside a mailbox message (a topic step)."""
        self._host.state_changed()

    def beat(self) -> None:
        """Tell the supervisor we are alive during long work (see heartbeat)."""
        self._host.journal.beat()

    def stop(self) -> None:
        """Stop this actor after the current message (a normal exit)."""
        self._host.request_stop()

    @property
    def incarnation(self) -> int:
        """1 for the first start, 2 after the first restart, and so on."""
        return self._host.incarnation


class Actor:
    """Base class of actors. Override the hooks you need."""

    #: Set by the runtime before ``on_start``.
    context: ActorContext

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        pass

    @property
    def name(self) -> str:
        return self.context.name

    def on_start(self) -> None:
        """Called in the actor's process before the first message."""

    def on_stop(self) -> None:
        """Called on a requested stop, after the last message."""

    def on_standby(self) -> None:
        """Called in a warm standby (a spawned process waiting to take over), before it waits.

        Do the slow part of getting ready here (import a framework, load a
        model onto a GPU): the standby has no mailbox, topics or journal yet,
        and ``context`` is not set. On takeover ``on_start`` runs as usual and
        should skip what this already did. Not called in an ordinary start.
        """

    def on_failure(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Called when a told message raised; the actor then exits (and may be restarted)."""

    def status_detail(self) -> dict[str, Any] | None:
        """More for ``embagents status`` than its standard row: plain data, its ``lines`` printed under the table.

        Called on the actor's thread for each status request; keep it cheap.
        """
        return None

    def on_receive(self, message: Any) -> Any:
        """Handle one message; the return value answers an ``ask``."""
        raise NotImplementedError(f"{type(self).__name__} does not handle messages: override on_receive")
