"""The simulated robot: a PyBullet world in the component's own process, stepped on absolute deadlines.

:class:`Sim` owns a PyBullet physics client (DIRECT mode: no window, no GL)
with an arm (the Franka Panda of ``pybullet_data`` by default; any URDF) and,
optionally, a mobile base (``husky/husky.urdf`` or ``r2d2.urdf``). Its trigger
is the physics rate in Hz: each tick steps the world up to wall time (after a
slow tick, such as a camera frame, the missed steps run at once, at most
``max_catchup_steps``), so simulated time keeps pace with real time. It
publishes, each at its own rate, ``JointState`` (``joint_state_hz``), a camera
``Image`` drawn by TinyRenderer on the CPU (``camera_hz``) and, with a base,
``Odometry``. It takes joint commands as ``JointState`` (positions: position
control; velocities only: velocity control), joint by joint by name, and
``Twist`` for the base. Like a real arm's driver it has a watchdog: a
velocity command older than ``command_timeout_s`` is replaced by zero.

Example::

    >>> from embagents.msgs import Image, JointState
    >>> from embagents.topic import Topic
    >>> sim = Sim(name="sim", inputs=[Topic("arm/command", JointState)],
    ...           outputs=[Topic("arm/joint_states", JointState), Topic("camera/image", Image)])
    >>> sim.rate_hz, sim.config.robot
    (240.0, 'franka_panda/panda.urdf')
"""

from __future__ import annotations

import math
import os
import time
from typing import Any

import numpy as np
from attrs import define, field

from embagents.components.component import Component, ComponentProblem
from embagents.config import (
    BaseComponentConfig,
    ConfigError,
    int_at_least,
    positive_float,
    positive_int,
    to_bool,
)
from embagents.msgs import Image, JointState, Odometry, Twist
from embagents.realtime import next_deadline, raise_priority

__all__ = ["Sim", "SimConfig", "robot_path"]


def robot_path(urdf: str) -> str:
    """A URDF path as given, or found in ``pybullet_data`` (``"franka_panda/panda.urdf"``).

    >>> robot_path("franka_panda/panda.urdf").endswith("pybullet_data/franka_panda/panda.urdf")
    True
    """
    if os.path.isfile(urdf):
        return os.path.abspath(urdf)
    try:
        import pybullet_data
    except ImportError as exc:
        raise ModuleNotFoundError("the simulator needs pybullet: pip install 'embagents[sim]'") from exc
    path = os.path.join(pybullet_data.getDataPath(), urdf)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"URDF {urdf!r} is neither a file nor in pybullet_data ({pybullet_data.getDataPath()}); "
                                "give a path, or a name such as 'franka_panda/panda.urdf' or 'kuka_iiwa/model.urdf'")
    return path


def _vec3(value: object) -> tuple[float, float, float]:
    try:
        x, y, z = (float(v) for v in value)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        raise ConfigError(f"expected three numbers (x, y, z), got {value!r}") from None
    return (x, y, z)


def _positions(value: object) -> dict[str, float] | None:
    if value is None:
        return None
    if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
        raise ConfigError(f"initial_positions must be a dict of joint name -> position, got {value!r}")
    return {k: float(v) for k, v in value.items()}


#: The Panda's usual ready pose (rad), joints 1..7.
PANDA_READY = {"panda_joint1": 0.0, "panda_joint2": -0.6, "panda_joint3": 0.0, "panda_joint4": -2.2,
               "panda_joint5": 0.0, "panda_joint6": 1.6, "panda_joint7": 0.8}


def _camera_side(value: object) -> int:
    return int_at_least(8)(value)


@define(kw_only=True)
class SimConfig(BaseComponentConfig):
    """Settings of :class:`Sim` (see the module docstring).

    - ``robot``: the arm's URDF (a path or a ``pybullet_data`` name); ``initial_positions`` by joint name
      (default: the Panda's ready pose on a Panda, else the URDF's zeros).
    - ``mobile_base``: a base's URDF (``"husky/husky.urdf"``, ``"r2d2.urdf"``) driven by ``Twist``; None: none.
    - ``joint_state_hz``, ``camera_hz``: publishing rates; the physics rate is the trigger (default 240 Hz).
    - ``camera_width`` / ``camera_height`` / ``camera_eye`` / ``camera_target`` / ``camera_fov``: the camera.
    - ``command_timeout_s``: a velocity command older than this is replaced by zero (a watchdog).
    - ``realtime``: its process at a control loop's priority (:func:`~embagents.realtime.raise_priority`).

    >>> SimConfig(camera_eye=[1, 1, 1]).camera_eye
    (1.0, 1.0, 1.0)
    """

    robot: str = "franka_panda/panda.urdf"
    initial_positions: dict[str, float] | None = field(default=None, converter=_positions)
    mobile_base: str | None = None
    joint_state_hz: float = field(default=50.0, converter=positive_float)
    camera_hz: float = field(default=5.0, converter=positive_float)
    camera_width: int = field(default=320, converter=_camera_side)
    camera_height: int = field(default=240, converter=_camera_side)
    camera_eye: tuple[float, float, float] = field(default=(1.3, -0.2, 0.9), converter=_vec3)
    camera_target: tuple[float, float, float] = field(default=(0.3, 0.15, 0.4), converter=_vec3)
    camera_fov: float = field(default=60.0, converter=positive_float)
    frame_id: str = "camera"
    command_timeout_s: float = field(default=0.5, converter=positive_float)
    max_catchup_steps: int = field(default=20, converter=positive_int)
    realtime: bool = field(default=False, converter=to_bool)


class Sim(Component):
    """A PyBullet world with an arm (and a base) as a component (see the module docstring)."""

    allowed_inputs = {"Optional": [JointState, Twist]}
    allowed_outputs = {"Required": [JointState], "Optional": [Image, Odometry]}
    config_class = SimConfig

    def __init__(self, *, name: str, **kw: Any) -> None:
        self._client: int | None = None
        self.steps = 0
        self.commands = 0
        self.last_command: JointState | None = None
        self.last_frame: np.ndarray | None = None
        super().__init__(name=name, **kw)

    def default_trigger(self) -> float:
        return 240.0

    def validate(self) -> list[ComponentProblem]:
        problems = super().validate()
        try:
            robot_path(self.config.robot)
            if self.config.mobile_base:
                robot_path(self.config.mobile_base)
        except (FileNotFoundError, ModuleNotFoundError) as exc:
            problems.append(("bad-robot", f"{self._label()}: {exc}"))
        return problems

    # --- the world ------------------------------------------------------------------------
    def on_configure(self) -> None:
        import pybullet as pb
        import pybullet_data

        cfg = self.config
        self._pb = pb
        cid = pb.connect(pb.DIRECT)
        self._client = cid
        pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=cid)
        pb.setGravity(0, 0, -9.81, physicsClientId=cid)
        pb.setTimeStep(1.0 / self.rate_hz if self.rate_hz else 1.0 / 240, physicsClientId=cid)
        pb.loadURDF("plane.urdf", physicsClientId=cid)
        self.robot = pb.loadURDF(robot_path(cfg.robot), useFixedBase=True, physicsClientId=cid)
        self.joints: dict[str, int] = {}
        self.max_force: dict[str, float] = {}
        for i in range(pb.getNumJoints(self.robot, physicsClientId=cid)):
            info = pb.getJointInfo(self.robot, i, physicsClientId=cid)
            if info[2] in (pb.JOINT_REVOLUTE, pb.JOINT_PRISMATIC):
                name = info[1].decode()
                self.joints[name] = i
                self.max_force[name] = float(info[10]) if info[10] > 0 else 100.0
        self.initial = self._initial_positions()
        for name, q in self.initial.items():
            pb.resetJointState(self.robot, self.joints[name], q, physicsClientId=cid)
        self._hold(list(self.joints), [self._q(n) for n in self.joints])
        self.base: int | None = None
        if cfg.mobile_base:
            self.base = pb.loadURDF(robot_path(cfg.mobile_base), [1.5, -1.0, 0.2], physicsClientId=cid)
        self._twist = Twist()
        self._velocity_until = 0.0
        self._view = pb.computeViewMatrix(cfg.camera_eye, cfg.camera_target, [0, 0, 1], physicsClientId=cid)
        self._proj = pb.computeProjectionMatrixFOV(cfg.camera_fov, cfg.camera_width / cfg.camera_height, 0.05, 10.0,
                                                   physicsClientId=cid)
        self.logger.info("%s: %s with joints %s%s, physics %.0f Hz", self._label(), cfg.robot, ", ".join(self.joints),
                         f", base {cfg.mobile_base}" if cfg.mobile_base else "", self.rate_hz or 0)

    def _initial_positions(self) -> dict[str, float]:
        """``initial_positions``; by default the Panda's ready pose on a Panda, else the URDF's zeros."""
        given = self.config.initial_positions
        if given is None:
            return dict(PANDA_READY) if set(PANDA_READY) <= set(self.joints) else {}
        unknown = sorted(set(given) - set(self.joints))
        if unknown:
            raise ValueError(f"{self._label()}: initial_positions names joints {unknown} that {self.config.robot} does "
                             f"not have; its joints: {', '.join(self.joints)}")
        return dict(given)

    def on_activate(self) -> None:
        if self.config.realtime:

            self.logger.info("%s: stepping at %s", self._label(), raise_priority(whole_process=True))
        now = time.monotonic()
        self._sim_start, self._sim_steps = now, 0
        self._js_due = now
        self._cam_due = now

    def on_shutdown(self) -> None:
        if self._client is not None:
            self._pb.disconnect(physicsClientId=self._client)
            self._client = None

    def _q(self, name: str) -> float:
        return float(self._pb.getJointState(self.robot, self.joints[name], physicsClientId=self._client)[0])

    def _hold(self, names: list[str], positions: list[float]) -> None:
        pb = self._pb
        pb.setJointMotorControlArray(self.robot, [self.joints[n] for n in names], pb.POSITION_CONTROL,
                                     targetPositions=positions, forces=[self.max_force[n] for n in names],
                                     physicsClientId=self._client)

    # --- commands -------------------------------------------------------------------------
    def _apply(self, cmd: JointState) -> None:
        """One joint command: positions (position control) or, with none, velocities."""
        known = [(i, n) for i, n in enumerate(cmd.name) if n in self.joints]
        unknown = [n for n in cmd.name if n not in self.joints]
        if unknown:
            self.set_algorithm_failure(f"command names joints {unknown} this robot does not have; "
                                       f"its joints: {', '.join(self.joints)}")
        if not known:
            return
        pb = self._pb
        idx, names = [i for i, _ in known], [n for _, n in known]
        ids, forces = [self.joints[n] for n in names], [self.max_force[n] for n in names]
        if len(cmd.position) == len(cmd.name):
            pb.setJointMotorControlArray(self.robot, ids, pb.POSITION_CONTROL, targetPositions=cmd.position[idx].tolist(),
                                         forces=forces, physicsClientId=self._client)
            self._velocity_until = 0.0
        elif len(cmd.velocity) == len(cmd.name):
            pb.setJointMotorControlArray(self.robot, ids, pb.VELOCITY_CONTROL, targetVelocities=cmd.velocity[idx].tolist(),
                                         forces=forces, physicsClientId=self._client)
            self._velocity_until = time.monotonic() + self.config.command_timeout_s
        else:
            self.set_algorithm_failure(f"a JointState command needs one position (or one velocity) per name: "
                                       f"{len(cmd.name)} names, {len(cmd.position)} positions, {len(cmd.velocity)} velocities")
            return
        self.commands += 1
        self.last_command = cmd

    def _watchdog(self) -> None:
        if self._velocity_until and time.monotonic() > self._velocity_until:
            self._velocity_until = 0.0
            names = list(self.joints)
            self._hold(names, [self._q(n) for n in names])  # stop where it is
            self.logger.warning("%s: no velocity command for %.2f s: holding position", self._label(),
                                self.config.command_timeout_s)

    def _drive_base(self) -> None:
        if self.base is None:
            return
        pb, cid = self._pb, self._client
        pos, orn = pb.getBasePositionAndOrientation(self.base, physicsClientId=cid)
        yaw = pb.getEulerFromQuaternion(orn)[2]
        vx, vy = self._twist.linear[0], self._twist.linear[1]
        lin = [vx * math.cos(yaw) - vy * math.sin(yaw), vx * math.sin(yaw) + vy * math.cos(yaw), 0.0]
        pb.resetBaseVelocity(self.base, lin, [0.0, 0.0, self._twist.angular[2]], physicsClientId=cid)

    # --- the step -------------------------------------------------------------------------
    def _execution_step(self, **inputs: Any) -> None:
        if self._client is None:
            self.on_configure()
            self.on_activate()
        for topic in self.inputs:
            msg = inputs.get(topic.name)
            if topic.name not in self.fresh_inputs or msg is None:
                continue
            if isinstance(msg, JointState):
                self._apply(msg)
            elif isinstance(msg, Twist):
                self._twist = msg
        self._watchdog()
        now = time.monotonic()
        due = int((now - self._sim_start) * (self.rate_hz or 240.0)) + 1
        n = min(max(1, due - self._sim_steps), self.config.max_catchup_steps)
        for _ in range(n):
            self._drive_base()
            self._pb.stepSimulation(physicsClientId=self._client)
        self._sim_steps = max(self._sim_steps + n, due - 1)  # never more than max_catchup_steps behind
        self.steps += n
        if now >= self._js_due:
            self._js_due, _ = next_deadline(self._js_due, 1.0 / self.config.joint_state_hz, now)
            self.publish_state()
        if now >= self._cam_due and any(t.msg_type is Image for t in self.outputs):
            self._cam_due, _ = next_deadline(self._cam_due, 1.0 / self.config.camera_hz, now)
            self.publish_frame()

    def joint_state(self) -> JointState:
        """The arm's joints now: positions, velocities, efforts (applied motor torques)."""
        states = self._pb.getJointStates(self.robot, list(self.joints.values()), physicsClientId=self._client)
        return JointState(name=list(self.joints), position=[s[0] for s in states], velocity=[s[1] for s in states],
                          effort=[s[3] for s in states], stamp=time.time())

    def publish_state(self) -> None:
        """Publish the joint states (and the odometry of a base) now."""
        js = self.joint_state()
        for t in self.outputs:
            if t.msg_type is JointState:
                self.publish(t, js)
        if self.base is not None:
            pb, cid = self._pb, self._client
            pos, orn = pb.getBasePositionAndOrientation(self.base, physicsClientId=cid)
            lin, ang = pb.getBaseVelocity(self.base, physicsClientId=cid)
            odom = Odometry(position=pos, orientation=orn, linear=lin, angular=ang, stamp=js.stamp)
            for t in self.outputs:
                if t.msg_type is Odometry:
                    self.publish(t, odom)

    def render(self) -> np.ndarray:
        """One camera frame, (height, width, 3) uint8 RGB, drawn on the CPU (TinyRenderer)."""
        cfg, pb = self.config, self._pb
        _, _, rgba, _, _ = pb.getCameraImage(cfg.camera_width, cfg.camera_height, self._view, self._proj,
                                             renderer=pb.ER_TINY_RENDERER, physicsClientId=self._client)
        rgba = np.asarray(rgba, np.uint8).reshape(cfg.camera_height, cfg.camera_width, 4)
        return np.ascontiguousarray(rgba[..., :3])

    def publish_frame(self) -> None:
        """Render and publish one frame on the Image outputs."""
        frame = self.render()
        self.last_frame = frame
        img = Image(data=frame, encoding="rgb8", stamp=time.time(), frame_id=self.config.frame_id)
        for t in self.outputs:
            if t.msg_type is Image:
                self.publish(t, img)

    # --- actions --------------------------------------------------------------------------
    def save_frame(self, path: str) -> str:
        """Render a frame now and write it as a PNG; returns its path."""
        import cv2

        frame = self.render()
        if not cv2.imwrite(path, cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)):
            raise OSError(f"{self._label()}: could not write {path!r} (is the folder writable?)")
        return os.path.abspath(path)

    def reset_joints(self, positions: dict[str, float] | None = None) -> list[str]:
        """Put the joints at ``positions`` (default: ``initial_positions``) at once; returns the joints set."""
        positions = dict(self.initial if positions is None else positions)
        unknown = sorted(set(positions) - set(self.joints))
        if unknown:
            raise ValueError(f"{self._label()}: no joints {unknown}; its joints: {', '.join(self.joints)}")
        for name, q in positions.items():
            self._pb.resetJointState(self.robot, self.joints[name], float(q), physicsClientId=self._client)
        self._hold(list(positions), list(positions.values()))
        return list(positions)
