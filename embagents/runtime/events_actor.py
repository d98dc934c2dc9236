"""Evaluates a System's events and fallbacks, and carries out their actions.

One actor per system (``_events``) subscribes to every topic an event
condition reads and to ``_health`` (each component's health reports). When
an event fires, or a component's fallback decides on a failure report, the
action runs:

- ``publish``: publish the message on the topic;
- ``call`` / ``reconfigure`` / ``switch_model_client``: a tell to the
  component's actor (its next incarnation gets it if it is restarting);
- ``start`` / ``stop`` / ``restart`` / ``give_up``: a
  :class:`~embagents.requests.SupervisorRequest` on the
  ``_supervisor_requests`` topic, carried out by the root's supervisor.

A fallback acts once per failing incarnation: a health report carries its
sender's incarnation (and model client switches), and reports from a sender
already acted on (its restart or switch pending) or from an older one are
ignored, so a component failing at 30 Hz while its replacement loads is
restarted once.

It also runs an LLM's tool calls (:class:`~embagents.requests.ToolCall`,
see :mod:`embagents.components.llm_tools`): the arguments are checked against the method's
signature here, then the component's actor is asked and its result answered;
and a router's route actions (:class:`~embagents.requests.RouteFired`).
"""

from __future__ import annotations

import copy
import logging
from collections import defaultdict
from functools import partial
from typing import Any

from actors import Actor, ActorNotFound
from actors.errors import UnknownMessage
from embagents.requests import (
    SUPERVISOR_REQUESTS,
    Call,
    ChangeModelClient,
    Reconfigure,
    RouteFired,
    SupervisorRequest,
    ToolCall,
)
from embagents.system import loaded_system

__all__ = ["EventsActor"]

log = logging.getLogger("embagents.events")
HEALTH_TOPIC = "_health"


class EventsActor(Actor):
    """Runs the events and fallbacks of the system loaded from ``system_path``."""

    def __init__(self, system_path: str) -> None:
        self.system_path = system_path

    #: How long a tool call may take in the component (a memory query, a picture).
    TOOL_TIMEOUT_S = 60.0

    def on_start(self) -> None:
        system = loaded_system(self.system_path)
        self.system = system
        self.events = system.events
        # One Fallback per component: one object given to two components must not share their counts.
        self.fallbacks = {c.name: copy.deepcopy(c.fallback) for c in system.components if getattr(c, "fallback", None)}
        self.ignored: dict[str, int] = defaultdict(int)  # reports from senders already acted on, per component
        self.fired: list[dict[str, Any]] = []
        by_topic: dict[str, list[tuple[Any, Any]]] = defaultdict(list)
        for event, actions in self.events:
            for t in event.topics:
                by_topic[t.name].append((event, actions))
        for name, pairs in by_topic.items():
            self.context.subscribe(name, partial(self._on_message, name, pairs), queue_size=100, keep="all")
        self.context.subscribe(HEALTH_TOPIC, self._on_health, queue_size=100, keep="all")

    def _on_message(self, topic: str, pairs: list[tuple[Any, Any]], msg: Any) -> None:
        for event, actions in pairs:
            if event.check(topic, msg):
                log.info("event %r fired on %s", event.name, topic)
                for action in actions:
                    self.run_action(action, because=f"event {event.name!r}")

    def _on_health(self, health: Any) -> None:
        fallback = self.fallbacks.get(health.component)
        if fallback is None:
            return
        # Outside a supervised run (incarnation 0) every report counts.
        sender = (health.incarnation, health.switches) if health.incarnation else None
        action = fallback.decide(health.status, health.component, sender)
        if action is None and sender is not None and health.status and fallback.rules[health.status.name]:
            self.ignored[health.component] += 1  # its restart or switch is pending
        if action is not None:
            self.run_action(action, because=f"{health.component} reported {health.status.name}: {health.text}")

    def run_action(self, action: Any, *, because: str) -> None:
        d = action.to_dict()
        kind, comp, args = d["kind"], d["component"], d["args"]
        self.fired.append({"kind": kind, "component": comp, "because": because})
        log.info("action %s on %s (%s)", kind, comp, because)
        try:
            if kind == "publish":
                topic = args["topic"]
                self.context.publish(getattr(topic, "name", topic), args["msg"])
            elif kind == "call":
                self.context.ref(comp).tell(Call(args["method"], args.get("args") or (), args.get("kwargs") or {}))
            elif kind == "reconfigure":
                self.context.ref(comp).tell(Reconfigure(args["overrides"]))
            elif kind == "switch_model_client":
                self.context.ref(comp).tell(ChangeModelClient(args["client"]))
            else:  # start / stop / restart / give_up: the supervisor's business
                self.context.publish(SUPERVISOR_REQUESTS, SupervisorRequest(kind, comp, because))
        except ActorNotFound as exc:
            log.error("action %s failed: %s", kind, exc)

    def run_tool(self, call: ToolCall) -> Any:
        """Check ``call``'s arguments against the method, then ask the component's actor to run it."""
        import inspect

        try:
            comp = self.system.component(call.component)
        except (KeyError, ValueError) as exc:
            raise LookupError(f"tool {call.method!r}: no component {call.component!r} in this system ({exc})") from None
        fn = getattr(comp, call.method, None)
        if not callable(fn) or call.method.startswith("_"):
            raise LookupError(f"component {call.component!r} has no action {call.method!r}")
        sig = inspect.signature(fn)
        try:
            sig.bind(**call.kwargs)
        except TypeError as exc:
            shown = ", ".join(str(p).replace("'", "") for p in sig.parameters.values())
            raise TypeError(f"bad arguments for {call.method}({shown}): {exc}; got {call.kwargs!r}") from None
        log.info("tool call %s.%s(%s)", call.component, call.method,
                 ", ".join(f"{k}={v!r}" for k, v in call.kwargs.items()))
        result = self.context.ref(call.component).ask(Call(call.method, [], call.kwargs)).get(timeout=self.TOOL_TIMEOUT_S)
        log.info("tool %s.%s answered %.200r", call.component, call.method, result)
        return result

    def route_fired(self, msg: RouteFired) -> None:
        comp = self.system.component(msg.component)
        for action in getattr(comp, "route_actions", {}).get(msg.route, ()):
            self.run_action(action, because=f"router {msg.component!r} routed {msg.text!r:.60} to {msg.route!r}")

    def on_receive(self, message: Any) -> Any:
        if isinstance(message, ToolCall):
            return self.run_tool(message)
        if isinstance(message, RouteFired):
            return self.route_fired(message)
        if message == "fired":
            return list(self.fired)
        if message == "ignored":
            return dict(self.ignored)
        raise UnknownMessage("the events actor", message, "it answers 'fired' and 'ignored'")
