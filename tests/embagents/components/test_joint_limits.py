"""Joint limits read from a real URDF (the Panda of pybullet_data) and the clipping of commands."""

from __future__ import annotations

import logging

import numpy as np
import pytest

pytest.importorskip("pybullet")
pytest.importorskip("urdf_parser_py")

from embagents.components.joint_limits import Clipper, JointLimit, limits_from_urdf, merge_limits  # noqa: E402
from embagents.components.sim import robot_path  # noqa: E402


def test_the_pandas_urdf_gives_its_joint_limits() -> None:
    limits = limits_from_urdf("franka_panda/panda.urdf")
    assert limits["panda_joint4"] == JointLimit(-3.1416, 0.0, 2.175)
    assert limits["panda_finger_joint1"] == JointLimit(0.0, 0.04, 0.2)
    assert len([j for j in limits if j.startswith("panda_joint")]) == 7  # fixed joints have none


def test_a_urdf_that_declares_its_encoding_is_read() -> None:
    # xacro output and most vendors' URDFs (pybullet_data's xArm6 too) start with <?xml ... encoding="utf-8"?>
    with open(robot_path("xarm/xarm6_robot.urdf"), encoding="utf-8") as f:
        assert f.readline().startswith('<?xml version="1.0" encoding="utf-8"?>')
    limits = limits_from_urdf("xarm/xarm6_robot.urdf")  # its transmissions do not parse: they are not needed
    assert sorted(limits) == [f"joint{i}" for i in range(1, 7)]
    assert limits["joint2"] == JointLimit(-2.059, 2.0944, 3.14)


def test_a_written_urdf_with_a_utf8_declaration_and_a_non_ascii_name_is_read(tmp_path) -> None:  # noqa: ANN001
    path = tmp_path / "arm.urdf"
    path.write_text('<?xml version="1.0" encoding="utf-8"?>\n<robot name="bras_électrique"><link name="a"/>'
                    '<link name="b"/><joint name="coude" type="revolute"><parent link="a"/><child link="b"/>'
                    '<limit lower="-1.5" upper="1.5" velocity="2.0" effort="10"/></joint></robot>', encoding="utf-8")
    assert limits_from_urdf(str(path)) == {"coude": JointLimit(-1.5, 1.5, 2.0)}


def test_a_dict_overrides_the_urdf_joint_by_joint() -> None:
    limits = merge_limits("franka_panda/panda.urdf", {"panda_joint1": {"velocity": 0.5}})
    assert limits["panda_joint1"] == JointLimit(-2.9671, 2.9671, 0.5)
    with pytest.raises(ValueError, match="use lower, upper, velocity"):
        merge_limits(None, {"j": {"max": 1.0}})


def test_a_file_that_is_not_a_urdf_is_named(tmp_path) -> None:  # noqa: ANN001
    bad = tmp_path / "robot.urdf"
    bad.write_text("<robot><joint")
    with pytest.raises(ValueError, match="is not a URDF"):
        limits_from_urdf(str(bad))


def test_positions_are_clipped_to_limits_and_speed_and_logged_once_per_joint(caplog: pytest.LogCaptureFixture) -> None:
    clip = Clipper(["a", "b"], {"a": JointLimit(-1, 1, 1.0), "b": JointLimit(-1, 1, 10.0)}, period_s=0.1)
    with caplog.at_level(logging.WARNING, "embagents.safety"):
        for _ in range(3):
            out = clip.position([5.0, 5.0], previous=[0.95, 0.0])
    assert out.tolist() == [1.0, 1.0]  # a: the limit; b: 10 rad/s x 0.1 s = 1.0 from 0.0
    assert clip.counts == {"a": 3, "b": 3}
    assert [r.getMessage().split(":")[1].strip() for r in caplog.records] == [
        "command for joint a clipped", "command for joint b clipped"]


def test_velocities_never_push_past_a_position_limit() -> None:
    clip = Clipper(["a"], {"a": JointLimit(-1, 1, 2.0)}, period_s=0.1)
    assert clip.velocity([5.0], position=[0.0]).tolist() == [2.0]
    assert np.allclose(clip.velocity([5.0], position=[0.9]), [1.0])  # 0.1 rad of room in 0.1 s
    assert clip.velocity([-5.0], position=[1.0]).tolist() == [-2.0]  # moving away from a limit is fine


def test_a_joint_without_limits_is_refused() -> None:
    with pytest.raises(ValueError, match=r"no limits for joints \['c'\]"):
        Clipper(["c"], {}, period_s=0.1)
