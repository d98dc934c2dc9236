"""``ros_bridge_image``: a ROS publisher -> the bridge actor -> an internal subscriber.

A 1080p rgb8 frame (6,220,800 B) is published by a plain rclpy node in its
own process, received by the bridge actor (the one process that imports
rclpy), converted with its pixels viewed in place, written once into shared
memory and delivered to a subscriber actor in a third process. In the same
run the same publisher feeds a plain rclpy subscriber process: ``ratio`` is
bridge p50 / plain rclpy p50 (bar: <= 1.5). Latency is one way, from the
CLOCK_MONOTONIC stamp the publisher writes into the header.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from typing import Any

import numpy as np

import embagents.msgs  # noqa: F401 - registers Image for the subscriber's decoding
from actors import Actor, ActorSystem
from embagents.bench.registry import FRAME_1080P, BenchOptions, case, percentiles, scoped_environ
from embagents.ros.bridge_actor import RosBridgeActor

__all__ = ["FrameLatency"]

TOPIC = "/bench_frames"

# The publisher: plain rclpy, monotonic stamps, a 64 MB Fast DDS segment (as the bridge uses).
PUBLISHER = r"""
import sys, time, numpy as np, rclpy
from sensor_msgs.msg import Image
from embagents.ros.node import configure_fastdds_shm
configure_fastdds_shm(64)
n, period, warm = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
rclpy.init()
node = rclpy.create_node("bench_frame_pub")
pub = node.create_publisher(Image, "/bench_frames", 2)
frame = (np.arange(1080 * 1920 * 3) % 251).astype(np.uint8)
msg = Image(height=1080, width=1920, encoding="rgb8", step=1920 * 3)
msg.data = frame.tobytes()
time.sleep(warm)  # discovery
for i in range(n):
    t = time.monotonic_ns()
    msg.header.stamp.sec, msg.header.stamp.nanosec = t // 10**9, t % 10**9
    msg.header.frame_id = str(i)
    pub.publish(msg)
    time.sleep(period)
"""

SUBSCRIBER = r"""
import json, sys, time, rclpy
from sensor_msgs.msg import Image
rclpy.init()
node = rclpy.create_node("bench_frame_sub")
lat = []
def cb(m):
    lat.append(time.monotonic_ns() - (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec))
node.create_subscription(Image, "/bench_frames", cb, 2)
print("READY", flush=True)
end = time.time() + float(sys.argv[1])
while time.time() < end:
    rclpy.spin_once(node, timeout_sec=0.1)
print(json.dumps(lat), flush=True)
"""


class FrameLatency(Actor):
    """Subscribes to the bridged frames and records one-way latency (ns)."""

    def on_start(self) -> None:
        self.lat: list[int] = []
        self.context.subscribe("bench_frames", self._on_frame, queue_size=4, keep="all")

    def _on_frame(self, img: Any) -> None:
        self.lat.append(time.monotonic_ns() - int(round(img.stamp * 1e9)))
        assert img.data.shape == (1080, 1920, 3)

    def on_receive(self, message: Any) -> Any:
        return list(self.lat)


def _publish(n: int, period: float, warm: float, env: dict[str, str]) -> None:
    subprocess.run([sys.executable, "-c", PUBLISHER, str(n), str(period), str(warm)], env=env, check=True, timeout=120)


def _trimmed(lat: list[int], skip: int) -> np.ndarray:
    return np.asarray(lat[skip:] if len(lat) > skip + 2 else lat, dtype=np.int64)


@case("ros_bridge_image", transport="embagents", payload_bytes=FRAME_1080P, kind="ros_bridge", needs="rclpy")
def ros_bridge_image(opts: BenchOptions) -> dict[str, Any]:
    n = 10 if opts.quick else 40
    period, warm, skip = 0.1, 2.0, 3
    env = {**os.environ, "ROS_DOMAIN_ID": str(150 + os.getpid() % 80), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    # Plain rclpy: publisher process -> subscriber process.
    sub = subprocess.Popen(
        [sys.executable, "-c", SUBSCRIBER, str(warm + n * period + 5)], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        assert sub.stdout is not None
        sub.stdout.readline()
        _publish(n, period, warm, env)
        plain = json.loads(sub.stdout.readline() or "[]")
    finally:
        sub.kill()
        sub.wait()
    # Through the bridge: publisher process -> bridge actor -> subscriber actor.
    with scoped_environ({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}):
        with ActorSystem() as asys:
            probe = asys.spawn(FrameLatency, "bench_frame_latency")
            inputs = [{"ros_topic": TOPIC, "ros_type": "sensor_msgs/Image", "topic": "bench_frames", "qos": {"depth": 2}}]
            asys.spawn(RosBridgeActor, "bench_ros_bridge", None, "bench_bridge", inputs, [], wait=60)
            _publish(n, period, warm, env)
            time.sleep(0.5)
            bridged = probe.ask("latencies", timeout=10).get()
    if not bridged or not plain:
        raise RuntimeError(f"frames received: bridge {len(bridged)}, plain rclpy {len(plain)} of {n}")
    ours, base = percentiles(_trimmed(bridged, skip)), percentiles(_trimmed(plain, skip))
    return {
        **ours,
        "msgs_per_s": None,
        "rclpy_p50_us": base["p50_us"],
        "rclpy_p99_us": base["p99_us"],
        "ratio": ours["p50_us"] / base["p50_us"],
        "received": len(bridged),
        "rclpy_received": len(plain),
        "note": f"{n} frames at 10 Hz, reliable depth 2; ratio = bridge p50 / plain rclpy p50 (bar <= 1.5)",
    }
