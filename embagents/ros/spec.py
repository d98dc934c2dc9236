"""Declarations of the ROS 2 bridge, written in ``system.py`` (no rclpy needed).

A :class:`RosInput` brings a ROS topic into the system (each ROS message is
converted and published on an internal topic); a :class:`RosOutput` sends an
internal topic out to ROS. Both carry a :class:`QoS`. This module never
imports rclpy, so ``embagents check system.py`` validates the wiring on a
machine without ROS; :func:`ros_available` says whether the bridge can run.

Example::

    >>> from embagents.ros import QoS, RosInput, RosOutput
    >>> cam = RosInput("/camera/image_raw", "sensor_msgs/Image", qos=QoS(depth=1, reliability="best_effort"))
    >>> cam.topic, cam.ros_type
    ('camera/image_raw', 'sensor_msgs/msg/Image')
    >>> RosOutput("cmd_vel", ros_type="geometry_msgs/Twist").ros_topic
    '/cmd_vel'

Supported pairs (:data:`SUPPORTED`, ROS type -> our message class):

=======================================  ===================================================================
``std_msgs/msg/String``                  :class:`~embagents.msgs.String`
``sensor_msgs/msg/Image``                :class:`~embagents.msgs.Image`
``sensor_msgs/msg/CompressedImage``      :class:`~embagents.msgs.CompressedImage`
``geometry_msgs/msg/Twist``              :class:`~embagents.msgs.Twist`
``nav_msgs/msg/Odometry``                :class:`~embagents.msgs.Odometry`
``nav_msgs/msg/OccupancyGrid``           :class:`~embagents.msgs.OccupancyGrid`
``sensor_msgs/msg/JointState``           :class:`~embagents.msgs.JointState`
``sensor_msgs/msg/PointCloud``           :class:`~embagents.msgs.Detections` (see below)
``geometry_msgs/msg/PoseStamped``        :class:`~embagents.msgs.PoseStamped` (also Pose, Point, Quaternion)
``sensor_msgs/msg/Imu``                  :class:`~embagents.msgs.Imu`
``sensor_msgs/msg/LaserScan``            :class:`~embagents.msgs.LaserScan`
``sensor_msgs/msg/PointCloud2``          :class:`~embagents.msgs.PointCloud2` (a structured-array view)
``trajectory_msgs/msg/JointTrajectory``  :class:`~embagents.msgs.JointTrajectory`
=======================================  ===================================================================

Every other installed message type is carried as a
:class:`~embagents.msgs.RosMessage`, introspected by
:mod:`embagents.ros.generic`; a type whose package is not installed is
refused naming its wheel (:func:`wheel_for`). :class:`RosService` serves a
component method as a ROS service, :func:`ros_call` calls one,
:class:`RosAction` sends goals to an action server, and
:class:`RosLifecycle` makes components ROS managed nodes.

Outgoing only: :class:`~embagents.msgs.StreamingString` goes out as
``std_msgs/msg/String``, one ROS message per chunk carrying the chunk's
text (not the text so far). Chunks with empty ``data`` (typically the final
``done=True`` marker) are not published: ROS has no end-of-stream field, and
an empty string would reach TTS or logging nodes as a real utterance.

Lossy fields: ROS covariances (Odometry), ``Image.is_bigendian`` (data is
made native), ``JointState.header.frame_id`` and ``OccupancyGrid.info
.map_load_time`` (set to the stamp going out) are not kept.

Detections mapping
------------------
``vision_msgs`` has no wheel on PyPI (``pip index versions ros-vision-msgs``
finds nothing) and custom ``.msg`` packages cannot be built without a ROS
install, so :class:`~embagents.msgs.Detections` travels as
``sensor_msgs/msg/PointCloud``, one of the few stock messages with a header,
per-item strings and float arrays:

- ``header.stamp`` / ``header.frame_id``: ``stamp`` / ``frame_id``;
- ``points``: empty;
- ``channels[0]``: ``name="image_size"``, ``values=[image_width, image_height]``;
- ``channels[1 + i]``: detection ``i``, ``name`` = its label,
  ``values=[x1, y1, x2, y2, score]`` (pixels, float32).

A ROS consumer reads it as::

    w, h = msg.channels[0].values
    for ch in msg.channels[1:]:
        x1, y1, x2, y2, score = ch.values; label = ch.name

Anything else arriving on such a topic is rejected with a ValueError that
quotes this layout.
"""

from __future__ import annotations

import importlib
import importlib.util
import re
from typing import Any, TypeVar

import attrs

from actors import ActorRef
from actors.codec import message
from actors.errors import RemoteError, Timeout
from embagents.msgs import (
    CompressedImage,
    Detections,
    Image,
    Imu,
    JointState,
    JointTrajectory,
    LaserScan,
    OccupancyGrid,
    Odometry,
    Point,
    PointCloud2,
    Pose,
    PoseStamped,
    Quaternion,
    RosMessage,
    StreamingString,
    String,
    Twist,
)

__all__ = [
    "DEFAULT_ROS_TYPE",
    "OUTGOING",
    "QoS",
    "ROS_EXTRA_HINT",
    "RosInput",
    "RosCall",
    "RosOutput",
    "RosService",
    "SUPPORTED",
    "check_bridge",
    "msg_class_for",
    "normalize_ros_type",
    "ros_available",
    "ros_call",
    "ros_interface_class",
    "ros_type_for",
    "wheel_for",
]

#: ROS type (``pkg/msg/Name``) -> our message class, both directions.
SUPPORTED: dict[str, type] = {
    "std_msgs/msg/String": String,
    "sensor_msgs/msg/Image": Image,
    "sensor_msgs/msg/CompressedImage": CompressedImage,
    "geometry_msgs/msg/Twist": Twist,
    "nav_msgs/msg/Odometry": Odometry,
    "nav_msgs/msg/OccupancyGrid": OccupancyGrid,
    "sensor_msgs/msg/JointState": JointState,
    "sensor_msgs/msg/PointCloud": Detections,
    "geometry_msgs/msg/Point": Point,
    "geometry_msgs/msg/Quaternion": Quaternion,
    "geometry_msgs/msg/Pose": Pose,
    "geometry_msgs/msg/PoseStamped": PoseStamped,
    "sensor_msgs/msg/Imu": Imu,
    "sensor_msgs/msg/LaserScan": LaserScan,
    "sensor_msgs/msg/PointCloud2": PointCloud2,
    "trajectory_msgs/msg/JointTrajectory": JointTrajectory,
}

#: ROS type -> our classes accepted on a RosOutput of that type (a RosMessage of that type always is).
OUTGOING: dict[str, tuple[type, ...]] = {k: (v, RosMessage) for k, v in SUPPORTED.items()}
OUTGOING["std_msgs/msg/String"] = (String, StreamingString, RosMessage)

#: Our class -> the ROS type used when a RosOutput gives none.
DEFAULT_ROS_TYPE: dict[type, str] = {v: k for k, v in SUPPORTED.items()}
DEFAULT_ROS_TYPE[StreamingString] = "std_msgs/msg/String"

ROS_EXTRA_HINT = "install the ROS 2 extra: pip install 'embagents[ros]'"
#: The ROS bridge actor's name in a supervised system.
BRIDGE_NAME = "_ros_bridge"

_RELIABILITY = ("reliable", "best_effort")
_DURABILITY = ("volatile", "transient_local")
# ROS 2 topic names: tokens of [A-Za-z0-9_] not starting with a digit, joined by '/'.
_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_ROS_NAME = re.compile(rf"^/?{_TOKEN}(/{_TOKEN})*$")
_ROS_TYPE = re.compile(rf"^({_TOKEN})/(?:(msg|srv|action)/)?({_TOKEN})$")


def wheel_for(package: str) -> str:
    """The PyPI wheel that installs ROS package ``package``.

    >>> wheel_for("vision_msgs")
    'ros-vision-msgs'
    """
    return "ros-" + package.replace("_", "-")


def normalize_ros_type(ros_type: str, kind: str = "msg") -> str:
    """``"std_msgs/String"`` or ``"std_msgs/msg/String"`` -> ``"std_msgs/msg/String"``.

    ``kind`` is ``msg``, ``srv`` or ``action``. A type with a class of its own
    (:data:`SUPPORTED`) is accepted without ROS installed; any other must be
    installed (its Python module is imported, not rclpy). Raises ValueError
    for a malformed type, a package that is not installed (naming the wheel)
    or a name the package does not define (naming the ones it does).

    >>> normalize_ros_type("geometry_msgs/Twist")
    'geometry_msgs/msg/Twist'
    """
    if not isinstance(ros_type, str):
        raise TypeError(f"ros_type must be a str like 'std_msgs/{kind}/Name', got {ros_type!r}")
    m = _ROS_TYPE.match(ros_type.strip())
    if m is None or (m.group(2) not in (None, kind)):
        raise ValueError(f"malformed ROS {kind} type {ros_type!r}: write 'package/{kind}/Name' or 'package/Name'")
    full = f"{m.group(1)}/{kind}/{m.group(3)}"
    if full not in SUPPORTED:
        ros_interface_class(full)  # raises the errors above
    return full


def ros_interface_class(full: str) -> type:
    """The Python class of an installed ROS interface ``pkg/(msg|srv|action)/Name`` (imports no rclpy)."""
    pkg, kind, name = full.split("/")
    try:
        spec = importlib.util.find_spec(pkg)
    except (ImportError, ValueError):
        spec = None
    if spec is None:
        raise ValueError(
            f"ROS type {full!r}: package {pkg!r} is not installed; pip install {wheel_for(pkg)} "
            f"(types with a class of their own need no install: {', '.join(sorted(SUPPORTED))})"
        )
    try:
        module = importlib.import_module(f"{pkg}.{kind}")
    except ImportError as e:
        raise ValueError(f"ROS type {full!r}: package {pkg!r} has no {kind} types ({e})") from None
    cls = getattr(module, name, None)
    if not isinstance(cls, type):
        have = ", ".join(sorted(n for n, v in vars(module).items() if isinstance(v, type) and not n.startswith("_")))
        raise ValueError(f"ROS type {full!r}: {pkg} has no {kind} {name!r}; it has: {have or 'none'}")
    return cls


def msg_class_for(ros_type: str) -> type:
    """Our message class carrying ROS type ``ros_type`` (a :class:`~embagents.msgs.RosMessage` if none is mapped).

    >>> msg_class_for("sensor_msgs/msg/Imu").__name__
    'Imu'
    """
    return SUPPORTED.get(ros_type, RosMessage)


def ros_type_for(msg_class: type) -> str:
    """The ROS type our message class goes out as.

    >>> from embagents.msgs import Twist
    >>> ros_type_for(Twist)
    'geometry_msgs/msg/Twist'
    """
    try:
        return DEFAULT_ROS_TYPE[msg_class]
    except KeyError:
        names = ", ".join(sorted(c.__name__ for c in DEFAULT_ROS_TYPE))
        raise ValueError(
            f"{getattr(msg_class, '__name__', msg_class)!r} has no ROS mapping; "
            f"message classes that do: {names}"
        ) from None


def _check_ros_name(what: str, name: str) -> None:
    if not isinstance(name, str) or not _ROS_NAME.match(name):
        raise ValueError(
            f"invalid ROS topic name for {what}: {name!r}; ROS names are tokens of letters, "
            "digits and '_' (not starting with a digit) separated by single '/', "
            "e.g. '/camera/image_raw'"
        )


def _in_choices(name: str, choices: tuple[str, ...]):  # noqa: ANN202 - attrs validator factory
    def check(_inst: object, _attr: object, value: object) -> None:
        if value not in choices:
            raise ValueError(f"QoS {name} must be one of {', '.join(map(repr, choices))}; got {value!r}")

    return check


def _positive_int(_inst: object, _attr: object, value: object) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"QoS depth must be an int >= 1 (messages kept per topic); got {value!r}")


@attrs.define(frozen=True)
class QoS:
    """ROS 2 quality of service (history is always keep-last ``depth``).

    Sensor streams usually want ``QoS(depth=1, reliability="best_effort")``;
    latched maps want ``durability="transient_local"``.

    >>> QoS(depth=1, reliability="best_effort")
    QoS(depth=1, reliability='best_effort', durability='volatile')
    """

    depth: int = attrs.field(default=10, validator=_positive_int)
    reliability: str = attrs.field(default="reliable", validator=_in_choices("reliability", _RELIABILITY))
    durability: str = attrs.field(default="volatile", validator=_in_choices("durability", _DURABILITY))


def _qos(value: object) -> QoS:
    if not isinstance(value, QoS):
        raise TypeError(f"qos must be an embagents.ros.QoS, got {value!r}")
    return value


@attrs.define(frozen=True)
class RosInput:
    """A ROS topic coming into the system, republished on internal ``topic``.

    ``topic`` defaults to the ROS name without its leading slash.

    >>> RosInput("/text_in", "std_msgs/String").topic
    'text_in'
    """

    ros_topic: str
    ros_type: str = attrs.field(converter=normalize_ros_type)
    topic: str = attrs.field(default=None)  # None: ros_topic without its leading slash (__attrs_post_init__)
    qos: QoS = attrs.field(factory=QoS, validator=lambda _i, _a, v: _qos(v))

    def __attrs_post_init__(self) -> None:
        _check_ros_name("RosInput", self.ros_topic)
        if self.topic is None:
            object.__setattr__(self, "topic", self.ros_topic.lstrip("/"))
        elif not isinstance(self.topic, str) or not self.topic:
            raise ValueError(f"RosInput({self.ros_topic!r}): topic must be a non-empty str, got {self.topic!r}")

    @property
    def msg_type(self) -> type:
        """Our message class published on the internal topic."""
        return msg_class_for(self.ros_type)


@attrs.define(frozen=True)
class RosOutput:
    """An internal ``topic`` going out to ROS on ``ros_topic`` (default ``"/" + topic``).

    Without ``ros_type`` the bridge picks it from the first message's class
    (:data:`DEFAULT_ROS_TYPE`) and creates the ROS publisher then; give it (or
    call :meth:`resolved`) to have the publisher discoverable from the start.

    >>> RosOutput("answer", ros_type="std_msgs/String").accepts
    (<class 'embagents.msgs.String'>, <class 'embagents.msgs.StreamingString'>, <class 'embagents.msgs.RosMessage'>)
    """

    topic: str
    ros_topic: str = attrs.field(default=None)  # None: "/" + topic (__attrs_post_init__)
    ros_type: str | None = attrs.field(
        default=None, converter=lambda v: None if v is None else normalize_ros_type(v)
    )
    qos: QoS = attrs.field(factory=QoS, validator=lambda _i, _a, v: _qos(v))

    def __attrs_post_init__(self) -> None:
        if not isinstance(self.topic, str) or not self.topic:
            raise ValueError(f"RosOutput: topic must be a non-empty str, got {self.topic!r}")
        if self.ros_topic is None:
            default = "/" + self.topic.lstrip("/")
            if not _ROS_NAME.match(default):
                raise ValueError(
                    f"RosOutput({self.topic!r}): the internal topic name is not a valid ROS name "
                    "(letters, digits, '_' and '/'), so give ros_topic= explicitly"
                )
            object.__setattr__(self, "ros_topic", default)
        _check_ros_name(f"RosOutput({self.topic!r})", self.ros_topic)

    @property
    def accepts(self) -> tuple[type, ...]:
        """Our message classes this output publishes (all mapped ones while ros_type is unset)."""
        if self.ros_type is None:  # a RosMessage goes out as its own ros_type
            return (*DEFAULT_ROS_TYPE, RosMessage)
        return OUTGOING.get(self.ros_type, (RosMessage,))

    def resolved(self, msg_class: type) -> RosOutput:
        """This output with ``ros_type`` filled in from the internal topic's message class."""
        if self.ros_type is not None and msg_class is RosMessage:
            return self
        ros_type = ros_type_for(msg_class)
        if self.ros_type is not None and msg_class not in self.accepts:
            raise TypeError(
                f"RosOutput({self.topic!r}) is declared as {self.ros_type}, which carries "
                f"{', '.join(c.__name__ for c in self.accepts)}, but the topic "
                f"carries {msg_class.__name__}"
            )
        return attrs.evolve(self, ros_type=self.ros_type or ros_type)


def _positive_seconds(_inst: object, attr: Any, value: object) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < 3600:
        raise ValueError(f"{attr.name} must be seconds > 0 (and < 3600), got {value!r}")


def _srv_type(value: str) -> str:
    return normalize_ros_type(value, "srv")


@attrs.define(frozen=True)
class RosService:
    """Serve ``component.method`` as the ROS service ``ros_name`` of type ``srv_type``.

    The request's fields are the method's keyword arguments. Its return value
    fills the response: a dict (or RosMessage) of the response's fields; for a
    response with ``success`` and ``message`` (``std_srvs/Trigger``,
    ``SetBool``) any other value is the message text with ``success=True``, and
    an exception (or no answer within ``timeout`` s) ``success=False`` with the
    error as the message.

    >>> RosService("/memory/locate", "std_srvs/Trigger", component="memory", method="locate").srv_type
    'std_srvs/srv/Trigger'
    """

    ros_name: str
    srv_type: str = attrs.field(converter=_srv_type)
    component: str = attrs.field(kw_only=True)
    method: str = attrs.field(kw_only=True)
    timeout: float = attrs.field(default=10.0, kw_only=True, validator=_positive_seconds)

    def __attrs_post_init__(self) -> None:
        _check_ros_name("RosService", self.ros_name)
        for what in ("component", "method"):
            v = getattr(self, what)
            if not isinstance(v, str) or not v.isidentifier() and what == "method" or not v:
                raise ValueError(f"RosService({self.ros_name!r}): {what} must be a non-empty name, got {v!r}")


_S = TypeVar("_S")  # the type of the field a validator checks


def _topic_name(_inst: object, attr: attrs.Attribute[_S], value: _S) -> None:
    if value is not None and (not isinstance(value, str) or not value):
        raise ValueError(f"RosAction {attr.name} must be a non-empty internal topic name, got {value!r}")


@attrs.define(frozen=True)
class RosAction:
    """A ROS action the system uses as a client, through internal topics.

    Each :class:`~embagents.msgs.RosMessage` (or message with the Goal's
    fields) a component publishes on ``goal`` is sent as a goal of
    ``action_type`` to the server ``ros_name``. Its feedback is published on
    ``feedback`` (a RosMessage with the Feedback's fields) and its outcome on
    ``result``: a RosMessage with ``status`` ("succeeded", "aborted",
    "canceled" or "rejected") and ``result`` (the Result's fields). Any
    message on ``cancel`` cancels the goals still running. Nothing waits in
    the bridge: a goal may run for minutes.

    >>> RosAction("/navigate_to_pose", "nav2_msgs/NavigateToPose", goal="nav_goal", result="nav_result",
    ...           check_installed=False).action_type
    'nav2_msgs/action/NavigateToPose'
    """

    ros_name: str
    action_type: str = attrs.field()
    goal: str = attrs.field(kw_only=True, validator=_topic_name)
    result: str = attrs.field(kw_only=True, validator=_topic_name)
    feedback: str | None = attrs.field(default=None, kw_only=True, validator=_topic_name)
    cancel: str | None = attrs.field(default=None, kw_only=True, validator=_topic_name)
    check_installed: bool = attrs.field(default=True, kw_only=True, repr=False)

    def __attrs_post_init__(self) -> None:
        _check_ros_name("RosAction", self.ros_name)
        if self.check_installed:
            full = normalize_ros_type(self.action_type, "action")
        else:
            m = _ROS_TYPE.match(str(self.action_type).strip())
            if m is None:
                raise ValueError(f"malformed ROS action type {self.action_type!r}")
            full = f"{m.group(1)}/action/{m.group(3)}"
        object.__setattr__(self, "action_type", full)

    @property
    def provides(self) -> list[str]:
        """The internal topics the bridge publishes for this action."""
        return [t for t in (self.result, self.feedback) if t]


@attrs.define(frozen=True)
class RosLifecycle:
    """Components as ROS 2 managed nodes: ``ros2 lifecycle get/set /<component>`` drive our lifecycle.

    For each component (``components``; default every one) the bridge serves
    ``/<component>/get_state``, ``/<component>/change_state`` and
    ``/<component>/get_available_transitions`` (``lifecycle_msgs``), runs a
    requested transition through the supervisor's lifecycle (the hooks run in the
    component's process), and publishes ``/<component>/transition_event``.
    A transition not valid from the current state gets ``success=False``, as ROS's
    own managed nodes answer.

    >>> RosLifecycle(["llm"]).components
    ('llm',)
    """

    components: tuple[str, ...] | None = attrs.field(
        default=None, converter=lambda v: None if v is None else tuple(str(c) for c in v)
    )

    def __attrs_post_init__(self) -> None:
        for c in self.components or ():
            _check_ros_name(f"RosLifecycle component {c!r} (its ROS node name)", "/" + c)


@message("embagents/RosCall")
@attrs.define
class RosCall:
    """A request to the bridge: call ROS service ``ros_name`` (see :func:`ros_call`)."""

    ros_name: str
    srv_type: str
    fields: dict[str, Any] = attrs.field(factory=dict)
    timeout: float = 5.0


def ros_call(ros_name: str, srv_type: str, timeout: float = 5.0, **fields: Any) -> RosMessage:
    """Call ROS service ``ros_name`` through the system's bridge; returns the response.

    For a component method or an LLM tool of a system with a ROS bridge.
    Request ``fields`` as keyword arguments (nested messages as dicts).
    Raises TimeoutError when no server answers within ``timeout`` s (no
    server, a server that vanished mid-call), ValueError for a type mismatch
    or a field the request type lacks, RuntimeError without a bridge.

    The bridge does not wait for the answer: it sends the request with
    rclpy's ``call_async`` and answers this ask when the response (or the
    timeout) comes, forwarding topics and serving other calls meanwhile. The
    caller waits up to ``timeout``; a long-running ROS request with progress
    is an action (:class:`RosAction`).

    Example (in a component)::

        reply = ros_call("/arm/home", "std_srvs/Trigger", timeout=10)
        if not reply.success: ...
    """
    _check_ros_name("ros_call", ros_name)
    full = normalize_ros_type(srv_type, "srv")
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or timeout <= 0:
        raise ValueError(f"ros_call timeout must be seconds > 0, got {timeout!r}")
    try:
        return ActorRef(BRIDGE_NAME).ask(RosCall(ros_name, full, fields, float(timeout)), timeout=timeout + 5).get()
    except Timeout:
        raise TimeoutError(f"ros_call {ros_name}: the ROS bridge did not answer within {timeout + 5:.1f} s "
                           "(does this system declare ros=[...]?)") from None
    except RemoteError as e:  # the bridge's own error, without its traceback
        kinds: dict[str, type[Exception]] = {"TimeoutError": TimeoutError, "ValueError": ValueError,
                                             "TypeError": ValueError}
        raise kinds.get(e.exc_type, RuntimeError)(e.remote_message) from None


def check_bridge(inputs: list[RosInput], outputs: list[RosOutput], services: list[RosService] = ()) -> None:  # type: ignore[assignment]
    """Reject wiring the bridge cannot serve unambiguously (raises ValueError).

    - two outputs for one internal topic (which ROS topic would ``publish`` use?);
    - one ROS topic declared with two types;
    - an input and an output joining the same ROS topic and internal topic
      (every message would loop back in forever).
    """
    seen_out: dict[str, RosOutput] = {}
    ros_types: dict[str, str] = {}
    for o in outputs:
        if not isinstance(o, RosOutput):
            raise TypeError(f"outputs must be RosOutput, got {o!r}")
        if o.topic in seen_out:
            raise ValueError(f"internal topic {o.topic!r} has two RosOutputs: {seen_out[o.topic]} and {o}")
        seen_out[o.topic] = o
    seen_in: set[tuple[str, str]] = set()
    for i in inputs:
        if not isinstance(i, RosInput):
            raise TypeError(f"inputs must be RosInput, got {i!r}")
        if (i.ros_topic, i.topic) in seen_in:
            raise ValueError(f"{i} is declared twice")
        seen_in.add((i.ros_topic, i.topic))
    declared: list[RosInput | RosOutput] = [*inputs, *outputs]
    for d in declared:
        if d.ros_type is None:
            continue
        key = "/" + d.ros_topic.lstrip("/")
        other = ros_types.setdefault(key, d.ros_type)
        if other != d.ros_type:
            raise ValueError(f"ROS topic {key!r} is declared both as {other} and as {d.ros_type}")
    names: dict[str, RosService] = {}
    for sv in services:
        if not isinstance(sv, RosService):
            raise TypeError(f"services must be RosService, got {sv!r}")
        key = "/" + sv.ros_name.lstrip("/")
        if key in names:
            raise ValueError(f"ROS service {key!r} is declared twice: {names[key]} and {sv}")
        names[key] = sv
    for i in inputs:
        out = seen_out.get(i.topic)
        if out is not None and out.ros_topic.lstrip("/") == i.ros_topic.lstrip("/"):
            raise ValueError(
                f"ROS topic {i.ros_topic!r} <-> internal topic {i.topic!r} is both a RosInput and a "
                "RosOutput: each message would be echoed back forever; use different names"
            )


_NEEDED_MODULES = (
    "rclpy",
    "builtin_interfaces.msg",
    "std_msgs.msg",
    "sensor_msgs.msg",
    "geometry_msgs.msg",
    "nav_msgs.msg",
)


def ros_available() -> tuple[bool, str]:
    """Whether rclpy and the message packages the bridge needs can be imported.

    Imports them (the first call costs ~0.1-0.5 s when they are there).

    >>> ok, why = ros_available()
    >>> isinstance(ok, bool) and isinstance(why, str)
    True
    """
    for mod in _NEEDED_MODULES:
        try:
            importlib.import_module(mod)
        except Exception as e:  # noqa: BLE001 - rclpy fails with ImportError, OSError, ...
            return False, (
                f"the ROS 2 bridge needs {mod!r}, which cannot be imported "
                f"({type(e).__name__}: {e}); {ROS_EXTRA_HINT}"
            )
    return True, "rclpy and std_msgs, sensor_msgs, geometry_msgs, nav_msgs import"
