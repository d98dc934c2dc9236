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

===================================  =============================================
``std_msgs/msg/String``              :class:`~embagents.msgs.String`
``sensor_msgs/msg/Image``            :class:`~embagents.msgs.Image`
``sensor_msgs/msg/CompressedImage``  :class:`~embagents.msgs.CompressedImage`
``geometry_msgs/msg/Twist``          :class:`~embagents.msgs.Twist`
``nav_msgs/msg/Odometry``            :class:`~embagents.msgs.Odometry`
``nav_msgs/msg/OccupancyGrid``       :class:`~embagents.msgs.OccupancyGrid`
``sensor_msgs/msg/JointState``       :class:`~embagents.msgs.JointState`
``sensor_msgs/msg/PointCloud``       :class:`~embagents.msgs.Detections` (see below)
===================================  =============================================

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
import re

import attrs

from embagents.msgs import (
    CompressedImage,
    Detections,
    Image,
    JointState,
    OccupancyGrid,
    Odometry,
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
    "RosOutput",
    "SUPPORTED",
    "check_bridge",
    "normalize_ros_type",
    "ros_available",
    "ros_type_for",
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
}

#: ROS type -> our classes accepted on a RosOutput of that type.
OUTGOING: dict[str, tuple[type, ...]] = {k: (v,) for k, v in SUPPORTED.items()}
OUTGOING["std_msgs/msg/String"] = (String, StreamingString)

#: Our class -> the ROS type used when a RosOutput gives none.
DEFAULT_ROS_TYPE: dict[type, str] = {v: k for k, v in SUPPORTED.items()}
DEFAULT_ROS_TYPE[StreamingString] = "std_msgs/msg/String"

ROS_EXTRA_HINT = "install the ROS 2 extra: pip install 'embagents[ros]'"

_RELIABILITY = ("reliable", "best_effort")
_DURABILITY = ("volatile", "transient_local")
# ROS 2 topic names: tokens of [A-Za-z0-9_] not starting with a digit, joined by '/'.
_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_ROS_NAME = re.compile(rf"^/?{_TOKEN}(/{_TOKEN})*$")
_ROS_TYPE = re.compile(rf"^({_TOKEN})/(?:msg/)?({_TOKEN})$")


def _supported_text() -> str:
    return ", ".join(sorted(SUPPORTED))


def normalize_ros_type(ros_type: str) -> str:
    """``"std_msgs/String"`` or ``"std_msgs/msg/String"`` -> ``"std_msgs/msg/String"``.

    Raises ValueError for a malformed or unsupported type, naming the supported ones.

    >>> normalize_ros_type("geometry_msgs/Twist")
    'geometry_msgs/msg/Twist'
    """
    if not isinstance(ros_type, str):
        raise TypeError(f"ros_type must be a str like 'std_msgs/msg/String', got {ros_type!r}")
    m = _ROS_TYPE.match(ros_type.strip())
    if m is None:
        raise ValueError(
            f"malformed ROS type {ros_type!r}: write 'package/msg/Name' or 'package/Name'; "
            f"supported: {_supported_text()}"
        )
    full = f"{m.group(1)}/msg/{m.group(2)}"
    if full not in SUPPORTED:
        raise ValueError(f"unsupported ROS type {ros_type!r}; supported: {_supported_text()}")
    return full


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
    topic: str | None = None
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
        return SUPPORTED[self.ros_type]


@attrs.define(frozen=True)
class RosOutput:
    """An internal ``topic`` going out to ROS on ``ros_topic`` (default ``"/" + topic``).

    Without ``ros_type`` the bridge picks it from the first message's class
    (:data:`DEFAULT_ROS_TYPE`) and creates the ROS publisher then; give it (or
    call :meth:`resolved`) to have the publisher discoverable from the start.

    >>> RosOutput("answer", ros_type="std_msgs/String").accepts
    (<class 'embagents.msgs.String'>, <class 'embagents.msgs.StreamingString'>)
    """

    topic: str
    ros_topic: str | None = None
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
        if self.ros_type is None:
            return tuple(DEFAULT_ROS_TYPE)
        return OUTGOING[self.ros_type]

    def resolved(self, msg_class: type) -> RosOutput:
        """This output with ``ros_type`` filled in from the internal topic's message class."""
        ros_type = ros_type_for(msg_class)
        if self.ros_type is not None and msg_class not in OUTGOING[self.ros_type]:
            raise TypeError(
                f"RosOutput({self.topic!r}) is declared as {self.ros_type}, which carries "
                f"{', '.join(c.__name__ for c in OUTGOING[self.ros_type])}, but the topic "
                f"carries {msg_class.__name__}"
            )
        return attrs.evolve(self, ros_type=self.ros_type or ros_type)


def check_bridge(inputs: list[RosInput], outputs: list[RosOutput]) -> None:
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
    for d in [*inputs, *outputs]:
        if d.ros_type is None:
            continue
        key = "/" + d.ros_topic.lstrip("/")
        other = ros_types.setdefault(key, d.ros_type)
        if other != d.ros_type:
            raise ValueError(f"ROS topic {key!r} is declared both as {other} and as {d.ros_type}")
    for i in inputs:
        o = seen_out.get(i.topic)
        if o is not None and o.ros_topic.lstrip("/") == i.ros_topic.lstrip("/"):
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
