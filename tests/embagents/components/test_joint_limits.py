"""Joint limits read from a real URDF (the Panda of pybullet_data) and the clipping of commands."""

from __future__ import annotations

import logging

import numpy as np
import pytest

pytest.importorskip("pybullet")
pytest.importorskip("urdf_parser_py")

from embagents.components.joint_limits import Clipper, JointLimit, limits_from_urdf, merge_limits  # noqa: E402


def test_the_pandas_urdf_gives_its_joint_limits() -> None:
    limits = limits_from_urdf("franka_panda/panda.urdf")
    assert limits["panda_joint4"] == JointLimit(-3.1416, 0.0, 2.175)
    assert limits["panda_finger_joint1"] == JointLimit(0.0, 0.04, 0.2)
    assert len([j for j in limits if j.startswith("panda_joint")]) == 7  # fixed joints have none


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
