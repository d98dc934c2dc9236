"""Events, actions and fallbacks: declared in ``system.py``, evaluated purely.

A :class:`Condition` compares message fields of topics
(``on(topic).field("data") == "stop"``) and combines with ``&``, ``|``, ``~``.
An :class:`Event` is a named, stateful condition: :meth:`Event.check` is fed
every message of the topics it watches and says when the event fires
(rising edge by default, optionally only once, optionally debounced).

Actions are plain data (``kind``, ``component``, ``args``) so the runtime
dispatches them with a table and ships them across processes; nothing here
executes anything. A :class:`Fallback` maps a component's health status to
actions with a bounded number of retries.

Example::

    >>> from embagents.msgs import String
    >>> from embagents.topic import Topic
    >>> text = Topic("text", String)
    >>> stop_said = Event("stop_said", on(text).field("data").contains("stop"))
    >>> stop_said.check("text", String("please stop")), stop_said.check("text", String("stop!"))
    (True, False)
    >>> restart("nav")
    Action(kind='restart', component='nav', args={})
"""

from __future__ import annotations

import operator
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import attrs

from embagents.msgs import HealthStatus
from embagents.topic import Topic

__all__ = [
    "ACTION_KINDS",
    "FALLBACK_KINDS",
    "Action",
    "Condition",
    "Event",
    "Fallback",
    "FieldRef",
    "TopicRef",
    "call",
    "give_up",
    "on",
    "publish",
    "reconfigure",
    "restart",
    "start",
    "stop",
    "switch_model_client",
]

#: Every action kind the runtime must dispatch, with the keys of its ``args``.
ACTION_KINDS: dict[str, tuple[str, ...]] = {
    "start": (),
    "stop": (),
    "restart": (),
    "reconfigure": ("overrides",),
    "publish": ("topic", "msg"),
    "call": ("method", "args", "kwargs"),
    "switch_model_client": ("client",),
    "give_up": (),
}
#: Kinds meant for fallbacks (they act on the failing component).
FALLBACK_KINDS = ("switch_model_client", "restart", "give_up")


# --- conditions ---------------------------------------------------------------------------


class Condition:
    """A boolean expression over the latest message of one or more topics.

    Evaluation never raises: a topic not heard from yet, a missing field or
    values that cannot be compared make a comparison false.
    """

    topics: tuple[Topic, ...] = ()

    def evaluate(self, latest: Mapping[str, Any]) -> bool:
        """Whether the condition holds for ``latest`` (topic name -> last message)."""
        raise NotImplementedError

    def __and__(self, other: Condition) -> Condition:
        return _Bool("&", (self, _cond(other)))

    def __or__(self, other: Condition) -> Condition:
        return _Bool("|", (self, _cond(other)))

    def __invert__(self) -> Condition:
        return _Not(self)

    def __bool__(self) -> bool:
        # `a and b` / `not a` would silently drop a condition; force & | ~.
        raise TypeError("combine conditions with &, | and ~ (not 'and', 'or', 'not')")


def _cond(obj: object) -> Condition:
    if not isinstance(obj, Condition):
        raise TypeError(f"expected a Condition (e.g. on(topic).field('data') == 'x'), got {obj!r}")
    return obj


def _merge_topics(parts: Iterable[Condition]) -> tuple[Topic, ...]:
    seen: dict[str, Topic] = {}
    for part in parts:
        for t in part.topics:
            seen.setdefault(t.name, t)
    return tuple(seen.values())


class _Bool(Condition):
    def __init__(self, op: str, parts: tuple[Condition, ...]) -> None:
        self.op = op
        self.parts = parts
        self.topics = _merge_topics(parts)

    def evaluate(self, latest: Mapping[str, Any]) -> bool:
        results = (p.evaluate(latest) for p in self.parts)
        return all(results) if self.op == "&" else any(results)

    def __repr__(self) -> str:
        return "(" + f" {self.op} ".join(map(repr, self.parts)) + ")"


class _Not(Condition):
    def __init__(self, inner: Condition) -> None:
        self.inner = inner
        self.topics = inner.topics

    def evaluate(self, latest: Mapping[str, Any]) -> bool:
        return not self.inner.evaluate(latest)

    def __repr__(self) -> str:
        return f"~{self.inner!r}"


_MISSING = object()


def _contains(container: Any, item: Any) -> bool:
    return item in container


def _in(value: Any, choices: Any) -> bool:
    return value in choices


_OPS: dict[str, Callable[[Any, Any], Any]] = {
    "==": operator.eq,
    "!=": operator.ne,
    "<": operator.lt,
    "<=": operator.le,
    ">": operator.gt,
    ">=": operator.ge,
    "in": _in,
    "contains": _contains,
}


class _Compare(Condition):
    def __init__(self, ref: FieldRef, op: str, value: Any) -> None:
        self.ref = ref
        self.op = op
        self.value = value
        self.topics = _merge_topics([ref, value] if isinstance(value, FieldRef) else [ref])

    def evaluate(self, latest: Mapping[str, Any]) -> bool:
        left = self.ref.resolve(latest)
        right = self.value.resolve(latest) if isinstance(self.value, FieldRef) else self.value
        if left is _MISSING or right is _MISSING:
            return False
        try:
            return bool(_OPS[self.op](left, right))
        except (TypeError, ValueError, LookupError, AttributeError):
            return False  # e.g. "3" < 4, or an array compared element-wise

    def __repr__(self) -> str:
        return f"{self.ref!r} {self.op} {self.value!r}"


class FieldRef(Condition):
    """A field of a topic's latest message; compare it to get a :class:`Condition`.

    ``path`` is dotted; integer parts index sequences (``"linear.0"``). Used as
    a condition on its own, it is true when the field is truthy.
    """

    def __init__(self, topic: Topic, path: str) -> None:
        if not isinstance(path, str) or not path:
            raise ValueError(f"topic {topic.name!r}: field path must be a non-empty str, got {path!r}")
        self.topic = topic
        self.path = path
        self.parts: tuple[str | int, ...] = tuple(int(p) if p.isdigit() else p for p in path.split("."))
        self.topics = (topic,)
        first = self.parts[0]
        names = [f.name for f in attrs.fields(topic.msg_type)] if attrs.has(topic.msg_type) else []
        if isinstance(first, int) or (
            first not in names and not isinstance(getattr(topic.msg_type, first, None), property)
        ):
            raise ValueError(
                f"topic {topic.name!r} carries {topic.type_name}, which has no field {first!r}; "
                f"fields: {', '.join(names) or '(none)'}"
            )

    def resolve(self, latest: Mapping[str, Any]) -> Any:
        """The field's value in ``latest``, or a private marker when unavailable."""
        obj = latest.get(self.topic.name, _MISSING)
        for part in self.parts:
            if obj is _MISSING:
                break
            try:
                if isinstance(part, int) or isinstance(obj, Mapping):
                    obj = obj[part]
                else:
                    obj = getattr(obj, part)
            except (LookupError, AttributeError, TypeError):
                obj = _MISSING
        return obj

    def evaluate(self, latest: Mapping[str, Any]) -> bool:
        value = self.resolve(latest)
        try:
            return value is not _MISSING and bool(value)
        except (TypeError, ValueError):
            return False

    def _cmp(self, op: str, value: Any) -> Condition:
        return _Compare(self, op, value)

    def __eq__(self, value: object) -> Condition:  # type: ignore[override]
        return self._cmp("==", value)

    def __ne__(self, value: object) -> Condition:  # type: ignore[override]
        return self._cmp("!=", value)

    def __lt__(self, value: Any) -> Condition:
        return self._cmp("<", value)

    def __le__(self, value: Any) -> Condition:
        return self._cmp("<=", value)

    def __gt__(self, value: Any) -> Condition:
        return self._cmp(">", value)

    def __ge__(self, value: Any) -> Condition:
        return self._cmp(">=", value)

    __hash__ = None  # type: ignore[assignment]  # == builds a condition, so no hashing

    def in_(self, choices: Iterable[Any]) -> Condition:
        """True when the field's value is one of ``choices``."""
        return self._cmp("in", tuple(choices) if not isinstance(choices, (str, set, frozenset)) else choices)

    def contains(self, item: Any) -> Condition:
        """True when the field (a str, list, ...) contains ``item``."""
        return self._cmp("contains", item)

    def __repr__(self) -> str:
        return f"on({self.topic.name!r}).field({self.path!r})"


class TopicRef:
    """The starting point of a condition: ``on(topic).field("data")``."""

    def __init__(self, topic: Topic) -> None:
        if not isinstance(topic, Topic):
            raise TypeError(f"on() takes a Topic, got {topic!r}")
        self.topic = topic

    def field(self, path: str) -> FieldRef:
        """The field ``path`` (dotted for nested values) of the topic's latest message."""
        return FieldRef(self.topic, path)


def on(topic: Topic) -> TopicRef:
    """Start a condition on ``topic``.

    >>> from embagents.msgs import Twist
    >>> cond = on(Topic("cmd_vel", Twist)).field("linear.0") > 1.0
    >>> cond.evaluate({"cmd_vel": Twist(linear=(2.0, 0, 0))})
    True
    """
    return TopicRef(topic)


# --- events -------------------------------------------------------------------------------


class Event:
    """A named condition that fires.

    - ``on_change`` (default True): fire only on a rising edge (false -> true),
      not on every message while the condition holds.
    - ``once``: fire at most once (until :meth:`reset`).
    - ``keep_event_delay``: seconds during which a new firing is suppressed after one.

    Events compare by identity, so they can be keys of ``System(events={...})``.

    >>> from embagents.msgs import String
    >>> ev = Event("hi", on(Topic("text", String)).field("data") == "hi", on_change=False)
    >>> [ev.check("text", String(s)) for s in ("hi", "hi", "bye")]
    [True, True, False]
    """

    def __init__(
        self,
        name: str,
        condition: Condition,
        *,
        on_change: bool = True,
        once: bool = False,
        keep_event_delay: float = 0.0,
    ) -> None:
        if not isinstance(name, str) or not name:
            raise ValueError(f"an Event needs a non-empty str name, got {name!r}")
        if not isinstance(condition, Condition):
            raise TypeError(
                f"event {name!r}: condition must be built with on(topic).field(...), got {condition!r}"
            )
        if isinstance(keep_event_delay, bool) or not isinstance(keep_event_delay, (int, float)) or keep_event_delay < 0:
            raise ValueError(f"event {name!r}: keep_event_delay must be seconds >= 0, got {keep_event_delay!r}")
        self.name = name
        self.condition = condition
        self.on_change = bool(on_change)
        self.once = bool(once)
        self.keep_event_delay = float(keep_event_delay)
        self.reset()

    @property
    def topics(self) -> tuple[Topic, ...]:
        """The topics whose messages :meth:`check` must be fed."""
        return self.condition.topics

    def reset(self) -> None:
        """Forget the messages seen and whether the event fired."""
        self._latest: dict[str, Any] = {}
        self._last_value = False
        self._fired = False
        self._last_fire: float | None = None

    def check(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        """Feed one message; True when the event fires on it.

        Messages of topics the condition does not mention are ignored.
        ``now`` (seconds, monotonic) is for tests of ``keep_event_delay``.
        """
        if all(t.name != topic_name for t in self.condition.topics):
            return False
        self._latest[topic_name] = msg
        value = self.condition.evaluate(self._latest)
        rising = value and not self._last_value
        self._last_value = value
        fire = rising if self.on_change else value
        if not fire or (self.once and self._fired):
            return False
        now = time.monotonic() if now is None else now
        if self._last_fire is not None and now - self._last_fire < self.keep_event_delay:
            return False
        self._fired = True
        self._last_fire = now
        return True

    def __repr__(self) -> str:
        return f"Event({self.name!r}, {self.condition!r})"


# --- actions ------------------------------------------------------------------------------


def _component_name(component: object) -> str | None:
    if component is None:
        return None
    name = component if isinstance(component, str) else getattr(component, "name", None)
    if not isinstance(name, str) or not name:
        raise TypeError(f"expected a component or its name, got {component!r}")
    return name


def _check_kind(_inst: object, _attr: object, kind: str) -> None:
    if kind not in ACTION_KINDS:
        raise ValueError(f"unknown action kind {kind!r}; known: {', '.join(ACTION_KINDS)}")


@attrs.frozen
class Action:
    """One thing the runtime does when an event fires or a component fails.

    ``component`` is a component name (``None`` in a fallback: the failing
    component); ``args`` is plain, msgpack-able data whose keys are listed in
    :data:`ACTION_KINDS`.
    """

    kind: str = attrs.field(validator=_check_kind)
    component: str | None = None
    args: dict[str, Any] = attrs.field(factory=dict)

    def __hash__(self) -> int:  # args is a dict; equal actions still hash alike
        return hash((self.kind, self.component))

    def to_dict(self) -> dict[str, Any]:
        """``{"kind", "component", "args"}`` for the runtime's dispatch table."""
        return {"kind": self.kind, "component": self.component, "args": dict(self.args)}


def start(component: object) -> Action:
    """Start (activate) a component."""
    return Action("start", _component_name(component))


def stop(component: object) -> Action:
    """Stop (deactivate) a component."""
    return Action("stop", _component_name(component))


def restart(component: object = None) -> Action:
    """Restart a component (in a fallback, without argument: the failing one)."""
    return Action("restart", _component_name(component))


def reconfigure(component: object, overrides: Mapping[str, Any]) -> Action:
    """Apply config ``overrides`` to a component (see ``Component.reconfigure``)."""
    if not isinstance(overrides, Mapping):
        raise TypeError(f"reconfigure: overrides must be a dict of config key -> value, got {overrides!r}")
    return Action("reconfigure", _component_name(component), {"overrides": dict(overrides)})


def publish(topic: Topic, msg: Any) -> Action:
    """Publish ``msg`` on ``topic`` (the runtime publishes it as the system)."""
    if not isinstance(topic, Topic):
        raise TypeError(f"publish: expected a Topic, got {topic!r}")
    if not isinstance(msg, topic.msg_type):
        raise TypeError(
            f"publish: topic {topic.name!r} carries {topic.type_name}, got {type(msg).__name__}"
        )
    return Action("publish", None, {"topic": topic.name, "msg": msg})


def call(component: object, method: str, *args: Any, **kwargs: Any) -> Action:
    """Call ``component.method(*args, **kwargs)`` inside the component's process."""
    if not isinstance(method, str) or not method.isidentifier() or method.startswith("_"):
        raise ValueError(f"call: method must be the name of a public method, got {method!r}")
    return Action("call", _component_name(component), {"method": method, "args": list(args), "kwargs": dict(kwargs)})


def switch_model_client(client: str, component: object = None) -> Action:
    """Switch a ModelComponent to the model client named ``client`` (a fallback step)."""
    if not isinstance(client, str) or not client:
        raise TypeError(f"switch_model_client: expected a client name, got {client!r}")
    return Action("switch_model_client", _component_name(component), {"client": client})


def give_up(component: object = None) -> Action:
    """Stop retrying: the component is stopped and stays stopped."""
    return Action("give_up", _component_name(component))


# --- fallbacks ----------------------------------------------------------------------------


def _steps(value: Action | Sequence[Action] | None, what: str) -> tuple[Action, ...]:
    if value is None:
        return ()
    steps = (value,) if isinstance(value, Action) else tuple(value)
    if not steps or not all(isinstance(s, Action) for s in steps):
        raise TypeError(f"Fallback {what}: expected an Action or a non-empty list of Actions, got {value!r}")
    return steps


class Fallback:
    """What to do when a component reports a failure health status.

    Each rule is an action or a list of actions: the first failure runs the
    first action, the second failure the second, and so on (the last one
    repeats). After ``max_retries`` consecutive failures of one kind the
    answer is :func:`give_up`. A HEALTHY status resets the counts.

    >>> fb = Fallback(on_algorithm_fail=[switch_model_client("backup"), restart()], max_retries=2)
    >>> [fb.decide("ALGORITHM_FAILURE", "llm").kind for _ in range(3)]
    ['switch_model_client', 'restart', 'give_up']

    Under the runtime a failure is one failing *sender* (``incarnation``: its
    process start and model client switches, see :class:`~embagents.msgs.Health`),
    not one report: a component failing at 30 Hz until its restart takes
    effect is restarted once. Reports from a sender already acted on, or an
    older one, are ignored (``None``):

    >>> fb = Fallback(on_algorithm_fail=restart(), max_retries=1)
    >>> [getattr(fb.decide("ALGORITHM_FAILURE", "cam", incarnation=i), "kind", None) for i in (1, 1, 2, 1)]
    ['restart', None, 'give_up', None]
    """

    def __init__(
        self,
        *,
        on_algorithm_fail: Action | Sequence[Action] | None = None,
        on_component_fail: Action | Sequence[Action] | None = None,
        on_system_fail: Action | Sequence[Action] | None = None,
        max_retries: int = 3,
    ) -> None:
        if isinstance(max_retries, bool) or not isinstance(max_retries, int) or max_retries < 0:
            raise ValueError(f"Fallback: max_retries must be an int >= 0, got {max_retries!r}")
        self.rules: dict[str, tuple[Action, ...]] = {
            "ALGORITHM_FAILURE": _steps(on_algorithm_fail, "on_algorithm_fail"),
            "COMPONENT_FAILURE": _steps(on_component_fail, "on_component_fail"),
            "SYSTEM_FAILURE": _steps(on_system_fail, "on_system_fail"),
        }
        self.max_retries = max_retries
        self._counts: dict[str, int] = {}
        self._acted_on: Any = None  # the last sender an action was decided for

    @property
    def actions(self) -> tuple[Action, ...]:
        """Every action of every rule (for checks)."""
        return tuple(a for steps in self.rules.values() for a in steps)

    def reset(self) -> None:
        """Forget the failure counts."""
        self._counts.clear()

    def decide(self, status: object, component: str | None = None, incarnation: Any = None) -> Action | None:
        """The action for one failure report (``None``: healthy, no rule for it, or already acted on).

        ``status`` is a ``HealthStatus`` (or its name or value); ``component``
        fills actions declared without one. ``incarnation`` (comparable, growing:
        an int or ``(incarnation, switches)``) names the report's sender; ``None``
        counts every report.
        """
        status = HealthStatus.parse(status)
        if incarnation is not None and self._acted_on is not None and incarnation <= self._acted_on:
            return None  # its restart or switch is pending: it was acted on once
        if status is HealthStatus.HEALTHY:
            self.reset()
            return None
        steps = self.rules[status.name]
        if not steps:
            return None
        count = self._counts.get(status.name, 0) + 1
        self._counts[status.name] = count
        if incarnation is not None:
            self._acted_on = incarnation
        action = give_up() if count > self.max_retries else steps[min(count, len(steps)) - 1]
        if action.component is None and component is not None:
            action = attrs.evolve(action, component=component)
        return action
