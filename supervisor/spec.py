"""Child specs and supervisor specs: what to start and how to supervise it.

A :class:`ChildSpec` says what a child is (an actor class, an external
:class:`Command`, or a nested :class:`SupervisorSpec`) and how its
supervisor treats it: restart type, shutdown mode, hang deadline, resource
limits, scheduling, backoff. Specs are plain data, checked when built so a
typo fails at declaration time, not at the first crash.

Example::

    >>> from actors import Actor
    >>> class Detector(Actor):
    ...     pass
    >>> spec = SupervisorSpec(strategy="rest_for_one", intensity=3, period=10, children=[
    ...     ChildSpec("camera", Command(["sleep", "1000"]), shutdown=2.0),
    ...     ChildSpec("vision", (Detector, ("yolo",), {}), heartbeat=2.0, max_rss_mb=800),
    ... ])
    >>> spec.children[1].shutdown, spec.children[1].type
    (5.0, 'worker')
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple, TypeVar

from actors import Actor, HostExtension, extension_spec, wire
from supervisor.backoff import Backoff
from supervisor.states import StrEnum

__all__ = [
    "LIFECYCLE_TARGETS",
    "RESTART_TYPES",
    "START_METHODS",
    "STRATEGIES",
    "ActorStart",
    "ChildSpec",
    "Command",
    "Restart",
    "Strategy",
    "SupervisorSpec",
]


_C = TypeVar("_C")


class Strategy(StrEnum):
    """Which children a restart involves (see :mod:`supervisor.supervisor`)."""

    ONE_FOR_ONE = "one_for_one"
    ONE_FOR_ALL = "one_for_all"
    REST_FOR_ONE = "rest_for_one"
    SIMPLE_ONE_FOR_ONE = "simple_one_for_one"

    def involves(self, children: Sequence[_C], failed: _C) -> list[_C]:
        """The children (in start order) that the restart of ``failed`` stops and starts again.

        >>> Strategy.REST_FOR_ONE.involves(["a", "b", "c"], "b")
        ['b', 'c']
        """
        if self is Strategy.ONE_FOR_ALL:
            return list(children)
        if self is Strategy.REST_FOR_ONE:
            return list(children[list(children).index(failed):])
        return [failed]


class Restart(StrEnum):
    """When a child that exited is restarted: always, after an abnormal exit, never."""

    PERMANENT = "permanent"
    TRANSIENT = "transient"
    TEMPORARY = "temporary"

    def restarts(self, normal_exit: bool) -> bool:
        """Whether a child of this type that exited (normally or not) is restarted."""
        return self is Restart.PERMANENT or (self is Restart.TRANSIENT and not normal_exit)


STRATEGIES = tuple(s.value for s in Strategy)
RESTART_TYPES = tuple(r.value for r in Restart)
LIFECYCLE_TARGETS = ("unconfigured", "inactive", "active")
#: How an actor child's process starts: forked from the fork server, or a fresh interpreter.
START_METHODS = ("fork", "spawn")


class ActorStart(NamedTuple):
    """An actor class and the arguments of its constructor."""

    cls: type[Actor]
    args: tuple[Any, ...] = ()
    kwargs: dict[str, Any] = {}


@dataclass(frozen=True)
class Command:
    """An external program run as a supervised child (a camera SDK binary, ``socat``).

    Its stdout and stderr lines are logged under ``supervisor.child.<id>``
    at ``stdout_level`` and ``stderr_level``. It runs in its own process
    group (Ctrl-C is the root's to handle) and is killed if the root dies.
    """

    argv: Sequence[str]
    env: Mapping[str, str] | None = None
    cwd: str | None = None
    stdout_level: int = logging.INFO
    stderr_level: int = logging.WARNING

    def __post_init__(self) -> None:
        if isinstance(self.argv, str) or not self.argv or not all(isinstance(a, str) for a in self.argv):
            raise TypeError(
                f"Command needs a non-empty list of strings (argv), got {self.argv!r}; "
                "e.g. Command(['socat', 'TCP-LISTEN:9000', 'STDOUT'])"
            )
        object.__setattr__(self, "argv", tuple(self.argv))


@dataclass
class ChildSpec:
    """One child of a supervisor.

    ``start`` is an actor class, ``(cls, args)``, ``(cls, args, kwargs)``, a
    :class:`Command` or a :class:`SupervisorSpec`. Times are in seconds.

    - ``restart``: "permanent" (always restarted), "transient" (restarted
      only after an abnormal exit) or "temporary" (never restarted).
    - ``shutdown``: seconds to wait after the stop request before SIGKILL,
      "brutal_kill" (SIGKILL at once) or "infinity" (wait forever). Default
      5.0 for workers, "infinity" for supervisors (as OTP).
    - ``heartbeat``: hang deadline; a started actor whose loop has not beaten
      for this long is killed and restarted. None: no hang detection.
    - ``start_timeout``: a start that is not ready by then counts as failed.
    - ``max_rss_mb``, ``max_cpu_percent`` over ``cpu_window`` s: limits.
    - ``nice``, ``cpu_affinity``: scheduling of the child's process.
    - ``backoff``: delay restarts (see :mod:`supervisor.backoff`).
    - ``lifecycle``: state to bring a fresh actor to ("inactive", "active").
    - ``snapshot_interval``: least seconds between two snapshots (0: after
      every message).
    - ``extensions``: more :class:`actors.HostExtension` subclasses to run in
      the actor's process, each a class or ``(class, config dict)``; they run
      after the supervisor's own (snapshots, lifecycle).
    - ``start_method``: "fork" (from the pre-imported fork server: tens of
      ms) or "spawn" (a fresh interpreter, :mod:`actors.spawn`: for an actor
      that may initialise CUDA, which does not survive ``fork``).
    - ``standby``: keep a warm standby (spawned; see
      :mod:`supervisor.standby`): a second process that ran the actor's
      ``on_standby()`` and waits; when the active one dies or is restarted
      it takes over at once, and a new standby is prepared. Twice the memory.
    """

    id: str
    start: Any
    restart: Restart | str = Restart.PERMANENT
    shutdown: float | str | None = None
    type: str | None = None
    heartbeat: float | None = None
    start_timeout: float | None = 30.0
    max_rss_mb: float | None = None
    max_cpu_percent: float | None = None
    cpu_window: float = 10.0
    nice: int | None = None
    cpu_affinity: Sequence[int] | None = None
    backoff: Backoff | None = None
    poison_limit: int = 3
    lifecycle: str | None = None
    snapshot_interval: float = 0.0
    extensions: Sequence[Any] = ()
    start_method: str = "fork"
    standby: bool = False

    def __post_init__(self) -> None:
        wire.check_name(self.id)
        self.start = _normalize_start(self.id, self.start)
        kind = self.kind
        if self.type is None:
            self.type = "supervisor" if kind == "supervisor" else "worker"
        if self.type not in ("worker", "supervisor") or (self.type == "supervisor") != (kind == "supervisor"):
            raise ValueError(
                f"child {self.id!r}: type must be 'supervisor' for a SupervisorSpec and 'worker' otherwise, "
                f"not {self.type!r}"
            )
        if self.restart not in RESTART_TYPES:
            raise ValueError(f"child {self.id!r}: restart must be one of {', '.join(RESTART_TYPES)}, not {self.restart!r}")
        self.restart = Restart(self.restart)
        if self.shutdown is None:
            self.shutdown = "infinity" if self.type == "supervisor" else 5.0
        if isinstance(self.shutdown, str):
            if self.shutdown not in ("brutal_kill", "infinity"):
                raise ValueError(
                    f"child {self.id!r}: shutdown is seconds, 'brutal_kill' or 'infinity', not {self.shutdown!r}"
                )
        elif not isinstance(self.shutdown, (int, float)) or self.shutdown < 0:
            raise ValueError(f"child {self.id!r}: shutdown must be >= 0 seconds, not {self.shutdown!r}")
        else:
            self.shutdown = float(self.shutdown)
        for attr in ("heartbeat", "start_timeout", "max_rss_mb", "max_cpu_percent"):
            v = getattr(self, attr)
            if v is not None and not v > 0:
                raise ValueError(f"child {self.id!r}: {attr} must be > 0 (or None), not {v!r}")
        if self.cpu_window <= 0 or self.snapshot_interval < 0:
            raise ValueError(f"child {self.id!r}: cpu_window must be > 0 and snapshot_interval >= 0")
        if self.heartbeat is not None and kind != "actor":
            raise ValueError(f"child {self.id!r}: heartbeat (hang detection) needs an actor child")
        if self.lifecycle is not None and self.lifecycle not in LIFECYCLE_TARGETS:
            raise ValueError(
                f"child {self.id!r}: lifecycle must be one of {', '.join(LIFECYCLE_TARGETS)}, not {self.lifecycle!r}"
            )
        if self.backoff is not None and not isinstance(self.backoff, Backoff):
            raise TypeError(f"child {self.id!r}: backoff must be a supervisor.Backoff, not {self.backoff!r}")
        if self.cpu_affinity is not None:
            self.cpu_affinity = [int(c) for c in self.cpu_affinity]
        self.extensions = tuple(_normalize_extension(self.id, e) for e in self.extensions)
        if self.start_method not in START_METHODS:
            raise ValueError(
                f"child {self.id!r}: start_method must be one of {', '.join(START_METHODS)}, not {self.start_method!r}"
            )
        if not isinstance(self.standby, bool):
            raise TypeError(f"child {self.id!r}: standby must be True or False, not {self.standby!r}")
        if self.standby and kind != "actor":
            raise ValueError(f"child {self.id!r}: standby (a warm second process) needs an actor child")
        if self.standby:
            self.start_method = "spawn"  # a standby may initialise CUDA: every incarnation is spawned

    @property
    def kind(self) -> str:
        """"actor", "command" or "supervisor"."""
        if isinstance(self.start, ActorStart):
            return "actor"
        return "command" if isinstance(self.start, Command) else "supervisor"

    @property
    def managed(self) -> bool:
        """An actor that uses the managed lifecycle (a target state or any lifecycle hook)."""
        if not isinstance(self.start, ActorStart):
            return False
        hooks = ("on_configure", "on_activate", "on_deactivate", "on_cleanup", "on_shutdown")
        return self.lifecycle is not None or any(hasattr(self.start.cls, h) for h in hooks)

    @property
    def module(self) -> str:
        """What runs, for listings: ``module:Class``, the program, or "supervisor"."""
        if isinstance(self.start, ActorStart):
            return f"{self.start.cls.__module__}:{self.start.cls.__qualname__}"
        if isinstance(self.start, Command):
            return self.start.argv[0]
        return "supervisor"

    def with_args(self, name: str, extra: Sequence[Any]) -> ChildSpec:
        """A copy named ``name`` whose start arguments get ``extra`` appended (simple_one_for_one)."""
        start = self.start
        if isinstance(start, ActorStart):
            start = ActorStart(start.cls, tuple(start.args) + tuple(extra), dict(start.kwargs))
        elif isinstance(start, Command):
            start = replace(start, argv=tuple(start.argv) + tuple(str(a) for a in extra))
        elif extra:
            raise ValueError(f"child {self.id!r} is a supervisor: start_child takes no arguments for it")
        return replace(self, id=name, start=start)


def _normalize_extension(cid: str, ext: Any) -> tuple[type[HostExtension], dict[str, Any]]:
    cls, config = ext if isinstance(ext, tuple) and len(ext) == 2 else (ext, {})
    try:
        extension_spec(cls, config)  # a class at module top level, config a mapping
    except (TypeError, ValueError) as exc:
        raise TypeError(f"child {cid!r}: extensions takes HostExtension classes or (class, config) pairs: {exc}") from None
    return cls, dict(config)


def _normalize_start(cid: str, start: Any) -> ActorStart | Command | SupervisorSpec:
    if isinstance(start, (Command, SupervisorSpec)):
        return start
    if isinstance(start, type):
        start = (start,)
    if isinstance(start, tuple) and 1 <= len(start) <= 3 and isinstance(start[0], type):
        cls = start[0]
        args = tuple(start[1]) if len(start) > 1 else ()
        kwargs = dict(start[2]) if len(start) > 2 else {}
        if not issubclass(cls, Actor):
            raise TypeError(f"child {cid!r}: {cls.__qualname__} is not an actors.Actor subclass")
        if "<locals>" in cls.__qualname__:
            raise TypeError(
                f"child {cid!r}: {cls.__qualname__} is defined inside a function; actor processes "
                "load their class by module path, so define it at module top level"
            )
        return ActorStart(cls, args, kwargs)
    raise TypeError(
        f"child {cid!r}: start must be an Actor class, (cls, args, kwargs), a Command or a "
        f"SupervisorSpec, not {start!r}"
    )


@dataclass
class SupervisorSpec:
    """A supervisor: its strategy, restart intensity and children (in start order).

    More than ``intensity`` restarts within ``period`` seconds make it stop
    all its children and exit with reason "shutdown". Defaults are OTP's
    (1 restart in 5 s). ``simple_one_for_one`` takes exactly one child spec,
    the template of the children :meth:`Supervisor.start_child` adds.
    """

    children: list[ChildSpec] = field(default_factory=list)
    strategy: Strategy | str = Strategy.ONE_FOR_ONE
    intensity: int = 1
    period: float = 5.0

    def __post_init__(self) -> None:
        if self.strategy not in STRATEGIES:
            raise ValueError(f"strategy must be one of {', '.join(STRATEGIES)}, not {self.strategy!r}")
        self.strategy = Strategy(self.strategy)
        if isinstance(self.intensity, bool) or not isinstance(self.intensity, int) or self.intensity < 0:
            raise ValueError(f"intensity must be an integer >= 0 (most restarts within period), not {self.intensity!r}")
        if isinstance(self.period, bool) or not isinstance(self.period, (int, float)) or not self.period > 0:
            raise ValueError(f"period must be > 0 seconds, not {self.period!r}")
        self.children = list(self.children)
        for c in self.children:
            if not isinstance(c, ChildSpec):
                raise TypeError(f"children must be ChildSpec objects, not {c!r}")
        ids = [c.id for c in self.children]
        dup = {i for i in ids if ids.count(i) > 1}
        if dup:
            raise ValueError(f"duplicate child ids: {', '.join(sorted(dup))}; every child needs its own id")
        if self.strategy == "simple_one_for_one" and len(self.children) != 1:
            raise ValueError(
                f"simple_one_for_one takes exactly one child spec (the template of the children start_child "
                f"adds), got {len(self.children)}" + (f" ({', '.join(ids)})" if ids else "")
                + "; for a fixed set of children use one_for_one, one_for_all or rest_for_one"
            )
