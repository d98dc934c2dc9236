"""RosBridgeCore against real ROS 2 nodes in other processes (rclpy over DDS, no mocks).

Every test run uses its own ROS_DOMAIN_ID (from the pid) and localhost-only
discovery, so parallel runs do not see each other; every subprocess is
killed in teardown.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

pytest.importorskip("rclpy", reason="ROS 2 bridge tests need: pip install 'embagents[ros]'")

from actors.codec import Codec, Flat  # noqa: E402
from embagents.msgs import Image, Imu, StreamingString, String, Twist  # noqa: E402
from embagents.ros import QoS, RosInput, RosOutput  # noqa: E402
from embagents.ros.fastdds_shm import clean_zombie_fastdds_segments  # noqa: E402
from embagents.ros.node import RosBridgeCore  # noqa: E402
from tests.helpers import wait_until  # noqa: E402

DOMAIN_ID = 1 + os.getpid() % 100
DEADLINE = 15.0  # seconds for any one exchange; discovery takes ~0.1-1 s here

# An external ROS 2 node (plain rclpy): publishes text, a padded rgb8 image and
# a 16UC1 depth image every 50 ms.
EXTERNAL_PUBLISHER = r"""
import time, numpy as np, rclpy
from std_msgs.msg import String
from sensor_msgs.msg import Image
rclpy.init()
node = rclpy.create_node("external_pub")
pub_text = node.create_publisher(String, "/text_in", 10)
pub_img = node.create_publisher(Image, "/image_in", 10)
pub_depth = node.create_publisher(Image, "/depth_in", 10)
h, w, pad = 4, 5, 7
rgb = (np.arange(h * w * 3) % 251).astype(np.uint8).reshape(h, w, 3)
img = Image(height=h, width=w, encoding="rgb8", step=w * 3 + pad)
img.header.frame_id = "camera"
img.header.stamp.sec, img.header.stamp.nanosec = 12, 500000000
img.data = b"".join(rgb[r].tobytes() + b"\xee" * pad for r in range(h))
depth = (np.arange(480 * 640) % 65536).astype("<u2").reshape(480, 640)
dimg = Image(height=480, width=640, encoding="16UC1", step=1280, is_bigendian=0)
dimg.data = depth.tobytes()
print("READY", flush=True)
end = time.time() + 30
while time.time() < end:
    pub_text.publish(String(data="hello from ROS"))
    pub_img.publish(img)
    pub_depth.publish(dimg)
    time.sleep(0.05)
"""

# An external ROS 2 node (plain rclpy): prints what arrives as JSON lines and
# exits once it has the text, the image and both stream chunks.
EXTERNAL_SUBSCRIBER = r"""
import json, sys, time, numpy as np, rclpy
from std_msgs.msg import String
from sensor_msgs.msg import Image
from geometry_msgs.msg import Twist
rclpy.init()
node = rclpy.create_node("external_sub")
seen = {}
def out(key, rec):
    if key not in seen:
        seen[key] = rec
        print(json.dumps(rec), flush=True)
def on_text(m): out(("text", m.data), {"topic": "/text_out", "data": m.data})
def on_chunk(m): out(("chunk", m.data), {"topic": "/chunks_out", "data": m.data})
def on_twist(m): out(("twist",), {"topic": "/cmd_vel", "linear_x": m.linear.x, "angular_z": m.angular.z})
def on_image(m):
    a = np.frombuffer(m.data, np.uint8).reshape(m.height, m.width, 3)
    out(("image",), {"topic": "/image_out", "shape": list(a.shape), "encoding": m.encoding,
        "step": m.step, "frame_id": m.header.frame_id, "sec": m.header.stamp.sec,
        "nanosec": m.header.stamp.nanosec, "pixels": a.reshape(-1).tolist()})
node.create_subscription(String, "/text_out", on_text, 10)
node.create_subscription(String, "/chunks_out", on_chunk, 10)
node.create_subscription(Image, "/image_out", on_image, 10)
node.create_subscription(Twist, "/cmd_vel", on_twist, 10)
print(json.dumps({"ready": True}), flush=True)
end = time.time() + 30
want = {("text", "hello ROS"), ("image",), ("chunk", "Hel"), ("chunk", "lo"), ("twist",)}
while time.time() < end and not want <= set(seen):
    rclpy.spin_once(node, timeout_sec=0.05)
# Give a stray empty chunk (which must never be published) time to show up.
t = time.time() + 0.3
while time.time() < t:
    rclpy.spin_once(node, timeout_sec=0.05)
"""

# Our bridge in its own process, forwarding /text_in to stdout: the supervisor
# restarts the bridge by killing such a process and starting a new one.
BRIDGE_PROCESS = r"""
import sys
from embagents.ros import RosInput
from embagents.ros.node import RosBridgeCore
core = RosBridgeCore(inputs=[RosInput("/text_in", "std_msgs/String")])
core.start(sys.argv[1], lambda topic, msg: print(topic, msg.data, flush=True))
print("READY", flush=True)
sys.stdin.read()  # run until killed
"""

# A bridge process publishing 20 1080p frames best-effort, from a 64 MB DDS segment.
BRIDGE_BIG_PUBLISHER = r"""
import time, numpy as np
from embagents.msgs import Image
from embagents.ros import QoS, RosOutput
from embagents.ros.node import RosBridgeCore
core = RosBridgeCore(outputs=[RosOutput("frames", ros_topic="/big_out", ros_type="sensor_msgs/Image",
                                        qos=QoS(depth=1, reliability="best_effort"))])
core.start("big_pub", lambda t, m: None, shm_segment_mb=64)
end = time.time() + 15
while core.node.count_subscribers("/big_out") < 1 and time.time() < end:
    time.sleep(0.05)
time.sleep(0.5)
frame = (np.arange(1080 * 1920 * 3) % 253).astype(np.uint8).reshape(1080, 1920, 3)
for i in range(20):
    core.publish("frames", Image(data=frame, frame_id=str(i)))
    time.sleep(0.05)
time.sleep(1.0)
core.stop()
"""

BIG_SUBSCRIBER = r"""
import json, time, numpy as np, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image
rclpy.init()
node = rclpy.create_node("big_sub")
got = []
expect = (np.arange(1080 * 1920 * 3) % 253).astype(np.uint8)
def cb(m):
    got.append((m.header.frame_id, bool(np.array_equal(np.frombuffer(m.data, np.uint8), expect))))
node.create_subscription(Image, "/big_out", cb, QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
end = time.time() + 20
while time.time() < end and (not got or got[-1][0] != "19"):
    rclpy.spin_once(node, timeout_sec=0.1)
print(json.dumps(got), flush=True)
"""


@pytest.fixture(autouse=True)
def ros_env(monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", str(DOMAIN_ID))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


@pytest.fixture
def spawn():
    procs: list[subprocess.Popen] = []

    def run(script: str, *args: str) -> subprocess.Popen:
        p = subprocess.Popen(
            [sys.executable, "-c", script, *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=os.environ.copy(),
            start_new_session=True,
        )
        procs.append(p)
        return p

    yield run
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
        p.wait(timeout=10)
        for f in (p.stdin, p.stdout, p.stderr):
            f.close()


@pytest.fixture
def core_factory():
    cores: list[RosBridgeCore] = []

    def make(inputs=(), outputs=()) -> RosBridgeCore:
        c = RosBridgeCore(inputs, outputs)
        cores.append(c)
        return c

    yield make
    for c in cores:
        c.stop()


def line_reader(p: subprocess.Popen) -> queue.Queue:
    """Lines of p's stdout, read in a thread so waits can be bounded."""
    q: queue.Queue = queue.Queue()

    def pump() -> None:
        for line in p.stdout:
            q.put(line.rstrip("\n"))
        q.put(None)

    threading.Thread(target=pump, daemon=True).start()
    return q


def wait_line(q: queue.Queue, p: subprocess.Popen, timeout: float = DEADLINE) -> str:
    try:
        line = q.get(timeout=timeout)
    except queue.Empty:
        raise AssertionError(f"no output from the external node within {timeout} s") from None
    if line is None:
        raise AssertionError(f"external node exited ({p.poll()}): {p.stderr.read()[-2000:]}")
    return line


def test_receives_text_and_images_from_an_external_node(spawn, core_factory):
    got: queue.Queue = queue.Queue()
    core = core_factory(
        inputs=[
            RosInput("/text_in", "std_msgs/String"),
            RosInput("/image_in", "sensor_msgs/Image", topic="camera", qos=QoS(depth=1, reliability="best_effort")),
            RosInput("/depth_in", "sensor_msgs/msg/Image", topic="depth"),
        ]
    )
    core.start("bridge_in", lambda topic, msg: got.put((topic, msg)), domain_id=DOMAIN_ID)
    pub = spawn(EXTERNAL_PUBLISHER)
    first: dict[str, object] = {}
    end = time.monotonic() + DEADLINE
    while len(first) < 3 and time.monotonic() < end:
        try:
            topic, msg = got.get(timeout=0.5)
        except queue.Empty:
            assert pub.poll() is None, pub.stderr.read()
            continue
        first.setdefault(topic, msg)
    assert set(first) == {"text_in", "camera", "depth"}, f"only got {set(first)}"

    assert first["text_in"] == String(data="hello from ROS")
    img = first["camera"]
    assert isinstance(img, Image) and img.encoding == "rgb8" and img.frame_id == "camera"
    assert img.stamp == pytest.approx(12.5)
    # The padded rows (step 22 for 15 bytes of pixels) are skipped, pixels exact.
    np.testing.assert_array_equal(img.data, (np.arange(60) % 251).astype(np.uint8).reshape(4, 5, 3))
    depth = first["depth"]
    assert depth.data.dtype == np.uint16 and depth.data.shape == (480, 640)
    np.testing.assert_array_equal(depth.data, (np.arange(480 * 640) % 65536).astype(np.uint16).reshape(480, 640))
    assert core.counts["text_in"].received >= 1 and core.counts["camera"].errors == 0


IMU_PUBLISHER = r"""
import time, rclpy
from sensor_msgs.msg import Imu
rclpy.init()
node = rclpy.create_node("external_imu")
pub = node.create_publisher(Imu, "/imu_in", 10)
msg = Imu()
msg.header.frame_id, msg.header.stamp.sec, msg.header.stamp.nanosec = "imu_link", 3, 250000000
msg.linear_acceleration.z, msg.orientation.w = 9.81, 1.0
msg.angular_velocity_covariance[4] = 0.5
end = time.time() + 30
while time.time() < end:
    pub.publish(msg)
    time.sleep(0.05)
"""


def test_a_flat_core_hands_an_imu_on_as_its_flat_form_ready_to_publish(spawn):
    got: queue.Queue = queue.Queue()
    core = RosBridgeCore([RosInput("/imu_in", "sensor_msgs/Imu", topic="imu")], flat=True)
    try:
        core.start("bridge_flat", lambda topic, msg: got.put(msg), domain_id=DOMAIN_ID)
        pub = spawn(IMU_PUBLISHER)
        try:
            flat = got.get(timeout=DEADLINE)
        except queue.Empty:
            raise AssertionError(f"no Imu within {DEADLINE} s (publisher exit status {pub.poll()})") from None
    finally:
        core.stop()
    assert isinstance(flat, Flat) and flat.cls is Imu  # what the bridge publishes: no Imu built
    codec = Codec()
    imu = codec.decode(codec.encode(flat)[0])  # what a subscriber gets
    assert isinstance(imu, Imu) and (imu.frame_id, imu.stamp) == ("imu_link", 3.25)
    assert imu.linear_acceleration == (0.0, 0.0, 9.81) and imu.orientation == (0.0, 0.0, 0.0, 1.0)
    assert imu.angular_velocity_covariance[1, 1] == 0.5


def test_publishes_to_an_external_node(spawn, core_factory):
    sub = spawn(EXTERNAL_SUBSCRIBER)
    lines = line_reader(sub)
    assert json.loads(wait_line(lines, sub)) == {"ready": True}
    core = core_factory(
        outputs=[
            RosOutput("answer", ros_topic="/text_out", ros_type="std_msgs/String"),
            RosOutput("tokens", ros_topic="/chunks_out", ros_type="std_msgs/msg/String"),
            RosOutput("image_out", ros_type="sensor_msgs/Image"),
            RosOutput("cmd_vel"),  # no ros_type: fixed by the first message (Twist)
        ]
    )
    core.start("bridge_out", lambda topic, msg: None, domain_id=DOMAIN_ID)
    pixels = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3) * 7
    records = []

    def publish_all() -> None:
        core.publish("answer", String(data="hello ROS"))
        core.publish("image_out", Image(data=pixels, encoding="rgb8", stamp=42.25, frame_id="cam0"))
        for chunk in (StreamingString(data="Hel", stream_id="s"), StreamingString(data="lo", stream_id="s"), StreamingString(data="", done=True, stream_id="s")):
            core.publish("tokens", chunk)
        core.publish("cmd_vel", Twist(linear=(0.5, 0, 0), angular=(0, 0, -1.0)))

    # The subscriber exits once it has one of each.
    wait_until(lambda: sub.poll() is not None, DEADLINE, "the ROS subscriber's exit", interval=0.05, poke=publish_all)
    while (line := lines.get(timeout=5)) is not None:
        records.append(json.loads(line))
    assert sub.returncode == 0, sub.stderr.read()[-2000:]
    by_topic: dict[str, list[dict]] = {}
    for r in records:
        by_topic.setdefault(r["topic"], []).append(r)
    assert [r["data"] for r in by_topic["/text_out"]] == ["hello ROS"]
    # One ROS message per non-empty chunk; the empty `done` marker is not published.
    assert sorted(r["data"] for r in by_topic["/chunks_out"]) == ["Hel", "lo"]
    (img,) = by_topic["/image_out"]
    assert img["shape"] == [2, 3, 3] and img["encoding"] == "rgb8" and img["step"] == 9
    assert (img["frame_id"], img["sec"], img["nanosec"]) == ("cam0", 42, 250000000)
    assert img["pixels"] == pixels.reshape(-1).tolist()
    assert by_topic["/cmd_vel"] == [{"topic": "/cmd_vel", "linear_x": 0.5, "angular_z": -1.0}]
    assert core.counts["answer"].published >= 1


def test_publish_errors_name_topic_and_types(core_factory):
    core = core_factory(outputs=[RosOutput("answer", ros_type="std_msgs/String"), RosOutput("cmd_vel", ros_type="geometry_msgs/Twist")])
    with pytest.raises(RuntimeError, match="not started"):
        core.publish("answer", String(data="x"))
    core.start("bridge_errors", lambda t, m: None, domain_id=DOMAIN_ID)
    with pytest.raises(TypeError, match=r"topic 'cmd_vel' \(ROS /cmd_vel, geometry_msgs/msg/Twist\) expects Twist or RosMessage, got String"):
        core.publish("cmd_vel", String(data="go"))
    with pytest.raises(TypeError, match="expects String or StreamingString or RosMessage, got Twist"):
        core.publish("answer", Twist())
    with pytest.raises(ValueError, match="no RosOutput is declared for internal topic 'nope'; declared: answer, cmd_vel"):
        core.publish("nope", String())
    with pytest.raises(RuntimeError, match="already started"):
        core.start("again", lambda t, m: None)
    core.publish("answer", String(data="fine"))


def test_declared_qos_reaches_the_ros_graph(core_factory):
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

    core = core_factory(
        inputs=[RosInput("/scan_in", "std_msgs/String", qos=QoS(depth=1, reliability="best_effort"))],
        outputs=[RosOutput("map", ros_type="nav_msgs/OccupancyGrid", qos=QoS(depth=1, durability="transient_local"))],
    )
    core.start("bridge_qos", lambda t, m: None, domain_id=DOMAIN_ID)
    (pub,) = core.node.get_publishers_info_by_topic("/map")
    assert pub.topic_type == "nav_msgs/msg/OccupancyGrid"
    assert pub.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert pub.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    (sub,) = core.node.get_subscriptions_info_by_topic("/scan_in")
    assert sub.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT


def test_bad_messages_and_failing_consumers_do_not_stop_the_bridge(core_factory):
    calls: list[str] = []

    def on_message(topic, msg):
        calls.append(msg.data)
        if msg.data == "boom":
            raise RuntimeError("consumer failed")

    rx = core_factory(inputs=[RosInput("/loop_in", "std_msgs/String")])
    tx = core_factory(outputs=[RosOutput("loop", ros_topic="/loop_in", ros_type="std_msgs/String")])
    rx.start("bridge_rx", on_message, domain_id=DOMAIN_ID)
    tx.start("bridge_tx", lambda t, m: None, domain_id=DOMAIN_ID)

    def publish() -> None:
        tx.publish("loop", String(data="boom"))
        tx.publish("loop", String(data="after"))

    wait_until(lambda: "after" in calls, DEADLINE, "'after' through the bridge", interval=0.05, poke=publish)
    assert "boom" in calls
    assert rx.counts["loop_in"].errors >= 1


def test_stop_is_idempotent_leaves_no_threads_and_restarts():
    def native_threads() -> int:
        return len(os.listdir("/proc/self/task"))

    before = set(threading.enumerate())
    counts = []
    for i in range(3):
        got: queue.Queue = queue.Queue()
        rx = RosBridgeCore(inputs=[RosInput("/restart_in", "std_msgs/String")])
        tx = RosBridgeCore(outputs=[RosOutput("r", ros_topic="/restart_in", ros_type="std_msgs/String")])
        rx.start("bridge_restart_rx", lambda t, m, q=got: q.put(m.data), domain_id=DOMAIN_ID)
        tx.start("bridge_restart_tx", lambda t, m: None, domain_id=DOMAIN_ID)
        try:
            wait_until(lambda q=got: not q.empty(), DEADLINE, f"round {i}", interval=0.02,
                       poke=lambda tx=tx, i=i: tx.publish("r", String(data=f"round {i}")))
            assert got.get_nowait() == f"round {i}"
        finally:
            t0 = time.monotonic()
            rx.stop()
            tx.stop()
            assert time.monotonic() - t0 < 2.0
            rx.stop()  # idempotent
        assert set(threading.enumerate()) == before
        counts.append(native_threads())
    # DDS keeps a few process-wide threads (e.g. its shared-memory watchdog)
    # after the first participant; restarts must not add more.
    assert counts[2] == counts[1] == counts[0]


def _segments() -> set[str]:
    return {f for f in os.listdir("/dev/shm") if f.startswith(("fastdds_", "sem.fastdds_"))}


def test_killed_bridge_process_is_replaced_by_a_fresh_one(spawn):
    pub = spawn(EXTERNAL_PUBLISHER)
    assert wait_line(line_reader(pub), pub) == "READY"
    for name in ("bridge_first", "bridge_second"):
        before = _segments()
        bridge = spawn(BRIDGE_PROCESS, name)
        lines = line_reader(bridge)
        assert wait_line(lines, bridge) == "READY"
        assert wait_line(lines, bridge) == "text_in hello from ROS"
        mine = _segments() - before
        os.killpg(bridge.pid, signal.SIGKILL)  # as the supervisor does
        bridge.wait(timeout=5)
        assert pub.poll() is None
        # The killed bridge could not unlink its DDS segment and ports; the next start cleans them.
        removed = {os.path.basename(p) for p in clean_zombie_fastdds_segments(min_age=0)}
        assert any(len(f) == 24 for f in mine & removed), f"killed bridge's segment in {mine} not cleaned ({removed})"
        assert any(f.startswith("fastdds_port") for f in removed), f"killed bridge's ports in {mine} not cleaned"
        left = _segments()
        assert not {f for f in mine & left if f.endswith(("_el", "_sl"))}, f"locks left: {mine & left}"


def test_large_frames_best_effort_with_a_big_dds_segment(spawn, monkeypatch):
    # Fast DDS's default 0.5 MB segment loses nearly every best-effort 6.2 MB
    # frame over fragmented UDP; the bridge's 64 MB segment delivers them.
    monkeypatch.delenv("FASTDDS_DEFAULT_PROFILES_FILE", raising=False)
    sub = spawn(BIG_SUBSCRIBER)
    time.sleep(0.3)
    pub = spawn(BRIDGE_BIG_PUBLISHER)
    out, err = sub.communicate(timeout=30)
    assert sub.returncode == 0, err[-2000:]
    got = json.loads(out.strip().splitlines()[-1])
    assert pub.wait(timeout=15) == 0, pub.stderr.read()[-2000:]
    assert all(ok for _, ok in got), "a frame arrived with wrong pixels"
    assert len(got) >= 10, f"only {len(got)} of 20 best-effort 1080p frames arrived"


def test_stop_from_inside_on_message(core_factory):
    before = set(threading.enumerate())
    stopped = threading.Event()
    rx = core_factory(inputs=[RosInput("/stop_in", "std_msgs/String")])

    def on_message(topic, msg):
        rx.stop()  # e.g. the actor is told to shut down while handling a message
        stopped.set()

    tx = core_factory(outputs=[RosOutput("s", ros_topic="/stop_in", ros_type="std_msgs/String")])
    rx.start("bridge_stop_rx", on_message, domain_id=DOMAIN_ID)
    tx.start("bridge_stop_tx", lambda t, m: None, domain_id=DOMAIN_ID)
    wait_until(stopped.is_set, DEADLINE, "a stop from inside on_message", interval=0.02,
               poke=lambda: tx.publish("s", String(data="stop")))
    assert not rx.running
    tx.stop()
    wait_until(lambda: set(threading.enumerate()) == before, 5, "the bridge threads' exit")


def test_matched_counts_peers_and_restart_makes_a_new_participant(core_factory):
    events: queue.Queue = queue.Queue()
    got: queue.Queue = queue.Queue()
    rx = core_factory(inputs=[RosInput("/peer_in", "std_msgs/String")])
    tx = core_factory(outputs=[RosOutput("p", ros_topic="/peer_in", ros_type="std_msgs/String")])
    with pytest.raises(RuntimeError, match="needs an earlier start"):
        rx.restart()
    rx.start("bridge_peer_rx", lambda t, m: got.put(m.data), domain_id=DOMAIN_ID, on_matched=lambda *e: events.put(e))
    assert rx.matched() == {"/peer_in": 0}
    tx.start("bridge_peer_tx", lambda t, m: None, domain_id=DOMAIN_ID)
    assert events.get(timeout=DEADLINE) == ("/peer_in", 1)
    assert rx.matched() == {"/peer_in": 1}
    assert wait_until(lambda: tx.matched() == {"/peer_in": 1}, timeout=DEADLINE)
    old = rx.node.get_fully_qualified_name(), rx.node.context

    rx.restart()  # same node and declarations, a new context (DDS participant)
    assert rx.node.get_fully_qualified_name() == old[0] and rx.node.context is not old[1]
    assert events.get(timeout=DEADLINE) == ("/peer_in", 1)  # the new participant found the peer again
    wait_until(lambda: not got.empty(), DEADLINE, "a message after the restart", interval=0.02,
               poke=lambda: tx.publish("p", String(data="after restart")))
    assert got.get_nowait() == "after restart"
    rx.stop()
    assert rx.matched() == {}


def test_a_ros_message_goes_out_as_its_own_type_on_an_output_declared_without_one(core_factory):
    from embagents.msgs import RosMessage

    core = core_factory(outputs=[RosOutput("fix_out", ros_topic="/fix_out")])
    core.start("bridge_generic_out", lambda t, m: None, domain_id=DOMAIN_ID)
    core.publish("fix_out", RosMessage("sensor_msgs/msg/NavSatFix", {"latitude": 1.0}))
    (pub,) = core.node.get_publishers_info_by_topic("/fix_out")
    assert pub.topic_type == "sensor_msgs/msg/NavSatFix"
    with pytest.raises(ValueError, match="NavSatFix has no field 'lat'"):
        core.publish("fix_out", RosMessage("sensor_msgs/msg/NavSatFix", {"lat": 1.0}))
