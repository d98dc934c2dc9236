"""The rclpy side of the ROS 2 bridge: one node, its own Context, a few threads.

:class:`RosBridgeCore` knows nothing of actors: the bridge actor creates it
in its process, hands it an ``on_message`` callback that forwards incoming
messages onto internal topics, and calls :meth:`RosBridgeCore.publish` for
internal messages bound for ROS. Importing this module imports rclpy.

Threads: the subscriptions' (a wait set of their own: each message is taken
and handed to ``on_message`` without a turn of rclpy's executor; an ``Imu``
is read straight from its CDR bytes), the services' (requests we serve), and
the executor's spin (service calls, actions, publishers' events). Measured
with ``embagents bench --only ros_generic`` (Imu at 200 Hz, p50, one way
into a subscriber actor; per stage, 2 busy cores): rclpy's executor turn and
Python message (~55 us warm) made the take as slow as a plain rclpy
subscriber's whole path; a hand-over to the actor's loop thread cost one
more wake-up (70-200 us); building an ``Imu`` and encoding it as a map of
fields cost ~50 + ~50 us with cold caches, where its flat form is a slice of
the CDR bytes (see :func:`embagents.ros.convert.converter_from_cdr`).

Example::

    from embagents.msgs import String
    from embagents.ros import RosInput, RosOutput
    from embagents.ros.node import RosBridgeCore

    core = RosBridgeCore(
        inputs=[RosInput("/text_in", "std_msgs/String")],
        outputs=[RosOutput("answer", ros_type="std_msgs/String")],
    )
    core.start("embagents_bridge", lambda topic, msg: print(topic, msg))
    core.publish("answer", String(data="hello ROS"))
    core.stop()
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future as Future_
from concurrent.futures import InvalidStateError
from contextlib import AbstractContextManager, nullcontext
from typing import Any

import attrs
import rclpy
from rclpy.action import ActionClient
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.context import Context
from rclpy.event_handler import EventHandler, PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.guard_condition import GuardCondition
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.service import Service
from rclpy.signals import SignalHandlerOptions
from rclpy.subscription import Subscription
from rclpy.task import Future

from actors import private_file
from embagents.msgs import RosMessage, StreamingString
from embagents.ros.convert import converter_from_cdr, converter_from_ros, ros_msg_class, to_ros
from embagents.ros.fastdds_shm import clean_zombie_fastdds_segments
from embagents.ros.generic import generic_from_ros, generic_to_ros
from embagents.ros.spec import (
    QoS,
    RosAction,
    RosInput,
    RosOutput,
    RosService,
    check_bridge,
    normalize_ros_type,
    ros_interface_class,
    ros_type_for,
)

__all__ = ["RosBridgeCore", "configure_fastdds_shm", "qos_profile"]

log = logging.getLogger("embagents.ros")

OnMessage = Callable[[str, object], None]
OnMatched = Callable[[str, int], None]
#: Serves one request of a RosService: (declaration, ROS request, empty ROS response) -> filled response.
OnRequest = Callable[[RosService, Any, Any], Any]

_RELIABILITY = {"reliable": ReliabilityPolicy.RELIABLE, "best_effort": ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {"volatile": DurabilityPolicy.VOLATILE, "transient_local": DurabilityPolicy.TRANSIENT_LOCAL}


def qos_profile(q: QoS) -> QoSProfile:
    """Our QoS declaration -> rclpy QoSProfile (keep-last history)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=q.depth,
        reliability=_RELIABILITY[q.reliability],
        durability=_DURABILITY[q.durability],
    )


@attrs.define
class _Counts:
    received: int = 0
    published: int = 0
    errors: int = 0


@attrs.define
class _Running:
    context: Context
    node: Node
    executor: SingleThreadedExecutor
    thread: threading.Thread
    stopping: Future
    publishers: dict[str, Any]  # internal topic -> rclpy Publisher
    subscriptions: dict[str, Any]  # ROS topic (as declared) -> rclpy Subscription
    on_matched: OnMatched | None
    services_thread: threading.Thread | None = None
    wake_services: GuardCondition | None = None
    topics_thread: threading.Thread | None = None
    wake_topics: GuardCondition | None = None
    clients: dict[tuple[str, str], Any] = attrs.field(factory=dict)  # (service, type) -> rclpy Client
    raw_publishers: dict[str, Any] = attrs.field(factory=dict)  # ROS topic -> publisher of publish_ros
    # goal topic -> (declaration, ActionClient, running goal handles by id(): they are not hashable)
    actions: dict[str, tuple[RosAction, Any, dict[int, Any]]] = attrs.field(factory=dict)
    on_message: OnMessage | None = None


class _TakenElsewhere(ReentrantCallbackGroup):
    """The group of our services and subscriptions: the executor leaves them to threads of their own.

    Services go to :meth:`RosBridgeCore._serve`, whose thread may wait for a
    component's answer without holding up topics. Subscriptions and their
    event handlers (matched, incompatible QoS) go to
    :meth:`RosBridgeCore._take_topics`: its wait set takes each message and
    hands it on with a few microseconds of Python, where a turn of rclpy's
    executor costs ~100 us (and holds the GIL the actor's loop thread needs to
    send the message on). The event handlers go with their subscription: with
    Fast DDS a subscription wakes only the last wait set that waited on it or
    on its events, so two threads sharing one subscription lose wake-ups
    (measured: the Imu's p50 from 0.3 to 0.75-1.1 ms).
    """

    # rclpy annotates the Reentrant group's can_execute as Literal[True]; this subclass refuses ours.
    def can_execute(self, entity: Any) -> bool:  # type: ignore[override]
        return not isinstance(entity, (Service, Subscription, EventHandler))


class RosBridgeCore:
    """ROS 2 node mapping ROS topics to internal topics and back.

    ``start`` calls ``on_message(internal_topic, our_msg)`` for each incoming
    ROS message: from its subscription thread (always the same one while it
    runs) for the RosInputs, from its spin thread for actions' feedback and
    results. With ``flat``, types read from their CDR bytes (``Imu``) come
    as an :class:`actors.codec.Flat`, ready to publish (subscribers receive
    the message). ``publish`` may be called from any
    thread. Each ``start`` uses a fresh rclpy Context, so a core can be
    stopped and started again, and several can coexist in one process.
    """

    def __init__(
        self,
        inputs: Sequence[RosInput] = (),
        outputs: Sequence[RosOutput] = (),
        services: Sequence[RosService] = (),
        on_request: OnRequest | None = None,
        actions: Sequence[RosAction] = (),
        *,
        flat: bool = False,
        service_thread: Callable[[], AbstractContextManager[Any]] | None = None,
    ) -> None:
        self.flat = flat
        self.service_thread = service_thread
        self.inputs = list(inputs)
        self.outputs = list(outputs)
        self.services = list(services)
        self.actions = list(actions)
        self.on_request = on_request
        check_bridge(self.inputs, self.outputs, self.services)
        if self.services and on_request is None:
            raise ValueError("RosBridgeCore: services need on_request (what answers them)")
        self._outputs = {o.topic: o for o in self.outputs}
        self._lock = threading.Lock()
        self._run: _Running | None = None
        self._started_with: dict[str, Any] = {}
        self._here = threading.local()  # the services' thread: its run's ``stopping``
        self.counts: dict[str, _Counts] = {}

    @property
    def running(self) -> bool:
        return self._run is not None

    @property
    def node(self) -> Node | None:
        """The rclpy node while running (for advanced use: timers, services)."""
        run = self._run
        return run.node if run else None

    def start(
        self,
        node_name: str,
        on_message: OnMessage,
        *,
        domain_id: int | None = None,
        namespace: str | None = None,
        clean_shm: bool = True,
        shm_segment_mb: int | None = None,
        participant_id: int | None = None,
        on_matched: OnMatched | None = None,
    ) -> None:
        """Init a Context (``domain_id`` default: $ROS_DOMAIN_ID), create the node and spin it.

        With ``clean_shm`` (and Fast DDS, the default RMW), shared-memory
        segments left in /dev/shm by killed ROS processes (a bridge the
        supervisor restarted, say) are removed first; see
        :func:`clean_zombie_fastdds_segments`. ``shm_segment_mb`` calls
        :func:`configure_fastdds_shm` first (needed for publishing large
        images; only effective before this process's first start).
        ``on_matched(ros_topic, count)`` is called from the subscription or spin thread
        whenever the number of ROS peers matched on a declared ROS topic
        changes (publishers of an input, subscriptions of an output).

        Raises RuntimeError if already started; on any failure everything
        created so far is torn down before the error propagates.
        """
        with self._lock:
            if self._run is not None:
                raise RuntimeError("RosBridgeCore is already started; stop() it first")
            if clean_shm and os.environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp").startswith("rmw_fastrtps"):
                removed = clean_zombie_fastdds_segments()
                if removed:
                    log.info("removed %d stale Fast DDS shared-memory segments", len(removed))
            if shm_segment_mb is not None:
                configure_fastdds_shm(shm_segment_mb, participant_id)
            context = Context()
            # No signal handlers: the supervisor owns this process's signals.
            rclpy.init(context=context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
            node = executor = None
            try:
                node = Node(node_name, namespace=namespace, context=context, start_parameter_services=False)
                declared: list[RosInput | RosOutput] = [*self.inputs, *self.outputs]
                self.counts = {d.topic: _Counts() for d in declared}
                group = _TakenElsewhere()
                subscriptions = {
                    inp.ros_topic: node.create_subscription(
                        ros_msg_class(inp.ros_type),
                        inp.ros_topic,
                        self._callback(inp, on_message),
                        qos_profile(inp.qos),
                        callback_group=group,
                        raw=converter_from_cdr(inp.ros_type) is not None,  # the CDR bytes: see _callback
                        event_callbacks=SubscriptionEventCallbacks(matched=_matched(inp.ros_topic, on_matched)),
                    )
                    for inp in self.inputs
                }
                publishers = {
                    o.topic: _create_publisher(node, o, on_matched)
                    for o in self._outputs.values()
                    if o.ros_type is not None
                }
                executor = SingleThreadedExecutor(context=context)
                executor.add_node(node)
                stopping: Future[None] = Future()
                thread = threading.Thread(
                    target=self._spin, args=(executor, context, stopping), name=f"ros-spin-{node_name}", daemon=True
                )
                self._run = _Running(context, node, executor, thread, stopping, publishers, subscriptions, on_matched)
                self._run.on_message = on_message
                for a in self.actions:
                    client: ActionClient[Any, Any, Any] = ActionClient(node, ros_interface_class(a.action_type), a.ros_name)
                    self._run.actions[a.goal] = (a, client, {})
                if subscriptions:
                    wake = self._run.wake_topics = GuardCondition(None, None, context=context)
                    self._run.topics_thread = threading.Thread(
                        target=self._take_topics, args=(list(subscriptions.values()), context, wake, stopping),
                        name=f"ros-sub-{node_name}", daemon=True,
                    )
                if self.services:
                    served = [
                        (sv, node.create_service(ros_interface_class(sv.srv_type), sv.ros_name, _never_called,
                                                 callback_group=group))
                        for sv in self.services
                    ]
                    wake = self._run.wake_services = GuardCondition(None, None, context=context)
                    self._run.services_thread = threading.Thread(
                        target=self._serve, args=(served, context, wake, stopping),
                        name=f"ros-srv-{node_name}", daemon=True,
                    )
                self._started_with = {
                    "node_name": node_name, "on_message": on_message, "domain_id": domain_id, "namespace": namespace,
                    "clean_shm": clean_shm, "shm_segment_mb": shm_segment_mb, "participant_id": participant_id,
                    "on_matched": on_matched,
                }
                thread.start()
                for extra in (self._run.topics_thread, self._run.services_thread):
                    if extra is not None:
                        extra.start()
            except BaseException:
                self._run = None
                _teardown(context, node, executor)
                raise
        log.info("ROS bridge node %r up: %d inputs, %d outputs", node_name, len(self.inputs), len(self.outputs))

    def _callback(self, inp: RosInput, on_message: OnMessage) -> Callable[[Any], None]:
        topic, ros_type = inp.topic, inp.ros_type
        counts = self.counts[topic]
        convert = converter_from_ros(ros_type)
        from_cdr = converter_from_cdr(ros_type, flat=self.flat)
        if from_cdr is not None:  # a raw subscription: reading its CDR skips rclpy's Python message (~55 us)
            typed, cls = convert, ros_msg_class(ros_type)

            def convert(data: bytes) -> Any:
                msg = from_cdr(data)
                return msg if msg is not None else typed(deserialize_message(data, cls))

        def cb(ros_msg: Any) -> None:
            # Never let one bad message (or a failing consumer) stop the subscription thread.
            try:
                msg = convert(ros_msg)
            except Exception:
                counts.errors += 1
                if _worth_logging(counts.errors):
                    log.exception("dropping a %s from %s (error #%d): cannot convert it", ros_type, inp.ros_topic, counts.errors)
                return
            counts.received += 1
            try:
                on_message(topic, msg)
            except Exception:
                counts.errors += 1
                if _worth_logging(counts.errors):
                    log.exception("on_message failed for internal topic %r (error #%d)", topic, counts.errors)

        return cb

    @staticmethod
    def _take_topics(subs: list[Subscription], context: Context, wake: GuardCondition, stopping: Future) -> None:
        """Take the messages (and events) of our subscriptions and call their callbacks, in this thread."""
        events = [h for sub in subs for h in sub.event_handlers]
        try:
            handle = context.handle
            assert handle is not None  # a started context
            with handle:
                wait_set = _rclpy.WaitSet(len(subs), 1, 0, 0, 0, len(events), handle)
            while not stopping.done() and context.ok():
                wait_set.clear_entities()
                for sub in subs:
                    wait_set.add_subscription(sub.handle)
                for h in events:
                    h.add_to_wait_set(wait_set)
                wait_set.add_guard_condition(wake.handle)
                wait_set.wait(-1)  # releases the GIL
                if stopping.done():
                    break
                ready = wait_set.get_ready_entities("subscription")
                for sub in subs:
                    if sub.handle.pointer not in ready:
                        continue
                    with sub.handle:
                        taken = sub.handle.take_message(sub.msg_type, sub.raw)
                    if taken is not None:
                        callback: Callable[[Any], None] = sub.callback  # type: ignore[assignment]  # rclpy types it loosely
                        callback(taken[0])  # never raises: see _callback
                for h in events:
                    if h.is_ready(wait_set):
                        data = h.take_data()
                        if data:
                            h.callback(data)
        except Exception:
            if not stopping.done() and context.ok():
                log.exception("ROS subscription thread failed; topics from ROS stop")

    def _serve(self, served: list[tuple[RosService, Any]], context: Context, wake: GuardCondition,
               stopping: Future) -> None:
        """Take requests of our services and answer each with ``on_request`` (in this thread).

        Inside ``service_thread()`` when given (the bridge gives this thread links of its own to the
        components it asks); ``on_request`` may ask :meth:`stopping_here` while it waits.
        """
        assert self.on_request is not None
        self._here.stopping = stopping
        try:
            with self.service_thread() if self.service_thread is not None else nullcontext():
                self._serve_requests(served, context, wake, stopping)
        except Exception:
            if not stopping.done() and context.ok():
                log.exception("ROS service thread failed; services stop answering")

    def stopping_here(self) -> bool:
        """Whether the core's run of the calling thread (the services' thread) is stopping."""
        stopping = getattr(self._here, "stopping", None)
        return stopping is not None and stopping.done()

    def _serve_requests(self, served: list[tuple[RosService, Any]], context: Context, wake: GuardCondition,
                        stopping: Future) -> None:
        assert self.on_request is not None
        handle = context.handle
        assert handle is not None  # rclpy.init ran on this context
        with handle:
            wait_set = _rclpy.WaitSet(0, 1, 0, 0, len(served), 0, handle)
        while not stopping.done() and context.ok():
            wait_set.clear_entities()
            for _, srv in served:
                wait_set.add_service(srv.handle)
            wait_set.add_guard_condition(wake.handle)
            wait_set.wait(-1)  # releases the GIL
            if stopping.done():
                break
            ready = wait_set.get_ready_entities("service")
            for decl, srv in served:
                if srv.handle.pointer not in ready:
                    continue
                with srv.handle:
                    request, header = srv.handle.service_take_request(srv.srv_type.Request)
                if header is None:
                    continue
                response = self.on_request(decl, request, srv.srv_type.Response())
                srv.send_response(response, header)

    def call(self, ros_name: str, srv_type: str, fields: dict[str, Any], timeout: float) -> Any:
        """Call ROS service ``ros_name`` and return its ROS response (blocks up to ``timeout`` s).

        Raises TimeoutError naming what is wrong when no answer comes (no
        server, or a server of another type), ValueError for request fields
        the type lacks, RuntimeError when not started.
        """
        return self.call_async(ros_name, srv_type, fields, timeout).result()

    def call_async(self, ros_name: str, srv_type: str, fields: dict[str, Any], timeout: float) -> Future_[Any]:
        """Start a call of ROS service ``ros_name``; the returned future gets its ROS response.

        Returns at once (the bridge's loop goes on forwarding topics): a
        short-lived thread waits for the server to be matched, sends the
        request with rclpy's ``call_async``, and fails the future with
        TimeoutError at ``timeout`` (as :meth:`call` raises). Bad input raises
        here: ValueError for request fields the type lacks or a service known
        by another type, RuntimeError when not started.
        """
        srv_cls: Any = ros_interface_class(normalize_ros_type(srv_type, "srv"))  # generated: Request, Response
        request = generic_to_ros(fields, srv_cls.Request)
        with self._lock:
            run = self._run
            if run is None:
                raise RuntimeError(f"cannot call {ros_name}: RosBridgeCore is not started")
            key = (ros_name, srv_type)
            client = run.clients.get(key)
            if client is None:
                mismatch = self._other_types(run.node, ros_name, srv_type)
                if mismatch:
                    raise ValueError(f"ROS service {ros_name} is a {mismatch}, not a {srv_type} (a type mismatch)")
                client = run.clients[key] = run.node.create_client(srv_cls, ros_name)
        out: Future_[Any] = Future_()

        def settle(result: Any = None, error: BaseException | None = None) -> None:
            try:
                if error is not None:
                    out.set_exception(error)
                else:
                    out.set_result(result)
            except InvalidStateError:  # the answer and the timeout crossed: the first one counts
                pass

        def on_reply(future: Future) -> None:
            if future.cancelled():
                return
            exc = future.exception()
            if exc is not None:
                settle(error=RuntimeError(f"ROS service {ros_name}: {exc}"))
            else:
                settle(future.result())

        def send() -> None:
            try:
                deadline = time.monotonic() + timeout
                # A request sent before the server is matched is lost. rclpy has no event for that match
                # (its own wait_for_service sleeps 0.25 s steps, rclpy issue 58): check every 20 ms, only
                # until the first match of this client (clients are kept).
                while not client.service_is_ready() and time.monotonic() < deadline and run.context.ok():
                    time.sleep(0.02)
                future = client.call_async(request)
                future.add_done_callback(on_reply)
                run.executor.wake()
                try:
                    out.exception(max(0.0, deadline - time.monotonic()))  # waits for the answer
                except TimeoutError:
                    future.cancel()
                    client.remove_pending_request(future)
                    settle(error=TimeoutError(self._no_answer(run.node, client, ros_name, srv_type, timeout)))
            except Exception as exc:  # noqa: BLE001 - the core stopped meanwhile, say: the caller's answer
                settle(error=RuntimeError(f"ROS service {ros_name}: {exc}"))

        threading.Thread(target=send, name=f"ros-call-{ros_name}", daemon=True).start()
        return out

    @staticmethod
    def _other_types(node: Node, ros_name: str, srv_type: str) -> str:
        """The types ROS knows ``ros_name`` by, when ``srv_type`` is not among them ('' otherwise)."""
        types = dict(node.get_service_names_and_types()).get("/" + ros_name.lstrip("/"))
        return ", ".join(types) if types and srv_type not in types else ""

    def _no_answer(self, node: Node, client: Any, ros_name: str, srv_type: str, timeout: float) -> str:
        mismatch = self._other_types(node, ros_name, srv_type)
        if mismatch:
            return (f"ROS service {ros_name} did not answer within {timeout} s: it is a {mismatch}, "
                    f"not a {srv_type} (a type mismatch)")
        if not client.service_is_ready():
            return (f"ROS service {ros_name} did not answer within {timeout} s: no server for it is up "
                    f"(`ros2 service list` shows the ones that are)")
        return f"ROS service {ros_name} did not answer within {timeout} s: its server took the request and went silent"

    @staticmethod
    def _spin(executor: SingleThreadedExecutor, context: Context, stopping: Future) -> None:
        # Waiting on a future (not spin_once in a loop) lets stop() wake the
        # wait at once: a bare executor.wake() is swallowed until the timeout.
        while not stopping.done() and context.ok():
            try:
                executor.spin_until_future_complete(stopping)
            except ExternalShutdownException:
                break
            except Exception:
                if stopping.done() or not context.ok():
                    break
                log.exception("ROS executor error; continuing")

    def publish(self, internal_topic: str, msg: object) -> None:
        """Convert ``msg`` and publish it on the ROS topic declared for ``internal_topic``.

        Raises ValueError for an undeclared topic, TypeError for a message
        class the topic does not carry, RuntimeError when not started.
        Empty StreamingString chunks are skipped (see :mod:`embagents.ros.spec`).
        """
        out = self._outputs.get(internal_topic)
        if out is None:
            declared = ", ".join(sorted(self._outputs)) or "none"
            raise ValueError(f"no RosOutput is declared for internal topic {internal_topic!r}; declared: {declared}")
        if out.ros_type is None and isinstance(msg, RosMessage) and msg.ros_type:
            out = attrs.evolve(out, ros_type=normalize_ros_type(msg.ros_type))
        ros_type = out.ros_type or self._ros_type_of(out, msg)
        accepted = out.accepts if out.ros_type else (type(msg),)
        if type(msg) not in accepted:
            raise TypeError(
                f"topic {internal_topic!r} (ROS {out.ros_topic}, {ros_type}) expects "
                f"{' or '.join(c.__name__ for c in accepted)}, got {type(msg).__name__}"
            )
        if isinstance(msg, StreamingString) and not msg.data:
            return
        ros_msg = to_ros(msg, ros_type)  # outside the lock: big images take ~1 ms
        with self._lock:
            run = self._run
            if run is None:
                raise RuntimeError(f"cannot publish on {internal_topic!r}: RosBridgeCore is not started")
            pub = run.publishers.get(internal_topic)
            if pub is None:  # output declared without ros_type: its first message fixes the type
                out = self._outputs[internal_topic] = out if out.ros_type else out.resolved(type(msg))
                pub = run.publishers[internal_topic] = _create_publisher(run.node, out, run.on_matched)
            pub.publish(ros_msg)
        self.counts[internal_topic].published += 1

    def send_goal(self, goal_topic: str, msg: Any, wait_server: float = 5.0) -> None:
        """Send ``msg`` (a RosMessage or dict of the Goal's fields) as a goal of the RosAction on ``goal_topic``.

        Returns at once: a short-lived thread waits (up to ``wait_server`` s) for the
        server to be matched, then sends; feedback and the outcome reach ``on_message``
        on the action's topics (``status`` "no_server" when none was matched).
        """
        run = self._run
        if run is None:
            raise RuntimeError(f"cannot send a goal from {goal_topic!r}: RosBridgeCore is not started")
        decl, client, goals = run.actions[goal_topic]
        fields = msg.fields if isinstance(msg, RosMessage) else msg
        action_cls: Any = ros_interface_class(decl.action_type)  # generated: Goal, Result, Feedback
        goal = generic_to_ros(fields, action_cls.Goal)  # a bad field raises here
        on_message = run.on_message
        assert on_message is not None

        def outcome(status: str, result: Any = None) -> None:
            on_message(decl.result, RosMessage(decl.action_type, {"status": status, "result": result}))

        def on_result(handle: Any, fut: Any) -> None:
            goals.pop(id(handle), None)
            res = fut.result()
            outcome(_GOAL_STATUS.get(res.status, str(res.status)) if res else "aborted",
                    generic_from_ros(res.result) if res else None)

        def on_accepted(fut: Any) -> None:
            handle = fut.result()
            if handle is None or not handle.accepted:
                outcome("rejected")
                return
            goals[id(handle)] = handle
            handle.get_result_async().add_done_callback(lambda f: on_result(handle, f))
            run.executor.wake()

        def feedback(fb: Any) -> None:
            if decl.feedback:
                on_message(decl.feedback, generic_from_ros(fb.feedback))

        def send() -> None:
            deadline = time.monotonic() + wait_server
            while not client.server_is_ready() and time.monotonic() < deadline and run.context.ok():
                time.sleep(0.02)  # as in call(): rclpy has no event for a server being matched
            if not client.server_is_ready():
                outcome("no_server")
                return
            client.send_goal_async(goal, feedback_callback=feedback).add_done_callback(on_accepted)
            run.executor.wake()

        threading.Thread(target=send, name=f"ros-goal-{decl.ros_name}", daemon=True).start()

    def cancel_goals(self, goal_topic: str) -> int:
        """Cancel the running goals of the RosAction on ``goal_topic``; returns how many were asked to cancel."""
        run = self._run
        if run is None:
            return 0
        _, _, goals = run.actions[goal_topic]
        for handle in list(goals.values()):
            handle.cancel_goal_async()
        run.executor.wake()
        return len(goals)

    def publish_ros(self, ros_topic: str, ros_msg: Any, depth: int = 10) -> None:
        """Publish a ROS message on ``ros_topic`` (a publisher of its type is made at first use; reliable)."""
        with self._lock:
            run = self._run
            if run is None:
                raise RuntimeError(f"cannot publish on {ros_topic}: RosBridgeCore is not started")
            pub = run.raw_publishers.get(ros_topic)
            if pub is None:
                pub = run.raw_publishers[ros_topic] = run.node.create_publisher(type(ros_msg), ros_topic, depth)
            pub.publish(ros_msg)

    def matched(self) -> dict[str, int]:
        """ROS topic (as declared) -> peers matched now: publishers of an input, subscriptions of an output.

        An output declared without ``ros_type`` counts once its first message created its publisher.
        """
        with self._lock:
            run = self._run
            if run is None:
                return {}
            counts = {name: sub.get_publisher_count() for name, sub in run.subscriptions.items()}
            for topic, pub in run.publishers.items():
                name = self._outputs[topic].ros_topic
                counts[name] = counts.get(name, 0) + pub.get_subscription_count()
        return counts

    def restart(self) -> None:
        """Stop, then start again with the arguments of the last ``start``: a new DDS participant.

        Remote participants answer a participant they have not seen before at
        once; see :class:`embagents.ros.bridge_actor.RosBridgeActor` for why
        the bridge needs that. Raises RuntimeError if never started.
        """
        if not self._started_with:
            raise RuntimeError("RosBridgeCore.restart() needs an earlier start()")
        self.stop()
        self.start(**self._started_with)

    @staticmethod
    def _ros_type_of(out: RosOutput, msg: object) -> str:
        try:
            return ros_type_for(type(msg))
        except ValueError as e:
            raise TypeError(f"topic {out.topic!r} (ROS {out.ros_topic}): {e}") from None

    def stop(self, timeout: float = 5.0) -> None:
        """Stop spinning, destroy the node and shut the Context down (idempotent).

        Called from inside ``on_message`` (one of the core's threads), it returns at
        once and a short-lived thread finishes the teardown after the
        callback returns.
        """
        with self._lock:
            run, self._run = self._run, None
        if run is None:
            return
        run.stopping.set_result(None)
        run.executor.wake()
        for wake in (run.wake_topics, run.wake_services):
            if wake is not None:
                wake.trigger()
        if threading.current_thread() in (run.thread, run.topics_thread, run.services_thread):
            threading.Thread(target=self._finish, args=(run, timeout), name="ros-teardown").start()
        else:
            self._finish(run, timeout)

    @staticmethod
    def _finish(run: _Running, timeout: float) -> None:
        for extra in (run.topics_thread, run.services_thread):
            if extra is not None and extra is not threading.current_thread():
                extra.join(timeout)
        run.thread.join(timeout)
        if run.thread.is_alive():
            # A callback is stuck in on_message; shutting the context down ends
            # the loop as soon as it returns.
            log.error("ROS spin thread did not stop within %.1f s", timeout)
        _teardown(run.context, run.node, run.executor)
        run.thread.join(timeout)
        log.info("ROS bridge node stopped")

    def __enter__(self) -> RosBridgeCore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _matched(topic: str, on_matched: OnMatched | None) -> Callable[[Any], None] | None:
    if on_matched is None:
        return None
    return lambda info: on_matched(topic, info.current_count)


def _create_publisher(node: Node, out: RosOutput, on_matched: OnMatched | None) -> Any:
    assert out.ros_type is not None  # the callers resolve it first
    events = PublisherEventCallbacks(matched=_matched(out.ros_topic, on_matched))
    return node.create_publisher(ros_msg_class(out.ros_type), out.ros_topic, qos_profile(out.qos), event_callbacks=events)


_GOAL_STATUS = {4: "succeeded", 5: "canceled", 6: "aborted"}  # action_msgs/GoalStatus


def _never_called(_request: Any, response: Any) -> Any:  # our services are taken by RosBridgeCore._serve
    return response


def _worth_logging(n: int) -> bool:
    # A stream of bad frames at 30 Hz must not flood the log: #1-3, then every 1000th.
    return n <= 3 or n % 1000 == 0


def _teardown(context: Context, node: Node | None, executor: SingleThreadedExecutor | None) -> None:
    # Each step may fail on a half-built core; none may keep the others from running.
    for step in (
        (lambda: executor.shutdown(timeout_sec=0)) if executor else None,
        node.destroy_node if node else None,
        context.try_shutdown,
        context.destroy,
    ):
        if step is None:
            continue
        try:
            step()
        except Exception:
            log.debug("ROS teardown step failed", exc_info=True)


_SHM_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<dds xmlns="http://www.eprosima.com">
  <profiles>
    <transport_descriptors>
      <transport_descriptor>
        <transport_id>embagents_shm</transport_id>
        <type>SHM</type>
        <segment_size>{size}</segment_size>
        <maxMessageSize>{size}</maxMessageSize>
      </transport_descriptor>
    </transport_descriptors>
    <participant profile_name="embagents_participant" is_default_profile="true">
      <rtps>
        <builtin>
          <discovery_config>
            <!-- A restarted bridge must be found again at once: announce itself often at first. -->
            <leaseDuration><sec>10</sec></leaseDuration>
            <leaseAnnouncement><sec>1</sec></leaseAnnouncement>
            <initialAnnouncements>
              <count>30</count>
              <period><nanosec>50000000</nanosec></period>
            </initialAnnouncements>
          </discovery_config>
        </builtin>{participant_id}
        <userTransports><transport_id>embagents_shm</transport_id></userTransports>
        <useBuiltinTransports>true</useBuiltinTransports>
      </rtps>
    </participant>
  </profiles>
</dds>
"""


_profile: str | None = None  # the profile file configure_fastdds_shm wrote for this process


def configure_fastdds_shm(segment_mb: int = 64, participant_id: int | None = None) -> str | None:
    """Give this process's DDS participants a ``segment_mb`` shared-memory segment.

    Fast DDS's default segment is 0.5 MB: a writer's larger samples (a
    6.2 MB 1080p frame) go over fragmented UDP instead, where best-effort
    readers lose nearly all of them and reliable ones wait ~60 ms (measured;
    with a 64 MB segment: every frame, ~17-33 ms). The writer's segment is
    the one that counts, so this helps what the bridge publishes. It sets
    ``FASTDDS_DEFAULT_PROFILES_FILE``, read once per process when the first
    participant is created: call it before the first ``start``. Returns the
    profile's path, or None when the user already set that variable (theirs
    wins). The profile is a :func:`actors.private_file`: only this user can
    read it, and it is removed when the run (or, outside a run, this process)
    ends. Segment pages are only backed by memory as they are written.

    ``participant_id`` pins the DDS participant id (0-119). A restarted
    bridge must not reuse its killed predecessor's id: that id's shared-memory
    port is still held by the dead process, and Fast DDS only recovers it
    after its port watchdog times out (measured: ~3 s without data).
    """
    global _profile
    given = os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE")
    if given and (given != _profile or os.path.exists(given)):
        return None  # the user's, or ours and still there (a run that ended took it away: write anew)
    if not isinstance(segment_mb, int) or segment_mb < 1:
        raise ValueError(f"segment_mb must be a positive int, got {segment_mb!r}")
    pid_xml = "" if participant_id is None else f"\n        <participantID>{int(participant_id)}</participantID>"
    profile = _SHM_PROFILE.format(size=segment_mb * 1024 * 1024, participant_id=pid_xml)
    # A private, unpredictable file: in the run directory (goes with the run), else removed at exit.
    path = _profile = private_file("fastdds", ".xml", profile.encode())
    os.environ["FASTDDS_DEFAULT_PROFILES_FILE"] = path
    return path
