"""Message types of the robotics layer: attrs classes with msgpack codecs.

Arrays (images, audio, boxes, grids) are numpy arrays; above ~64 KB they
travel through shared memory between actor processes without copies.

Example::

    >>> from embagents.msgs import String, Twist
    >>> String(data="hello")
    String(data='hello')
    >>> Twist(linear=(0.2, 0.0, 0.0)).angular
    (0.0, 0.0, 0.0)
"""

from __future__ import annotations

import contextlib
import enum
import struct
from collections.abc import Iterable
from typing import Any, SupportsFloat

import attrs
import numpy as np

from actors.codec import message

__all__ = [
    "MESSAGE_TYPES",
    "Audio",
    "BargeIn",
    "CompressedImage",
    "Detections",
    "Health",
    "HealthStatus",
    "IMU_FLAT",
    "Image",
    "Imu",
    "JointState",
    "JointTrajectory",
    "LaserScan",
    "Odometry",
    "OccupancyGrid",
    "Point",
    "PointCloud2",
    "Pose",
    "PoseStamped",
    "Quaternion",
    "RosMessage",
    "String",
    "StreamingString",
    "TaskFeedback",
    "Trackings",
    "Twist",
    "Video",
    "VoiceStage",
]

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


def _vec3(v: Iterable[SupportsFloat | str]) -> Vec3:
    x, y, z = (float(c) for c in v)
    return (x, y, z)


def _quat(v: Iterable[SupportsFloat | str]) -> Quat:
    x, y, z, w = (float(c) for c in v)
    return (x, y, z, w)


def _array(dtype: str, ndim: int | None = None):  # noqa: ANN202 - attrs converter factory
    def conv(v: object) -> np.ndarray:
        a = np.asarray(v, dtype=dtype)
        if ndim is not None and a.ndim != ndim:
            if a.size == 0:
                return a.reshape((0,) * ndim) if ndim > 1 else a.reshape(0)
            raise ValueError(f"expected a {ndim}-D array, got shape {a.shape}")
        return a

    return conv


# Named converters: mypy's attrs plugin types a field through a named function, not a factory's result;
# each calls a converter built once (a message's construction is a hot path).
_INT8_2D, _FLOAT64_1D, _FLOAT64_2D, _UINT8_3D = _array("int8", 2), _array("float64", 1), _array("float64", 2), _array("uint8", 3)


def _int8_2d(v: object) -> np.ndarray:
    return _INT8_2D(v)


def _float64_1d(v: object) -> np.ndarray:
    return _FLOAT64_1D(v)


def _float64_2d(v: object) -> np.ndarray:
    return _FLOAT64_2D(v)


def _uint8_3d(v: object) -> np.ndarray:
    return _UINT8_3D(v)


@message("embagents/String")
@attrs.define
class String:
    """A piece of text."""

    data: str = ""


@message("embagents/StreamingString")
@attrs.define
class StreamingString:
    """One chunk of a streamed text; ``done`` marks the last chunk of ``stream_id``."""

    data: str = ""
    done: bool = False
    stream_id: str = ""


@message("embagents/Image")
@attrs.define(eq=False)
class Image:
    """A raw image, ``data`` of shape (height, width, channels) or (height, width)."""

    data: np.ndarray = attrs.field(factory=lambda: np.zeros((0, 0, 3), np.uint8))
    encoding: str = "rgb8"
    stamp: float = 0.0
    frame_id: str = ""

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        return int(self.data.shape[1])


@message("embagents/CompressedImage")
@attrs.define
class CompressedImage:
    """An encoded image (``format`` is "jpeg" or "png")."""

    data: bytes = b""
    format: str = "jpeg"
    stamp: float = 0.0
    frame_id: str = ""


@message("embagents/Audio")
@attrs.define(eq=False)
class Audio:
    """PCM audio: ``data`` int16 or float32 samples, interleaved when channels > 1.

    ``text``: the words this audio says, when its maker knows them (TextToSpeech sets it on the first
    chunk of each sentence; the chunks after it with the same ``stream_id`` and no ``text`` go on with
    that sentence); ``stream_id``: the text stream it was made from (the ``StreamingString`` of an LLM's
    answer). With them, the Speaker can say which words have been played (its ``StreamingString`` output).
    """

    data: np.ndarray = attrs.field(factory=lambda: np.zeros(0, np.int16))
    sample_rate: int = 16000
    channels: int = 1
    stamp: float = 0.0
    text: str = ""
    stream_id: str = ""


def _boxes() -> Any:  # an attrs field
    return attrs.field(factory=lambda: np.zeros((0, 4), np.float32), converter=_array("float32", 2))


def _column(dtype: str) -> Any:  # an attrs field
    return attrs.field(factory=lambda: np.zeros(0, dtype), converter=_array(dtype, 1))


def _same_length(owner: object, **columns: object) -> None:
    """Every column has one entry per box (``boxes`` first)."""
    lengths = {k: len(v) for k, v in columns.items()}  # type: ignore[arg-type]
    if len(set(lengths.values())) > 1:
        n, others = lengths.pop("boxes"), ", ".join(f"{v} {k}" for k, v in lengths.items())
        raise ValueError(f"{type(owner).__name__} needs as many {', '.join(lengths)} as boxes: {n} boxes, {others}")


@message("embagents/Detections")
@attrs.define(eq=False)
class Detections:
    """Object detections in one image: ``boxes`` (N, 4) as x1, y1, x2, y2 pixels."""

    boxes: np.ndarray = _boxes()
    labels: list[str] = attrs.field(factory=list)
    scores: np.ndarray = _column("float32")
    image_width: int = 0
    image_height: int = 0
    stamp: float = 0.0
    frame_id: str = ""

    def __attrs_post_init__(self) -> None:
        _same_length(self, boxes=self.boxes, labels=self.labels, scores=self.scores)


@message("embagents/Trackings")
@attrs.define(eq=False)
class Trackings:
    """Tracked objects in one image: ``track_ids`` (N,) stay the same for one object over frames."""

    boxes: np.ndarray = _boxes()
    labels: list[str] = attrs.field(factory=list)
    scores: np.ndarray = _column("float32")
    track_ids: np.ndarray = _column("int64")
    image_width: int = 0
    image_height: int = 0
    stamp: float = 0.0
    frame_id: str = ""

    def __attrs_post_init__(self) -> None:
        _same_length(self, boxes=self.boxes, labels=self.labels, scores=self.scores, track_ids=self.track_ids)


@message("embagents/Video")
@attrs.define(eq=False)
class Video:
    """A clip of raw frames: ``frames`` (T, H, W, C) uint8, ``stamps`` (T,) seconds, RGB by default.

    Raw frames, not encoded bytes: a consumer (a VLM, a recorder) reads them
    without a codec, and the clip travels through shared memory.
    """

    frames: np.ndarray = attrs.field(factory=lambda: np.zeros((0, 0, 0, 3), np.uint8))
    stamps: np.ndarray = _column("float64")
    encoding: str = "rgb8"
    frame_id: str = ""

    def __attrs_post_init__(self) -> None:
        if self.frames.ndim != 4 or len(self.frames) != len(self.stamps):
            raise ValueError(f"Video needs frames (T, H, W, C) and T stamps: frames {self.frames.shape}, "
                             f"{len(self.stamps)} stamps")


@message("embagents/Twist")
@attrs.define
class Twist:
    """Velocity command: linear (m/s) and angular (rad/s) vectors."""

    linear: Vec3 = attrs.field(default=(0.0, 0.0, 0.0), converter=_vec3)
    angular: Vec3 = attrs.field(default=(0.0, 0.0, 0.0), converter=_vec3)


@message("embagents/Odometry")
@attrs.define
class Odometry:
    """Pose (position, orientation quaternion x, y, z, w) and twist of ``child_frame_id``."""

    position: Vec3 = attrs.field(default=(0.0, 0.0, 0.0), converter=_vec3)
    orientation: Quat = attrs.field(default=(0.0, 0.0, 0.0, 1.0), converter=_quat)
    linear: Vec3 = attrs.field(default=(0.0, 0.0, 0.0), converter=_vec3)
    angular: Vec3 = attrs.field(default=(0.0, 0.0, 0.0), converter=_vec3)
    frame_id: str = "odom"
    child_frame_id: str = "base_link"
    stamp: float = 0.0


@message("embagents/OccupancyGrid")
@attrs.define(eq=False)
class OccupancyGrid:
    """A 2-D map: ``data`` (height, width) int8, -1 unknown, 0..100 occupancy."""

    data: np.ndarray = attrs.field(factory=lambda: np.zeros((0, 0), np.int8), converter=_int8_2d)
    resolution: float = 0.05
    origin_position: Vec3 = attrs.field(default=(0.0, 0.0, 0.0), converter=_vec3)
    origin_orientation: Quat = attrs.field(default=(0.0, 0.0, 0.0, 1.0), converter=_quat)
    frame_id: str = "map"
    stamp: float = 0.0


@message("embagents/JointState")
@attrs.define(eq=False)
class JointState:
    """Joint names with positions (rad or m), velocities and efforts."""

    name: list[str] = attrs.field(factory=list)
    position: np.ndarray = attrs.field(factory=lambda: np.zeros(0), converter=_float64_1d)
    velocity: np.ndarray = attrs.field(factory=lambda: np.zeros(0), converter=_float64_1d)
    effort: np.ndarray = attrs.field(factory=lambda: np.zeros(0), converter=_float64_1d)
    stamp: float = 0.0


@message("embagents/JointTrajectory")
@attrs.define(eq=False)
class JointTrajectory:
    """A chunk of joint commands: ``positions`` / ``velocities`` (T, N) for ``joint_names``, point t due
    ``time_from_start[t]`` seconds after ``stamp``. Either array may be empty (shape (0, N))."""

    joint_names: list[str] = attrs.field(factory=list)
    positions: np.ndarray = attrs.field(factory=lambda: np.zeros((0, 0)), converter=_float64_2d)
    velocities: np.ndarray = attrs.field(factory=lambda: np.zeros((0, 0)), converter=_float64_2d)
    time_from_start: np.ndarray = _column("float64")
    stamp: float = 0.0


@message("embagents/TaskFeedback")
@attrs.define
class TaskFeedback:
    """Progress of a long-running task (a VLA's ``manipulate``): ``step`` of ``max_steps``;
    ``done`` marks the last, ``outcome`` says how it ended (succeeded, max_steps, stopped, replaced)."""

    task: str = ""
    step: int = 0
    max_steps: int = 0
    done: bool = False
    outcome: str = ""
    stamp: float = 0.0


@message("embagents/BargeIn")
@attrs.define
class BargeIn:
    """The user speaks while the robot does (published by SpeechToText with ``barge_in``).

    ``action``: ``"pause"`` (speech began: stop the sound, keep the rest), ``"resume"`` (it was a
    backchannel or a noise: play on), ``"interrupt"`` (real words: drop the answer, cancel its
    generation); ``text``: what was heard; ``stamp``: when the speech began (wall time).
    """

    action: str = ""
    text: str = ""
    stamp: float = 0.0


@message("embagents/VoiceStage")
@attrs.define
class VoiceStage:
    """A voice turn reached a stage (a metrics topic; see :mod:`embagents.components.voice_stages`).

    ``stage``: ``end_of_speech``, ``end_of_turn``, ``transcript`` (SpeechToText), ``llm_first_token`` (LLM),
    ``tts_first_audio`` (TextToSpeech), ``speaker_start`` (Speaker); ``stamp``: when (wall time);
    ``source``: the component that published it.
    """

    stage: str = ""
    stamp: float = 0.0
    source: str = ""


class HealthStatus(enum.IntEnum):
    """How a component is doing; failures drive :class:`~embagents.events.Fallback` rules."""

    HEALTHY = 0
    ALGORITHM_FAILURE = 1  # a step raised or its result is unusable; the process is fine
    COMPONENT_FAILURE = 2  # the component itself is broken (crashed, hung, lost its model)
    SYSTEM_FAILURE = 3  # something outside it is broken (a device, the network)

    @classmethod
    def parse(cls, value: object) -> HealthStatus:
        """A status from itself, its value or its name (any case).

        >>> HealthStatus.parse("algorithm_failure")
        <HealthStatus.ALGORITHM_FAILURE: 1>
        """
        if isinstance(value, cls):
            return value
        if isinstance(value, str) and value.upper() in cls.__members__:
            return cls[value.upper()]
        if isinstance(value, int) and not isinstance(value, bool):
            with contextlib.suppress(ValueError):
                return cls(value)
        raise ValueError(f"unknown health status {value!r}; known: {', '.join(cls.__members__)}")


def _health_status(value: object) -> HealthStatus:  # named: mypy's attrs plugin does not take a classmethod
    return HealthStatus.parse(value)


@message("embagents/Health")
@attrs.define
class Health:
    """A component's health report (published by the runtime, read by fallbacks).

    ``incarnation`` (1, 2, ... per process start; 0 outside a supervised run) and
    ``switches`` (model client switches that incarnation made) say who sent it: a
    fallback acts once per failing sender, however many reports it sent.
    """

    component: str = ""
    status: HealthStatus = attrs.field(default=HealthStatus.HEALTHY, converter=_health_status)
    text: str = ""
    stamp: float = 0.0
    incarnation: int = 0
    switches: int = 0


# Converters of nested fields: the class itself, a tuple, or a dict of its fields (JSON, YAML).
def _point(v: dict[str, Any] | Point | Iterable[SupportsFloat | str]) -> Point:
    if isinstance(v, dict):
        return Point(**v)
    return v if isinstance(v, Point) else Point(*_vec3(v))


def _quaternion(v: dict[str, Any] | Quaternion | Iterable[SupportsFloat | str]) -> Quaternion:
    if isinstance(v, dict):
        return Quaternion(**v)
    return v if isinstance(v, Quaternion) else Quaternion(*_quat(v))


def _pose(v: dict[str, Any] | Pose | Iterable[Any]) -> Pose:
    if isinstance(v, dict):
        return Pose(**v)
    if isinstance(v, Pose):
        return v
    position, orientation = v
    return Pose(position, orientation)


@message("embagents/Point")
@attrs.define
class Point:
    """A position in metres (``geometry_msgs/Point``)."""

    x: float = attrs.field(default=0.0, converter=float)
    y: float = attrs.field(default=0.0, converter=float)
    z: float = attrs.field(default=0.0, converter=float)


@message("embagents/Quaternion")
@attrs.define
class Quaternion:
    """An orientation as a unit quaternion x, y, z, w (``geometry_msgs/Quaternion``)."""

    x: float = attrs.field(default=0.0, converter=float)
    y: float = attrs.field(default=0.0, converter=float)
    z: float = attrs.field(default=0.0, converter=float)
    w: float = attrs.field(default=1.0, converter=float)


@message("embagents/Pose")
@attrs.define
class Pose:
    """Position and orientation (``geometry_msgs/Pose``); tuples are accepted.

    >>> Pose((1, 2, 0)).position
    Point(x=1.0, y=2.0, z=0.0)
    """

    position: Point = attrs.field(factory=Point, converter=_point)
    orientation: Quaternion = attrs.field(factory=Quaternion, converter=_quaternion)


@message("embagents/PoseStamped")
@attrs.define
class PoseStamped:
    """A pose in ``frame_id`` at ``stamp`` (``geometry_msgs/PoseStamped``; a Nav2 goal on ``/goal_pose``).

    >>> PoseStamped(Pose((2.0, 0.5, 0.0))).pose.position.x
    2.0
    """

    pose: Pose = attrs.field(factory=Pose, converter=_pose)
    frame_id: str = "map"
    stamp: float = 0.0


def _cov3() -> Any:  # an attrs field: a 3x3 covariance, row-major as ROS sends it
    return attrs.field(factory=lambda: np.zeros((3, 3)), converter=lambda v: np.asarray(v, np.float64).reshape(3, 3))


#: An Imu's flat form (see actors.codec): the stamp, then the 37 doubles in sensor_msgs/Imu's field
#: order (orientation, its covariance, angular velocity, its covariance, ...), then frame_id (UTF-8).
IMU_FLAT = struct.Struct("<38d")


def _imu_flat(m: Imu) -> bytes:
    parts = (m.orientation, m.orientation_covariance, m.angular_velocity, m.angular_velocity_covariance,
             m.linear_acceleration, m.linear_acceleration_covariance)
    doubles = np.concatenate([[m.stamp], *(np.ravel(p) for p in parts)]).astype("<f8", copy=False)
    return doubles.tobytes() + m.frame_id.encode()


def _imu_unflat(data: memoryview) -> Imu:
    # Built without attrs' converters: the values have their fields' types already. With cold caches
    # (a 200 Hz stream's) every Python or numpy call counts: 11 floats, 3 array views, one object.
    v = _IMU_SCALARS.unpack_from(data)
    imu = object.__new__(Imu)
    put, view = object.__setattr__, np.ndarray
    put(imu, "orientation", v[1:5])
    put(imu, "orientation_covariance", view((3, 3), _F8, data, 40))
    put(imu, "angular_velocity", v[5:8])
    put(imu, "angular_velocity_covariance", view((3, 3), _F8, data, 136))
    put(imu, "linear_acceleration", v[8:11])
    put(imu, "linear_acceleration_covariance", view((3, 3), _F8, data, 232))
    put(imu, "frame_id", str(data[IMU_FLAT.size :], "utf-8"))
    put(imu, "stamp", v[0])
    return imu


_IMU_SCALARS = struct.Struct("<5d72x3d72x3d")  # IMU_FLAT's stamp, orientation, angular velocity, acceleration
_F8 = np.dtype("<f8")


@message("embagents/Imu", flat=(_imu_flat, _imu_unflat))
@attrs.define(eq=False)
class Imu:
    """An IMU sample (``sensor_msgs/Imu``): orientation quaternion x, y, z, w, angular velocity (rad/s),
    linear acceleration (m/s^2), their 3x3 covariances (``[0, 0] == -1`` marks a missing estimate).

    Sent in its flat form (:data:`IMU_FLAT`), not as a map of fields: at 200 Hz each message finds
    the caches cold, where a map of fields and three arrays took ~60 us to encode and ~75 us to decode.
    """

    orientation: Quat = attrs.field(default=(0.0, 0.0, 0.0, 1.0), converter=_quat)
    angular_velocity: Vec3 = attrs.field(default=(0.0, 0.0, 0.0), converter=_vec3)
    linear_acceleration: Vec3 = attrs.field(default=(0.0, 0.0, 0.0), converter=_vec3)
    orientation_covariance: np.ndarray = _cov3()
    angular_velocity_covariance: np.ndarray = _cov3()
    linear_acceleration_covariance: np.ndarray = _cov3()
    frame_id: str = "imu_link"
    stamp: float = 0.0


@message("embagents/LaserScan")
@attrs.define(eq=False)
class LaserScan:
    """A planar laser scan (``sensor_msgs/LaserScan``): ``ranges`` (N,) metres from ``angle_min``
    in steps of ``angle_increment`` (rad); readings outside [range_min, range_max] are invalid."""

    ranges: np.ndarray = _column("float32")
    intensities: np.ndarray = _column("float32")
    angle_min: float = 0.0
    angle_max: float = 0.0
    angle_increment: float = 0.0
    time_increment: float = 0.0
    scan_time: float = 0.0
    range_min: float = 0.0
    range_max: float = 0.0
    frame_id: str = "laser"
    stamp: float = 0.0

    @property
    def angles(self) -> np.ndarray:
        """The angle (rad) of each reading."""
        return self.angle_min + self.angle_increment * np.arange(len(self.ranges))


@message("embagents/PointCloud2")
@attrs.define(eq=False)
class PointCloud2:
    """A point cloud (``sensor_msgs/PointCloud2``) as the ROS bytes plus their layout.

    ``data`` is (height, width, point_step) uint8 as it came; ``fields`` lists
    ``(name, offset, numpy dtype str, count)``. :attr:`points` views it as a
    numpy structured array without a copy (``cloud.points["x"]``);
    :meth:`from_points` builds one from a structured array.

    >>> import numpy as np
    >>> pts = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    >>> PointCloud2.from_points(pts).points["z"].shape
    (1, 3)
    """

    data: np.ndarray = attrs.field(factory=lambda: np.zeros((0, 0, 0), np.uint8), converter=_uint8_3d)
    fields: list[tuple[str, int, str, int]] = attrs.field(
        factory=list, converter=lambda v: [(str(n), int(o), str(t), int(c)) for n, o, t, c in v]
    )
    is_dense: bool = True
    frame_id: str = ""
    stamp: float = 0.0

    @property
    def dtype(self) -> np.dtype:
        """The structured dtype of one point (``itemsize`` is the point step)."""
        names, formats, offsets = [], [], []
        for name, offset, dt, count in self.fields:
            names.append(name)
            formats.append(np.dtype(dt) if count == 1 else np.dtype((dt, (count,))))
            offsets.append(offset)
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": self.data.shape[2]})

    @property
    def points(self) -> np.ndarray:
        """(height, width) structured array viewing ``data``."""
        h, w, step = self.data.shape
        flat = np.ascontiguousarray(self.data).reshape(-1)
        return flat.view(self.dtype).reshape(h, w) if flat.size else np.zeros((h, w), self.dtype)

    @classmethod
    def from_points(cls, points: np.ndarray, frame_id: str = "", stamp: float = 0.0) -> PointCloud2:
        """A cloud of a (N,) or (H, W) structured array (fields of plain numeric dtypes)."""
        pts = np.ascontiguousarray(points)
        names, layout = pts.dtype.names, pts.dtype.fields  # both None or neither
        if names is None or layout is None:
            raise ValueError(f"PointCloud2.from_points needs a structured array (fields x, y, z, ...), got {pts.dtype}")
        if pts.ndim == 1:
            pts = pts.reshape(1, -1)
        fields = []
        for name in names:
            dt, offset = layout[name][:2]
            base, count = (dt.base, int(np.prod(dt.shape))) if dt.shape else (dt, 1)
            fields.append((name, int(offset), base.str, count))
        data = pts.view(np.uint8).reshape(pts.shape[0], pts.shape[1], pts.dtype.itemsize)
        return cls(data=data, fields=fields, frame_id=frame_id, stamp=stamp)


@message("embagents/RosMessage")
@attrs.define(eq=False)
class RosMessage:
    """Any ROS message without a class of its own, as the bridge introspects it.

    ``ros_type`` is ``pkg/msg/Name``; ``fields`` holds the ROS field names:
    nested messages are RosMessages, numeric arrays numpy arrays, strings str,
    ``builtin_interfaces/Time`` and ``Duration`` (``header.stamp``) float
    seconds. Fields read as attributes, as on the ROS message.

    >>> m = RosMessage("sensor_msgs/msg/Temperature", {"temperature": 21.5, "variance": 0.0})
    >>> m.temperature
    21.5
    >>> m.humidity
    Traceback (most recent call last):
    ...
    AttributeError: sensor_msgs/msg/Temperature has no field 'humidity'; its fields: temperature, variance
    """

    ros_type: str = ""
    fields: dict[str, Any] = attrs.field(factory=dict)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        try:
            return self.fields[name]
        except KeyError:
            have = ", ".join(self.fields) or "none"
            raise AttributeError(f"{self.ros_type or 'RosMessage'} has no field {name!r}; its fields: {have}") from None

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dicts and lists (arrays as lists): for JSON and printing."""
        return {k: _plain(v) for k, v in self.fields.items()}


def _plain(v: Any) -> Any:
    if isinstance(v, RosMessage):
        return v.to_dict()
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v


MESSAGE_TYPES: dict[str, type] = {
    cls.__name__: cls
    for cls in (
        String, StreamingString, Image, CompressedImage, Audio, Detections, Trackings, Video, Twist, Odometry,
        OccupancyGrid, JointState, JointTrajectory, TaskFeedback, Health, Point, Quaternion, Pose, PoseStamped,
        Imu, LaserScan, PointCloud2, RosMessage, BargeIn, VoiceStage,
    )
}
