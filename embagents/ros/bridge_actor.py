"""The ROS 2 bridge actor: the one process of a system that imports rclpy.

It serves the ``RosInput`` / ``RosOutput`` declarations of a System:
incoming ROS messages are converted and published on internal topics (an
image's pixels are viewed in place on the ROS buffer and written once into
shared memory); internal topics declared as outputs are converted and
published to ROS. A thread of the ROS core takes the subscriptions' messages
and publishes them on the internal topics itself; rclpy's executor (services
called, actions, events) runs in another and hands its messages to the
actor's loop thread. Supervised like any actor: if it
crashes, its next incarnation creates its node, publishers and
subscriptions again, and the rest of the system never notices rclpy.

Rediscovery after a restart. Fast DDS answers a participant it has not
seen before with one immediate announcement; when that answer lands while
the new participant is still starting (its receivers not yet attached) it
is dropped, and the new bridge only learns of that peer at the peer's next
periodic announcement, up to 3 s later (by default: rclpy nodes cannot be
told to announce more often from here). Measured on this 2-core machine:
8 of 60 restarts hit it. So the bridge snapshots which of its ROS topics
have peers; an incarnation that does not see those peers again within
``REDISCOVER_AFTER`` seconds creates its DDS participant anew (a new
participant gets a new immediate answer), up to ``REDISCOVER_TRIES`` times.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Sequence
from functools import partial
from typing import Any

from actors import Actor, ActorRef, Deferred
from actors.errors import Timeout, UnknownMessage
from embagents.msgs import RosMessage
from embagents.requests import Call
from embagents.ros.fastdds_shm import clean_zombie_fastdds_segments, mapped_fastdds_files
from embagents.ros.spec import (
    BRIDGE_NAME,
    DEFAULT_ROS_TYPE,
    QoS,
    RosAction,
    RosCall,
    RosInput,
    RosLifecycle,
    RosOutput,
    RosService,
    ros_interface_class,
)
from embagents.system import loaded_system

__all__ = ["BRIDGE_NAME", "REDISCOVER_AFTER", "REDISCOVER_TRIES", "RosBridgeActor", "lifecycle_services"]

log = logging.getLogger("embagents.ros.bridge")
REDISCOVER_AFTER = 0.3  # s; a live local peer matches within 0.01-0.15 s when no answer is lost
REDISCOVER_TRIES = 5  # a lost answer is ~1 in 4-8 tries here: 5 in a row is rare
STOP_CHECK = 0.2  # s; a service request waiting for a component's answer sees the bridge stop within this


# lifecycle_msgs ids: states, and transitions (id -> our transition, the state it starts from).
_STATE_ID = {"unconfigured": 1, "inactive": 2, "active": 3, "finalized": 4}
_TRANSITIONS = {
    1: ("configure", "unconfigured"), 2: ("cleanup", "inactive"), 3: ("activate", "inactive"),
    4: ("deactivate", "active"), 5: ("shutdown", "unconfigured"), 6: ("shutdown", "inactive"),
    7: ("shutdown", "active"),
}
_GOAL = {"configure": "inactive", "cleanup": "unconfigured", "activate": "active", "deactivate": "inactive",
         "shutdown": "finalized"}
_AVAILABLE = {state: tuple(i for i, (_, start) in _TRANSITIONS.items() if start == state) for state in _STATE_ID}
_LIFECYCLE_METHODS = ("_ros_get_state", "_ros_change_state", "_ros_get_available_transitions")


def lifecycle_services(components: Sequence[str]) -> list[Any]:
    """The ``lifecycle_msgs`` services that make each component a ROS managed node (see RosLifecycle)."""

    out = []
    for c in components:
        for suffix, srv, method in (("get_state", "GetState", "_ros_get_state"),
                                    ("change_state", "ChangeState", "_ros_change_state"),
                                    ("get_available_transitions", "GetAvailableTransitions",
                                     "_ros_get_available_transitions")):
            out.append(RosService(f"/{c}/{suffix}", f"lifecycle_msgs/{srv}", component=c, method=method))
    return out


class _ServePlan:
    """What serving a RosService's requests needs, worked out at its first request."""

    __slots__ = ("has_fields", "ref", "status", "where")

    def __init__(self, decl: RosService, request_cls: Any, response_cls: Any) -> None:
        names = response_cls.get_fields_and_field_types()
        self.status = "success" in names and "message" in names  # std_srvs/Trigger, SetBool and the like
        self.has_fields = bool(request_cls.get_fields_and_field_types())
        self.ref = ActorRef(decl.component)
        self.where = f"ROS service {decl.ros_name} -> {decl.component}.{decl.method}"


def _describe(response: Any, tid: int) -> Any:
    d = ros_interface_class("lifecycle_msgs/msg/TransitionDescription")()
    what, start = _TRANSITIONS[tid]
    d.transition.id, d.transition.label = tid, what
    d.start_state.id, d.start_state.label = _STATE_ID[start], start
    d.goal_state.id, d.goal_state.label = _STATE_ID[_GOAL[what]], _GOAL[what]
    return d


class RosBridgeActor(Actor):
    """Bridges the ROS declarations of the system at ``system_path``.

    ``inputs`` / ``outputs`` may instead be given directly (as plain dicts of
    RosInput / RosOutput fields) for use outside a System (the benchmark).
    Its snapshot is the ROS topics that have peers (see the module docstring).
    """

    def __init__(
        self,
        system_path: str | None = None,
        node_name: str = "embagents_bridge",
        inputs: list[dict[str, Any]] | None = None,
        outputs: list[dict[str, Any]] | None = None,
        services: list[dict[str, Any]] | None = None,
    ) -> None:
        self.system_path = system_path
        self.node_name = node_name
        self.raw_inputs = inputs or []
        self.raw_outputs = outputs or []
        self.raw_services = services or []
        # Set by restore() from the last incarnation's snapshot:
        self.peer_ros_topics: frozenset[str] = frozenset()
        self.predecessor_dds_files: frozenset[str] = frozenset()  # its Fast DDS files in /dev/shm

    def _declarations(self) -> tuple[list[Any], list[Any], list[Any], list[Any]]:
        if self.system_path is not None:

            system = loaded_system(self.system_path)
            ins = [d for d in system.ros if isinstance(d, RosInput)]
            outs = [d for d in system.ros if isinstance(d, RosOutput)]
            services = [d for d in system.ros if isinstance(d, RosService)]
            for d in system.ros:
                if isinstance(d, RosLifecycle):
                    services += lifecycle_services(d.components or [str(c.name) for c in system.components])
            topics = system.topics
            outs = [
                o.resolved(topics[o.topic].msg_type)
                if o.ros_type is None and o.topic in topics and topics[o.topic].msg_type in DEFAULT_ROS_TYPE
                else o
                for o in outs
            ]
            return ins, outs, services, [d for d in system.ros if isinstance(d, RosAction)]

        def build(cls: type, d: dict[str, Any]) -> Any:
            d = dict(d)
            if "qos" in d:
                d["qos"] = QoS(**d["qos"])
            return cls(**d)

        return (
            [build(RosInput, d) for d in self.raw_inputs],
            [build(RosOutput, d) for d in self.raw_outputs],
            [build(RosService, d) for d in self.raw_services if "lifecycle" not in d]
            + lifecycle_services([d["lifecycle"] for d in self.raw_services if "lifecycle" in d]),
            [],
        )

    def on_start(self) -> None:
        from embagents.ros.node import RosBridgeCore  # lazy: heavy (builtin_interfaces)

        # A killed predecessor could not unlink its DDS segment and ports; their names say they are
        # not some other participant's half-made files, so they need no minimum age.
        if self.predecessor_dds_files:
            clean_zombie_fastdds_segments(min_age=0, names=self.predecessor_dds_files)
        self.dds_files: set[str] = set()

        ins, outs, services, actions = self._declarations()
        self.forwarded_in = 0
        self.forwarded_out = 0
        self.served = 0
        self._plans: dict[RosService, _ServePlan] = {}  # the services' thread's alone
        ctx = self.context
        # The services' thread asks components on links of its own and blocks on their socket: no hand-over
        # to the process's client IO thread and back (two wake-ups, ~90 us of a Trigger call's ~750).
        self.core = RosBridgeCore(ins, outs, services, self._serve, actions, flat=True,  # Imu: see node.py
                                  service_thread=ctx.thread_loop)
        expected, self.peers = set(self.peer_ros_topics), set(self.peer_ros_topics)

        # RosInputs' messages come from the core's subscription thread, which publishes them itself with
        # publishers of its own: a hand-over to our loop thread costs a wake-up (70-200 us under load,
        # a third of the Imu's latency). Any other thread's (action feedback and results) hands over.
        in_topics = {d.topic for d in ins}
        thread_pubs: dict[str, Any] = {}  # kept across core restarts: one taking thread at a time

        def from_ros(topic: str, msg: Any) -> None:
            if topic in in_topics:
                pub = thread_pubs.get(topic)
                if pub is None:
                    pub = thread_pubs[topic] = ctx.thread_publisher(topic)
                pub.publish(msg)
                self._count_in(topic)
                return
            ctx.call_soon_threadsafe(lambda: self._publish_in(topic, msg))

        # A fresh DDS participant id per incarnation (see configure_fastdds_shm): rediscovery at once.
        pid = 60 + self.context.incarnation % 50
        self.core.start(
            self.node_name,
            from_ros,
            shm_segment_mb=64,
            participant_id=pid,
            on_matched=lambda topic, n: ctx.call_soon_threadsafe(lambda: self._matched(topic, n)),
        )
        self.dds_files = mapped_fastdds_files()
        ctx.changed()
        for o in outs:
            ctx.subscribe(o.topic, partial(self._to_ros, o.topic), queue_size=o.qos.depth, keep="all")
        for a in actions:
            ctx.subscribe(a.goal, partial(self._send_goal, a.goal), queue_size=10, keep="all")
            if a.cancel:
                ctx.subscribe(a.cancel, partial(self._cancel_goals, a.goal), queue_size=10, keep="all")
        if expected:
            ctx.call_later(REDISCOVER_AFTER, lambda: self._rediscover(expected, 1))

    def _matched(self, topic: str, count: int) -> None:
        had = topic in self.peers
        if count > 0:
            self.peers.add(topic)
        else:
            self.peers.discard(topic)  # the peers left: a next incarnation need not look for them
        if had != (topic in self.peers):
            self.context.changed()

    def _rediscover(self, expected: set[str], attempt: int) -> None:
        matched = self.core.matched()
        missing = sorted(t for t in expected if not matched.get(t))
        if not missing:
            return
        if attempt > REDISCOVER_TRIES:
            log.warning("no ROS peer seen again on %s; waiting for their periodic announcements", ", ".join(missing))
            return
        log.info(
            "no ROS peer seen again on %s %.1f s after start; new DDS participant (%d of %d)",
            ", ".join(missing), REDISCOVER_AFTER, attempt, REDISCOVER_TRIES,
        )
        self.core.restart()
        self.dds_files = mapped_fastdds_files()
        self.context.changed()
        self.context.call_later(REDISCOVER_AFTER, lambda: self._rediscover(expected, attempt + 1))

    def snapshot(self) -> dict[str, Any]:
        return {"peer_ros_topics": sorted(self.peers), "dds_files": sorted(self.dds_files)}

    def restore(self, state: dict[str, Any]) -> None:
        self.peer_ros_topics = frozenset(state.get("peer_ros_topics", ()))
        self.predecessor_dds_files = frozenset(state.get("dds_files", ()))

    def _publish_in(self, topic: str, msg: Any) -> None:
        self.context.publish(topic, msg)
        self._count_in(topic)

    def _count_in(self, topic: str) -> None:
        self.forwarded_in += 1
        if self.forwarded_in == 1:
            log.info("first message from ROS on %s", topic)

    def _to_ros(self, topic: str, msg: Any) -> None:
        try:
            self.core.publish(topic, msg)
            self.forwarded_out += 1
            if self.forwarded_out == 1:
                log.info("first message to ROS from %s", topic)
        except (TypeError, ValueError) as exc:  # a message ROS cannot carry: say so, keep bridging
            log.error("not sent to ROS: %s", exc)

    def _serve(self, decl: Any, request: Any, response: Any) -> Any:
        """One request of a RosService (the core's service thread): ask the component, fill the response."""
        plan = self._plans.get(decl)
        if plan is None:
            if decl.method in _LIFECYCLE_METHODS:
                return self._lifecycle(decl, request, response)
            plan = self._plans[decl] = _ServePlan(decl, type(request), type(response))
        from embagents.ros.generic import (  # lazy: heavy (rosidl_parser)
            generic_from_ros,
            generic_to_ros,
        )

        status, where = plan.status, plan.where
        try:
            # A call comes ~0.5 ms after the service thread last ran, its caches cold: each step costs ~5x.
            kwargs = generic_from_ros(request).fields if plan.has_fields else {}
            call = Call(decl.method, kwargs=kwargs, deadline=time.monotonic() + decl.timeout)
            value = self._answer(plan.ref.ask(call), decl.timeout)
        except Exception as exc:  # noqa: BLE001 - every failure is the caller's answer, not our crash
            text = f"no answer within {decl.timeout} s" if "Timeout" in type(exc).__name__ else str(exc)
            text = getattr(exc, "remote_message", text)  # a RemoteError: the method's own error, no traceback
            log.warning("%s failed: %s", where, text)
            if status:
                response.success, response.message = False, f"{decl.component}.{decl.method}: {text}"[:4000]
            return response
        self.served += 1
        if isinstance(value, (dict, RosMessage)):
            try:
                return generic_to_ros(value, type(response))
            except ValueError as exc:  # a type mismatch: the method's answer does not fit the response
                log.error("%s: its answer does not fit %s: %s", where, decl.srv_type, exc)
                if status:
                    response.success, response.message = False, f"answer does not fit {decl.srv_type}: {exc}"
                return response
        if status:
            response.success = value if isinstance(value, bool) else True
            response.message = "" if value is None or isinstance(value, bool) else (
                value if isinstance(value, str) else json.dumps(value, default=str))
            return response
        log.error("%s returned a %s; a %s response needs a dict of its fields (%s)",
                  where, type(value).__name__, decl.srv_type, ", ".join(response.get_fields_and_field_types()))
        return response

    def _answer(self, future: Any, timeout: float) -> Any:
        """The ask's answer, waited for in slices: a bridge that stops gives up (RuntimeError) within one."""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            try:
                return future.get(timeout=max(0.0, min(left, STOP_CHECK)))
            except Timeout:
                if left <= STOP_CHECK:
                    raise
                if self.core.stopping_here():
                    raise RuntimeError("the ROS bridge is stopping") from None

    def _lifecycle(self, decl: Any, request: Any, response: Any) -> Any:
        """``lifecycle_msgs`` services of a component, answered from (and driving) the supervisor's lifecycle."""
        comp, t = ActorRef(decl.component), decl.timeout
        try:
            state = self._answer(comp.control("lifecycle_state"), t)
        except Exception as exc:  # noqa: BLE001 - not up (restarting): ROS's unknown state
            log.warning("lifecycle state of %s unknown: %s", decl.component, exc)
            state = "unknown"
        if decl.method == "_ros_get_state":
            response.current_state.id, response.current_state.label = _STATE_ID.get(state, 0), state
            return response
        if decl.method == "_ros_get_available_transitions":
            response.available_transitions = [_describe(response, tid) for tid in _AVAILABLE.get(state, ())]
            return response
        tid, label = request.transition.id, request.transition.label
        if not tid and label:  # given by label only
            tid = next((i for i in _AVAILABLE.get(state, ()) if _TRANSITIONS[i][0] == label), 0)
        if tid not in _AVAILABLE.get(state, ()):
            log.warning("%s: transition %s (%r) is not valid from %s", decl.component, tid, label, state)
            response.success = False
            return response
        what = _TRANSITIONS[tid][0]
        try:
            new = self._answer(comp.control("lifecycle", what), t)
        except Exception as exc:  # noqa: BLE001 - a hook failed or returned False: ROS's failure result
            log.warning("%s: %s failed: %s", decl.component, what, getattr(exc, "remote_message", exc))
            response.success = False
            return response
        response.success = True
        self._transition_event(decl.component, tid, state, new)
        return response

    def _transition_event(self, component: str, tid: int, start: str, goal: str) -> None:
        event = ros_interface_class("lifecycle_msgs/msg/TransitionEvent")()
        event.timestamp = time.time_ns()
        event.transition.id, event.transition.label = tid, _TRANSITIONS[tid][0]
        event.start_state.id, event.start_state.label = _STATE_ID.get(start, 0), start
        event.goal_state.id, event.goal_state.label = _STATE_ID.get(goal, 0), goal
        try:
            self.core.publish_ros(f"/{component}/transition_event", event)
        except Exception:  # noqa: BLE001 - the transition happened; a lost event is only logged
            log.exception("transition_event of %s not published", component)

    def _cancel_goals(self, goal_topic: str, _msg: Any) -> None:
        self.core.cancel_goals(goal_topic)

    def _send_goal(self, goal_topic: str, msg: Any) -> None:
        try:
            self.core.send_goal(goal_topic, msg)
        except (TypeError, ValueError) as exc:  # a goal that does not fit the Goal type
            log.error("goal on %s not sent: %s", goal_topic, exc)

    def on_receive(self, message: Any) -> Any:
        if isinstance(message, RosCall):
            return self._call(message)
        if message == "stats":
            return {"in": self.forwarded_in, "out": self.forwarded_out, "served": self.served}
        raise UnknownMessage("the ROS bridge", message, "it answers 'stats' and RosCall")

    def _call(self, message: Any) -> Deferred:
        """A RosCall, answered when the ROS service answers: meanwhile this actor goes on (topics, asks)."""
        from embagents.ros.generic import generic_from_ros  # lazy: heavy (rosidl_parser)

        answer = Deferred()

        def done(future: Any) -> None:  # the core's threads
            exc = future.exception()
            if exc is not None:
                answer.fail(exc)
                return
            try:
                answer.resolve(generic_from_ros(future.result()))
            except Exception as conv:  # noqa: BLE001 - a response we cannot carry: the caller's error
                answer.fail(conv)

        # Bad input (fields, a type mismatch) raises here: the ask's answer at once.
        self.core.call_async(message.ros_name, message.srv_type, message.fields, message.timeout).add_done_callback(done)
        return answer

    def on_stop(self) -> None:
        self.core.stop()
