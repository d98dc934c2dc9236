"""The System declaration and loading ``system.py`` files.

``system.py`` is plain Python that ends with one top-level ``System(...)``;
:func:`load_system` imports it (as a uniquely named module, with its folder
on ``sys.path`` so its local imports work) and returns that System. Nothing
is started: the runtime does that, after :func:`embagents.check.check_system`.

Example::

    >>> from embagents.components import Component
    >>> from embagents.msgs import String
    >>> from embagents.topic import Topic
    >>> class Printer(Component):
    ...     def _execution_step(self, **inputs):
    ...         print(inputs["text"].data)
    >>> text = Topic("text", String)
    >>> system = System([Printer(name="printer", inputs=[text], trigger=text)], external=[text])
    >>> [c.name for c in system.components], sorted(system.topics)
    (['printer'], ['text'])
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import itertools
import os
import sys
import traceback
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from embagents.components.component import Component, ComponentError, lenient_construction
from embagents.events import Action, Event
from embagents.topic import Topic

__all__ = [
    "SUPERVISION_DEFAULTS", "SYSTEM_STOP", "System", "SystemFileError", "counted", "load_system", "loaded_system",
    "loading", "register", "remember_system",
]

#: Publish anything on this topic to stop the whole system cleanly.
SYSTEM_STOP = "system_stop"

#: Supervision policy of the system's root supervisor (OTP's meaning of each key).
SUPERVISION_DEFAULTS: dict[str, Any] = {"strategy": "one_for_one", "intensity": 3, "period": 5.0}

_module_ids = itertools.count()
#: Systems registered by the file being loaded (``register``); None: no file is being loaded.
_registered: list[System] | None = None


def loading() -> bool:
    """Whether a system file is being loaded by :func:`load_system` (``embagents check`` / ``supervise``)."""
    return _registered is not None


def register(system: System) -> None:
    """Make ``system`` the one :func:`load_system` returns for the file being loaded.

    For a file that builds its System inside a call instead of at top level (a compatibility
    layer's ``Launcher().bringup()``); outside a load it raises.
    """
    if _registered is None:
        raise RuntimeError("register(system) is for a system file being loaded by embagents check/supervise")
    _registered.append(system)


def counted(n: int, noun: str) -> str:
    """``counted(1, "component")`` -> "1 component"; ``counted(3, "topic")`` -> "3 topics"."""
    return f"{n} {noun}" + ("" if n == 1 else "s")


class SystemFileError(Exception):
    """A ``system.py`` could not be loaded; names the file, the line and the cause."""

    def __init__(self, path: str, message: str, line: int | None = None, cause: BaseException | None = None) -> None:
        where = f"{path}:{line}" if line else path
        super().__init__(f"{where}: {message}")
        self.path = path
        self.line = line
        self.cause = cause


def _supervision(value: Mapping[str, Any] | None) -> dict[str, Any]:
    # Only the shape here: the values (and whether they fit this system's children) are checked
    # by building the supervision tree itself, in `embagents check` (one truth: supervisor.spec).
    if value is None or value == ():
        return dict(SUPERVISION_DEFAULTS)
    if not isinstance(value, Mapping):
        raise TypeError(f"System supervision must be a dict, got {value!r}")
    unknown = sorted(set(value) - set(SUPERVISION_DEFAULTS))
    if unknown:
        raise ValueError(f"unknown supervision key(s) {', '.join(map(repr, unknown))}; valid: {', '.join(SUPERVISION_DEFAULTS)}")
    return {**SUPERVISION_DEFAULTS, **value}


def _events(events: Mapping[Event, Any] | Iterable[tuple[Event, Any]]) -> list[tuple[Event, tuple[Action, ...]]]:
    pairs = events.items() if isinstance(events, Mapping) else events
    out = []
    for pair in pairs:
        try:
            event, actions = pair
        except (TypeError, ValueError):
            raise TypeError(f"System events must be {{Event: Action(s)}} or (Event, Action(s)) pairs; got {pair!r}") from None
        if not isinstance(event, Event):
            raise TypeError(f"System events: expected an Event as key, got {event!r}")
        acts = (actions,) if isinstance(actions, Action) else tuple(actions)
        if not acts or not all(isinstance(a, Action) for a in acts):
            raise TypeError(f"event {event.name!r}: expected an Action or a non-empty list of Actions, got {actions!r}")
        out.append((event, acts))
    return out


class System:
    """Everything ``embagents supervise`` runs: components, events, models, ROS bridge, policy.

    - ``components``: the :class:`Component` objects (each becomes an actor).
    - ``events``: ``{Event: Action or [Actions]}`` or a list of such pairs.
    - ``models`` / ``clients``: model declarations and clients to serve (carried for the runtime).
    - ``ros``: ``RosInput`` / ``RosOutput`` declarations of the ROS bridge (carried).
    - ``zenoh``: this host's :class:`~embagents.zenoh.ZenohBridge` (topics to and from other hosts), or None.
    - ``external``: topics published from outside (a test harness, another system);
      they count as provided in checks.
    - ``managers``: :class:`~embagents.manager.Manager` loops (each a supervised actor; its
      isolated agents actors of their own, started before it).
    - ``supervision``: ``{"strategy", "intensity", "period"}`` of the root supervisor, defaults in
      :data:`SUPERVISION_DEFAULTS`; checked by building the supervision tree (``embagents check``).

    Construction checks only types; wiring problems are reported by
    :func:`embagents.check.check_system` (all of them at once).
    """

    def __init__(
        self,
        components: Sequence[Component],
        events: Mapping[Event, Any] | Iterable[tuple[Event, Any]] = (),
        models: Sequence[Any] = (),
        clients: Sequence[Any] = (),
        ros: Sequence[Any] = (),
        external: Sequence[Topic] = (),
        supervision: Mapping[str, Any] | None = None,
        name: str = "system",
        managers: Sequence[Any] = (),
        zenoh: Any = None,
    ) -> None:
        if isinstance(components, Component) or not isinstance(components, Sequence):
            raise TypeError(f"System components must be a list of components, got {components!r}")
        for i, c in enumerate(components):
            if not isinstance(c, Component):
                raise TypeError(f"System components[{i}] is not a Component: {c!r}")
        for t in external:
            if not isinstance(t, Topic):
                raise TypeError(f"System external must be Topics, got {t!r}")
        from embagents.manager import Manager  # lazy: a cycle

        for m in managers:
            if not isinstance(m, Manager):
                raise TypeError(f"System managers must be Manager objects, got {m!r}")
        if not isinstance(name, str) or not name:
            raise ValueError(f"System name must be a non-empty str, got {name!r}")
        self.components = list(components)
        self.events = _events(events)
        self.models = list(models)
        self.clients = list(clients)
        self.ros = list(ros)
        self.external = list(external)
        self.supervision = _supervision(supervision)
        self.name = name
        self.managers = list(managers)
        # Its type is checked by `embagents check` (embagents.zenoh is not imported here: it loads systems).
        self.zenoh = zenoh

    def __repr__(self) -> str:
        return f"System(name={self.name!r}, components={[c.name for c in self.components]})"

    def component(self, name: str) -> Component:
        """The component called ``name``."""
        for c in self.components:
            if c.name == name:
                return c
        known = ", ".join(str(c.name) for c in self.components) or "none"
        raise KeyError(f"no component named {name!r} in system {self.name!r}; components: {known}")

    def manager(self, name: str) -> Any:
        """The manager called ``name``."""
        for m in self.managers:
            if m.name == name:
                return m
        known = ", ".join(m.name for m in self.managers) or "none"
        raise KeyError(f"no manager named {name!r} in system {self.name!r}; managers: {known}")

    @property
    def topics(self) -> dict[str, Topic]:
        """Every topic by name: component inputs and outputs, event topics, external ones.

        When a name is declared with two types the first one wins here; the
        check reports the conflict.
        """
        out: dict[str, Topic] = {}
        for c in self.components:
            for t in (*c.outputs, *c.subscriptions):
                out.setdefault(t.name, t)
        for event, _ in self.events:
            for t in event.topics:
                out.setdefault(t.name, t)
        for m in self.managers:
            for node in m.nodes:
                for t in (*node.outputs.values(), *node.subscriptions):
                    out.setdefault(t.name, t)
        for t in self.external:
            out.setdefault(t.name, t)
        return out


# --- loading system.py --------------------------------------------------------------------------


def _line_in(path: str, exc: BaseException) -> int | None:
    if isinstance(exc, SyntaxError) and exc.filename and os.path.abspath(exc.filename) == path:
        return exc.lineno
    line = None
    for frame, lineno in traceback.walk_tb(exc.__traceback__):
        if os.path.abspath(frame.f_code.co_filename) == path:
            line = lineno  # the innermost line of system.py is the one to show
    return line


def _source_line(path: str, line: int | None) -> str:
    if not line:
        return ""
    try:
        with open(path, encoding="utf-8") as f:
            return next(itertools.islice(f, line - 1, None), "").strip()
    except OSError:
        return ""


def _exception_line(exc: BaseException) -> str:
    """Python's own last line for ``exc``, with its "Did you mean: 'LLM'?" hint.

    Python 3.10 and 3.11 add that hint only when the interpreter prints a traceback
    (3.12's traceback module adds it too), so it is taken from the interpreter's own printing.
    """
    line = f"{type(exc).__name__}: {exc}"
    if isinstance(exc, (NameError, AttributeError)):
        python = traceback.format_exception_only(type(exc), exc)[-1].strip()
        if "Did you mean" not in python:
            printed = io.StringIO()
            with contextlib.redirect_stderr(printed):
                sys.__excepthook__(type(exc), exc, exc.__traceback__)
            python = printed.getvalue().rstrip().rpartition("\n")[2]
        if python.startswith(line) and "Did you mean" in python:
            line = python
    return line


def _import(path: str) -> Any:
    module_name = f"_embagents_system_{next(_module_ids)}"
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:
        raise SystemFileError(path, "cannot be imported as a Python module (is it a .py file?)")
    module = importlib.util.module_from_spec(spec)
    folder = os.path.dirname(path)
    if folder not in sys.path:
        sys.path.insert(0, folder)  # stays: the file's lazy local imports need it later too
    sys.modules[module_name] = module  # classes defined there must find their module
    global _registered
    outer, _registered = _registered, []
    try:
        spec.loader.exec_module(module)
        module.__dict__["__embagents_registered__"] = _registered  # what bringup() registered
    except BaseException as exc:
        sys.modules.pop(module_name, None)
        if isinstance(exc, KeyboardInterrupt):
            raise
        line = _line_in(path, exc)
        code = _source_line(path, line)
        shown = f"\n    {code}" if code else ""  # the source line on its own, as Python shows it
        if isinstance(exc, ComponentError):
            raise SystemFileError(path, f"invalid component:\n{exc}{shown}", line, exc) from exc
        raise SystemFileError(path, f"{_exception_line(exc)}{shown}", line, exc) from exc
    finally:
        _registered = outer
    return module


def _suggest_system_file(folder: str) -> str:
    """"pass one of its system files: ..." naming the .py files there that build a System."""
    found = []
    for name in sorted(os.listdir(folder)):
        if name.endswith(".py"):
            with contextlib.suppress(OSError, UnicodeDecodeError), open(os.path.join(folder, name), encoding="utf-8") as f:
                if "System(" in f.read():
                    found.append(os.path.join(folder, name))
    if not found:
        return "pass the .py file that defines `system = System(...)`"
    return f"pass one of its system files, e.g. `{found[0]}`" + (f" (or: {', '.join(found[1:])})" if found[1:] else "")


def load_system(path: str | os.PathLike[str], *, lenient: bool = False) -> System:
    """Import ``system.py`` and return its one top-level :class:`System`.

    ``lenient=True`` builds components without raising on declaration
    problems (they are kept in each component's ``problems``), so a check can
    report every problem of the file. Any error is a :class:`SystemFileError`.
    """
    given = os.fspath(path)
    path = os.path.abspath(given)
    if os.path.isdir(path):
        raise SystemFileError(path, f"is a directory, not a system file; {_suggest_system_file(given)}")
    if not os.path.isfile(path):
        raise SystemFileError(path, "no such file")
    if lenient:
        with lenient_construction():
            module = _import(path)
    else:
        module = _import(path)
    found: dict[int, list[str]] = {}
    systems: dict[int, System] = {}
    for var, value in vars(module).items():
        if isinstance(value, System):
            found.setdefault(id(value), []).append(var)
            systems[id(value)] = value
    for value in getattr(module, "__embagents_registered__", []):
        if id(value) not in systems:
            found.setdefault(id(value), []).append(f"registered {value.name!r}")
            systems[id(value)] = value
    if not systems:
        raise SystemFileError(path, "no System found: define `system = System(...)` at top level")
    if len(systems) > 1:
        names = ", ".join(" = ".join(names) for names in found.values())
        raise SystemFileError(path, f"found {len(systems)} Systems ({names}); keep exactly one at top level")
    return next(iter(systems.values()))


_SYSTEMS: dict[str, System] = {}


def remember_system(path: str, system: System) -> None:
    """Keep the loaded System so forked actor processes find it without re-importing."""
    _SYSTEMS[path] = system


def loaded_system(path: str) -> System:
    """The System loaded from ``path``: the one the launcher remembered, else loaded now (once per process)."""
    system = _SYSTEMS.get(path)
    if system is None:
        system = _SYSTEMS[path] = load_system(path)
    return system
