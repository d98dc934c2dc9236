"""EmbodiedAgents' ``agents.ros``: Topic, FixedInput, MapLayer, Route, Action, Event, Launcher.

- ``Topic(name=..., msg_type="String")``: an embagents Topic; ``topic.msg.data == "x"``
  builds an event condition (``topic.msg.labels.contains("person")`` too).
- ``Event(event_condition=..., on_change=...)``: an embagents Event (named for you);
  a bare topic as the condition fires on each of its messages.
- ``Action(method=component.method, args=(...))``: an embagents action run in that
  component's process (``start``/``stop``/``restart``/``change_model_client`` map to
  the supervisor's actions).
- ``Launcher().add_pkg(components=[...], events_actions={...})``, ``enable_ui(...)``,
  ``bringup()``: the System; loaded by ``embagents check``/``supervise`` it is
  registered, run as ``python recipe.py [--offline]`` it is supervised.

Example::

    >>> text = Topic(name="text0", msg_type="String")
    >>> ev = Event(event_condition=text.msg.data == "stop", on_change=True)
    >>> from embagents.msgs import String
    >>> ev.check("text0", String("stop"))
    True
"""

from __future__ import annotations

import itertools
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import attrs

from embagents import events as native_events
from embagents.cli.supervise import run
from embagents.compat._core import CompatError, note, unsupported
from embagents.components.component import Component
from embagents.components.memory import MapLayer as _NativeMapLayer
from embagents.components.router import Route as _NativeRoute
from embagents.msgs import RosMessage
from embagents.system import System, loading, register
from embagents.topic import FixedInput as _NativeFixedInput
from embagents.topic import Topic as _NativeTopic

__all__ = ["Action", "Event", "FixedInput", "Launcher", "MapLayer", "MemLayer", "Route", "Topic"]

_event_ids = itertools.count(1)


class _Field(native_events.FieldRef):
    """``topic.msg.a.b``: a field of a topic's message, for conditions (EmbodiedAgents' spelling)."""

    def __getattr__(self, name: str) -> _Field:
        if name.startswith("_"):
            raise AttributeError(name)
        return _Field(self.topic, f"{self.path}.{name}")

    def is_in(self, choices: Sequence[Any]) -> native_events.Condition:
        return self.in_(choices)

    def not_in(self, choices: Sequence[Any]) -> native_events.Condition:
        return ~self.in_(choices)

    def contains_any(self, items: Sequence[Any]) -> native_events.Condition:
        conds = [self.contains(i) for i in items]
        out = conds[0]
        for c in conds[1:]:
            out = out | c
        return out

    def contains_all(self, items: Sequence[Any]) -> native_events.Condition:
        conds = [self.contains(i) for i in items]
        out = conds[0]
        for c in conds[1:]:
            out = out & c
        return out


class _Msg:
    def __init__(self, topic: _NativeTopic) -> None:
        self._topic = topic

    def __getattr__(self, name: str) -> _Field:
        if name.startswith("_"):
            raise AttributeError(name)
        return _Field(self._topic, name)


#: ROS message types with no embagents class: such a topic carries a RosMessage (the ROS bridge's generic one).
_ROS_ONLY = {
    **{t: "std_msgs" for t in ("Bool", "Byte", "Char", "Float32", "Float64", "Int8", "Int16", "Int32", "Int64",
                               "UInt8", "UInt16", "UInt32", "UInt64", "ColorRGBA", "Header", "Empty")},
    **{t: "sensor_msgs" for t in ("BatteryState", "Temperature", "RelativeHumidity", "FluidPressure", "Illuminance",
                                  "Range", "NavSatFix", "Joy", "MagneticField")},
}


@attrs.frozen
class Topic(_NativeTopic):
    """``Topic(name=..., msg_type="String", qos_profile=...)``; ``.msg.<field>`` builds conditions.

    A ROS type embagents has no class for (``"Float32"``, ``"BatteryState"``) carries a
    :class:`~embagents.msgs.RosMessage` (its fields by their ROS names).
    """

    qos_profile: Any = attrs.field(default=None, kw_only=True, eq=False)

    def __attrs_post_init__(self) -> None:
        if isinstance(self.msg_type, str) and self.msg_type in _ROS_ONLY:
            note(f"topic {self.name!r}: {_ROS_ONLY[self.msg_type]}/msg/{self.msg_type} carries a RosMessage here "
                 "(its fields by their ROS names)")
            object.__setattr__(self, "msg_type", RosMessage)
        super().__attrs_post_init__()

    @property
    def msg(self) -> _Msg:
        return _Msg(self)


def FixedInput(name: str, msg_type: Any, fixed: Any) -> _NativeFixedInput:  # noqa: N802 - EmbodiedAgents' class name
    """A constant input: ``fixed`` (a str for a text type) is every step's message on it."""
    return _NativeFixedInput(name, msg_type, fixed=fixed)


@attrs.define(kw_only=True)
class _MemLayer(_NativeMapLayer):
    """A native layer that also says whether it is internal state (read by Memory's ``body_status``)."""

    is_internal_state: bool = False


def MapLayer(subscribes_to: _NativeTopic, temporal_change: bool = True, resolution_multiple: int | None = None,
             pre_defined: Any = None, is_internal_state: bool = False) -> _NativeMapLayer:  # noqa: N802
    """A layer of the map memory (``resolution_multiple`` counts the map's cells; here: metres, 0.5);
    ``is_internal_state``: a Memory's body-state layer (battery...), read by its ``body_status`` tool."""
    if pre_defined:
        unsupported("MapLayer(pre_defined=...) (a layer filled from a file)",
                    "Memory.remember(text, layer) from a component's on_activate")
    return _MemLayer(subscribes_to=subscribes_to, temporal_change=temporal_change,
                     is_internal_state=bool(is_internal_state))


#: EmbodiedAgents' newer name of a memory layer.
MemLayer = MapLayer


def Route(routes_to: _NativeTopic, samples: Sequence[str]) -> _NativeRoute:  # noqa: N802
    """A route of a SemanticRouter: texts like ``samples`` go to ``routes_to``."""
    return _NativeRoute(routes_to=routes_to, samples=list(samples))


class _AnyMessage(native_events.Condition):
    """True once the topic has a message: ``Event(event_condition=topic)`` fires on each one."""

    def __init__(self, topic: _NativeTopic) -> None:
        self.topics = (topic,)

    def evaluate(self, latest: Mapping[str, Any]) -> bool:
        return latest.get(self.topics[0].name) is not None

    def __repr__(self) -> str:
        return f"message on {self.topics[0].name}"


def Event(event_condition: Any, on_change: bool = False, keep_event_delay: float = 0.0,  # noqa: N802
          name: str | None = None, trigger_once: bool = False, handle_once: bool = False,
          **kw: Any) -> native_events.Event:
    """An event; a Topic as ``event_condition`` fires on each of its messages; ``handle_once``: at most once."""
    if kw:
        unsupported(f"Event({', '.join(kw)}=...)", "Event(event_condition, on_change, keep_event_delay, name)")
    if isinstance(event_condition, _NativeTopic):
        condition: native_events.Condition = _AnyMessage(event_condition)
        on_change = False  # each message is an occurrence
    elif isinstance(event_condition, native_events.Condition):
        condition = event_condition
    else:
        raise CompatError(f"Event: event_condition must be a Topic or a condition such as topic.msg.data == 'x', "
                          f"got {event_condition!r}")
    return native_events.Event(name or f"event_{next(_event_ids)}", condition, on_change=on_change,
                               once=trigger_once or handle_once, keep_event_delay=keep_event_delay)


_SUPERVISOR = {"start": native_events.start, "stop": native_events.stop, "restart": native_events.restart}


@attrs.frozen
class FunctionAction:
    """``Action(method=fn, description=...)`` of a plain function: a tool of a Cortex (run in its process)."""

    method: Callable[..., Any]
    description: str


def Action(method: Callable[..., Any], args: Sequence[Any] = (), kwargs: Mapping[str, Any] | None = None,  # noqa: N802
           description: str | None = None) -> Any:
    """``component.method(*args, **kwargs)`` as an embagents action (run in that component's process);
    a plain function with a ``description`` is a Cortex's tool (:class:`FunctionAction`)."""
    owner = getattr(method, "__self__", None)
    fname = getattr(method, "__name__", repr(method))
    if not isinstance(owner, Component) and description is not None and callable(method):
        return FunctionAction(method, description)
    if not isinstance(owner, Component):
        unsupported(f"Action(method={fname}) on something that is not a component (it would run in the launcher's "
                    "process)", "a public method of a component: Action(method=component.method)")
    args = tuple(args) if isinstance(args, (list, tuple)) else (args,)
    if getattr(method, "_supervisor_action", False):
        return _SUPERVISOR[fname](owner)
    if fname == "change_model_client":
        return native_events.switch_model_client(str(args[0]), owner)
    local = getattr(owner, "local_fallback_client", None)
    if fname == "fallback_to_local" and callable(local):
        return native_events.switch_model_client(local(), owner)
    if fname == "publish_message":
        unsupported("Action(method=component.publish_message)", "embagents.events.publish(topic, msg)")
    return native_events.call(owner, fname, *args, **dict(kwargs or {}))


class Launcher:
    """EmbodiedAgents' (ros_sugar's) launcher: collects components and events into an embagents System."""

    def __init__(self, namespace: str = "", config_file: str | None = None, activate_all_components_on_start: bool = True,
                 robot_plugin: Any = None, **kw: Any) -> None:
        if config_file:
            unsupported("Launcher(config_file=...) (ROS parameters from a file)",
                        "each component's config=, or embagents.config.load_configs(path)")
        self.namespace = namespace
        self.components: list[Component] = []
        self.events: list[tuple[Any, Any]] = []
        self.external: list[_NativeTopic] = []
        self.name = "agents"
        self.fallback_rate: float | None = None
        self.supervision: dict[str, Any] | None = None

    def add_pkg(self, components: Sequence[Component], events_actions: Mapping[Any, Any] | None = None,
                package_name: str | None = None, executable_entry_point: str | None = None,
                multiprocessing: bool = True, activate_all_components_on_start: bool = True,
                ros_log_level: str | None = None, fallback_rate: float | None = None, **kw: Any) -> None:
        """Add ``components`` (each its own supervised process here) and ``{Event: Action(s)}``."""
        for c in components:
            if not isinstance(c, Component):
                raise CompatError(f"add_pkg: {c!r} is not a component")
            self.components.append(c)
            self.components += getattr(c, "companions", [])
        for event, actions in (events_actions or {}).items():
            for a in actions if isinstance(actions, (list, tuple)) else [actions]:
                if isinstance(a, FunctionAction):
                    unsupported(f"Action(method={a.method.__name__}) of a plain function in an event (it would run "
                                "in the launcher's process)", "a public method of a component: Action(method=component.method)")
            self.events.append((event, actions))
        if package_name:
            self.name = package_name
        self.fallback_rate = fallback_rate

    def enable_ui(self, inputs: Sequence[_NativeTopic] = (), outputs: Sequence[_NativeTopic] = (), **kw: Any) -> None:
        """The web UI's inputs come from outside: ``embagents publish TOPIC TEXT``; watch outputs with
        ``embagents topic echo TOPIC`` or ``embagents supervise --dashboard``."""
        self.external += [t for t in inputs if not isinstance(t, _NativeFixedInput)]
        names = ", ".join(t.name for t in inputs) or "none"
        note(f"enable_ui: type into {names} with `embagents publish TOPIC TEXT`; watch with `embagents topic echo "
             "TOPIC` (or `embagents supervise --dashboard`)")

    def on_process_fail(self, max_retries: int = 3) -> None:
        """Restart a component whose process dies: the supervisor always does; here at most ``max_retries``
        restarts within its period (OTP's intensity) before the supervisor gives up."""
        if int(max_retries) < 1:
            raise CompatError(f"on_process_fail: max_retries must be at least 1, got {max_retries!r}")
        self.supervision = {"intensity": int(max_retries)}

    def system(self) -> System:
        """The embagents System these components and events make (a Cortex gets the others' tools)."""
        for c in self.components:
            wire = getattr(c, "discover_tools", None)
            if callable(wire):
                wire([o for o in self.components if o is not c])
        # A RAG's embeddings in a local model actor: the system serves that model (it is no chat client).
        rag = [getattr(getattr(c, "rag", None), "client", None) for c in self.components]
        models = [getattr(client, "model", None) for client in rag if getattr(client, "in_run", False)]
        return System(self.components, events=self.events, external=self.external, name=self.name,
                      supervision=self.supervision, models=[m for m in models if m is not None])

    def bringup(self) -> None:
        """Register the System (under ``embagents check``/``supervise``), else supervise it (``python recipe.py``)."""
        system = self.system()
        if loading():
            register(system)
            return
        import __main__

        path = getattr(__main__, "__file__", None)
        if not path:
            raise CompatError("Launcher.bringup(): run the recipe as a file (python recipe.py), "
                              "or `embagents supervise recipe.py`")
        if "--offline" in sys.argv:
            os.environ["EMBAGENTS_OFFLINE"] = "1"  # the actor processes (spawned ones too) map clients the same way
        import argparse


        raise SystemExit(run(argparse.Namespace(system=os.path.abspath(path), verbose=False, dashboard=False)))
