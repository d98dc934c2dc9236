"""Agents: the manager's computing parts, attached or isolated by one flag.

An :class:`Agent` declares a class (a detector, a planner) whose methods
handlers call. ``isolated=False`` (attached) builds it in the loop's process
and runs its calls one at a time on a worker thread of its own;
``isolated=True`` makes it an actor process of its own, supervised like any
other, so a GIL-holding or crashing agent cannot stall the loop. Handlers
call both the same way, ``agent.call("detect", image)``, and get an
:class:`AgentFuture` (a :class:`concurrent.futures.Future`): poll
``done()`` on later ticks, or ``result(timeout)`` to wait.

A call to an isolated agent whose process dies fails at once with
:class:`AgentCrashed`; a call that raised fails with :class:`AgentError`
carrying the agent's traceback. Meanwhile the supervisor restarts the
agent and the next call reaches the new incarnation.

Example::

    >>> class Adder:
    ...     def add(self, a, b):
    ...         return a + b
    >>> adder = Agent("adder", Adder)          # attached: a thread in this process
    >>> adder.start()
    >>> adder.call("add", 2, 3).result(timeout=5)
    5
    >>> adder.call("nope").exception(timeout=5)
    AgentError("agent 'adder' has no method 'nope'; its methods: add")
    >>> adder.stop()
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import logging
from collections.abc import Callable
from typing import Any

from actors import ActorNotFound, runtime, wire
from actors.errors import ActorCrashed, RemoteError
from actors.link import Pending
from actors.wire import check_name
from embagents.requests import Call

__all__ = ["Agent", "AgentCall", "AgentCrashed", "AgentError", "AgentFuture", "AgentNotRunning"]

log = logging.getLogger("embagents.manager.agents")


#: One call to an isolated agent's actor is the message a component's actor gets: a
#: :class:`~embagents.requests.Call` (``method(*args, **kwargs)``; the ask gets its return value).
AgentCall = Call


class AgentError(RuntimeError):
    """An agent call failed: the agent raised, or was asked for a method it lacks."""


class AgentCrashed(AgentError):
    """The isolated agent's process died during the call; its supervisor restarts it."""


class AgentNotRunning(RuntimeError):
    """An agent was called before its manager started it (or after it stopped)."""


class AgentFuture(concurrent.futures.Future[Any]):
    """The future of one agent call; ``result()`` may wait, ``done()`` never does.

    For an isolated agent called from the manager's loop thread, waiting in
    ``result()`` serves only that agent's socket (the next tick does not
    start inside a handler).
    """

    def __init__(self, drive: Callable[[float | None], object] | None = None) -> None:
        super().__init__()
        self._drive = drive

    def result(self, timeout: float | None = None) -> Any:
        """The call's return value, waiting at most ``timeout`` s (an attached agent's call runs here)."""
        if not self.done() and self._drive is not None:
            self._drive(timeout)
        return super().result(timeout=0 if self._drive is not None and not self.done() else timeout)

    def exception(self, timeout: float | None = None) -> BaseException | None:
        """The exception the call raised, or None, waiting at most ``timeout`` s."""
        if not self.done() and self._drive is not None:
            self._drive(timeout)
        return super().exception(timeout=0 if self._drive is not None and not self.done() else timeout)


def public_methods(obj: object) -> list[str]:
    return sorted(n for n in dir(obj) if not n.startswith("_") and callable(getattr(obj, n, None)))


def invoke(agent: str, obj: object, method: str, args: Any, kwargs: Any) -> Any:
    """Call ``obj.method(*args, **kwargs)``, refusing private or unknown names clearly."""
    fn = None if method.startswith("_") else getattr(obj, method, None)
    if not callable(fn):
        raise AgentError(
            f"agent {agent!r} has no method {method!r}; its methods: {', '.join(public_methods(obj)) or 'none'}"
        )
    return fn(*args, **kwargs)


class Agent:
    """``factory(*args, **kwargs)`` as an agent named ``name``; ``isolated`` picks where it runs.

    ``heartbeat`` is an isolated agent's hang deadline in seconds (one call
    longer than that gets it killed and restarted); ``nice`` and
    ``cpu_affinity`` schedule its process (keep a CPU-bound agent off the
    loop's core).
    """

    def __init__(
        self,
        name: str,
        factory: Callable[..., Any],
        *args: Any,
        isolated: bool = False,
        heartbeat: float = 30.0,
        nice: int | None = None,
        cpu_affinity: list[int] | None = None,
        **kwargs: Any,
    ) -> None:

        check_name(name)
        if not callable(factory):
            raise TypeError(f"agent {name!r}: factory must be a class or callable, got {factory!r}")
        self.name = name
        self.factory = factory
        self.args = args
        self.kwargs = kwargs
        self.isolated = bool(isolated)
        self.heartbeat = heartbeat
        self.nice = nice
        self.cpu_affinity = cpu_affinity
        #: The actor name of an isolated agent (set by its manager: "<manager>.<agent>").
        self.actor_name = name
        self._call: Callable[[str, Any, Any], AgentFuture] | None = None
        self._executor: concurrent.futures.ThreadPoolExecutor | None = None
        self._obj: Any = None

    def build(self) -> Any:
        """A new instance of the agent's class (in whatever process runs it)."""
        return self.factory(*self.args, **self.kwargs)

    # -- running ---------------------------------------------------------------
    def start(self) -> None:
        """Attached: build the object and its worker thread. Isolated: connect to its actor."""
        if self.isolated:
            self._call = self._isolated_call
            self._connect()
        else:
            self._obj = self.build()
            self._executor = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix=f"agent-{self.name}")
            self._call = self._attached_call

    def _connect(self) -> None:
        """On an actor's loop thread, connect to the agent's actor now, not on the first tick that calls it."""

        rt = runtime.current()
        loop = rt.loop_here()
        if loop is not None:
            with contextlib.suppress(ActorNotFound):  # not started (yet): the first call connects
                rt.link(self.actor_name, loop)

    def stop(self) -> None:
        self._call = None
        if self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)
            self._executor = None
        closer = getattr(self._obj, "close", None)
        if callable(closer):
            try:
                closer()
            except Exception:
                log.exception("agent %r failed in close()", self.name)
        self._obj = None

    def call(self, method: str, *args: Any, **kwargs: Any) -> AgentFuture:
        """Call ``method`` on the agent; returns at once with its future."""
        if self._call is None:
            raise AgentNotRunning(
                f"agent {self.name!r} is not running: add it to a Manager (agents=[...]) and call it from "
                "the manager's handlers"
            )
        return self._call(method, args, kwargs)

    def _attached_call(self, method: str, args: Any, kwargs: Any) -> AgentFuture:
        assert self._executor is not None
        fut = AgentFuture()
        obj = self._obj

        def run() -> None:
            if not fut.set_running_or_notify_cancel():
                return
            try:
                fut.set_result(invoke(self.name, obj, method, args, kwargs))
            except AgentError as exc:
                fut.set_exception(exc)
            except Exception as exc:
                err = AgentError(f"agent {self.name!r}: {method}() raised {type(exc).__name__}: {exc}")
                err.__cause__ = exc
                fut.set_exception(err)

        def cancelled(job: concurrent.futures.Future[None]) -> None:
            if job.cancelled() and not fut.done():
                fut.set_exception(AgentNotRunning(f"agent {self.name!r} stopped before running {method}()"))

        self._executor.submit(run).add_done_callback(cancelled)
        return fut

    def _isolated_call(self, method: str, args: Any, kwargs: Any) -> AgentFuture:
        rt = runtime.current()
        fut: AgentFuture

        def settle(ok: bool, value: Any) -> None:
            if ok:
                fut.set_result(value)
            elif isinstance(value, ActorCrashed):
                fut.set_exception(AgentCrashed(
                    f"agent {self.name!r} crashed during {method}() ({value}); its supervisor restarts it, "
                    "call again once it is back"
                ))
            elif isinstance(value, RemoteError):
                fut.set_exception(AgentError(f"agent {self.name!r}: {method}() failed: {value}"))
            else:
                fut.set_exception(value if isinstance(value, BaseException) else AgentError(str(value)))

        pending = Pending(settle)
        message = Call(method, list(args), dict(kwargs))
        loop = rt.loop_here()
        if loop is not None:  # the manager actor's own loop thread: answers arrive between ticks
            link = rt.link(self.actor_name, loop)
            fut = AgentFuture(lambda timeout: link.wait(pending, timeout))
            link.send(wire.ASK, message, pending)
        else:
            fut = AgentFuture()
            rt.on_client(lambda: rt.link(self.actor_name, rt.client_loop()).send(wire.ASK, message, pending))
        return fut

    def __repr__(self) -> str:
        where = "isolated" if self.isolated else "attached"
        return f"<Agent {self.name!r} {where} {getattr(self.factory, '__name__', self.factory)!r}>"
