"""Round trips our messages <-> real ROS 2 messages (rclpy, no mocks).

Each pair is checked twice: straight through to_ros/from_ros, and through
CDR serialization (what a publish/subscription does), so the zero-copy
buffer path is proven on the wire format too.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("rclpy", reason="ROS 2 bridge tests need: pip install 'embagents[ros]'")

from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import ChannelFloat32, PointCloud  # noqa: E402
from sensor_msgs.msg import Image as RosImage  # noqa: E402

from actors.codec import Codec  # noqa: E402
from embagents.msgs import (  # noqa: E402
    IMU_FLAT,
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
from embagents.ros import SUPPORTED, ros_type_for  # noqa: E402
from embagents.ros.convert import (  # noqa: E402
    ENCODINGS,
    converter_from_cdr,
    from_ros,
    ros_msg_class,
    stamp_to_time,
    time_to_stamp,
    to_ros,
)


def wire(ros_msg):
    """Serialize and deserialize, as publish + subscription do."""
    return deserialize_message(serialize_message(ros_msg), type(ros_msg))


def both_ways(msg, ros_type=None):
    """Our msg -> ROS -> ours, directly and over the wire; returns both results."""
    ros_type = ros_type or ros_type_for(type(msg))
    ros = to_ros(msg, ros_type)
    assert isinstance(ros, ros_msg_class(ros_type))
    return from_ros(ros, ros_type), from_ros(wire(ros), ros_type)


def test_every_supported_type_has_a_round_trip_test():
    assert set(SUPPORTED.values()) == {String, Image, CompressedImage, Twist, Odometry, OccupancyGrid, JointState, Detections,
                                       Point, Quaternion, Pose, PoseStamped, Imu, LaserScan, PointCloud2, JointTrajectory}


def test_string():
    for back in both_ways(String(data="héllo ROS ✓")):
        assert back == String(data="héllo ROS ✓")


def test_streaming_string_goes_out_as_one_string_per_chunk():
    ros = to_ros(StreamingString(data="chunk", done=False, stream_id="s1"), "std_msgs/String")
    assert type(ros).__name__ == "String" and ros.data == "chunk"
    assert from_ros(wire(ros), "std_msgs/msg/String") == String(data="chunk")


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
def test_image_each_encoding(encoding):
    dtype, ch = ENCODINGS[encoding]
    shape = (3, 5) if ch == 1 else (3, 5, ch)
    rng = np.random.default_rng(1)
    if dtype.kind == "f":
        data = rng.standard_normal(shape).astype(dtype)
    else:
        data = rng.integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)
    img = Image(data=data, encoding=encoding, stamp=1700000000.25, frame_id="cam")
    ros = to_ros(img)
    assert (ros.height, ros.width, ros.encoding) == (3, 5, encoding)
    assert ros.step == 5 * ch * dtype.itemsize
    for back in both_ways(img):
        assert back.encoding == encoding and back.frame_id == "cam"
        assert back.data.dtype == dtype and back.data.shape == shape
        np.testing.assert_array_equal(back.data, data)
        assert back.stamp == pytest.approx(1700000000.25, abs=1e-6)


def test_image_1080p_outgoing_shares_the_numpy_buffer():
    data = np.random.default_rng(2).integers(0, 256, (1080, 1920, 3), dtype=np.uint8)
    ros = to_ros(Image(data=data))
    # No copy until publish: the message references our buffer.
    assert np.shares_memory(np.frombuffer(ros.data, np.uint8), data)
    assert len(serialize_message(ros)) > data.nbytes
    back = from_ros(wire(ros), "sensor_msgs/Image")
    np.testing.assert_array_equal(back.data, data)


def test_image_incoming_is_a_view_without_copy():
    ros = wire(to_ros(Image(data=np.arange(24, dtype=np.uint8).reshape(2, 4, 3))))
    back = from_ros(ros, "sensor_msgs/Image")
    assert np.shares_memory(back.data, np.frombuffer(ros.data, np.uint8))


def _padded_ros_image(h, w, ch, dtype, pad):
    """A ROS Image whose rows carry `pad` bytes of junk after the pixels."""
    dtype = np.dtype(dtype)
    pixels = (np.arange(h * w * ch) % 251).astype(dtype).reshape(h, w, ch)
    row = w * ch * dtype.itemsize
    raw = bytearray()
    for r in range(h):
        raw += pixels[r].tobytes() + b"\xab" * pad
    m = RosImage(height=h, width=w, step=row + pad, is_bigendian=0)
    m.data = bytes(raw)
    return m, pixels


@pytest.mark.parametrize(("encoding", "ch", "dtype", "pad"), [("rgb8", 3, np.uint8, 7), ("16UC1", 1, np.uint16, 6), ("32FC1", 1, np.float32, 4)])
def test_image_padded_step_rows(encoding, ch, dtype, pad):
    m, pixels = _padded_ros_image(4, 5, ch, dtype, pad)
    m.encoding = encoding
    expect = pixels if ch > 1 else pixels[..., 0]
    for ros in (m, wire(m)):
        back = from_ros(ros, "sensor_msgs/msg/Image")
        np.testing.assert_array_equal(back.data, expect)
        assert back.data.strides[0] == ros.step  # a view that skips the padding
        # Going back out, the rows are packed again.
        again = to_ros(back)
        assert again.step == 5 * ch * np.dtype(dtype).itemsize
        np.testing.assert_array_equal(from_ros(wire(again), "sensor_msgs/Image").data, expect)


def test_image_big_endian_incoming_is_made_native():
    data = np.arange(12, dtype=">u2").reshape(3, 4) * 257
    m = RosImage(height=3, width=4, step=8, encoding="16UC1", is_bigendian=1)
    m.data = data.tobytes()
    back = from_ros(wire(m), "sensor_msgs/Image")
    assert back.data.dtype == np.dtype(np.uint16)
    np.testing.assert_array_equal(back.data, data.astype(np.uint16))


def test_image_errors_are_clear():
    with pytest.raises(ValueError, match="encoding 'yuv422' is not supported"):
        to_ros(Image(data=np.zeros((2, 2, 2), np.uint8), encoding="yuv422"))
    with pytest.raises(ValueError, match=r"'rgb8' needs uint8 data of shape \(height, width, 3\); got float32"):
        to_ros(Image(data=np.zeros((2, 2, 3), np.float32), encoding="rgb8"))
    with pytest.raises(ValueError, match="'mono8' needs uint8 data of shape"):
        to_ros(Image(data=np.zeros((2, 2, 3), np.uint8), encoding="mono8"))
    short = RosImage(height=4, width=4, step=12, encoding="rgb8")
    short.data = bytes(40)
    with pytest.raises(ValueError, match="40 bytes; 4 rows of step 12 need 48"):
        from_ros(short, "sensor_msgs/Image")
    narrow = RosImage(height=1, width=4, step=8, encoding="rgb8")
    narrow.data = bytes(12)
    with pytest.raises(ValueError, match="step 8 is shorter than a row"):
        from_ros(narrow, "sensor_msgs/Image")


def test_empty_image():
    for back in both_ways(Image()):
        assert back.data.shape == (0, 0, 3)


def test_compressed_image():
    payload = bytes(range(256)) * 40
    for back in both_ways(CompressedImage(data=payload, format="png", stamp=3.5, frame_id="f")):
        assert back == CompressedImage(data=payload, format="png", stamp=3.5, frame_id="f")
    ros = to_ros(CompressedImage(data=b"\xff\xd8", format="rgb8; jpeg compressed bgr8"))
    assert from_ros(wire(ros), "sensor_msgs/CompressedImage").format == "jpeg"


def test_twist():
    t = Twist(linear=(0.5, -0.25, 0.0), angular=(0.0, 0.0, 1.25))
    for back in both_ways(t):
        assert back == t


def test_odometry():
    o = Odometry(
        position=(1.0, 2.0, 0.5),
        orientation=(0.0, 0.0, math.sin(0.3), math.cos(0.3)),
        linear=(0.3, 0.0, 0.0),
        angular=(0.0, 0.0, -0.1),
        frame_id="odom",
        child_frame_id="base_footprint",
        stamp=12.000001,
    )
    for back in both_ways(o):
        assert back.stamp == pytest.approx(o.stamp, abs=1e-9)
        assert back == Odometry(**{**{f: getattr(o, f) for f in ("position", "orientation", "linear", "angular", "frame_id", "child_frame_id")}, "stamp": back.stamp})


def test_occupancy_grid():
    data = np.random.default_rng(3).integers(-1, 101, (40, 60)).astype(np.int8)
    g = OccupancyGrid(data=data, resolution=0.05, origin_position=(-1.0, -2.0, 0.0), origin_orientation=(0, 0, 0, 1), frame_id="map", stamp=7.5)
    ros = to_ros(g)
    assert (ros.info.width, ros.info.height) == (60, 40)
    for back in both_ways(g):
        np.testing.assert_array_equal(back.data, data)
        assert back.resolution == 0.05  # float32 on the wire, shortest decimal back
        assert back.origin_position == (-1.0, -2.0, 0.0) and back.origin_orientation == (0.0, 0.0, 0.0, 1.0)
        assert (back.frame_id, back.stamp) == ("map", 7.5)


def test_joint_state():
    j = JointState(name=["shoulder", "elbow"], position=[0.1, -0.2], velocity=[0.0, 1.5], effort=[], stamp=100.125)
    for back in both_ways(j):
        assert back.name == ["shoulder", "elbow"]
        np.testing.assert_array_equal(back.position, [0.1, -0.2])
        np.testing.assert_array_equal(back.velocity, [0.0, 1.5])
        assert back.effort.shape == (0,) and back.stamp == 100.125


def test_detections_layout_and_round_trip():
    d = Detections(
        boxes=[[10, 20, 110, 220], [0.5, 1.5, 2.5, 3.5]],
        labels=["person", "cup"],
        scores=[0.9, 0.25],
        image_width=640,
        image_height=480,
        stamp=5.25,
        frame_id="cam",
    )
    ros = to_ros(d)
    assert type(ros) is PointCloud and len(ros.points) == 0
    assert ros.channels[0].name == "image_size" and list(ros.channels[0].values) == [640.0, 480.0]
    assert ros.channels[1].name == "person"
    np.testing.assert_allclose(list(ros.channels[1].values), [10, 20, 110, 220, 0.9], rtol=1e-6)
    for back in both_ways(d):
        np.testing.assert_array_equal(back.boxes, d.boxes)
        np.testing.assert_array_equal(back.scores, d.scores)
        assert back.labels == ["person", "cup"]
        assert (back.image_width, back.image_height, back.stamp, back.frame_id) == (640, 480, 5.25, "cam")
    for back in both_ways(Detections()):
        assert back.boxes.shape == (0, 4) and back.labels == []


def test_detections_rejects_other_point_clouds():
    with pytest.raises(ValueError, match="not a Detections message.*image_size"):
        from_ros(PointCloud(), "sensor_msgs/PointCloud")
    bad = PointCloud(channels=[ChannelFloat32(name="image_size", values=[1.0, 2.0]), ChannelFloat32(name="x", values=[1.0])])
    with pytest.raises(ValueError, match=r"channel 1 \('x'\) has 1 values, not 5"):
        from_ros(bad, "sensor_msgs/PointCloud")


@pytest.mark.parametrize("stamp", [0.0, 1.5, 1700000000.123456, -2.25, 0.9999999999])
def test_stamps(stamp):
    t = stamp_to_time(stamp)
    assert 0 <= t.nanosec < 1_000_000_000
    assert time_to_stamp(t) == pytest.approx(stamp, abs=1e-6)
    assert time_to_stamp(wire(t)) == time_to_stamp(t)


def test_bad_stamps():
    with pytest.raises(ValueError, match="finite"):
        stamp_to_time(float("nan"))
    with pytest.raises(ValueError, match="int32"):
        stamp_to_time(2.0**40)


def test_type_mismatches():
    with pytest.raises(TypeError, match="geometry_msgs/msg/Twist carries Twist, RosMessage, got String"):
        to_ros(String(data="x"), "geometry_msgs/Twist")
    with pytest.raises(TypeError, match="cannot convert dict"):
        to_ros({"data": 1})
    with pytest.raises(TypeError, match="expected a sensor_msgs/msg/Image message, got std_msgs.msg.*String"):
        from_ros(to_ros(String(data="x")), "sensor_msgs/Image")
    with pytest.raises(TypeError, match="expected a sensor_msgs/msg/Imu message"):
        from_ros(to_ros(String(data="x")), "sensor_msgs/msg/Imu")
    with pytest.raises(TypeError, match="a RosMessage of std_msgs/msg/String cannot go out as sensor_msgs/msg/Imu"):
        to_ros(RosMessage("std_msgs/msg/String", {"data": "x"}), "sensor_msgs/Imu")


def test_public_setter_fallback_gives_the_same_messages(monkeypatch):
    # Where the generated message code lacks the buffer path, _put_buffer uses array('B').
    from embagents.ros import convert

    monkeypatch.setattr(convert, "_fast_slot", False)
    data = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    ros = to_ros(Image(data=data))
    assert type(ros.data).__name__ == "array"
    np.testing.assert_array_equal(from_ros(wire(ros), "sensor_msgs/Image").data, data)
    grid = np.array([[-1, 0], [50, 100]], np.int8)
    np.testing.assert_array_equal(from_ros(wire(to_ros(OccupancyGrid(data=grid))), "nav_msgs/OccupancyGrid").data, grid)


# --- declarations (embagents.ros.spec) ---------------------------------------


def test_declarations_defaults_and_normalization():
    from embagents.ros import QoS, RosInput, RosOutput

    i = RosInput("/camera/image_raw", "sensor_msgs/Image")
    assert (i.topic, i.ros_type, i.qos) == ("camera/image_raw", "sensor_msgs/msg/Image", QoS())
    assert i.msg_type is Image
    o = RosOutput("answer", ros_type="std_msgs/msg/String", qos=QoS(depth=1, reliability="best_effort"))
    assert o.ros_topic == "/answer" and o.accepts == (String, StreamingString, RosMessage)
    assert RosOutput("cmd_vel").resolved(Twist).ros_type == "geometry_msgs/msg/Twist"
    with pytest.raises(TypeError, match="declared as geometry_msgs/msg/Twist.*carries String"):
        RosOutput("cmd_vel", ros_type="geometry_msgs/Twist").resolved(String)


def test_declaration_errors_are_clear():
    from embagents.ros import QoS, RosInput, RosOutput, check_bridge

    with pytest.raises(ValueError, match="QoS depth must be an int >= 1"):
        QoS(depth=0)
    with pytest.raises(ValueError, match="reliability must be one of 'reliable', 'best_effort'; got 'fast'"):
        QoS(reliability="fast")
    with pytest.raises(ValueError, match="durability must be one of 'volatile', 'transient_local'"):
        QoS(durability="persistent")
    with pytest.raises(ValueError, match="package 'vision_msgs' is not installed; pip install ros-vision-msgs"):
        RosInput("/dets", "vision_msgs/Detection2DArray")
    with pytest.raises(ValueError, match="sensor_msgs has no msg 'Imus'; it has: .*Imu, "):
        RosInput("/imu", "sensor_msgs/Imus")
    with pytest.raises(ValueError, match="malformed ROS msg type .String.: write .package/msg/Name."):
        RosInput("/dets", "String")
    with pytest.raises(ValueError, match="invalid ROS topic name for RosInput: '/2cams'"):
        RosInput("/2cams", "sensor_msgs/Image")
    with pytest.raises(ValueError, match="not a valid ROS name.*give ros_topic="):
        RosOutput("llm.answer")
    with pytest.raises(ValueError, match="has two RosOutputs"):
        check_bridge([], [RosOutput("a", ros_type="std_msgs/String"), RosOutput("a", ros_topic="/b")])
    with pytest.raises(ValueError, match="declared both as std_msgs/msg/String and as geometry_msgs/msg/Twist"):
        check_bridge([RosInput("/x", "std_msgs/String")], [RosOutput("y", ros_topic="/x", ros_type="geometry_msgs/Twist")])
    with pytest.raises(ValueError, match="echoed back forever"):
        check_bridge([RosInput("/x", "std_msgs/String")], [RosOutput("x", ros_type="std_msgs/String")])


def test_ros_available_here():
    from embagents.ros import ros_available

    ok, why = ros_available()
    assert ok, why


# --- typed classes beyond the first eight --------------------------------------


def test_pose_point_quaternion():
    goal = PoseStamped(Pose((2.0, -1.5, 0.0), (0.0, 0.0, 0.7071068, 0.7071068)), frame_id="map", stamp=12.5)
    for back in both_ways(goal):
        assert back == goal
    for msg in (Point(1, 2, 3), Quaternion(0, 0, 1, 0), Pose((1, 1, 1))):
        for back in both_ways(msg):
            assert back == msg
    ros = to_ros(goal)
    assert (ros.pose.position.x, ros.pose.orientation.w, ros.header.frame_id) == (2.0, 0.7071068, "map")


def test_imu():
    cov = np.arange(9.0).reshape(3, 3)
    imu = Imu(orientation=(0, 0, 0.1, 0.995), angular_velocity=(0.1, 0.2, 0.3), linear_acceleration=(0, 0, 9.81),
              orientation_covariance=cov, linear_acceleration_covariance=-np.eye(3), frame_id="imu", stamp=3.5)
    for back in both_ways(imu):
        assert back.orientation == imu.orientation and back.linear_acceleration == (0, 0, 9.81)
        np.testing.assert_array_equal(back.orientation_covariance, cov)
        np.testing.assert_array_equal(back.linear_acceleration_covariance, -np.eye(3))
        assert (back.frame_id, back.stamp) == ("imu", 3.5)
    assert list(to_ros(imu).orientation_covariance) == list(range(9))  # row-major, as ROS documents


def test_an_imu_crosses_processes_in_its_flat_form_with_every_field():
    imu = Imu(orientation=(0.1, 0.2, 0.3, 0.9), angular_velocity=(1, 2, 3), linear_acceleration=(4, 5, 6),
              orientation_covariance=np.arange(9.0).reshape(3, 3), angular_velocity_covariance=np.arange(9.0, 18.0),
              linear_acceleration_covariance=-np.eye(3), frame_id="imu_ñ", stamp=12.25)
    codec = Codec()
    data = codec.encode(imu)[0]
    assert len(data) == 4 + 1 + len("embagents/Imu") + IMU_FLAT.size + len("imu_ñ".encode())  # ext 16; no field names
    back = codec.decode(data)
    for name in ("orientation", "angular_velocity", "linear_acceleration", "frame_id", "stamp"):
        assert getattr(back, name) == getattr(imu, name), name
        assert type(getattr(back, name)) is type(getattr(imu, name)), name
    for name in ("orientation_covariance", "angular_velocity_covariance", "linear_acceleration_covariance"):
        got = getattr(back, name)
        assert got.shape == (3, 3) and got.dtype == np.float64, name
        np.testing.assert_array_equal(got, getattr(imu, name))
    back.angular_velocity = [7, 8, 9]  # a decoded Imu converts what is set on it like any other
    assert back.angular_velocity == (7.0, 8.0, 9.0)


def test_an_imu_read_from_its_cdr_bytes_equals_rclpys_deserialization():
    read, flat, codec = converter_from_cdr("sensor_msgs/Imu"), converter_from_cdr("sensor_msgs/Imu", flat=True), Codec()
    for frame_id in ("", "i", "imu", "imu_lin", "imu_link", "a_longer_frame_ñ"):  # every alignment of the doubles
        ros = to_ros(Imu(orientation=(0.1, 0.2, 0.3, 0.9), angular_velocity=(1, 2, 3), linear_acceleration=(4, 5, 6),
                         orientation_covariance=np.arange(9.0).reshape(3, 3), angular_velocity_covariance=-np.eye(3),
                         linear_acceleration_covariance=np.full((3, 3), 0.5), frame_id=frame_id, stamp=12.25))
        data = serialize_message(ros)
        rclpys = from_ros(deserialize_message(data, type(ros)), "sensor_msgs/Imu")
        # Read into an Imu, and as the bridge publishes it: its flat form, decoded by a subscriber.
        for ours in (read(data), codec.decode(codec.encode(flat(data))[0])):
            assert type(ours) is Imu
            for name in ("orientation", "angular_velocity", "linear_acceleration", "frame_id", "stamp"):
                assert getattr(ours, name) == getattr(rclpys, name), (frame_id, name)
            for name in ("orientation_covariance", "angular_velocity_covariance", "linear_acceleration_covariance"):
                np.testing.assert_array_equal(getattr(ours, name), getattr(rclpys, name))
    assert read(b"\x00\x00" + data[2:]) is None and flat(b"\x00\x00" + data[2:]) is None  # big endian: left to rclpy
    assert read(data[:40]) is None and flat(data[:40]) is None  # cut short
    assert converter_from_cdr("std_msgs/String") is None


def test_laser_scan():
    ranges = np.linspace(0.2, 10.0, 360, dtype=np.float32)
    scan = LaserScan(ranges=ranges, angle_min=-3.14, angle_max=3.14, angle_increment=0.0175, range_min=0.1,
                     range_max=12.0, frame_id="laser", stamp=1.0)
    for back in both_ways(scan):
        np.testing.assert_array_equal(back.ranges, ranges)
        assert back.intensities.shape == (0,)
        assert (back.angle_min, back.angle_increment, back.range_max) == (-3.14, 0.0175, 12.0)
    assert scan.angles[1] == pytest.approx(-3.14 + 0.0175)


def test_point_cloud2_is_a_structured_array():
    pts = np.zeros(1000, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "<u2")])
    pts["x"] = np.arange(1000)
    pts["ring"] = 7
    cloud = PointCloud2.from_points(pts, frame_id="lidar", stamp=2.0)
    ros = to_ros(cloud)
    assert (ros.height, ros.width, ros.point_step, [f.name for f in ros.fields]) == (1, 1000, 18, ["x", "y", "z", "intensity", "ring"])
    assert [f.datatype for f in ros.fields] == [7, 7, 7, 7, 4]
    for back in both_ways(cloud):
        got = back.points.reshape(-1)
        np.testing.assert_array_equal(got["x"], pts["x"])
        assert (got["ring"] == 7).all() and back.frame_id == "lidar"
    with pytest.raises(ValueError, match="needs a structured array"):
        PointCloud2.from_points(np.zeros((3, 3), np.float32))


def test_point_cloud2_from_a_padded_organized_ros_cloud():
    from sensor_msgs.msg import PointCloud2 as RosCloud
    from sensor_msgs.msg import PointField

    h, w, step, row = 2, 3, 16, 3 * 16 + 8  # 8 padding bytes per row
    raw = bytearray(h * row)
    for r in range(h):
        for c in range(w):
            raw[r * row + c * step: r * row + c * step + 4] = np.float32(10 * r + c).tobytes()
    ros = RosCloud(height=h, width=w, point_step=step, row_step=row, is_bigendian=False,
                   fields=[PointField(name="x", offset=0, datatype=7, count=1)])
    ros.data = bytes(raw)
    back = from_ros(wire(ros), "sensor_msgs/PointCloud2")
    np.testing.assert_array_equal(back.points["x"], [[0, 1, 2], [10, 11, 12]])
    ros.row_step = 10
    with pytest.raises(ValueError, match="PointCloud2 data has"):
        from_ros(ros, "sensor_msgs/PointCloud2")


def test_joint_trajectory():
    traj = JointTrajectory(joint_names=["j1", "j2"], positions=[[0.1, 0.2], [0.3, 0.4]],
                           time_from_start=[0.5, 1.25], stamp=4.0)
    ros = to_ros(traj)
    assert [p.time_from_start.nanosec for p in ros.points] == [500000000, 250000000]
    for back in both_ways(traj):
        np.testing.assert_array_equal(back.positions, traj.positions)
        assert back.velocities.shape == (0, 2) and list(back.time_from_start) == [0.5, 1.25]


# --- every other installed type, by introspection ------------------------------


def test_an_unmapped_type_comes_as_a_generic_message_with_ros_field_names():
    from sensor_msgs.msg import BatteryState, NavSatFix

    fix = NavSatFix(latitude=48.1, longitude=11.5, altitude=520.0)
    fix.header.stamp.sec, fix.header.stamp.nanosec = 10, 250_000_000
    fix.header.frame_id = "gps"
    fix.status.status = 2
    fix.position_covariance = np.arange(9.0)
    for back in (from_ros(fix, "sensor_msgs/NavSatFix"), from_ros(wire(fix), "sensor_msgs/NavSatFix")):
        assert isinstance(back, RosMessage) and back.ros_type == "sensor_msgs/msg/NavSatFix"
        assert (back.latitude, back.header.stamp, back.header.frame_id, back.status.status) == (48.1, 10.25, "gps", 2)
        assert back.position_covariance.dtype == np.float64 and back.position_covariance.shape == (9,)
        again = to_ros(back, "sensor_msgs/NavSatFix")
        assert wire(again) == wire(fix)
    battery = BatteryState(cell_voltage=[3.7, 3.8])
    got = from_ros(wire(battery), "sensor_msgs/BatteryState")
    assert got.cell_voltage.dtype == np.float32 and list(got.cell_voltage) == pytest.approx([3.7, 3.8])
    assert got.to_dict()["cell_voltage"] == pytest.approx([3.7, 3.8])


def test_generic_lists_of_nested_messages_and_durations():
    from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint

    ros = MultiDOFJointTrajectory(joint_names=["base"], points=[MultiDOFJointTrajectoryPoint()])
    ros.points[0].time_from_start.sec = 2
    back = from_ros(wire(ros), "trajectory_msgs/MultiDOFJointTrajectory")
    assert back.points[0].time_from_start == 2.0 and back.points[0].transforms == []
    assert wire(to_ros(back)) == wire(ros)


def test_generic_bad_fields_are_named():
    with pytest.raises(ValueError, match="sensor_msgs/msg/NavSatFix has no field 'lat'; its fields: header, status, latitude"):
        to_ros(RosMessage("sensor_msgs/msg/NavSatFix", {"lat": 1.0}))
    with pytest.raises(ValueError, match="field 'status.status'"):
        to_ros(RosMessage("sensor_msgs/msg/NavSatFix", {"status": {"status": "fixed"}}))
    with pytest.raises(AttributeError, match="NavSatFix has no field 'lat'; its fields: latitude"):
        _ = RosMessage("sensor_msgs/msg/NavSatFix", {"latitude": 1.0}).lat


def test_generic_messages_cross_processes_through_the_codec():
    from actors.codec import Codec

    back = from_ros(wire(to_ros(RosMessage("sensor_msgs/msg/NavSatFix", {"latitude": 1.5}))), "sensor_msgs/NavSatFix")
    codec = Codec()
    got = codec.decode(codec.encode(back)[0])
    assert got.latitude == 1.5 and got.header.stamp == 0.0 and got.position_covariance.shape == (9,)


def test_typed_and_generic_declarations_without_a_mapping_table():
    from embagents.ros import RosInput, RosOutput

    assert RosInput("/imu", "sensor_msgs/Imu").msg_type is Imu
    assert RosInput("/scan", "sensor_msgs/LaserScan").msg_type is LaserScan
    assert RosOutput("goal_pose", ros_type="geometry_msgs/PoseStamped").accepts == (PoseStamped, RosMessage)
    assert RosInput("/fix", "sensor_msgs/NavSatFix").msg_type is RosMessage
    assert RosOutput("goal_pose").resolved(PoseStamped).ros_type == "geometry_msgs/msg/PoseStamped"
    assert RosMessage in RosOutput("fix_out").accepts  # goes out as the message's own ros_type


def test_service_and_action_declarations_name_missing_wheels_and_bad_input():
    from embagents.ros import RosAction, RosLifecycle, RosService, check_bridge

    with pytest.raises(ValueError, match="package 'nav2_msgs' is not installed; pip install ros-nav2-msgs"):
        RosAction("/navigate_to_pose", "nav2_msgs/NavigateToPose", goal="nav_goal", result="nav_result")
    assert RosAction("/fibonacci", "test_msgs/Fibonacci", goal="g", result="r").action_type == "test_msgs/action/Fibonacci"
    with pytest.raises(ValueError, match="std_srvs has no srv 'Trigerr'; it has: .*Trigger"):
        RosService("/x", "std_srvs/Trigerr", component="c", method="m")
    with pytest.raises(ValueError, match="malformed ROS srv type 'std_srvs/msg/Trigger'"):
        RosService("/x", "std_srvs/msg/Trigger", component="c", method="m")
    with pytest.raises(ValueError, match="timeout must be seconds > 0"):
        RosService("/x", "std_srvs/Trigger", component="c", method="m", timeout=0)
    with pytest.raises(ValueError, match="is declared twice"):
        check_bridge([], [], [RosService("/x", "std_srvs/Trigger", component="c", method="m")] * 2)
    with pytest.raises(ValueError, match="RosLifecycle component 'my-llm'"):
        RosLifecycle(["my-llm"])
