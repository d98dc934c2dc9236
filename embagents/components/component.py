"""The component base class: typed inputs and outputs, a trigger, a config, health.

A component declares what it consumes and produces; it is validated when it
is built (so ``system.py`` fails at the line that is wrong) and knows nothing
of processes or sockets: the runtime feeds it messages and injects a
publisher. Subclasses implement :meth:`Component._execution_step`.

Triggers: a number is a rate in Hz (``trigger=10.0`` runs 10 steps per
second), a :class:`~embagents.topic.Topic` (each message on it runs a step),
a list of topics (any of them), an :class:`~embagents.events.Event` (each
time it fires), or ``None``: a server that only runs when called.

Example::

    >>> from embagents.msgs import String
    >>> from embagents.topic import Topic
    >>> class Shout(Component):
    ...     allowed_inputs = {"Required": [String]}
    ...     allowed_outputs = {"Required": [String]}
    ...     def _execution_step(self, **inputs):
    ...         self.publish("loud", String(inputs["text"].data.upper()))
    >>> text, loud = Topic("text", String), Topic("loud", String)
    >>> shout = Shout(name="shout", inputs=[text], outputs=[loud], trigger=text)
    >>> sent = []
    >>> shout.attach(lambda topic, msg: sent.append((topic, msg)))
    >>> shout.on_message("text", String("hi")) and shout.execute()
    True
    >>> sent
    [('loud', String(data='HI'))]
"""

from __future__ import annotations

import contextlib
import contextvars
import copy
import logging
import re
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import Any, ClassVar

from embagents.config import BaseComponentConfig, ConfigError, apply_config, config_fields
from embagents.events import Event, Fallback
from embagents.extras import install_hint
from embagents.msgs import Health, HealthStatus
from embagents.topic import FixedInput, Topic

__all__ = [
    "UNSET",
    "Component",
    "ComponentError",
    "Health",
    "HealthStatus",
    "ComponentProblem",
    "lenient_construction",
    "component_arguments",
    "unknown_argument",
]

#: A component problem: (code, message); the message names the component.
ComponentProblem = tuple[str, str]
#: ``{"Required": [...], "Optional": [...]}``; an entry is a class or a list of classes (one of).
AllowedTypes = Mapping[str, Sequence[type | Sequence[type]]]
Publisher = Callable[[str, Any], None]

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_\-]*$")
_lenient: contextvars.ContextVar[bool] = contextvars.ContextVar("embagents_lenient", default=False)


class _Unset:
    def __repr__(self) -> str:
        return "UNSET"


#: Default of ``trigger``: the component class chooses (:meth:`Component.default_trigger`).
UNSET: Any = _Unset()


class ComponentError(ValueError):
    """A component is declared wrongly; ``problems`` lists every (code, message) found."""

    def __init__(self, component: str, problems: Sequence[ComponentProblem]) -> None:
        self.component = component
        self.problems = list(problems)
        super().__init__("\n".join(msg for _, msg in self.problems))


@contextlib.contextmanager
def lenient_construction() -> Iterator[None]:
    """Within this block components keep their problems in ``.problems`` instead of raising.

    ``embagents check`` loads ``system.py`` this way to report every problem
    of a file, not only the first.
    """
    token = _lenient.set(True)
    try:
        yield
    finally:
        _lenient.reset(token)


#: EmbodiedAgents' spellings of component arguments -> ours (named when one is given to a component here).
EMBODIED_AGENTS_ARGUMENTS: dict[str, str] = {
    "component_name": "name",
    "additional_model_clients": "extra_clients",
    "db_client": "embedding_client (a client with embed(), e.g. LocalModelClient(EmbeddingModel(name='minilm')))",
    "callback_group": "nothing: each component is its own process here",
}


def component_arguments(cls: type) -> list[str]:
    """The keyword arguments ``cls(...)`` takes by name, from every ``__init__`` of its classes.

    >>> component_arguments(Component)[:3]
    ['name', 'inputs', 'outputs']
    """
    import inspect

    names: list[str] = []
    for klass in cls.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None or klass is object:
            continue
        for p in inspect.signature(init).parameters.values():
            if p.name != "self" and p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD) and p.name not in names:
                names.append(p.name)
    return names


def unknown_argument(cls: type, key: str, config_class: type | None = None) -> str:
    """The one line refusing ``cls(key=...)``: its arguments, its config keys, and ours for an EmbodiedAgents spelling."""
    ours = EMBODIED_AGENTS_ARGUMENTS.get(key)
    if key == "model_client" and "policy" in component_arguments(cls):
        ours = "policy"
    hint = f"EmbodiedAgents' {key} is {ours} here; " if ours else ""
    config = f"; or a key of {config_class.__name__}: {', '.join(config_fields(config_class))}" if config_class else ""
    return (f"unknown argument {key!r}; {hint}{cls.__name__} takes {', '.join(component_arguments(cls))}{config}")


def _named_culprit(cls: type, init: Callable[..., None]) -> Callable[..., None]:
    """``init``, refusing EmbodiedAgents' ``component_name=`` (without ``name=``) in words, not Python's
    "missing 1 required keyword-only argument: 'name'"."""
    import functools
    import inspect

    if "component_name" in inspect.signature(init).parameters:
        return init  # it takes EmbodiedAgents' spelling itself (MapEncoding)

    @functools.wraps(init)
    def wrapper(self: Any, *args: Any, **kw: Any) -> None:
        if "component_name" in kw and "name" not in kw and not args:
            raise TypeError(f"{cls.__name__}(component_name={kw['component_name']!r}): "
                            f"{unknown_argument(cls, 'component_name')}")
        init(self, *args, **kw)

    return wrapper


def _type_names(entry: Sequence[type]) -> str:
    return " or ".join(t.__name__ for t in entry)


def _check_allowed_spec(owner: str, what: str, spec: AllowedTypes | None) -> None:
    # A class-definition mistake: fail at import of the class, not per instance.
    if spec is None:
        return
    if not isinstance(spec, Mapping) or set(spec) - {"Required", "Optional"}:
        raise TypeError(f"{owner}.{what} must be a dict with keys 'Required' and/or 'Optional', got {spec!r}")
    for key, entries in spec.items():
        for entry in entries:
            classes = entry if isinstance(entry, (list, tuple)) else [entry]
            if not classes or not all(isinstance(c, type) for c in classes):
                raise TypeError(f"{owner}.{what}[{key!r}]: entries are message classes or lists of them, got {entry!r}")


def _entries(spec: AllowedTypes, key: str) -> list[tuple[type, ...]]:
    return [(e,) if isinstance(e, type) else tuple(e) for e in spec.get(key, ())]


class Component:
    """Base class of all components (see the module docstring).

    Keyword arguments beyond the named ones are config overrides, e.g.
    ``MyComponent(name="x", loop_rate_hz=5)``. ``start_method="spawn"`` starts
    its process as a fresh interpreter (for CUDA, which does not survive
    ``fork``); ``standby=True`` keeps a warm standby that ran ``on_configure``
    and takes over at once when this one dies (see :mod:`supervisor.standby`). Subclasses that take their own
    arguments set them before calling ``super().__init__`` and extend
    :meth:`validate` (which the constructor runs last).

    Runtime contract (everything that needs no IPC is done here):

    - :meth:`attach` injects the publisher (and a health callback);
    - subscribe to :attr:`subscriptions` (each Topic carries its queue policy);
    - for each received message: ``if c.on_message(topic, msg): c.execute()``;
    - a rate trigger: call :meth:`execute` every ``1 / rate_hz`` seconds;
    - lifecycle: ``on_configure``, ``on_activate``, ``on_deactivate``,
      ``on_cleanup``, ``on_shutdown``; after a restart, :meth:`restore` with the
      last :meth:`snapshot` before ``on_activate``.

    ``_execution_step`` receives the latest message of every input topic as
    keyword arguments named by topic (``None`` for a topic not heard from yet
    or older than ``config.input_max_age_s``). A step only runs once every
    required input has a message: until then a tick (or a trigger message)
    runs nothing, and the log says once which input it waits for;
    ``config.wait_for_inputs=False`` runs it with what is there.
    :attr:`fresh_inputs` names the topics with a new message since the
    previous step. Input topic names may contain ``/``: accept them with ``**inputs``.

    ``queued``: inputs whose step argument is the list of every message since
    the previous step (oldest first), not only the latest: ``{topic: bound}``
    or a list of topics (bound: the topic's ``queue_size``). Past the bound the
    oldest is dropped, counted in :attr:`dropped` and logged once. Use it for a
    rate-triggered step that must see every detection or every phrase.
    """

    allowed_inputs: ClassVar[AllowedTypes | None] = None  # None: any input types
    allowed_outputs: ClassVar[AllowedTypes | None] = None
    config_class: ClassVar[type] = BaseComponentConfig

    def __init_subclass__(cls, **kw: Any) -> None:
        super().__init_subclass__(**kw)
        if "__init__" in cls.__dict__:
            cls.__init__ = _named_culprit(cls, cls.__dict__["__init__"])  # type: ignore[method-assign]
        _check_allowed_spec(cls.__name__, "allowed_inputs", cls.allowed_inputs)
        _check_allowed_spec(cls.__name__, "allowed_outputs", cls.allowed_outputs)

    def __init__(
        self,
        *,
        name: str,
        inputs: Sequence[Topic] | Topic | None = None,
        outputs: Sequence[Topic] | Topic | None = None,
        trigger: float | Topic | Sequence[Topic] | Event | None = UNSET,
        config: Any = None,
        fallback: Fallback | None = None,
        standby: bool = False,
        start_method: str = "fork",
        queued: Mapping[Topic | str, int] | Sequence[Topic | str] | None = None,
        **config_overrides: Any,
    ) -> None:
        self._init_problems: list[ComponentProblem] = []
        self.name = name
        #: Keep a warm standby (spawned, configured, inactive) that takes over when this one dies:
        #: for a component whose on_configure takes seconds (a CUDA model); twice the memory.
        self.standby = standby
        #: "fork" (from the pre-imported fork server) or "spawn" (a fresh interpreter: for CUDA).
        self.start_method = start_method
        self.inputs = self._topics(inputs, "inputs")
        self.outputs = self._topics(outputs, "outputs")
        #: Queued inputs: topic name -> bound (see the class docstring).
        self.queued: dict[str, int] = self._queue_bounds(queued)
        self._queues: dict[str, deque[Any]] = {n: deque() for n in self.queued}
        #: Messages dropped from a full queued input, per topic.
        self.dropped: dict[str, int] = dict.fromkeys(self.queued, 0)
        self._waiting_logged: set[str] = set()
        self.config = self._make_config(config, config_overrides)
        self.fallback = fallback
        self.trigger = self.default_trigger() if trigger is UNSET else trigger
        self._parse_trigger()
        self.logger = logging.getLogger(f"embagents.component.{name}")
        self._apply_log_level()
        # Runtime state: filled by attach() and on_message().
        self._publisher: Publisher | None = None
        self._on_health: Callable[[Health], None] | None = None
        self._call_later: Callable[[float, Callable[[], None]], object] | None = None
        self._latest: dict[str, Any] = {}
        self._received_at: dict[str, float] = {}
        self._fresh: set[str] = set()
        self._health = Health(component=str(name))
        self._health_set_in_step = False
        self._health_reported = False
        #: Which start of the component's process this is (set by the runtime; health reports carry it).
        self.incarnation = 0
        #: Model client switches this incarnation made (health reports carry it).
        self.client_switches = 0
        self._missing_module: str | None = None  # set when a step found a module missing
        self.problems: list[ComponentProblem] = self.validate()
        self._required_inputs: list[Topic] = (
            self._match(self.allowed_inputs, self.inputs, "input")[1] if self.allowed_inputs is not None else []
        )
        # Looked up per message: keep them as sets.
        self._subscribed = frozenset(t.name for t in self.subscriptions)
        self._trigger_names = frozenset(t.name for t in self.trigger_topics)
        if self.problems and not _lenient.get():
            raise ComponentError(str(name), self.problems)

    # --- declaration ----------------------------------------------------------------------

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r})"

    def _label(self) -> str:
        return f"component {self.name!r} ({type(self).__name__})"

    def _problem(self, code: str, text: str) -> None:
        self._init_problems.append((code, f"{self._label()}: {text}"))

    def _topics(self, value: Sequence[Topic] | Topic | None, what: str) -> tuple[Topic, ...]:
        if value is None:
            return ()
        items = [value] if isinstance(value, Topic) else value
        if isinstance(items, (str, bytes)) or not isinstance(items, Sequence):
            self._problem("bad-topic", f"{what} must be a list of Topics, got {value!r}")
            return ()
        good = []
        for item in items:
            if isinstance(item, Topic):
                good.append(item)
            else:
                self._problem("bad-topic", f"{what} must be Topics, got {item!r}")
        return tuple(good)

    def _queue_bounds(self, queued: Mapping[Topic | str, int] | Sequence[Topic | str] | None) -> dict[str, int]:
        if queued is None:
            return {}
        if isinstance(queued, (str, Topic)) or not isinstance(queued, (Mapping, Sequence)):
            self._problem("bad-queued", f"queued must be a dict {{topic: bound}} or a list of input topics, "
                                        f"got {queued!r}")
            return {}
        by_name = {t.name: t for t in self.inputs}
        pairs = queued.items() if isinstance(queued, Mapping) else ((t, None) for t in queued)
        out: dict[str, int] = {}
        for topic, bound in pairs:
            name = topic.name if isinstance(topic, Topic) else str(topic).lstrip("/")
            if name not in by_name:
                self._problem("bad-queued", f"queued topic {name!r} is not one of its inputs "
                                            f"({', '.join(by_name) or 'none'}); add it to inputs")
                continue
            bound = by_name[name].queue_size if bound is None else bound
            if isinstance(bound, bool) or not isinstance(bound, int) or bound < 1:
                self._problem("bad-queued", f"queued[{name!r}]: the bound is how many messages a step may get, "
                                            f"an int >= 1; got {bound!r}")
                continue
            out[name] = bound
        return out

    def _make_config(self, config: Any, overrides: Mapping[str, Any]) -> Any:
        cls = self.config_class
        if config is None:
            config = cls()
        elif not isinstance(config, cls):
            self._problem("bad-config", f"config must be a {cls.__name__}, got {type(config).__name__}")
            config = cls()
        config = copy.deepcopy(config)  # never share a config object between components
        valid = set(config_fields(cls))
        unknown = [k for k in overrides if k not in valid]
        for key in unknown:
            self._problem("unknown-argument", unknown_argument(type(self), key, cls))
        overrides = {k: v for k, v in overrides.items() if k in valid}
        if overrides:
            try:
                config = apply_config(config, overrides)
            except ConfigError as exc:
                self._problem("bad-config", str(exc))
        return config

    def default_trigger(self) -> float | Topic | Sequence[Topic] | Event | None:
        """The trigger when none is given; the base class is a server (``None``)."""
        return None

    def _parse_trigger(self) -> None:
        trig = self.trigger
        self.trigger_kind = "none"
        self.trigger_topics: tuple[Topic, ...] = ()
        self.trigger_event: Event | None = None
        if trig is None:
            return
        if isinstance(trig, (int, float)) and not isinstance(trig, bool):
            if not trig > 0:
                self._problem("bad-trigger", f"a rate trigger is in Hz and must be > 0, got {trig!r}")
                return
            self.trigger_kind = "rate"
            self.config = apply_config(self.config, {"loop_rate_hz": float(trig)})
        elif isinstance(trig, Topic):
            self.trigger_kind, self.trigger_topics = "topics", (trig,)
        elif isinstance(trig, Event):
            self.trigger_kind, self.trigger_event = "event", trig
        elif isinstance(trig, Sequence) and not isinstance(trig, str) and trig and all(isinstance(t, Topic) for t in trig):
            self.trigger_kind, self.trigger_topics = "topics", tuple(trig)
        else:
            self._problem(
                "bad-trigger",
                f"trigger must be a rate in Hz (e.g. 10.0), a Topic, a non-empty list of Topics, "
                f"an Event or None; got {trig!r}",
            )

    @property
    def rate_hz(self) -> float | None:
        """The step rate in Hz of a rate-triggered component, else ``None``."""
        return self.config.loop_rate_hz if self.trigger_kind == "rate" else None

    @property
    def subscriptions(self) -> tuple[Topic, ...]:
        """Every topic the runtime must subscribe to: the inputs plus an event trigger's topics."""
        seen = {t.name: t for t in self.inputs if not isinstance(t, FixedInput)}  # a constant: nothing to hear
        if self.trigger_event is not None:
            for t in self.trigger_event.topics:
                seen.setdefault(t.name, t)
        return tuple(seen.values())

    def _match(self, spec: AllowedTypes, topics: Sequence[Topic], direction: str) -> tuple[list[ComponentProblem], list[Topic]]:
        """Check ``topics`` against ``spec``; returns problems and the topics filling Required entries."""
        problems: list[ComponentProblem] = []
        required, optional = _entries(spec, "Required"), _entries(spec, "Optional")
        allowed = [c for entry in required + optional for c in entry]
        allowed_text = ", ".join(dict.fromkeys(c.__name__ for c in allowed)) or "(none)"
        for t in topics:
            if not issubclass(t.msg_type, tuple(allowed)):
                code = "wrong-input-type" if direction == "input" else "wrong-output-type"
                problems.append((code, f"{self._label()}: {direction} topic {t.name!r} carries {t.type_name}, "
                                       f"which is not allowed; allowed {direction} types: {allowed_text}"))
        used: list[Topic] = []
        # Most specific entries first so a one-of list does not take a topic a single type needs.
        for entry in sorted(required, key=len):
            match = next((t for t in topics if t not in used and issubclass(t.msg_type, entry)), None)
            if match is None:
                given = ", ".join(str(t) for t in topics) or "none"
                problems.append((f"missing-{direction}", f"{self._label()}: needs an {direction} topic of type "
                                 f"{_type_names(entry)} (required); {direction}s given: {given}"))
            else:
                used.append(match)
        return problems, used

    def validate(self) -> list[ComponentProblem]:
        """Every declaration problem of this component as (code, message); empty when fine.

        Pure: the constructor and ``embagents check`` both call it.
        """
        problems = list(self._init_problems)
        if not isinstance(self.name, str) or not _NAME.match(self.name):
            problems.append(("bad-name", f"{self._label()}: a component name is letters, digits, '_' and '-' "
                                         "(not starting with a digit or '-')"))
        for what, topics in (("input", self.inputs), ("output", self.outputs)):
            names = [t.name for t in topics]
            for dup in sorted({n for n in names if names.count(n) > 1}):
                problems.append(("duplicate-topic", f"{self._label()}: {what} topic {dup!r} is listed twice"))
        if self.allowed_inputs is not None:
            problems += self._match(self.allowed_inputs, self.inputs, "input")[0]
        if self.allowed_outputs is not None:
            problems += self._match(self.allowed_outputs, self._typed_outputs(), "output")[0]
        by_name = {t.name: t for t in self.inputs}
        for t in self.trigger_topics:
            if isinstance(t, FixedInput):
                problems.append(("bad-trigger", f"{self._label()}: trigger topic {t.name!r} is a FixedInput, which "
                                                "never changes; trigger on a topic, a rate or an Event"))
                continue
            if t.name not in by_name or by_name[t.name].msg_type is not t.msg_type:
                inputs = ", ".join(by_name) or "none"
                problems.append(("trigger-not-input", f"{self._label()}: trigger topic {t.name!r} is not one of "
                                                      f"its inputs ({inputs}); add it to inputs"))
        if not isinstance(self.standby, bool):
            problems.append(("bad-standby", f"{self._label()}: standby must be True or False, got {self.standby!r}"))
        if self.start_method not in ("fork", "spawn"):
            problems.append(("bad-start-method", f"{self._label()}: start_method must be 'fork' or 'spawn' "
                                                 f"(spawn for a component that uses CUDA), got {self.start_method!r}"))
        if self.fallback is not None and not isinstance(self.fallback, Fallback):
            problems.append(("bad-fallback", f"{self._label()}: fallback must be a Fallback, got {self.fallback!r}"))
        elif self.fallback is not None:
            problems += self._validate_fallback(self.fallback)
        return problems

    def _typed_outputs(self) -> tuple[Topic, ...]:
        """The outputs held to ``allowed_outputs`` (all of them here; an LLM leaves out converted ones)."""
        return self.outputs

    def _validate_fallback(self, fallback: Fallback) -> list[ComponentProblem]:
        return [
            ("bad-fallback", f"{self._label()}: fallback action {a.kind} needs a ModelComponent")
            for a in fallback.actions
            if a.kind == "switch_model_client"
        ]

    # --- runtime: inputs, steps, publishing -----------------------------------------------------

    def attach(self, publisher: Publisher, on_health: Callable[[Health], None] | None = None,
               call_later: Callable[[float, Callable[[], None]], object] | None = None, incarnation: int = 0) -> None:
        """Give the component its way out: ``publisher(topic_name, msg)``; ``on_health(Health)``;
        ``call_later(delay_s, fn)``: run ``fn`` on the component's thread later (see :meth:`call_later`);
        ``incarnation``: which start of its process this is (its health reports say so)."""
        self._publisher = publisher
        self._on_health = on_health
        self._call_later = call_later
        self.incarnation = incarnation

    def call_later(self, delay: float, fn: Callable[[], None]) -> None:
        """Run ``fn`` on this component's thread after ``delay`` seconds, between messages and actions.

        Long work cut into pieces this way lets an action (``stop``, ``say``)
        come in between two pieces. Needs a runtime that gave ``call_later`` to :meth:`attach`.
        """
        if self._call_later is None:
            raise RuntimeError(f"{self._label()}: attach(publisher, on_health, call_later) gave no call_later; "
                               "run it under embagents supervise, or pass one")
        self._call_later(delay, fn)

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        """Store a received message; True when it triggers a step (then call :meth:`execute`).

        ``now`` is a monotonic time in seconds (for tests of ``input_max_age_s``).
        """
        if topic_name not in self._subscribed:
            return False
        self._latest[topic_name] = msg
        self._received_at[topic_name] = time.monotonic() if now is None else now
        self._fresh.add(topic_name)
        queue = self._queues.get(topic_name)
        if queue is not None:
            if len(queue) >= self.queued[topic_name]:
                queue.popleft()
                self.dropped[topic_name] += 1
                if self.dropped[topic_name] == 1:
                    self.logger.warning("%s: queued input %r is full (%d messages since the last step): dropping "
                                        "the oldest; raise its bound or step faster (logged once)",
                                        self._label(), topic_name, self.queued[topic_name])
            queue.append(msg)
        if self.trigger_kind == "topics":
            return topic_name in self._trigger_names
        if self.trigger_event is not None:
            return self.trigger_event.check(topic_name, msg, now)
        return False

    @property
    def required_inputs(self) -> tuple[Topic, ...]:
        """The input topics that fill ``allowed_inputs["Required"]``: a step waits for them."""
        return tuple(self._required_inputs)

    @property
    def fresh_inputs(self) -> frozenset[str]:
        """Names of the input topics with a new message since the previous step."""
        return frozenset(self._fresh)

    def current_inputs(self, now: float | None = None) -> dict[str, Any]:
        """The latest message of every input topic (``None``: none yet, or too old); a queued input's list."""
        max_age = self.config.input_max_age_s
        now = time.monotonic() if now is None else now
        out: dict[str, Any] = {}
        for t in self.inputs:
            if isinstance(t, FixedInput):
                out[t.name] = t.message
                continue
            msg = self._latest.get(t.name)
            if msg is not None and max_age is not None and now - self._received_at[t.name] > max_age:
                msg = None
            queue = self._queues.get(t.name)
            out[t.name] = list(queue) if queue is not None and msg is not None else msg
        return out

    def missing_inputs(self, now: float | None = None, inputs: Mapping[str, Any] | None = None) -> list[str]:
        """Required input topics without a (recent enough) message; a step waits for them."""
        inputs = self.current_inputs(now) if inputs is None else inputs
        return [t.name for t in self._required_inputs if inputs.get(t.name) is None]

    def execute(self, now: float | None = None) -> bool:
        """Run one step if the required inputs are there; True when a step ran and succeeded.

        An exception in the step is logged and reported as ALGORITHM_FAILURE
        (the process keeps running); a step that does not set a status itself
        leaves the component HEALTHY. A module missing (ModuleNotFoundError) is
        a COMPONENT_FAILURE naming the extra that installs it, logged once: the
        component steps no more (no traceback a second for a module that will
        not appear).
        """
        if self._missing_module is not None:
            return False  # it failed for good: nothing to retry until the process restarts
        inputs = self.current_inputs(now)
        missing = self.missing_inputs(inputs=inputs)
        if missing and self.config.wait_for_inputs:
            for name in missing:
                if name not in self._waiting_logged:  # once: a rate trigger would say it every tick
                    self._waiting_logged.add(name)
                    self.logger.info("%s: a step waits for required input %r (no message yet); "
                                     "wait_for_inputs=False runs it with what is there", self._label(), name)
            return False
        for queue in self._queues.values():
            queue.clear()  # the step has them now
        return self.run_step(inputs)

    def run_step(self, inputs: Mapping[str, Any], fresh: Iterable[str] | None = None) -> bool:
        """Run one step on ``inputs`` (topic name -> message), as :meth:`execute` does; True when it succeeded.

        ``fresh``: the topics :attr:`fresh_inputs` names during the step (default: those received since the
        previous step). A model component replays a failed step this way on a new model client.
        """
        if fresh is not None:
            self._fresh = set(fresh)
        self._health_set_in_step = False
        self._fresh |= {t.name for t in self.inputs if isinstance(t, FixedInput)}  # new at every step
        try:
            self._execution_step(**inputs)
        except ModuleNotFoundError as exc:
            # Every later step would fail the same way: one failure naming the extra, no traceback a second.
            self._missing_module = exc.name or str(exc)
            text = (f"{self._label()}: its step needs the module {exc.name!r}, which is not installed: "
                    f"{install_hint(exc.name)}" if exc.name else f"{self._label()}: its step failed: {exc}")
            text += f"; it stops stepping (after installing: embagents restart {self.name})"
            self.logger.error("%s", text)
            self.set_component_failure(text)
            return False
        except Exception as exc:
            self.logger.exception("%s: step failed", self._label())
            self.set_algorithm_failure(f"{type(exc).__name__}: {exc}")
            return False
        finally:
            self._fresh.clear()
        if not self._health_set_in_step:
            self.set_healthy()
        return True

    def _execution_step(self, **inputs: Any) -> None:
        """One step of work: read ``inputs``, :meth:`publish` results. Override this."""
        raise NotImplementedError(f"{type(self).__name__} must implement _execution_step(self, **inputs)")

    def output(self, topic: Topic | str) -> Topic:
        """The output Topic named ``topic`` (a Topic or its name)."""
        name = topic.name if isinstance(topic, Topic) else str(topic).lstrip("/")
        for t in self.outputs:
            if t.name == name:
                return t
        outputs = ", ".join(t.name for t in self.outputs) or "none"
        raise ValueError(f"{self._label()} has no output topic {name!r}; outputs: {outputs}")

    def publish(self, topic: Topic | str, msg: Any) -> None:
        """Publish ``msg`` on one of this component's output topics (checked by type)."""
        out = self.output(topic)
        if not isinstance(msg, out.msg_type):
            raise TypeError(
                f"{self._label()}: output topic {out.name!r} expects {out.type_name}, "
                f"got {type(msg).__name__}"
            )
        if self._publisher is None:
            raise RuntimeError(f"{self._label()} is not attached to a runtime; call attach(publisher) first")
        self._publisher(out.name, msg)

    # --- health ---------------------------------------------------------------------------

    @property
    def health(self) -> Health:
        """The latest health report."""
        return self._health

    @property
    def health_status(self) -> HealthStatus:
        """The current status; assign a HealthStatus (or its name) to change it."""
        return self._health.status

    @health_status.setter
    def health_status(self, status: HealthStatus | str) -> None:
        self._set_health(HealthStatus.parse(status), "")

    def _set_health(self, status: HealthStatus, text: str) -> None:
        changed = status != self._health.status or text != self._health.text
        self._health = Health(component=str(self.name), status=status, text=text, stamp=time.time(),
                              incarnation=self.incarnation, switches=self.client_switches)
        self._health_set_in_step = True
        # Every failure is reported (fallbacks act once per sender); recovery once, and an incarnation's
        # first status always (a healthy replacement ends its failure episode: the fallback's counts reset).
        if self._on_health is not None and (status != HealthStatus.HEALTHY or changed or not self._health_reported):
            self._health_reported = True
            self._on_health(self._health)

    def set_healthy(self) -> None:
        """Report HEALTHY."""
        self._set_health(HealthStatus.HEALTHY, "")

    def set_algorithm_failure(self, text: str = "") -> None:
        """Report that the algorithm failed (bad input, unusable result, exception)."""
        self._set_health(HealthStatus.ALGORITHM_FAILURE, text)

    def set_component_failure(self, text: str = "") -> None:
        """Report that this component is broken (e.g. its model client is gone)."""
        self._set_health(HealthStatus.COMPONENT_FAILURE, text)

    def set_system_failure(self, text: str = "") -> None:
        """Report that something outside this component is broken (a device, the network)."""
        self._set_health(HealthStatus.SYSTEM_FAILURE, text)

    # --- lifecycle and state ----------------------------------------------------------------

    def on_configure(self) -> None:
        """unconfigured -> inactive: load resources (models, devices). No-op by default."""

    def on_activate(self) -> None:
        """inactive -> active: steps start after this. No-op by default."""

    def on_deactivate(self) -> None:
        """active -> inactive: steps stop before this. No-op by default."""

    def on_cleanup(self) -> None:
        """inactive -> unconfigured: release what on_configure took. No-op by default."""

    def on_shutdown(self) -> None:
        """Any state -> finalized: last chance to release resources. No-op by default."""

    def on_reconfigure(self, old_config: Any) -> None:
        """Called after :meth:`reconfigure` replaced ``self.config``. No-op by default."""

    def reconfigure(self, overrides: Mapping[str, Any]) -> Any:
        """Apply config overrides (validated; the component is re-validated too) and return the new config."""
        old = self.config
        new = apply_config(old, overrides)
        self.config = new
        problems = [p for p in self.validate() if p not in self.problems]
        if problems:
            self.config = old
            raise ComponentError(str(self.name), problems)
        self._apply_log_level()
        self.on_reconfigure(old)
        return new

    def _apply_log_level(self) -> None:
        # config.log_level is this component's logger level (its own lines: step failures, client switches).
        self.logger.setLevel(getattr(self.config, "log_level", "info").upper())

    def snapshot(self) -> Any:
        """State (plain msgpack-able data) a restarted incarnation should get back; ``None``: nothing."""
        return None

    def restore(self, state: Any) -> None:
        """Take back what :meth:`snapshot` returned before a restart. No-op by default."""
