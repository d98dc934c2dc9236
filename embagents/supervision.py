"""The supervision tree that runs a System: model actors, the ROS bridge, components, managers, events.

``embagents supervise`` starts it; ``embagents check`` builds it too, so a
system that passes the check passes every rule of :mod:`supervisor.spec`
(one truth). Kept apart from :mod:`embagents.cli.supervise` so the check does not
import the launcher.

Example::

    >>> from embagents.system import System
    >>> spec = build_spec(System(name="empty", components=[]), "system.py")   # doctest: +SKIP
    >>> spec.strategy                                                         # doctest: +SKIP
    'one_for_one'
"""

from __future__ import annotations

from collections.abc import Collection
from typing import TYPE_CHECKING, Any

from embagents.components.llm_tools import uses_events_actor as needs_it
from embagents.models import models_of
from embagents.models.actor import ModelActor
from embagents.requests import EVENTS_ACTOR
from embagents.ros.bridge_actor import BRIDGE_NAME, RosBridgeActor
from embagents.runtime.agent_actor import AgentActor
from embagents.runtime.component_actor import ComponentActor
from embagents.runtime.events_actor import EventsActor
from embagents.runtime.manager_actor import ManagerActor
from embagents.zenoh.bridge_actor import BRIDGE_NAME as ZENOH_BRIDGE
from embagents.zenoh.bridge_actor import ZenohBridgeActor
from supervisor import ChildSpec, SupervisorSpec

if TYPE_CHECKING:  # for the annotation only: embagents.system imports most of the package
    from embagents.system import System

__all__ = ["EVENTS_NAME", "HEARTBEAT_S", "MODEL_HEARTBEAT_S", "build_spec", "uses_events_actor", "wiring"]

#: The events actor's name.
EVENTS_NAME = EVENTS_ACTOR
#: Hang deadlines: a component's loop must beat this often; a model's, per token.
HEARTBEAT_S = 30.0
MODEL_HEARTBEAT_S = 120.0


def uses_events_actor(system: System) -> bool:
    """Whether the system runs the events actor (events, fallbacks, LLM tools, route actions)."""

    return bool(system.events) or any(getattr(c, "fallback", None) or needs_it(c) for c in system.components)


def wiring(system: System) -> dict[str, dict[str, tuple[str, ...]]]:
    """The components that wait for their subscribers: name -> {output topic: the children declared to subscribe}.

    Subscribers are the other components and managers that read the topic, the
    events actor for event topics and the ROS bridge for RosOutputs. A
    component with none, or with ``config.wait_for_subscribers`` false, is not
    listed: it is activated as it starts, in list order. The others start
    inactive, and ``embagents supervise`` activates each once its subscribers
    are connected and active (see :mod:`embagents.cli.supervise`).
    """
    subs: dict[str, list[str]] = {}

    def add(topic: str, child: str) -> None:
        subs.setdefault(topic, []).append(child)

    for c in system.components:
        for t in c.subscriptions:
            add(t.name, str(c.name))
    for m in getattr(system, "managers", ()):
        for node in m.nodes:
            for t in node.subscriptions:
                add(t.name, m.name)
    if system.events:
        for event, _ in system.events:
            for t in event.topics:
                add(t.name, EVENTS_NAME)
    for d in system.ros:
        if type(d).__name__ == "RosOutput" and isinstance(getattr(d, "topic", None), str):

            add(d.topic, BRIDGE_NAME)
    out: dict[str, dict[str, tuple[str, ...]]] = {}
    for c in system.components:
        if not getattr(c.config, "wait_for_subscribers", True):
            continue
        waits = {t.name: tuple(dict.fromkeys(s for s in subs.get(t.name, ()) if s != c.name)) for t in c.outputs}
        waits = {topic: who for topic, who in waits.items() if who}
        if waits:
            out[str(c.name)] = waits
    return out


def build_spec(system: System, path: str, resolved: dict[str, str] | None = None, *,
               activate_later: Collection[str] = ()) -> Any:
    """The supervision tree of a System: model actors, the ROS bridge, components, events.

    ``resolved`` maps each model's name to its local file (``Model.resolve()``).
    ``activate_later``: components that start inactive, for the caller to activate
    (``embagents supervise`` passes :func:`wiring`'s; the others start active).
    Without it (``embagents check``) each model's name stands in for its file:
    the tree is built, so every rule of ``supervisor.spec`` is applied, and
    nothing is downloaded. Raises ``ValueError`` / ``TypeError`` naming the rule.
    """

    children = []
    for m in models_of(system):
        batch = {"max_batch": m.max_batch, "batch_wait_ms": m.batch_wait_ms}
        args = (m.kind, (resolved or {}).get(m.name, m.name), m.options(), m.warmup, batch)
        # A model beats per token; a long prompt evaluation is work, not a hang.
        children.append(ChildSpec(m.name, (ModelActor, args), heartbeat=MODEL_HEARTBEAT_S, start_timeout=600,
                                  standby=m.standby, start_method=m.start_method))
    if system.ros:

        children.append(ChildSpec(BRIDGE_NAME, (RosBridgeActor, (path,)), heartbeat=HEARTBEAT_S, start_timeout=60))
    if getattr(system, "zenoh", None) is not None:

        children.append(ChildSpec(ZENOH_BRIDGE, (ZenohBridgeActor, (path,)), heartbeat=HEARTBEAT_S, start_timeout=60))
    for c in system.components:
        # config.step_timeout_s is the component's hang deadline: a longer step gets it killed and restarted.
        heartbeat = getattr(c.config, "step_timeout_s", None) or HEARTBEAT_S
        children.append(ChildSpec(str(c.name), (ComponentActor, (path, str(c.name))), heartbeat=heartbeat,
                                  lifecycle="inactive" if str(c.name) in activate_later else "active",
                                  snapshot_interval=0.5, start_timeout=120,
                                  standby=getattr(c, "standby", False), start_method=getattr(c, "start_method", "fork")))
    for mgr in getattr(system, "managers", ()):

        for agent in mgr.agents:
            if agent.isolated:  # started first: the manager's first call finds it
                children.append(ChildSpec(agent.actor_name, (AgentActor, (path, mgr.name, agent.name)),
                                          heartbeat=agent.heartbeat, nice=agent.nice,
                                          cpu_affinity=agent.cpu_affinity, start_timeout=120))
        # The loop beats every tick: a tick longer than hang_timeout is a hang. Snapshots after each changed tick.
        children.append(ChildSpec(mgr.name, (ManagerActor, (path, mgr.name)), heartbeat=mgr.hang_timeout,
                                  lifecycle="active", snapshot_interval=0.0, start_timeout=120))
    # The events actor also carries LLM tool calls and route actions across processes.
    if uses_events_actor(system):
        children.append(ChildSpec(EVENTS_NAME, (EventsActor, (path,)), heartbeat=HEARTBEAT_S))
    sup = system.supervision
    return SupervisorSpec(strategy=sup["strategy"], intensity=sup["intensity"], period=sup["period"], children=children)
