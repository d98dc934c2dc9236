"""Typed and introspected ROS messages through the bridge, against plain rclpy peers in other processes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("rclpy", reason="ROS 2 bridge tests need: pip install 'embagents[ros]'")

DOMAIN_ID = 21 + os.getpid() % 60

# A component reads an Imu, a LaserScan and an introspected NavSatFix, and publishes a PoseStamped goal.
NAV_SYSTEM = '''
from embagents import Component, System, Topic
from embagents.msgs import Imu, LaserScan, Pose, PoseStamped, RosMessage
from embagents.ros import RosInput, RosOutput

imu, scan, fix = Topic("imu", Imu), Topic("scan", LaserScan), Topic("fix", RosMessage)
goal, fix_out = Topic("goal_pose", PoseStamped), Topic("fix_out", RosMessage)


class Nav(Component):
    allowed_inputs = {"Required": [Imu], "Optional": [LaserScan, RosMessage]}
    allowed_outputs = {"Required": [PoseStamped], "Optional": [RosMessage]}

    def _execution_step(self, **inputs):
        i, s, f = inputs["imu"], inputs.get("scan"), inputs.get("fix")
        if s is None or f is None:
            return
        x = float(s.ranges.min())  # numpy float32 ranges
        self.publish(goal, PoseStamped(Pose((x, i.linear_acceleration[2], f.latitude), i.orientation),
                                       frame_id=f.header.frame_id, stamp=i.stamp))
        # An introspected type goes out too: the fix moved north, as a dict of its ROS fields
        # (after one with a field NavSatFix lacks, which the bridge refuses and logs).
        self.publish(fix_out, RosMessage("sensor_msgs/msg/NavSatFix", {"lat": 0.0}))
        self.publish(fix_out, RosMessage("sensor_msgs/msg/NavSatFix",
                                         {"latitude": f.latitude + 1, "header": {"frame_id": "moved"}}))


system = System(
    [Nav(name="nav", inputs=[imu, scan, fix], outputs=[goal, fix_out], trigger=imu)],
    ros=[RosInput("/imu", "sensor_msgs/Imu"), RosInput("/scan", "sensor_msgs/LaserScan"),
         RosInput("/fix", "sensor_msgs/NavSatFix"), RosOutput("goal_pose", ros_type="geometry_msgs/PoseStamped"),
         RosOutput("fix_out", ros_type="sensor_msgs/NavSatFix")],
)
'''

PEER = r"""
import sys, time, numpy as np, rclpy
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import Imu, LaserScan, NavSatFix
deadline = time.time() + float(sys.argv[1])
rclpy.init()
node = rclpy.create_node("nav_peer")
pubs = [node.create_publisher(t, n, 10) for t, n in ((Imu, "/imu"), (LaserScan, "/scan"), (NavSatFix, "/fix"))]
got, fixes = [], []
node.create_subscription(PoseStamped, "/goal_pose", got.append, 10)
node.create_subscription(NavSatFix, "/fix_out", fixes.append, 10)
imu = Imu()
imu.linear_acceleration.z, imu.orientation.z, imu.orientation.w = 9.81, 0.6, 0.8
imu.header.stamp.sec, imu.header.stamp.nanosec = 7, 500_000_000
scan = LaserScan(angle_increment=0.01, range_max=30.0)
scan.ranges = np.linspace(4.0, 0.25, 360, dtype=np.float32).tolist()
fix = NavSatFix(latitude=48.25)
fix.header.frame_id = "utm"
while not (got and fixes) and time.time() < deadline:
    for p, m in zip(pubs, (imu, scan, fix)):
        p.publish(m)
    end = time.time() + 0.2
    while not (got and fixes) and time.time() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
if got:
    g = got[0]
    p, q = g.pose.position, g.pose.orientation
    print("GOT", p.x, p.y, p.z, q.z, q.w, g.header.frame_id, g.header.stamp.sec, g.header.stamp.nanosec, flush=True)
else:
    print("GOT nothing", flush=True)
print("FIX", *((fixes[0].latitude, fixes[0].header.frame_id) if fixes else ("nothing",)), flush=True)
"""


@pytest.fixture
def ros_env(monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    monkeypatch.setenv("ROS_DOMAIN_ID", str(DOMAIN_ID))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return dict(os.environ)


def test_imu_and_laser_scan_in_and_a_pose_stamped_goal_out(tmp_path: Path, ros_env: dict[str, str]) -> None:
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent(NAV_SYSTEM))
    sup = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(path)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ros_env)
    try:
        out = subprocess.run([sys.executable, "-c", PEER, "60"], capture_output=True, text=True, env=ros_env,
                             timeout=90)
    finally:
        sup.send_signal(signal.SIGTERM)
        log, _ = sup.communicate(timeout=30)
    assert sup.returncode == 0, log
    # x: the scan's nearest range; y: the Imu's z acceleration; z: NavSatFix.latitude read as a generic field.
    assert "GOT 0.25 9.81 48.25 0.6 0.8 utm 7 500000000" in out.stdout, out.stdout + out.stderr + log
    assert "FIX 49.25 moved" in out.stdout, out.stdout + out.stderr + log  # a RosMessage out as a NavSatFix
    assert "not sent to ROS: sensor_msgs/msg/NavSatFix has no field 'lat'; its fields: header, status" in log, log
    assert "crashed root/_ros_bridge" not in log, log


def test_check_accepts_imu_pose_stamped_and_laser_scan(tmp_path: Path) -> None:
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent(NAV_SYSTEM))
    proc = subprocess.run([sys.executable, "-m", "embagents.cli", "check", str(path)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and "OK" in proc.stdout, proc.stdout + proc.stderr


def test_check_names_the_wheel_of_a_missing_message_package(tmp_path: Path) -> None:
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent('''
        from embagents import System
        from embagents.ros import RosInput
        system = System([], ros=[RosInput("/detections", "vision_msgs/Detection2DArray")])
    '''))
    proc = subprocess.run([sys.executable, "-m", "embagents.cli", "check", str(path)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 1
    assert "pip install ros-vision-msgs" in proc.stdout + proc.stderr
