"""ROS Base style (b): one global ``state`` string drives every handler, broadcast on a topic.

    pip install -e .
    embagents supervise examples/manager_modes.py

Offline, no ROS, about five seconds. A simulated mobile base (``base``, a
component at 20 Hz) integrates the velocity commands it gets on ``cmd_vel``
(Twist) and publishes its odometry on ``odom`` (Odometry). The manager
``modes`` (50 Hz) keeps the robot's mode in ``state.mode``:

- ``cold_start``: wait until the odometry has settled (a second of readings);
- ``turn``: rotate in place until the robot faces the goal;
- ``navigation``: drive to the goal, steering as it goes;
- ``arrived``: stop the base and end the run (``system_stop``).

``Modes`` decides the mode; ``Turn`` and ``Navigate`` act only in theirs;
every change of mode is published on ``robot_state`` (String), where any
component, an ``embagents topic echo`` or ROS (through the bridge,
``RosOutput("robot_state", ...)``) sees it. A restarted manager resumes in
its mode (the shared state is snapshotted), not in ``cold_start``.
"""

from __future__ import annotations

import math
from typing import Any

from embagents.components import Component
from embagents.manager import HandshakeRule, Manager, Node, State
from embagents.msgs import Odometry, String, Twist
from embagents.system import SYSTEM_STOP, System
from embagents.topic import Topic

GOAL = (1.5, 1.0)  # metres, in the odometry frame

cmd_vel = Topic("cmd_vel", Twist, queue_size=1)
odom = Topic("odom", Odometry, queue_size=1)
robot_state = Topic("robot_state", String, queue_size=10, keep="all")
stop = Topic(SYSTEM_STOP, String)


def yaw_of(q: Any) -> float:
    x, y, z, w = q
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


class Base(Component):
    """A unicycle base: integrates cmd_vel (linear x, angular z) at 20 Hz into odometry."""

    allowed_inputs = {"Optional": [Twist]}
    allowed_outputs = {"Required": [Odometry]}

    def on_activate(self) -> None:
        self.x = self.y = self.yaw = 0.0

    def _execution_step(self, **inputs: Any) -> None:
        cmd = inputs.get("cmd_vel") or Twist()
        dt = 0.05
        self.yaw += cmd.angular[2] * dt
        self.x += cmd.linear[0] * math.cos(self.yaw) * dt
        self.y += cmd.linear[0] * math.sin(self.yaw) * dt
        half = self.yaw / 2
        self.publish(odom, Odometry(position=(self.x, self.y, 0.0), orientation=(0.0, 0.0, math.sin(half),
                                                                                 math.cos(half))))


io = Node("io", subscribe=[odom], publish=[cmd_vel, robot_state, stop])


def pose() -> tuple[float, float, float, float, float]:
    """x, y, yaw, distance and bearing error to the goal, from the latest odometry."""
    o = io.latest(odom)
    x, y, yaw = o.position[0], o.position[1], yaw_of(o.orientation)
    dx, dy = GOAL[0] - x, GOAL[1] - y
    error = math.atan2(dy, dx) - yaw
    return x, y, yaw, math.hypot(dx, dy), math.atan2(math.sin(error), math.cos(error))


def modes(state: State, tick: int) -> None:
    """Decides the mode; publishes it whenever it changes."""
    mode = state.get("mode")
    _, _, _, distance, error = pose()
    if mode is None:
        new = "cold_start"
    elif mode == "cold_start" and io.count(odom) >= 20:
        new = "turn"
    elif mode == "turn" and abs(error) < math.radians(2):
        new = "navigation"
    elif mode == "navigation" and distance < 0.05:
        new = "arrived"
    else:
        return
    state["mode"] = new
    io.publish(robot_state, String(data=new))
    print(f"tick {tick:4d}: mode {mode} -> {new}", flush=True)
    if new == "arrived":
        io.publish(cmd_vel, Twist())
        x, y, *_ = pose()
        print(f"arrived at ({x:.2f}, {y:.2f}), goal {GOAL}", flush=True)
        io.publish(stop, String(data="arrived"))


def turn(state: State, tick: int) -> None:
    if state.get("mode") == "turn":
        error = pose()[4]
        io.publish(cmd_vel, Twist(angular=(0.0, 0.0, max(-1.0, min(1.0, 2.0 * error)))))


def navigate(state: State, tick: int) -> None:
    if state.get("mode") == "navigation":
        _, _, _, distance, error = pose()
        io.publish(cmd_vel, Twist(linear=(min(0.8, distance), 0.0, 0.0), angular=(0.0, 0.0, 2.0 * error)))


manager = Manager(50, name="modes", nodes=[io], handlers=[modes, turn, navigate],
                  handshake=[HandshakeRule.first_message(odom)], handshake_timeout=10.0)

system = System([Base(name="base", inputs=[cmd_vel], outputs=[odom], trigger=20.0)], managers=[manager],
                name="modes")
