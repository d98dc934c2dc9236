"""``ros_generic``: an Imu at 200 Hz and a 100k-point PointCloud2 through the bridge, against plain rclpy.

A plain rclpy publisher process stamps each message's header with
CLOCK_MONOTONIC and publishes a ``sensor_msgs/Imu`` stream at 200 Hz, then a
``sensor_msgs/PointCloud2`` of 100,000 points (x, y, z, intensity float32:
1.6 MB) at 10 Hz. The same messages reach, at the same time, a plain rclpy
subscriber process and the bridge actor, whose messages (an
:class:`~embagents.msgs.Imu`, a :class:`~embagents.msgs.PointCloud2`) reach a
subscriber actor in a third process. ``imu_ratio`` / ``cloud_ratio``: bridge
p50 / plain rclpy p50 of one-way latency (bars: <= 1.5 each).

Run alone: ``python -m embagents.bench --only ros_generic``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from typing import Any

import embagents.msgs  # noqa: F401 - registers Imu and PointCloud2 for the subscriber's decoding
from actors import Actor, ActorSystem
from embagents.bench.cases_ros_bridge import _trimmed
from embagents.bench.registry import BenchOptions, case, percentiles, scoped_environ
from embagents.ros.bridge_actor import RosBridgeActor
from embagents.ros.fastdds_shm import sweeping_dead_peers

__all__ = ["GenericLatency"]

POINTS = 100_000

# argv: kind ("imu" | "cloud"), n, period, warm. Plain rclpy, monotonic stamps, a 64 MB Fast DDS segment.
PUBLISHER = r"""
import sys, time, numpy as np, rclpy
from sensor_msgs.msg import Imu, PointCloud2, PointField
from embagents.ros.node import configure_fastdds_shm
configure_fastdds_shm(64)
kind, n, period, warm = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
rclpy.init()
node = rclpy.create_node("bench_generic_pub")
if kind == "imu":
    pub = node.create_publisher(Imu, "/bench_imu", 10)
    msg = Imu()
    msg.linear_acceleration.z = 9.81
else:
    pub = node.create_publisher(PointCloud2, "/bench_cloud", 2)
    pts = np.random.default_rng(0).standard_normal((POINTS, 4)).astype(np.float32)
    msg = PointCloud2(height=1, width=len(pts), point_step=16, row_step=16 * len(pts), is_dense=True,
                      fields=[PointField(name=c, offset=4 * i, datatype=7, count=1) for i, c in enumerate("xyz") ]
                      + [PointField(name="intensity", offset=12, datatype=7, count=1)])
    msg.data = pts.tobytes()
time.sleep(warm)  # discovery
for i in range(n):
    t = time.monotonic_ns()
    msg.header.stamp.sec, msg.header.stamp.nanosec = t // 10**9, t % 10**9
    pub.publish(msg)
    time.sleep(period)
""".replace("POINTS", str(POINTS))

SUBSCRIBER = r"""
import json, sys, time, rclpy
from sensor_msgs.msg import Imu, PointCloud2
rclpy.init()
node = rclpy.create_node("bench_generic_sub")
lat = {"imu": [], "cloud": []}
def cb(kind):
    return lambda m: lat[kind].append(time.monotonic_ns() - (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec))
node.create_subscription(Imu, "/bench_imu", cb("imu"), 10)
node.create_subscription(PointCloud2, "/bench_cloud", cb("cloud"), 2)
print("READY", flush=True)
end, want = time.time() + float(sys.argv[1]), {"imu": int(sys.argv[2]), "cloud": int(sys.argv[3])}
while time.time() < end and any(len(lat[k]) < want[k] for k in lat):
    rclpy.spin_once(node, timeout_sec=0.1)
print(json.dumps(lat), flush=True)
"""


class GenericLatency(Actor):
    """Subscribes to the bridged Imu and PointCloud2 topics and records one-way latency (ns)."""

    def on_start(self) -> None:
        self.lat: dict[str, list[int]] = {"imu": [], "cloud": []}
        self.context.subscribe("bench_imu", lambda m: self._on("imu", m), queue_size=10, keep="all")
        self.context.subscribe("bench_cloud", lambda m: self._on("cloud", m), queue_size=2, keep="all")

    def _on(self, kind: str, msg: Any) -> None:
        self.lat[kind].append(time.monotonic_ns() - int(round(msg.stamp * 1e9)))
        if kind == "cloud":
            assert msg.data.shape == (1, POINTS, 16)

    def on_receive(self, message: Any) -> Any:
        return self.lat


def _publish(kind: str, n: int, period: float, warm: float, env: dict[str, str]) -> None:
    subprocess.run([sys.executable, "-c", PUBLISHER, kind, str(n), str(period), str(warm)], env=env, check=True,
                   timeout=180)


@case("ros_generic", transport="embagents", payload_bytes=POINTS * 16, kind="ros_bridge", needs="rclpy")
def ros_generic(opts: BenchOptions) -> dict[str, Any]:
    with sweeping_dead_peers():  # the rclpy peer is SIGKILLed: its Fast DDS files stay otherwise
        return _ros_generic(opts)


def _ros_generic(opts: BenchOptions) -> dict[str, Any]:
    n_imu, n_cloud = (200, 10) if opts.quick else (1000, 40)
    imu_period, cloud_period, warm, skip = 0.005, 0.1, 2.0, 5
    env = {**os.environ, "ROS_DOMAIN_ID": str(150 + (os.getpid() + 7) % 80), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    streams = (("imu", n_imu, imu_period), ("cloud", n_cloud, cloud_period))
    budget = sum(warm + n * p + 2 for _, n, p in streams) + 30
    # Both subscribers take the same messages at once: the same publisher, the same machine load.
    with scoped_environ({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}):
        with ActorSystem() as asys:
            probe = asys.spawn(GenericLatency, "bench_generic_latency")
            inputs = [
                {"ros_topic": "/bench_imu", "ros_type": "sensor_msgs/Imu", "topic": "bench_imu", "qos": {"depth": 10}},
                {"ros_topic": "/bench_cloud", "ros_type": "sensor_msgs/PointCloud2", "topic": "bench_cloud",
                 "qos": {"depth": 2}},
            ]
            asys.spawn(RosBridgeActor, "bench_ros_bridge", None, "bench_bridge", inputs, [], wait=60)
            sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, str(budget), str(n_imu), str(n_cloud)],
                                   stdout=subprocess.PIPE, text=True, env=env)
            try:
                assert sub.stdout is not None
                sub.stdout.readline()
                for kind, n, period in streams:
                    _publish(kind, n, period, warm, env)
                plain = json.loads(sub.stdout.readline() or "{}")
            except json.JSONDecodeError:
                plain = {}
            finally:
                sub.kill()
                sub.wait()
            time.sleep(0.2)
            bridged = probe.ask("latencies", timeout=10).get()
    got = {k: (len(bridged.get(k, [])), len(plain.get(k, []))) for k in ("imu", "cloud")}
    if not all(a and b for a, b in got.values()):
        raise RuntimeError(f"messages received (bridge, plain rclpy): {got}")
    imu, imu_base = percentiles(_trimmed(bridged["imu"], skip)), percentiles(_trimmed(plain["imu"], skip))
    cloud, cloud_base = percentiles(_trimmed(bridged["cloud"], skip)), percentiles(_trimmed(plain["cloud"], skip))
    return {
        "p50_us": imu["p50_us"],
        "p99_us": imu["p99_us"],
        "msgs_per_s": None,
        "imu_p50_us": imu["p50_us"],
        "imu_rclpy_p50_us": imu_base["p50_us"],
        "imu_ratio": imu["p50_us"] / imu_base["p50_us"],
        "cloud_p50_us": cloud["p50_us"],
        "cloud_rclpy_p50_us": cloud_base["p50_us"],
        "cloud_ratio": cloud["p50_us"] / cloud_base["p50_us"],
        "received": {k: v[0] for k, v in got.items()},
        "rclpy_received": {k: v[1] for k, v in got.items()},
        "note": f"Imu {n_imu} at 200 Hz (depth 10), PointCloud2 {POINTS} points {n_cloud} at 10 Hz (depth 2); "
                "ratios = bridge p50 / plain rclpy p50 (bars <= 1.5)",
    }
