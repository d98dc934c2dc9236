"""The VLA in a closed loop: the real simulator (PyBullet), a real ONNX policy in a model actor, safety."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("pybullet")
pytest.importorskip("onnxruntime")
onnx = pytest.importorskip("onnx")

from actors import ActorSystem  # noqa: E402
from embagents.components import VLA, ComponentError, HealthStatus, Sim, SimConfig, VLAConfig  # noqa: E402
from embagents.components.sim import PANDA_READY  # noqa: E402
from embagents.events import Event, on  # noqa: E402
from embagents.models import LocalPolicyClient  # noqa: E402
from embagents.models.actor import ModelActor  # noqa: E402
from embagents.msgs import Image, JointState, JointTrajectory, String, TaskFeedback  # noqa: E402
from embagents.topic import Topic  # noqa: E402
from tests.embagents.conftest import PANDA_TARGET  # noqa: E402
from tests.helpers import wait_until  # noqa: E402

JOINTS = list(PANDA_READY)
states, command, camera = Topic("arm/joint_states", JointState), Topic("arm/command", JointState), Topic("camera", Image)
chunks, feedback, halt = Topic("arm/chunk", JointTrajectory), Topic("vla/feedback", TaskFeedback), Topic("halt", String)


def write_three_actions(path: Path) -> str:
    """A policy answering the wrong shape: (1, 3) for a 7-joint state."""
    from onnx import TensorProto, helper, numpy_helper

    starts, ends, axes = (numpy_helper.from_array(np.array([v], np.int64), n) for v, n in ((0, "s"), (3, "e"), (1, "a")))
    graph = helper.make_graph([helper.make_node("Slice", ["observation.state", "s", "e", "a"], ["action"])], "three",
                              [helper.make_tensor_value_info("observation.state", TensorProto.FLOAT, [1, 7])],
                              [helper.make_tensor_value_info("action", TensorProto.FLOAT, [1, 3])], [starts, ends, axes])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, str(path))
    return str(path)


@pytest.fixture(scope="module")
def policies(reach_policy: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ActorSystem]:
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "reach", "policy", reach_policy, {"threads": 1}, True, wait=60)
        asys.spawn(ModelActor, "three", "policy", write_three_actions(tmp_path_factory.mktemp("p") / "three.onnx"),
                   {"threads": 1}, True, wait=60)
        yield asys


class Loop:
    """A Sim and a VLA wired in this process: each VLA tick gets a fresh state, its command drives 5 physics steps."""

    def __init__(self, policy: Any = "reach", images: bool = False, stop_event: Event | None = None,
                 done_event: Event | None = None, **config: Any) -> None:
        self.sim = Sim(name="sim", inputs=[command], outputs=[states, camera],
                       config=SimConfig(camera_width=32, camera_height=24))
        self.sim.attach(lambda topic, msg: None)
        self.sim.on_configure()
        self.sim.on_activate()
        cfg = {"joint_names_map": {f"j{i}": j for i, j in enumerate(JOINTS)}, "urdf": "franka_panda/panda.urdf",
               "actions_per_chunk": 10, "observation_rate_hz": 10.0, **config}
        if images:
            cfg["camera_inputs_map"] = {"front": camera.name}
        self.vla = VLA(name="vla", inputs=[states, camera] if images else [states],
                       outputs=[command, chunks, feedback], config=VLAConfig(**cfg),
                       policy=LocalPolicyClient(policy) if isinstance(policy, str) else policy,
                       stop_event=stop_event, done_event=done_event)
        self.sent: list[tuple[str, Any]] = []
        self.violations: list[JointState] = []
        self.vla.attach(self._out)

    def _out(self, topic: str, msg: Any) -> None:
        self.sent.append((topic, msg))
        if topic == command.name:
            # The invariant of every test here: the arm never receives a command outside its limits.
            # (Noted, not raised here: the VLA's step would catch it.)
            clip = self.vla.clipper
            if clip is None or not (np.all(msg.position >= clip.lower) and np.all(msg.position <= clip.upper)):
                self.violations.append(msg)
            self.sim.on_message(command.name, msg)

    def commands(self) -> list[JointState]:
        return [m for t, m in self.sent if t == command.name]

    def tick(self, n: int = 1, state: JointState | None = None, image: Image | None = None) -> None:
        for _ in range(n):
            self.vla.on_message(states.name, state or self.sim.joint_state())
            if image is not None:
                self.vla.on_message(camera.name, image)
            self.vla.execute()
            for _ in range(5):
                self.sim.execute()

    def q(self) -> np.ndarray:
        return self.sim.joint_state().position[:7]

    def close(self) -> None:
        self.vla.on_shutdown()
        self.sim.on_shutdown()
        assert self.violations == [], "commands outside the joint limits reached the arm"


@pytest.fixture
def loop(policies: ActorSystem) -> Iterator[Loop]:
    lp = Loop()
    yield lp
    lp.close()


def within_limits(cmds: list[JointState], vla: VLA) -> bool:
    assert vla.clipper is not None
    return all(np.all(c.position >= vla.clipper.lower) and np.all(c.position <= vla.clipper.upper) for c in cmds)


def test_the_policy_drives_the_arm_to_its_target_and_the_task_ends_by_step_count(loop: Loop) -> None:
    start = np.abs(loop.q() - PANDA_TARGET).max()
    assert loop.vla.manipulate("reach", max_steps=150)["running"]
    loop.tick(160)
    assert np.abs(loop.q() - PANDA_TARGET).max() < 0.02 < start
    fb = [m for t, m in loop.sent if t == feedback.name]
    assert [f.step for f in fb[:3]] == [1, 2, 3] and fb[-1].done and fb[-1].outcome == "max_steps"
    assert len(loop.commands()) == 150  # none after the end
    traj = next(m for t, m in loop.sent if t == chunks.name)
    assert traj.positions.shape == (10, 7) and traj.joint_names == JOINTS


def test_a_command_beyond_a_limit_is_clipped_and_logged_once_per_joint(policies: ActorSystem,
                                                                        caplog: pytest.LogCaptureFixture) -> None:
    # A target beyond joint 4's upper limit (0.0) and faster than any joint may move: velocity limits bite too.
    lp = Loop(joint_limits={"panda_joint4": {"upper": -2.1}})
    try:
        with caplog.at_level(logging.WARNING, "embagents.component.vla"):
            lp.vla.manipulate("reach", 60)
            lp.tick(60)
        cmds = lp.commands()
        assert len(cmds) == 60 and within_limits(cmds, lp.vla)
        assert max(c.position[3] for c in cmds) == pytest.approx(-2.1)  # held at the tighter limit, never past it
        clipped = [r.getMessage() for r in caplog.records if "clipped" in r.getMessage()]
        assert any("joint panda_joint4 clipped" in m for m in clipped)
        assert len(clipped) == len({m.split("joint ")[1].split(" ")[0] for m in clipped})  # once per joint
        assert lp.vla.status()["clipped"]["panda_joint4"] > 1  # clipped many times, logged once
        steps = np.diff([c.position for c in cmds], axis=0)
        assert np.all(np.abs(steps) <= lp.vla.clipper.vmax * 0.02 + 1e-9)  # never faster than the limit
    finally:
        lp.close()


def test_a_joint_state_missing_a_joint_stops_motion_and_names_it(loop: Loop) -> None:
    loop.vla.manipulate("reach", 100)
    loop.tick(5)
    partial = loop.sim.joint_state()
    bad = JointState(name=partial.name[1:], position=partial.position[1:], stamp=partial.stamp)
    loop.tick(1, state=bad)
    assert loop.vla.health.status == HealthStatus.ALGORITHM_FAILURE
    assert "lacks joints ['panda_joint1']" in loop.vla.health.text and "joint_names_map" in loop.vla.health.text
    hold = loop.commands()[-1]
    assert np.allclose(hold.position, loop.commands()[-2].position, atol=0.05)  # a hold, not a step onward
    loop.tick(3)
    assert loop.vla.health.status == HealthStatus.HEALTHY and loop.vla.running  # it goes on once the state is whole


def test_a_stale_observation_stops_motion(loop: Loop) -> None:
    loop.vla.manipulate("reach", 100)
    loop.tick(5)
    loop.vla.on_message(states.name, loop.sim.joint_state(), now=time.monotonic() - 2.0)  # received 2 s ago
    before = len(loop.commands())
    loop.vla.execute()
    assert loop.vla.health.status == HealthStatus.SYSTEM_FAILURE and "s old (input_timeout_s 0.5)" in loop.vla.health.text
    (hold,) = loop.commands()[before:]
    assert np.allclose(hold.position, loop.sim.joint_state().position[:7], atol=0.05)  # hold where it is


def test_an_image_of_the_wrong_shape_stops_motion_and_says_what_is_expected(policies: ActorSystem) -> None:
    lp = Loop(images=True, policy="reach")
    try:
        lp.vla.manipulate("reach", 100)
        lp.tick(1, image=Image(data=np.zeros((24, 32), np.uint8)))
        assert lp.vla.health.status == HealthStatus.ALGORITHM_FAILURE
        assert "has shape (24, 32) dtype uint8; the policy takes (H, W, 3) uint8 RGB" in lp.vla.health.text
        assert lp.vla.step == 0
    finally:
        lp.close()


def test_a_policy_output_of_the_wrong_shape_names_expected_and_actual(policies: ActorSystem) -> None:
    lp = Loop(policy="three")
    try:
        lp.vla.manipulate("reach", 100)
        lp.tick(2)
        assert lp.vla.health.status == HealthStatus.ALGORITHM_FAILURE
        assert "answered actions of shape (1, 3); expected (10, 7)" in lp.vla.health.text
        assert lp.vla.step == 0 and within_limits(lp.commands(), lp.vla)  # only holds went out
    finally:
        lp.close()


def test_a_policy_that_answers_late_stops_motion_says_why_and_resumes(loop: Loop) -> None:
    loop.vla.manipulate("reach", 200)
    loop.tick(5)
    loop.vla.reconfigure({"policy_timeout_s": 1e-6})  # no model actor answers within a microsecond
    loop.tick(6)  # the next ask (every 5 ticks) is late
    assert loop.vla.health.status == HealthStatus.SYSTEM_FAILURE
    loop.tick(5)  # the hold settles
    q = loop.q()
    loop.tick(20)
    assert loop.vla.health.status == HealthStatus.SYSTEM_FAILURE
    assert "answered late" in loop.vla.health.text and "motion stopped" in loop.vla.health.text
    assert np.abs(loop.q() - q).max() < 0.05  # it held
    loop.vla.reconfigure({"policy_timeout_s": 1.0})
    loop.tick(10)
    assert loop.vla.health.status == HealthStatus.HEALTHY and np.abs(loop.q() - q).max() > 0.05


def test_stop_and_a_stop_event_halt_at_once(policies: ActorSystem) -> None:
    lp = Loop(stop_event=Event("halt", on(halt).field("data") == "now"))
    try:
        lp.vla.manipulate("reach", 100)
        lp.tick(5)
        lp.vla.on_message(halt.name, String("now"))
        assert lp.vla.status()["outcome"] == "stopped" and not lp.vla.running
        n = len(lp.commands())
        lp.tick(5)
        assert len(lp.commands()) == n  # nothing after the stop
        lp.vla.manipulate("again", 100)
        lp.tick(2)
        assert lp.vla.stop()["outcome"] == "stopped" and lp.vla.step == 2
    finally:
        lp.close()


def test_average_merging_blends_overlapping_chunks(policies: ActorSystem) -> None:
    lp = Loop(chunk_merge="average", merge_weight=0.5, observation_rate_hz=50.0)
    try:
        lp.vla.manipulate("reach", 40)
        lp.tick(40)
        assert np.abs(lp.q() - PANDA_TARGET).max() < np.abs(np.array(list(PANDA_READY.values())) - PANDA_TARGET).max()
        assert lp.vla.status()["outcome"] == "max_steps"
    finally:
        lp.close()


def test_a_vla_without_limits_for_a_joint_is_refused() -> None:
    with pytest.raises(ComponentError, match=r"no limits for joints \['elbow'\].*safety"):
        VLA(name="vla", inputs=[states], outputs=[command], policy=LocalPolicyClient("reach"),
            config=VLAConfig(joint_names_map={"e": "elbow"}, urdf="franka_panda/panda.urdf"))


def test_a_string_on_a_task_input_starts_that_task() -> None:
    task = Topic("vla/task", String)
    vla = VLA(name="vla", inputs=[states, task], outputs=[command], policy=LocalPolicyClient("reach"),
              config=VLAConfig(joint_names_map={"j": "panda_joint1"}, urdf="franka_panda/panda.urdf", max_steps=7))
    assert not vla.running
    vla.on_message(task.name, String("wave"))
    status = vla.status()
    assert {k: status[k] for k in ("task", "step", "max_steps", "running", "outcome", "clipped")} == {
        "task": "wave", "step": 0, "max_steps": 7, "running": True, "outcome": "running", "clipped": {"panda_joint1": 0}}
    assert status["chunks"] == status["queue_empty"] == 0 and status["policy_latency_ms"] is None


def test_a_done_event_ends_the_task_as_succeeded_and_a_new_task_replaces_a_running_one(policies: ActorSystem) -> None:
    done = Topic("grasped", String)
    lp = Loop(done_event=Event("grasped", on(done).field("data") == "yes"))
    try:
        lp.vla.manipulate("first", 100)
        lp.tick(3)
        lp.vla.manipulate("second", 100)
        lp.tick(3)
        lp.vla.on_message(done.name, String("yes"))
        ends = [(m.task, m.outcome) for t, m in lp.sent if t == feedback.name and m.done]
        assert ends == [("first", "replaced"), ("second", "succeeded")] and not lp.vla.running
    finally:
        lp.close()


def test_a_policy_actor_that_dies_stops_motion_and_the_vla_resumes_when_it_is_back(policies: ActorSystem,
                                                                                    reach_policy: str) -> None:
    import signal

    asys = policies
    asys.spawn(ModelActor, "fragile", "policy", reach_policy, {"threads": 1}, True, wait=60)
    lp = Loop(policy="fragile", policy_timeout_s=0.05)  # each tick without it waits this long
    try:
        lp.vla.manipulate("reach", 500)
        lp.tick(3)
        asys.signal("fragile", signal.SIGKILL)
        assert asys.procs["fragile"].exited.wait(10)
        lp.tick(8)
        assert lp.vla.health.status == HealthStatus.SYSTEM_FAILURE and "motion stopped" in lp.vla.health.text
        assert "'fragile'" in lp.vla.health.text and lp.vla.running
        held = lp.q()
        lp.tick(5)
        assert np.abs(lp.q() - held).max() < 0.02  # it holds while the policy is away
        asys.stop("fragile")
        asys.spawn(ModelActor, "fragile", "policy", reach_policy, {"threads": 1}, True, wait=60)
        for _ in range(100):  # the client's socket reconnects on its own
            lp.tick(1)
            if lp.vla.health.status == HealthStatus.HEALTHY:
                break
        lp.tick(5)
        assert lp.vla.health.status == HealthStatus.HEALTHY and np.abs(lp.q() - held).max() > 0.05
    finally:
        lp.close()
        asys.stop("fragile")


class Broken:
    """A policy client (another kind than the ONNX one) whose calls fail with an error of its own."""

    name = "broken"

    def infer(self, observation: Any, task: str, timeout_s: float) -> np.ndarray:
        raise RuntimeError("StatusCode.UNAVAILABLE: connection refused")

    def close(self) -> None:
        pass


def test_any_policy_client_failure_stops_motion_and_is_named(policies: ActorSystem) -> None:
    lp = Loop(policy=Broken())
    try:
        lp.vla.manipulate("reach", 10)
        lp.tick(2)
        assert lp.vla.health.status == HealthStatus.SYSTEM_FAILURE
        assert "policy 'broken' failed: RuntimeError: StatusCode.UNAVAILABLE" in lp.vla.health.text
        assert lp.commands() and lp.vla.step == 0  # only holds went out
    finally:
        lp.close()


class GatedPolicy:
    """A PolicyClient whose answers wait for the test's go: a slow policy server, made deterministic.

    Action i of a chunk is the observed state plus (i + 1) mrad on every joint, so a command
    tells which action of which chunk it was.
    """

    name = "gated"

    def __init__(self, permits: int = 0) -> None:
        self.gate = threading.Semaphore(permits)
        self.asked = 0

    def infer(self, observation: dict[str, np.ndarray], task: str, timeout_s: float) -> np.ndarray:
        self.asked += 1
        assert self.gate.acquire(timeout=10), "the test never let the policy answer"
        q = observation["observation.state"].astype(np.float32)
        return q[None, :] + 0.001 * np.arange(1, 51, dtype=np.float32)[:, None]

    def close(self) -> None:
        pass


def test_async_inference_keeps_ticking_while_the_policy_thinks_and_aligns_the_chunk_to_its_observation() -> None:
    policy = GatedPolicy()
    lp = Loop(policy=policy, async_inference=True, actions_per_chunk=50, observation_rate_hz=10.0)
    try:
        lp.vla.manipulate("reach", 1000)
        q0 = lp.q().copy()
        lp.tick(5)  # the policy has not answered: every tick still went out (a hold), none waited
        assert len(lp.commands()) == 5 and lp.vla.step == 0 and policy.asked == 1
        np.testing.assert_allclose(lp.commands()[-1].position, q0, atol=2e-3)
        policy.gate.release(1000)
        wait_until(lambda: lp.vla._inflight is not None and lp.vla._inflight[0].done(), 10.0, "the chunk in")
        lp.tick(1)  # tick 6: action 5 of the chunk asked on tick 1 (actions for ticks 1-5 are past)
        np.testing.assert_allclose(lp.commands()[-1].position, q0 + 0.006, atol=2e-4)
        lp.tick(60)  # chunks keep coming (one every 5 ticks) before the queue runs dry
        assert lp.vla.queue_empty == 0 and lp.vla.step == 61 and lp.vla.chunks >= 2
        assert lp.vla.status()["policy_latency_ms"] is not None
    finally:
        lp.close()


def test_a_synchronous_ask_when_empty_loop_counts_each_refill_as_queue_empty() -> None:
    lp = Loop(policy=GatedPolicy(permits=1000), actions_per_chunk=50, observation_rate_hz=1.0)
    try:
        lp.vla.manipulate("reach", 1000)
        lp.tick(120)  # chunks of 50 asked when used up: on ticks 1 (the start), 51 and 101
        assert lp.vla.chunks == 3 and lp.vla.queue_empty == 2 and lp.vla.step == 120
    finally:
        lp.close()
