"""Runs one Component of a System as an actor.

The System was loaded in the root before the fork server started, so the
component object is already in this process's memory: the actor finds it
by name, wires its input topics to subscriptions, its outputs to
publishers, and drives its trigger (topics, an event, or a rate in Hz on
absolute deadlines, by the rule of :mod:`embagents.realtime`: a late tick runs at
once, whole missed periods are skipped; a tick starts within a fraction of a ms of its deadline).
"""

from __future__ import annotations

import logging
import time
from functools import partial
from typing import TYPE_CHECKING, Any, cast

from actors import Actor
from actors.errors import UnknownMessage
from embagents.realtime import next_deadline
from embagents.requests import Call, ChangeModelClient, HealthQuery, Reconfigure
from embagents.system import loaded_system

if TYPE_CHECKING:
    from embagents.components.model_component import ModelComponent

__all__ = ["ComponentActor"]

log = logging.getLogger("embagents.runtime")
#: A rate tick's timer fires this much before its deadline, and the tick sleeps the rest: the actor
#: loop's timers wait in whole milliseconds (rounded up), which alone would make ticks up to 1 ms late.
_EARLY_S = 0.001
class ComponentActor(Actor):
    """Hosts component ``name`` of the system loaded from ``system_path``."""

    def __init__(self, system_path: str, name: str) -> None:
        self.system_path = system_path
        self.component_name = name

    def on_start(self) -> None:
        comp = loaded_system(self.system_path).component(self.component_name)
        self.component = comp
        if getattr(self, "_restored", None) is not None:
            comp.restore(self._restored)
        self.active = False
        self._timer: int | None = None
        ctx = self.context
        comp.attach(lambda topic, msg: ctx.publish(topic, msg), lambda h: ctx.publish("_health", h),
                    lambda delay, fn: ctx.call_later(delay, self._guarded(fn)), incarnation=ctx.incarnation)
        for t in comp.subscriptions:
            ctx.subscribe(
                t.name,
                partial(self._on_message, t.name),
                queue_size=getattr(t, "queue_size", 10),
                keep=getattr(t, "keep", "latest"),
                msg_type=t.msg_type if isinstance(t.msg_type, type) else None,
            )
        if ctx.extension("lifecycle") is None:
            # Not managed by a supervisor: bring it up ourselves.
            self.on_configure()
            self.on_activate()

    def on_standby(self) -> None:
        # A warm standby (supervisor.standby): configure now, while the active incarnation serves; the
        # component has no publisher yet (publishing belongs in on_activate or a step).
        loaded_system(self.system_path).component(self.component_name).on_configure()
        self._configured_ahead = True

    # -- lifecycle (ROS 2 managed-node transitions, driven by the supervisor) --
    def on_configure(self) -> None:
        if getattr(self, "_configured_ahead", False):  # done by on_standby before the takeover
            self._configured_ahead = False
            return
        self.component.on_configure()

    def on_activate(self) -> None:
        self.component.on_activate()
        self.active = True
        rate = self.component.rate_hz
        if rate:
            self._period = 1.0 / rate
            self._next = time.monotonic() + self._period
            self._timer = self.context.call_later(max(0.0, self._period - _EARLY_S), self._tick)

    def on_deactivate(self) -> None:
        self.active = False
        if self._timer is not None:
            self.context.cancel(self._timer)
            self._timer = None
        self.component.on_deactivate()

    def on_cleanup(self) -> None:
        self.component.on_cleanup()

    def on_shutdown(self) -> None:
        self.component.on_shutdown()

    def _guarded(self, fn: Any) -> Any:
        """``fn`` as a timer callback: a raise is the component's failure (logged, on health), not the actor's."""
        def run() -> None:
            try:
                fn()
            except Exception as exc:
                self.component.logger.exception("%s: a scheduled call failed", self.component._label())
                self.component.set_algorithm_failure(f"{type(exc).__name__}: {exc}")
            self.context.changed()

        return run

    def _on_message(self, topic: str, msg: Any) -> None:
        if self.component.on_message(topic, msg) and self.active and self.component.execute():
            self.context.changed()

    def _tick(self) -> None:
        if not self.active:
            return
        early = self._next - time.monotonic()
        if early > 0:
            time.sleep(early)  # the last fraction of a ms: the loop's timers wake in whole ms
        if self.component.execute():
            self.context.changed()
        now = time.monotonic()
        self._next, _ = next_deadline(self._next, self._period, now)  # late: at once, missed periods skipped
        self._timer = self.context.call_later(max(0.0, self._next - now - _EARLY_S), self._tick)

    def on_receive(self, message: Any) -> Any:
        comp = self.component
        if isinstance(message, Call):
            late = 0.0 if message.deadline is None else time.monotonic() - message.deadline
            if late > 0:  # its caller gave up and said so: running it now would surprise them
                comp.logger.warning("%s: call of %s not run: its deadline passed %.2f s before its turn",
                                    comp._label(), message.method, late)
                raise TimeoutError(f"{message.method} not run: its deadline passed {late:.2f} s before its turn")
            method = getattr(comp, message.method, None) if isinstance(message.method, str) else None
            if not callable(method):
                raise UnknownMessage(f"component {self.component_name!r}", message,
                                     f"{type(comp).__name__} has no method {message.method!r}")
            return method(*message.args, **message.kwargs)
        if isinstance(message, HealthQuery):
            return {"status": int(comp.health_status), "text": comp.health.text}
        if isinstance(message, Reconfigure):
            comp.reconfigure(message.overrides)
            return None
        if isinstance(message, ChangeModelClient):
            # Another component has no change_model_client: the AttributeError goes back to the caller.
            return cast("ModelComponent", comp).change_model_client(message.client)
        raise UnknownMessage(f"component {self.component_name!r}", message, "send one of embagents.requests: "
                             "Call, HealthQuery, Reconfigure, ChangeModelClient")

    def snapshot(self) -> Any:
        return self.component.snapshot()

    def restore(self, state: Any) -> None:
        # Called before on_start (by the supervisor's snapshot hook): keep it until the component is found.
        self._restored = state

    def on_stop(self) -> None:
        if self.active:
            self.on_deactivate()
        self.component.on_shutdown()
