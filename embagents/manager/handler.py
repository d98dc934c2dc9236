"""Handlers: the code the manager runs every tick, in registration order.

A :class:`Handler` reads and writes the shared state in ``on_tick``. A
:class:`StateMachineHandler` runs its own state machine instead: a declared
``transitions`` table whose events are fired, and/or ``tick_<state>``
methods that return the next state (or an event); ``on_enter_<state>`` and
``on_exit_<state>`` run on every move.

Example::

    >>> from embagents.manager.state import State
    >>> class Mission(StateMachineHandler):
    ...     transitions = {"idle": {"go": "moving"}, "moving": {"arrived": "done"}}
    ...     def tick_idle(self, state):
    ...         return "go" if state.get("target") else None
    ...     def tick_moving(self, state):
    ...         return "done" if state.distance < 0.1 else None
    >>> mission, state = Mission(), State(target="door", distance=0.05)
    >>> mission.on_tick(state, 1)
    >>> mission.on_tick(state, 2)
    >>> mission.history
    ['idle', 'moving', 'done']
    >>> mission.fire("go", state)
    Traceback (most recent call last):
    embagents.manager.handler.InvalidTransition: handler 'Mission' in state 'done' has no transition for event 'go' (no transitions leave 'done')
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar

from embagents.manager.state import State

__all__ = [
    "FunctionHandler",
    "Handler",
    "InvalidTransition",
    "StateMachineHandler",
    "as_handler",
]

logger = logging.getLogger(__name__)

_HOOK_PREFIXES = ("tick_", "on_enter_", "on_exit_")


class Handler:
    """Base for per-tick logic: override :meth:`on_tick`, optionally the hooks."""

    def __init__(self, name: str | None = None) -> None:
        self.name = name or type(self).__name__

    def on_start(self, state: State) -> None:
        """Called once, after the handshake and before tick 1."""

    def on_tick(self, state: State, tick: int) -> None:
        """Called every tick; ``tick`` counts from 1."""

    def on_stop(self, state: State) -> None:
        """Called once at shutdown, in reverse registration order (halt motors here)."""

    def snapshot(self) -> Any:
        """What a restarted manager needs to resume this handler (msgpack-able); None: nothing."""
        return None

    def restore(self, saved: Any) -> str | None:
        """Resume from :meth:`snapshot`'s value, before ``on_start``; returns a phrase for the log."""
        return None

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r}>"


class FunctionHandler(Handler):
    """Adapts a plain ``fn(state, tick)`` to a handler named after the function."""

    def __init__(self, fn: Callable[[State, int], object], name: str | None = None) -> None:
        super().__init__(name or getattr(fn, "__name__", None) or "handler")
        self.fn = fn

    def on_tick(self, state: State, tick: int) -> None:
        self.fn(state, tick)


def as_handler(obj: Handler | Callable[[State, int], object]) -> Handler:
    """Return ``obj`` if it is a :class:`Handler`, else wrap a callable."""
    if isinstance(obj, Handler):
        return obj
    if callable(obj):
        return FunctionHandler(obj)
    raise TypeError(f"expected a Handler or a callable fn(state, tick), got {obj!r}")


class InvalidTransition(RuntimeError):
    """A state machine was asked for a move its declaration does not allow."""

    def __init__(self, handler: str, state: str, event: str, problem: str) -> None:
        super().__init__(f"handler {handler!r} in state {state!r} {problem}")
        self.handler = handler
        self.state = state
        self.event = event


class StateMachineHandler(Handler):
    """A handler that is a state machine; ``current`` is its state.

    Declare any of: ``transitions`` (``{state: {event: next_state}}``),
    ``states`` (all state names, in order) and ``initial`` (default: the first
    state). Each tick runs the events queued with :meth:`post`, then
    ``tick_<current>(state)``, whose result moves the machine: an event of the
    current state fires it; a state name moves there (if ``transitions`` is
    declared, only along a declared edge); None or the current state stays.
    Call :meth:`fire` from the loop thread only; other threads use :meth:`post`.
    """

    transitions: ClassVar[Mapping[str, Mapping[str, str]]] = {}
    states: ClassVar[Sequence[str]] = ()
    initial: ClassVar[str | None] = None
    #: How many visited states :attr:`history` keeps (a robot may cycle for days).
    history_limit: ClassVar[int] = 1000

    def __init__(self, name: str | None = None, *, initial: str | None = None) -> None:
        super().__init__(name)
        start = initial or type(self).initial
        self.known_states = _collect_states(type(self), start)
        if start is None:
            if not (self.states or self.transitions):
                # Hook methods have no order to take a first state from.
                raise TypeError(
                    f"{type(self).__name__} needs `initial` (or `states`/`transitions`) "
                    "to know where to start"
                )
            start = self.known_states[0]
        if start not in self.known_states:
            raise ValueError(
                f"{self.name}: initial state {start!r} is not one of {', '.join(self.known_states)}"
            )
        self.current: str = start
        self._history: deque[str] = deque(maxlen=self.history_limit)
        self._entered = False
        self._posted: deque[str] = deque()  # append/popleft are thread-safe

    @property
    def history(self) -> list[str]:
        """States entered so far, oldest first (the initial state included)."""
        return list(self._history)

    def post(self, event: str) -> None:
        """Queue ``event`` from any thread; it fires at the start of the next tick."""
        self._posted.append(event)

    def fire(self, event: str, state: State) -> str:
        """Take the transition for ``event`` from the current state; return the new state."""
        self._enter_initial(state)
        edges = self.transitions.get(self.current, {})
        if event not in edges:
            raise InvalidTransition(
                self.name, self.current, event,
                f"has no transition for event {event!r} ({self._allowed()})",
            )
        self._move(edges[event], state, event)
        return self.current

    def on_start(self, state: State) -> None:
        self._enter_initial(state)

    def snapshot(self) -> Any:
        return {"current": self.current, "history": list(self._history)[-20:]}

    def restore(self, saved: Any) -> str | None:
        """Resume in the saved state: ``on_enter_<state>`` does not run again (it ran before the restart)."""
        current = saved.get("current") if isinstance(saved, dict) else None
        if current not in self.known_states:
            logger.warning("%s: saved state %r is not one of %s; starting from %r",
                           self.name, current, ", ".join(self.known_states), self.current)
            return None
        self.current = current
        self._history.clear()
        self._history.extend(saved.get("history") or [current])
        self._entered = True
        return f"in state {current!r}"

    def on_tick(self, state: State, tick: int) -> None:
        self._enter_initial(state)
        while self._posted:
            self.fire(self._posted.popleft(), state)
        step = getattr(self, f"tick_{self.current}", None)
        if step is not None:
            result = step(state)
            if result is not None and result != self.current:
                self._follow(result, state)

    def _follow(self, name: str, state: State) -> None:
        edges = self.transitions.get(self.current, {})
        if name in edges:
            self._move(edges[name], state, name)
        elif name not in self.known_states:
            raise InvalidTransition(
                self.name, self.current, name,
                f"got {name!r} from tick_{self.current}, which is neither a state nor an "
                f"event here (states: {', '.join(self.known_states)}; {self._allowed()})",
            )
        elif self.transitions and name not in edges.values():
            raise InvalidTransition(
                self.name, self.current, name,
                f"cannot move to {name!r}: no transition leads there ({self._allowed()})",
            )
        else:
            self._move(name, state, None)

    def _enter_initial(self, state: State) -> None:
        if not self._entered:
            self._entered = True
            self._history.append(self.current)
            self._hook("on_enter_", state)

    def _move(self, target: str, state: State, event: str | None) -> None:
        self._hook("on_exit_", state)
        via = f" ({event})" if event else ""
        logger.info("%s: %s -> %s%s", self.name, self.current, target, via)
        self.current = target
        self._history.append(target)
        self._hook("on_enter_", state)

    def _hook(self, prefix: str, state: State) -> None:
        hook = getattr(self, prefix + self.current, None)
        if hook is not None:
            hook(state)

    def _allowed(self) -> str:
        edges = self.transitions.get(self.current, {})
        if not edges:
            return f"no transitions leave {self.current!r}"
        return "allowed here: " + ", ".join(f"{e} -> {t}" for e, t in edges.items())


def _collect_states(cls: type[StateMachineHandler], initial: str | None) -> tuple[str, ...]:
    """All state names, checking hook methods against them to catch typos."""
    in_table: dict[str, None] = {}  # an ordered set
    for source, edges in cls.transitions.items():
        in_table[source] = None
        in_table.update(dict.fromkeys(edges.values()))
    hooked = {
        attr[len(prefix):]: attr
        for attr in dir(cls)
        for prefix in _HOOK_PREFIXES
        if attr.startswith(prefix) and callable(getattr(cls, attr))
    }
    declared: Mapping[str, Any] = dict.fromkeys(cls.states) if cls.states else {}
    if declared:
        known, where = declared, "the declared states"
    elif in_table:
        known, where = in_table, "the transitions table"
    else:
        return tuple(dict.fromkeys([*([initial] if initial else []), *sorted(hooked)]))
    for name in in_table:
        if name not in known:
            raise ValueError(f"{cls.__name__}.transitions uses state {name!r}, not in {where}")
    for name, attr in hooked.items():
        if name not in known:
            raise ValueError(
                f"{cls.__name__}.{attr} names state {name!r}, which is not in {where} "
                f"({', '.join(known)})"
            )
    return tuple(known)
