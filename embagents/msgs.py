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
from typing import Any

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
    "Image",
    "JointState",
    "JointTrajectory",
    "Odometry",
    "OccupancyGrid",
    "String",
    "StreamingString",
    "TaskFeedback",
    "Trackings",
    "Twist",
    "Video",
]

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


def _vec3(v: object) -> Vec3:
    x, y, z = (float(c) for c in v)  # type: ignore[union-attr]
    return (x, y, z)


def _quat(v: object) -> Quat:
    x, y, z, w = (float(c) for c in v)  # type: ignore[union-attr]
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
    """PCM audio: ``data`` int16 or float32 samples, interleaved when channels > 1."""

    data: np.ndarray = attrs.field(factory=lambda: np.zeros(0, np.int16))
    sample_rate: int = 16000
    channels: int = 1
    stamp: float = 0.0


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

    data: np.ndarray = attrs.field(factory=lambda: np.zeros((0, 0), np.int8), converter=_array("int8", 2))
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
    position: np.ndarray = attrs.field(factory=lambda: np.zeros(0), converter=_array("float64", 1))
    velocity: np.ndarray = attrs.field(factory=lambda: np.zeros(0), converter=_array("float64", 1))
    effort: np.ndarray = attrs.field(factory=lambda: np.zeros(0), converter=_array("float64", 1))
    stamp: float = 0.0


@message("embagents/JointTrajectory")
@attrs.define(eq=False)
class JointTrajectory:
    """A chunk of joint commands: ``positions`` / ``velocities`` (T, N) for ``joint_names``, point t due
    ``time_from_start[t]`` seconds after ``stamp``. Either array may be empty (shape (0, N))."""

    joint_names: list[str] = attrs.field(factory=list)
    positions: np.ndarray = attrs.field(factory=lambda: np.zeros((0, 0)), converter=_array("float64", 2))
    velocities: np.ndarray = attrs.field(factory=lambda: np.zeros((0, 0)), converter=_array("float64", 2))
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


@message("embagents/Health")
@attrs.define
class Health:
    """A component's health report (published by the runtime, read by fallbacks)."""

    component: str = ""
    status: HealthStatus = attrs.field(default=HealthStatus.HEALTHY, converter=HealthStatus.parse)
    text: str = ""
    stamp: float = 0.0



MESSAGE_TYPES: dict[str, type] = {
    cls.__name__: cls
    for cls in (
        String, StreamingString, Image, CompressedImage, Audio, Detections, Trackings, Video, Twist, Odometry,
        OccupancyGrid, JointState, JointTrajectory, TaskFeedback, Health, BargeIn,
    )
}
