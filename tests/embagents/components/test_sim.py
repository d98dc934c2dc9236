"""The Sim component driving the real PyBullet simulator (DIRECT mode, TinyRenderer camera)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

pytest.importorskip("pybullet")

from embagents.components import ComponentError, HealthStatus, Sim, SimConfig  # noqa: E402
from embagents.msgs import Image, JointState, Odometry, Twist  # noqa: E402
from embagents.topic import Topic  # noqa: E402

command, cmd_vel = Topic("arm/command", JointState), Topic("cmd_vel", Twist)
states, camera, odom = Topic("arm/joint_states", JointState), Topic("camera/image", Image), Topic("odom", Odometry)


def make(**config: Any) -> tuple[Sim, list[tuple[str, Any]]]:
    sim = Sim(name="sim", inputs=[command, cmd_vel], outputs=[states, camera, odom],
              config=SimConfig(camera_width=64, camera_height=48, **config))
    sent: list[tuple[str, Any]] = []
    sim.attach(lambda topic, msg: sent.append((topic, msg)))
    sim.on_configure()
    sim.on_activate()
    return sim, sent


@pytest.fixture
def sim() -> Iterator[tuple[Sim, list[tuple[str, Any]]]]:
    s, sent = make()
    yield s, sent
    s.on_shutdown()


def run(sim: Sim, steps: int) -> None:
    for _ in range(steps):
        sim.execute()


def test_it_publishes_joint_states_and_a_camera_image(sim: tuple[Sim, list]) -> None:
    s, sent = sim
    run(s, 2)
    js = next(m for t, m in sent if t == states.name)
    img = next(m for t, m in sent if t == camera.name)
    assert js.name[:7] == [f"panda_joint{i}" for i in range(1, 8)] and len(js.position) == len(js.name) == 9
    assert js.position[3] == pytest.approx(-2.2, abs=1e-3)  # the ready pose
    assert img.data.shape == (48, 64, 3) and img.data.dtype == np.uint8 and img.data.std() > 5  # a drawn scene


def test_a_position_command_moves_the_joint_there(sim: tuple[Sim, list]) -> None:
    s, _ = sim
    s.on_message(command.name, JointState(name=["panda_joint1"], position=[0.5]))
    run(s, 480)
    assert s.joint_state().position[0] == pytest.approx(0.5, abs=0.01) and s.commands == 1


def test_a_velocity_command_moves_and_the_watchdog_stops_it() -> None:
    # The watchdog runs on wall time: 0.5 s leaves the 24 steps room on a loaded machine (0.05 s did not).
    s, _ = make(command_timeout_s=0.5)
    try:
        s.on_message(command.name, JointState(name=["panda_joint1"], velocity=[1.0]))
        run(s, 24)
        moving = s.joint_state()
        assert moving.velocity[0] > 0.5
        import time

        time.sleep(0.6)  # past the watchdog's timeout: no new velocity command came
        run(s, 120)
        assert abs(s.joint_state().velocity[0]) < 0.05
    finally:
        s.on_shutdown()


def test_a_twist_drives_the_mobile_base_and_odometry_follows() -> None:
    s, sent = make(mobile_base="r2d2.urdf")
    try:
        start = s.joint_state().stamp
        s.on_message(cmd_vel.name, Twist(linear=(0.5, 0.0, 0.0)))
        run(s, 240)
        s.publish_state()
        odoms = [m for t, m in sent if t == odom.name]
        assert odoms and start > 0
        assert odoms[-1].position[0] - 1.5 > 0.2  # it started at x = 1.5 and drove forward
    finally:
        s.on_shutdown()


def test_a_command_for_an_unknown_joint_says_which_and_lists_the_joints(sim: tuple[Sim, list]) -> None:
    s, _ = sim
    s.on_message(command.name, JointState(name=["elbow"], position=[0.1]))
    run(s, 1)
    assert s.health.status == HealthStatus.ALGORITHM_FAILURE
    assert "command names joints ['elbow']" in s.health.text and "panda_joint1" in s.health.text


def test_a_robot_that_is_not_there_is_a_declaration_error() -> None:
    with pytest.raises(ComponentError, match="neither a file nor in pybullet_data"):
        Sim(name="sim", outputs=[states], config=SimConfig(robot="nowhere/robot.urdf"))


def test_save_frame_writes_a_png(sim: tuple[Sim, list], tmp_path) -> None:  # noqa: ANN001
    import cv2

    s, _ = sim
    path = s.save_frame(str(tmp_path / "frame.png"))
    assert cv2.imread(path).shape == (48, 64, 3)


def test_another_arm_of_pybullet_data_loads_and_moves() -> None:
    s, sent = make(robot="kuka_iiwa/model.urdf", initial_positions={"lbr_iiwa_joint_2": 0.3})
    try:
        s.on_message(command.name, JointState(name=["lbr_iiwa_joint_1"], position=[0.4]))
        run(s, 480)
        js = s.joint_state()
        assert js.name[0] == "lbr_iiwa_joint_1" and len(js.name) == 7
        assert js.position[0] == pytest.approx(0.4, abs=0.01) and js.position[1] == pytest.approx(0.3, abs=0.02)
    finally:
        s.on_shutdown()
