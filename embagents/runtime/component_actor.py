"""Runs one Component of a System as an actor.

The System was loaded in the root before the fork server started, so the
component object is already in this process's memory: the actor finds it
by name, wires its input topics to subscriptions, its outputs to
publishers, and drives its trigger (topics, an event, or a rate in Hz on
absolute deadlines).
"""

from __future__ import annotations

import logging
import time
from typing import Any

from actors import Actor

__all__ = ["ComponentActor", "loaded_system", "remember_system"]

log = logging.getLogger("embagents.runtime")
_SYSTEMS: dict[str, Any] = {}


def remember_system(path: str, system: Any) -> None:
    """Keep the loaded System so forked actor processes find it without re-importing."""
    _SYSTEMS[path] = system


def loaded_system(path: str) -> Any:
    system = _SYSTEMS.get(path)
    if system is None:
        from embagents.system import load_system

        system = _SYSTEMS[path] = load_system(path)
    return system


class ComponentActor(Actor):
    """Hosts component ``name`` of the system loaded from ``system_path``."""

    def __init__(self, system_path: str, name: str) -> None:
        self.system_path = system_path
        self.component_name = name

    def on_start(self) -> None:
        comp = loaded_system(self.system_path).component(self.component_name)
        self.component = comp
        ctx = self.context
        comp.attach(lambda topic, msg: ctx.publish(topic, msg), lambda h: ctx.publish("_health", h))
        for t in comp.subscriptions:
            ctx.subscribe(
                t.name,
                lambda msg, name=t.name: self._on_message(name, msg),
                queue_size=getattr(t, "queue_size", 10),
                keep=getattr(t, "keep", "latest"),
                msg_type=t.msg_type if isinstance(t.msg_type, type) else None,
            )
        comp.on_configure()
        comp.on_activate()
        rate = comp.rate_hz
        if rate:
            self._period = 1.0 / rate
            self._next = time.monotonic() + self._period
            ctx.call_later(self._period, self._tick)

    def _on_message(self, topic: str, msg: Any) -> None:
        if self.component.on_message(topic, msg):
            self.component.execute()

    def _tick(self) -> None:
        self.component.execute()
        now = time.monotonic()
        self._next += self._period
        if self._next < now:  # overran: skip missed ticks, keep the phase
            self._next += ((now - self._next) // self._period + 1) * self._period
        self.context.call_later(self._next - now, self._tick)

    def on_receive(self, message: Any) -> Any:
        comp = self.component
        op = message.get("op") if isinstance(message, dict) else message
        if op == "health":
            return {"status": int(comp.health_status), "text": comp.health.text}
        if op == "call":
            return getattr(comp, message["method"])(*message.get("args", ()), **message.get("kwargs", {}))
        if op == "reconfigure":
            comp.reconfigure(message["overrides"])
            return None
        if op == "change_model_client":
            return comp.change_model_client(message["client"])
        raise ValueError(
            f"component {self.component_name!r}: unknown request {message!r}; "
            "use 'health' or {'op': 'call'|'reconfigure'|'change_model_client', ...}"
        )

    def snapshot(self) -> Any:
        return self.component.snapshot()

    def restore(self, state: Any) -> None:
        self.component.restore(state)

    def on_stop(self) -> None:
        self.component.on_deactivate()
        self.component.on_shutdown()
