"""Our message types in MCAP: Foxglove schemas for images and audio, JSON Schema for the rest; round trips."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from embagents.msgs import (
    Audio,
    CompressedImage,
    Detections,
    Health,
    Image,
    Imu,
    JointState,
    LaserScan,
    OccupancyGrid,
    Odometry,
    PointCloud2,
    Pose,
    PoseStamped,
    RosMessage,
    StreamingString,
    String,
    Trackings,
    Twist,
    Video,
)
from embagents.tools.mcap_codec import EVENTS_SCHEMA, decode, kind_of
from embagents.tools.recorder import _File

MESSAGES = [
    String(data="hi"), StreamingString(data="to", done=True, stream_id="s"),
    Image(data=np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3), stamp=1.5, frame_id="cam"),
    Image(data=np.arange(6, dtype=np.uint8).reshape(2, 3), encoding="mono8"),
    CompressedImage(data=b"\xff\xd8jpeg", format="jpeg", stamp=2.0),
    Audio(data=np.arange(8, dtype=np.int16), sample_rate=8000, channels=2),
    Audio(data=np.linspace(-1, 1, 8, dtype=np.float32)),
    Detections(boxes=[[1, 2, 3, 4]], labels=["cup"], scores=[0.5], image_width=8, image_height=6),
    Trackings(boxes=[[1, 2, 3, 4]], labels=["cup"], scores=[0.5], track_ids=[7]),
    Video(frames=np.zeros((2, 40, 60, 3), np.uint8), stamps=[0.0, 0.1]),
    Twist(linear=(1, 2, 3)), Odometry(position=(1, 0, 0)), JointState(name=["j"], position=[0.3]),
    OccupancyGrid(data=np.full((3, 4), -1, np.int8)), Health(component="c", status=2, text="t"),
    PoseStamped(Pose((1, 2, 3), (0, 0, 0.6, 0.8)), frame_id="map", stamp=3.0),
    Imu(linear_acceleration=(0, 0, 9.81), orientation_covariance=np.eye(3), stamp=1.0),
    LaserScan(ranges=np.linspace(0.1, 5, 360, dtype=np.float32), angle_increment=0.0175),
    PointCloud2.from_points(np.zeros(3000, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")]), frame_id="lidar"),
]


def _same(a: object, b: object) -> bool:
    import attrs

    for f in attrs.fields(type(a)):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            if x.dtype != y.dtype or x.shape != y.shape or not np.array_equal(x, y):
                return False
        elif x != y and not (isinstance(x, float) and abs(x - y) < 1e-6):
            return False
    return True


@pytest.mark.parametrize("msg", MESSAGES, ids=lambda m: type(m).__name__)
def test_every_message_type_round_trips(msg: object) -> None:
    kind = kind_of(type(msg))
    back = decode(kind.schema_name, kind.encode(msg))
    assert type(back) is type(msg) and _same(msg, back)


def test_an_introspected_ros_message_round_trips_with_nested_messages_and_arrays() -> None:
    header = RosMessage("std_msgs/msg/Header", {"stamp": 1.5, "frame_id": "gps"})
    fix = RosMessage("sensor_msgs/msg/NavSatFix", {"header": header, "latitude": 48.1, "status": {"status": 2},
                                                   "position_covariance": np.arange(9.0),
                                                   "big": np.arange(5000, dtype=np.float32)})
    kind = kind_of(RosMessage)
    back = decode(kind.schema_name, kind.encode(fix))
    assert back.ros_type == "sensor_msgs/msg/NavSatFix" and back.latitude == 48.1
    assert back.header.ros_type == "std_msgs/msg/Header" and back.header.stamp == 1.5
    assert back.big.dtype == np.float32 and np.array_equal(back.big, fix.big)  # a packed array comes back as one
    assert list(back.position_covariance) == list(range(9))


def test_images_and_audio_use_foxglove_schemas_the_rest_json_schema() -> None:
    assert kind_of(Image).schema_name == "foxglove.RawImage" and kind_of(Image).message_encoding == "protobuf"
    assert kind_of(Audio).schema_name == "foxglove.RawAudio"
    det = kind_of(Detections)
    schema = json.loads(det.schema_data)
    assert det.schema_encoding == "jsonschema" and schema["properties"]["labels"]["type"] == "array"
    assert kind_of(None).schema_name == EVENTS_SCHEMA


def test_a_file_written_with_the_mcap_library_reads_back(tmp_path: Path) -> None:
    f = _File(str(tmp_path / "t.mcap"), "zstd")
    for i, msg in enumerate(MESSAGES):
        f.writer.add_message(f.channel(f"t{i}", type(msg)), log_time=i, publish_time=i, data=kind_of(type(msg)).encode(msg))
    f.close()
    with open(tmp_path / "t.mcap", "rb") as fh:
        got = [decode(s.name, m.data) for s, _c, m in make_reader(fh).iter_messages()]
    assert [type(m) for m in got] == [type(m) for m in MESSAGES]


def test_an_unknown_schema_is_named() -> None:
    with pytest.raises(ValueError, match="unknown schema 'other.Thing'"):
        decode("other.Thing", b"{}")
