"""Host extensions: typed code that runs around an actor, in the actor's process.

A layer above the actors (the supervisor's lifecycle and snapshots) adds
behaviour to an actor process by subclassing :class:`HostExtension` and
overriding the hooks it needs. The host calls them in a declared order:

1. ``__init__(host, config)``: in list order, once the host is built.
2. :meth:`~HostExtension.before_start`: in list order, before ``Actor.on_start``.
3. :meth:`~HostExtension.after_start`: in list order, after ``on_start`` and
   before the actor reports ready (a hook that raises fails the start).
4. :meth:`~HostExtension.after_message`: in list order, after each handled
   message; only extensions that override it are called, and an actor
   without any pays nothing per message.
5. :meth:`~HostExtension.state_changed`: on ``ActorContext.changed()``.
6. :meth:`~HostExtension.after_stop`: in reverse order, after ``Actor.on_stop``
   on a clean stop.

:meth:`~HostExtension.controls` adds control commands (``system.ctrl``), and
``ActorContext.extension(name)`` finds an extension by its ``name``.

Extensions cross the fork server as data: :func:`extension_spec` makes the
msgpack-able ``["module:Class", config]`` pair a process spec lists, and
:func:`load_extension` resolves the string in the actor's process and checks
it names a ``HostExtension`` subclass.

Example::

    >>> class Counter(HostExtension):
    ...     name = "counter"
    ...     def after_message(self, kind, ok):
    ...         self.count = getattr(self, "count", 0) + 1
    >>> extension_spec(Snapshots, {"interval": 0.5})   # doctest: +SKIP
    ['supervisor.snapshot:Snapshots', {'interval': 0.5}]
    >>> load_extension("actors.extension:HostExtension") is HostExtension
    True
    >>> observes_messages(Counter), observes_messages(HostExtension)
    (True, False)
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, ClassVar

if TYPE_CHECKING:
    from actors.host import ActorHost

__all__ = ["HostExtension", "extension_spec", "load_extension", "observes_messages", "resolve"]


class HostExtension:
    """Base class of host extensions; override the hooks you need (see the module docstring)."""

    #: What ``ActorContext.extension(name)`` finds it by ("" when it needs no finding).
    name: ClassVar[str] = ""

    def __init__(self, host: ActorHost, config: Mapping[str, Any]) -> None:
        self.host = host
        self.config = config

    def controls(self) -> Mapping[str, Callable[..., Any]]:
        """Control commands this extension answers (name -> function of the command's args)."""
        return {}

    def before_start(self) -> None:
        """Before ``Actor.on_start`` (e.g. restore a snapshot)."""

    def after_start(self) -> None:
        """After ``Actor.on_start``, before the actor reports ready (e.g. replay a lifecycle)."""

    def after_message(self, kind: int, ok: bool) -> None:
        """After a message of ``kind`` (``wire.TELL``, ``ASK`` or ``CTRL``) was handled; ``ok``: it did not raise."""

    def state_changed(self) -> None:
        """The actor said its state changed outside a message (``ActorContext.changed``)."""

    def after_stop(self) -> None:
        """After ``Actor.on_stop`` on a clean stop (reverse list order)."""


def observes_messages(cls: type[HostExtension]) -> bool:
    """True if ``cls`` overrides :meth:`HostExtension.after_message`."""
    return cls.after_message is not HostExtension.after_message


def extension_spec(cls: type[HostExtension], config: Mapping[str, Any] | None = None) -> list[Any]:
    """The ``["module:Class", config]`` pair naming ``cls`` in a process spec (``config``: msgpack-able)."""
    if not (isinstance(cls, type) and issubclass(cls, HostExtension)):
        raise TypeError(f"an extension must be a HostExtension subclass, not {cls!r}")
    if "<locals>" in cls.__qualname__:
        raise TypeError(
            f"extension {cls.__qualname__} is defined inside a function; actor processes load "
            "extensions by module path, so define it at module top level"
        )
    return [f"{cls.__module__}:{cls.__qualname__}", dict(config or {})]


def resolve(path: str, what: str) -> Any:
    """The object ``module:QualName`` names; a clear error naming ``what`` if there is none."""
    mod_name, _, qual = path.partition(":")
    try:
        obj: Any = importlib.import_module(mod_name)
        for part in qual.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError, ValueError) as exc:
        raise ImportError(
            f"cannot load {what} {path!r}: {exc}; name it as 'module:Class', define the class at "
            "module top level (and import it before the ActorSystem starts)"
        ) from exc
    return obj


def load_extension(path: str) -> type[HostExtension]:
    """Import ``module:QualName`` and check it is a :class:`HostExtension` subclass."""
    obj = resolve(path, "host extension")
    if not (isinstance(obj, type) and issubclass(obj, HostExtension)):
        raise TypeError(f"host extension {path!r} is {obj!r}, not a HostExtension subclass; subclass actors.HostExtension")
    return obj
