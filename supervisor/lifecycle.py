"""Managed lifecycle in the style of ROS 2 managed nodes.

States: ``unconfigured`` -> ``inactive`` -> ``active``, and ``finalized``.

============  ==============  ==============  ==================
transition    from            to              hook on the actor
============  ==============  ==============  ==================
configure     unconfigured    inactive        ``on_configure()``
activate      inactive        active          ``on_activate()``
deactivate    active          inactive        ``on_deactivate()``
cleanup       inactive        unconfigured    ``on_cleanup()``
shutdown      any but final   finalized       ``on_shutdown()``
============  ==============  ==============  ==================

Hooks are optional methods of the actor class, called in the actor's
process, in its mailbox order (a transition is a control message). A hook
that raises or returns False fails the transition: the state stays as it
was and the caller gets the error. After ``shutdown`` the actor stops with
a normal exit (so a transient child is not restarted).

The state is kept in the actor's journal, which outlives its process. A
new incarnation replays the transitions from ``unconfigured`` to the state
its predecessor was in (configure, then activate) after ``on_start`` and
before it reports ready; a fresh actor (or one that had been finalized)
goes to its spec's ``lifecycle`` target instead. :class:`Lifecycle` is the
host extension (:mod:`actors.extension`) that does this in the actor's process. The journal records that
goal until the replay is done, so an actor whose ``on_configure`` keeps
failing fails to start (and its supervisor's intensity decides) rather than
coming up unconfigured.

Example::

    >>> transition(system, "camera", "activate")     # doctest: +SKIP
    'active'
    >>> state(system, "camera")                      # doctest: +SKIP
    'active'
"""

from __future__ import annotations

import enum
import logging
from collections.abc import Callable, Mapping
from typing import Any

from actors import Actor, ActorHost, ActorSystem, HostExtension

__all__ = [
    "ACTIVE",
    "FINALIZED",
    "INACTIVE",
    "TRANSITIONS",
    "UNCONFIGURED",
    "Lifecycle",
    "LifecycleError",
    "LifecycleState",
    "current",
    "state",
    "state_name",
    "transition",
]

log = logging.getLogger("supervisor.lifecycle")


class LifecycleState(enum.IntEnum):
    """A lifecycle state, as the journal keeps it (one byte; NEW: never set)."""

    NEW = 0
    UNCONFIGURED = 1
    INACTIVE = 2
    ACTIVE = 3
    FINALIZED = 4


NEW, UNCONFIGURED, INACTIVE, ACTIVE, FINALIZED = LifecycleState
_NAMES: dict[int, str] = {NEW: "unconfigured", UNCONFIGURED: "unconfigured", INACTIVE: "inactive", ACTIVE: "active", FINALIZED: "finalized"}
_BY_NAME = {"unconfigured": UNCONFIGURED, "inactive": INACTIVE, "active": ACTIVE}

#: transition -> (states it may start from, state it leads to, hook name)
TRANSITIONS: dict[str, tuple[tuple[LifecycleState, ...], LifecycleState, str]] = {
    "configure": ((UNCONFIGURED,), INACTIVE, "on_configure"),
    "activate": ((INACTIVE,), ACTIVE, "on_activate"),
    "deactivate": ((ACTIVE,), INACTIVE, "on_deactivate"),
    "cleanup": ((INACTIVE,), UNCONFIGURED, "on_cleanup"),
    "shutdown": ((UNCONFIGURED, INACTIVE, ACTIVE), FINALIZED, "on_shutdown"),
}
_PATH = {UNCONFIGURED: (), INACTIVE: ("configure",), ACTIVE: ("configure", "activate")}


class LifecycleError(Exception):
    """A transition that is not allowed from the current state, or whose hook failed."""


def state_name(code: int) -> str:
    return _NAMES.get(code, f"unknown({code})")


class Lifecycle(HostExtension):
    """The lifecycle of one actor, in its process (a host extension; config: ``{"target": state name}``)."""

    name = "lifecycle"

    def __init__(self, host: ActorHost, config: Mapping[str, Any]) -> None:
        super().__init__(host, config)
        target = config.get("target") or "unconfigured"
        if target not in _BY_NAME:
            raise LifecycleError(f"lifecycle target must be one of {', '.join(_BY_NAME)}, not {target!r}")
        previous = host.journal.state()
        self.state: LifecycleState = UNCONFIGURED
        # A restarted actor returns to where its predecessor was; a fresh (or finalized) one to its target.
        self.restored = previous in (UNCONFIGURED, INACTIVE, ACTIVE)
        self.goal = LifecycleState(previous) if self.restored else _BY_NAME[target]

    @property
    def state_name(self) -> str:
        return _NAMES[self.state]

    def controls(self) -> Mapping[str, Callable[..., Any]]:
        return {"lifecycle": self.transition, "lifecycle_state": lambda: self.state_name}

    def after_start(self) -> None:
        self.replay()

    def transition(self, name: str) -> str:
        """Run transition ``name``; returns the new state's name."""
        self._apply(name)
        self.host.journal.set_state(self.state)
        if self.state == FINALIZED:
            self.host.request_stop()
        return self.state_name

    def _apply(self, name: str) -> None:
        try:
            sources, target, hook = TRANSITIONS[name]
        except KeyError:
            raise LifecycleError(f"unknown transition {name!r}; one of: {', '.join(TRANSITIONS)}") from None
        if self.state not in sources:
            raise LifecycleError(f"cannot {name} actor {self.host.name!r}: it is {self.state_name}")
        fn = getattr(self.host.actor, hook, None)
        if fn is not None and fn() is False:
            raise LifecycleError(f"{hook}() of actor {self.host.name!r} returned False; it stays {self.state_name}")
        self.state = target

    def replay(self) -> None:
        """Bring a new incarnation to its goal; the journal keeps the goal meanwhile."""
        for t in _PATH[self.goal]:
            self._apply(t)
        self.host.journal.set_state(self.state)
        if self.restored and self.goal != UNCONFIGURED:
            log.info("[%s] lifecycle restored to %s", self.host.name, self.state_name)
        elif self.goal != UNCONFIGURED:  # a fresh actor: nothing was restored
            log.info("[%s] %s", self.host.name, "activated" if self.state == ACTIVE else "configured")


def current(actor: Actor) -> str:
    """The lifecycle state of ``actor``, from inside its own process (e.g. in a handler)."""
    lc = actor.context.extension(Lifecycle.name)
    return lc.state_name if isinstance(lc, Lifecycle) else "unconfigured"


def transition(system: ActorSystem, name: str, what: str, timeout: float = 10.0) -> str:
    """Ask actor ``name`` to run lifecycle transition ``what``; returns its new state."""
    return system.ctrl(name, "lifecycle", what, timeout=timeout)


def state(system: ActorSystem, name: str, timeout: float = 5.0) -> str:
    """The lifecycle state of actor ``name``, as the actor itself reports it."""
    return system.ctrl(name, "lifecycle_state", timeout=timeout)
