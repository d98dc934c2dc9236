"""Runs a :class:`~embagents.manager.Manager` of a System as a supervised actor.

The loop runs in this actor's process, on its IO thread, as timers on
absolute deadlines (the rule of :mod:`embagents.realtime`): the handshake is
checked at the loop rate, then every tick runs the handlers. Between ticks
the thread polls its sockets, so node subscriptions and isolated agents'
answers arrive between ticks, never during one, and the heartbeat is beaten
after every tick: a handler that hangs stops the beat and the supervisor
kills and restarts the manager (its ``hang_timeout``). The lifecycle decides
whether it ticks (active) or pauses (inactive). After every tick that
changed the shared state or a state machine (and at least every
:data:`SNAPSHOT_EVERY_S`), a snapshot is taken, so a restarted manager
resumes where it was (``on_restart="resume"``).

A handshake still unmet after ``handshake_timeout`` is logged with the rules
still unmet and reported on health (``SYSTEM_FAILURE``); the manager keeps
waiting, and reports healthy once it completes.

Example::

    >>> ManagerActor("system.py", "pick_place").manager_name           # doctest: +SKIP
    'pick_place'
"""

from __future__ import annotations

import gc
import logging
import os
import time
from collections.abc import Callable
from typing import Any

from actors import Actor, Codec
from actors.errors import UnknownMessage
from embagents.manager.handshake import HandshakeProgress
from embagents.manager.nodes import Node
from embagents.msgs import Health, HealthStatus
from embagents.realtime import next_deadline
from embagents.requests import Call, HealthQuery
from embagents.system import loaded_system

__all__ = ["SNAPSHOT_EVERY_S", "ManagerActor"]

log = logging.getLogger("embagents.runtime.manager")
#: The tick counter alone is snapshotted at least this often (state changes at once).
SNAPSHOT_EVERY_S = 0.5
#: The loop's poll waits in whole milliseconds, rounded up: the tick's timer is set this much early and
#: the last fraction is slept, so a tick starts on its deadline, not up to 1 ms after it.
EARLY_S = 0.0015
HEALTH_TOPIC = "_health"
_codec = Codec()


class ManagerActor(Actor):
    """Hosts manager ``name`` of the system loaded from ``system_path``."""

    def __init__(self, system_path: str, name: str) -> None:
        self.system_path = system_path
        self.manager_name = name
        self._restored: dict[str, Any] | None = None

    def on_start(self) -> None:
        m = loaded_system(self.system_path).manager(self.manager_name)
        self.manager = m
        self.active = False
        self.ticking = False
        self.stopped = False
        self._timer: int | None = None
        self._progress: HandshakeProgress | None = None
        self._reported_timeout = False
        self._health = (HealthStatus.HEALTHY, "starting")
        self._snap_key: Any = None
        self._snap_at = 0.0
        self._unencodable: set[str] = set()
        self._window = (0.0, 0, 0)  # rate logging: start, ticks, overruns
        ctx = self.context
        for node in m.nodes:
            node.bind(ctx.publish)
            for t in node.subscriptions:
                ctx.subscribe(t.name, self._deliverer(node, t.name), queue_size=t.queue_size, keep=t.keep,
                              msg_type=t.msg_type)
        agents = ", ".join(f"{a.name} ({'isolated' if a.isolated else 'attached'})" for a in m.agents) or "none"
        m.logger.info("pid %d: %g Hz, handlers %s; nodes %s; agents %s", os.getpid(), m.rate_hz,
                      ", ".join(h.name for h in m.handlers) or "none", ", ".join(n.name for n in m.nodes) or "none",
                      agents)
        if self._restored is not None:
            m.restore(self._restored)
        m.start_agents()
        # Everything this process inherited or built so far lives as long as it does: out of the collector's
        # sight, a full collection no longer walks the whole heap (about 5 ms for the 36,000 objects of a
        # loaded system: a tick's worth of jitter at 100 Hz).
        gc.freeze()
        if ctx.extension("lifecycle") is None:  # not supervised: bring it up ourselves
            self.on_activate()

    # -- topics -----------------------------------------------------------------------
    def _deliverer(self, node: Node, topic: str) -> Callable[[Any], None]:
        return lambda msg: self._on_message(node, topic, msg)

    def _on_message(self, node: Node, topic: str, msg: Any) -> None:
        try:
            node.deliver(topic, msg)
        except Exception:
            log.exception("node %r failed in on_message for a message on %r", node.name, topic)
        self.manager.state.mark_received(topic)

    # -- lifecycle (driven by the supervisor) ---------------------------------------
    def on_activate(self) -> None:
        self.active = True
        if self.stopped:
            return
        self._next = time.monotonic()
        self._timer = self.context.call_later(0.0, self._step)
        if self.ticking:
            log.info("active: manager %r ticks again from tick %d", self.manager.name, self.manager.tick)

    def on_deactivate(self) -> None:
        self.active = False
        if self._timer is not None:
            self.context.cancel(self._timer)
            self._timer = None
        log.info("inactive: manager %r pauses at tick %d", self.manager.name, self.manager.tick)

    # -- the loop -----------------------------------------------------------------------
    def _step(self) -> None:
        self._timer = None
        if not self.active or self.stopped:
            return
        early = self._next - time.monotonic()
        if self.ticking and early > 0:
            time.sleep(min(early, EARLY_S))  # the last fraction of a millisecond or so: a short sleep, no busy wait
        m = self.manager
        if not self.ticking and not self._handshake(m):
            self._timer = self.context.call_later(m.period, self._step)
            return
        if not m.tick_once():  # on_handler_error="stop" (raise/crash propagate: the actor crashes)
            self.stopped = True
            self._set_health(HealthStatus.COMPONENT_FAILURE,
                             f"stopped at tick {m.tick}: a handler failed (on_handler_error='stop')")
            m.shutdown()
            return
        self._maybe_snapshot(m)
        now = time.monotonic()
        self._next, overran = next_deadline(self._next, m.period, now)
        if overran:
            m.overruns += 1
        if m.log_rate_every is not None:
            self._log_rate(m, now)
        self._timer = self.context.call_later(max(0.0, self._next - now - EARLY_S), self._step)

    def _log_rate(self, m: Any, now: float) -> None:
        start, ticks, overruns = self._window
        ticks += 1
        if now - start >= m.log_rate_every:
            m.log_rate(ticks / (now - start), m.overruns - overruns, now - start)
            self._window = (now, 0, m.overruns)
        else:
            self._window = (start, ticks, overruns)

    def _handshake(self, m: Any) -> bool:
        if self._progress is None:
            self._progress = HandshakeProgress(m.handshake, m.logger)
        progress = self._progress
        if progress.check(m.state):
            self.ticking = True
            m.start_handlers()
            self._set_health(HealthStatus.HEALTHY, f"ticking at {m.rate_hz:g} Hz")
            self._next = time.monotonic()
            self._window = (self._next, 0, m.overruns)
            return True
        timeout = m.handshake_timeout
        if timeout is not None and not self._reported_timeout and time.monotonic() - progress.start >= timeout:
            self._reported_timeout = True
            text = f"{progress.timeout_error(timeout)}; still waiting"
            m.logger.error("%s", text)
            self._set_health(HealthStatus.SYSTEM_FAILURE, text)
        return False

    def _maybe_snapshot(self, m: Any) -> None:
        key = (m.state.revision, [h.snapshot() for h in m.handlers])
        now = time.monotonic()
        if key != self._snap_key or now - self._snap_at >= SNAPSHOT_EVERY_S:
            self._snap_key, self._snap_at = key, now
            self.context.changed()

    def _set_health(self, status: HealthStatus, text: str) -> None:
        if (status, text) == self._health:
            return
        self._health = (status, text)
        self.context.publish(HEALTH_TOPIC, Health(component=self.manager.name, status=status, text=text,
                                                  stamp=time.time(), incarnation=self.context.incarnation))

    # -- requests --------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """Tick, handlers' states, overruns, achieved rate (``log_rate_every``), health, handshake rules unmet."""
        m = self.manager
        return {
            "tick": m.tick,
            "ticking": self.ticking and self.active and not self.stopped,
            "states": {h.name: getattr(h, "current", None) for h in m.handlers},
            "overruns": m.overruns,
            "rate_hz": m.achieved_rate,
            "status": int(self._health[0]),
            "text": self._health[1],
            "unmet": [r.name for r in self._progress.pending] if self._progress else [],
            "incarnation": self.context.incarnation,
        }

    def on_receive(self, message: Any) -> Any:
        if isinstance(message, HealthQuery):
            return {"status": int(self._health[0]), "text": self._health[1]}
        if isinstance(message, Call) and message.method == "status":
            return self.status()
        if isinstance(message, Call) and message.method == "state":
            return self._encodable(self.manager.state.kept())
        raise UnknownMessage(f"manager {self.manager_name!r}", message, "send HealthQuery(), Call('status') or Call('state')")

    # -- snapshots -------------------------------------------------------------------
    def snapshot(self) -> Any:
        snap = self.manager.snapshot()
        try:
            _codec.encode(snap, shm=False)
        except Exception:
            snap["state"] = self._encodable(snap["state"])
        return snap

    def _encodable(self, values: dict[str, Any]) -> dict[str, Any]:
        kept = {}
        for key, value in values.items():
            try:
                _codec.encode(value, shm=False)
            except Exception as exc:
                if key not in self._unencodable:
                    self._unencodable.add(key)
                    log.warning("state[%r] is not kept across restarts: %s (keep plain data, numpy arrays or "
                                "registered message classes in the state)", key, exc)
            else:
                kept[key] = value
        return kept

    def restore(self, state: Any) -> None:
        # Called before on_start (the supervisor's snapshot hook): kept until the manager is found.
        self._restored = state

    def on_stop(self) -> None:
        if self.active:
            self.on_deactivate()
        self.manager.shutdown()
