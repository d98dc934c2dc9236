"""Go to X over ROS 2: a place name on /goto (std_msgs/String) -> a Nav2 goal on /goal_pose.

    pip install -e ".[ros]"
    embagents supervise examples/ros_goto.py
    # with the ros-rclpy wheels, in another terminal (or `ros2 topic pub` where ROS is installed):
    python -c "import rclpy, time; from std_msgs.msg import String; rclpy.init(); \\
      n = rclpy.create_node('q'); p = n.create_publisher(String, '/goto', 10); time.sleep(1); \\
      p.publish(String(data='kitchen')); time.sleep(0.5)"
    # Nav2 (or `ros2 topic echo /goal_pose`) gets a geometry_msgs/PoseStamped in frame "map".

The ``goto`` component is also the ROS service /goto/home (``std_srvs/Trigger``: a goal to the
dock) and a ROS managed node (``ros2 lifecycle set /goto deactivate`` stops it sending goals).
Only the bridge actor imports rclpy. EmbodiedAgents' go-to-X recipe finds the place with an LLM
and a map; swap ``PLACES`` for ``Memory.locate`` (see ``examples/memory.py``) to do the same.
"""

from __future__ import annotations

import math
import time

from embagents import Component, String, System, Topic
from embagents.msgs import Pose, PoseStamped
from embagents.ros import RosInput, RosLifecycle, RosOutput, RosService

# Named places in the map frame: x, y (m) and heading (rad).
PLACES = {"kitchen": (4.0, 1.5, 0.0), "door": (0.5, -2.0, math.pi / 2), "dock": (0.0, 0.0, math.pi)}

goto = Topic("goto", String)
goal_pose = Topic("goal_pose", PoseStamped)


class GoTo(Component):
    """Turns a place name into a PoseStamped goal."""

    allowed_inputs = {"Required": [String]}
    allowed_outputs = {"Required": [PoseStamped]}

    def _execution_step(self, **inputs: String) -> None:
        self.send_to(inputs["goto"].data.strip().lower())

    def send_to(self, place: str) -> str:
        if place not in PLACES:
            raise ValueError(f"unknown place {place!r}; known: {', '.join(PLACES)}")
        x, y, yaw = PLACES[place]
        goal = PoseStamped(Pose((x, y, 0.0), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))),
                           frame_id="map", stamp=time.time())
        self.publish(goal_pose, goal)
        return f"going to {place} ({x:.1f}, {y:.1f})"

    def home(self) -> str:
        return self.send_to("dock")


system = System(
    [GoTo(name="goto", inputs=[goto], outputs=[goal_pose], trigger=goto)],
    ros=[
        RosInput("/goto", "std_msgs/String"),
        RosOutput("goal_pose", ros_type="geometry_msgs/PoseStamped"),
        RosService("/goto/home", "std_srvs/Trigger", component="goto", method="home"),
        RosLifecycle(),
    ],
    name="ros_goto",
)
