"""The VLA component: joint states and camera images in, safe joint commands out, in a closed loop.

Its trigger is the action rate in Hz (default 50). While a task runs
(:meth:`VLA.manipulate`, from an event, another component, or a ``String``
on a task input topic), each tick takes one action from the queue of action
chunks; at the observation rate (and whenever the queue runs dry) it first
asks the policy (any :class:`~embagents.models.policy.PolicyClient`: a local
ONNX policy, a LeRobot server) for a new chunk for the latest observation,
and merges it in (``chunk_merge``: ``newest`` wins, or a weighted
``average`` of the overlap).

Safety first, on every tick:

- every command is clipped to the joint limits (from ``urdf`` and/or
  ``joint_limits``): positions inside the limits and no faster than the
  velocity limit over one period; velocities within the limit and never past a
  position limit. A clipped joint is logged once. No limits, no start: a
  joint without limits is a declaration error.
- an input older than ``input_timeout_s``, a joint missing from the state,
  a camera image of the wrong shape, a policy that answers late or with the
  wrong shape: motion stops (hold position, or zero velocity), health says
  why, and the next tick tries again.
- :meth:`VLA.stop` (or ``stop_event``) halts at once.

``async_inference``: the policy is asked on a worker thread, so no tick ever
waits on it (a policy server 100 ms away at 50 Hz): a chunk that comes back
is aligned to the tick of its observation (its actions for ticks already
past are dropped), and a tick that finds no action holds the arm and counts a
``queue_empty`` event. Synchronously (the default) a tick whose queue is empty
waits for the chunk; ``queue_empty`` counts those. ``status()`` also gives
the policy's latency (p50 of observation sent -> chunk received) and the
server's own ``server_timing`` when its client reports one
(:class:`~embagents.models.openpi.OpenPIPolicyClient`); a ``String`` output
gets the same as JSON with each chunk (a metrics topic).

A task ends after ``max_steps`` steps, on ``done_event``, or on a stop; its
progress (step, done, outcome) is published as ``TaskFeedback``.

Example::

    >>> from embagents.models.policy import LocalPolicyClient, PolicyModel
    >>> from embagents.msgs import JointState
    >>> from embagents.topic import Topic
    >>> vla = VLA(name="vla", inputs=[Topic("joints", JointState)], outputs=[Topic("command", JointState)],
    ...           policy=LocalPolicyClient(PolicyModel(name="reach", local_model_path="reach.onnx")),
    ...           config=VLAConfig(joint_names_map={"j1": "panda_joint1"}, urdf="franka_panda/panda.urdf"))
    >>> vla.rate_hz, vla.clipper.upper.tolist()
    (50.0, [2.9671])
"""

from __future__ import annotations

import json
import time
from collections import deque
from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np
from attrs import define, field

from embagents.components.component import Component, ComponentProblem
from embagents.components.joint_limits import Clipper, merge_limits
from embagents.config import (
    BaseComponentConfig,
    ConfigError,
    one_of,
    positive_float,
    positive_int,
    to_bool,
)
from embagents.events import Event
from embagents.models.policy import STATE_KEY, PolicyLate, image_key
from embagents.models.protocol import ModelError, ModelUnavailable
from embagents.msgs import Image, JointState, JointTrajectory, String, TaskFeedback
from embagents.realtime import raise_priority
from embagents.topic import Topic

__all__ = ["VLA", "VLAConfig"]


def _str_map(value: object) -> dict[str, str]:
    if not isinstance(value, Mapping) or not all(isinstance(k, str) and isinstance(v, str) for k, v in value.items()):
        raise ConfigError(f"expected a dict of name -> name, got {value!r}")
    return dict(value)


def _weight(value: object) -> float:
    w = float(value)  # type: ignore[arg-type]
    if not 0.0 < w <= 1.0:
        raise ConfigError(f"merge_weight is the new chunk's weight in (0, 1], got {value!r}")
    return w


def _chunk_merge(value: object) -> str:
    return one_of("chunk_merge", "newest", "average")(value)


def _action_type(value: object) -> str:
    return one_of("action_type", "position", "velocity")(value)


@define(kw_only=True)
class VLAConfig(BaseComponentConfig):
    """Settings of :class:`VLA` (see the module docstring).

    - ``joint_names_map``: the policy's joints in its order -> the robot's joint names.
    - ``camera_inputs_map``: the policy's camera names -> Image input topic names.
    - ``observation_rate_hz``: how often a new chunk is asked for; the action rate is the trigger.
    - ``actions_per_chunk``: actions used of each chunk; ``chunk_merge``: ``newest`` or ``average``
      (``merge_weight``: the new chunk's weight).
    - ``action_type``: ``position`` (targets) or ``velocity``.
    - ``input_timeout_s``: an input older than this stops motion; ``policy_timeout_s``: the longest wait for a chunk.
    - ``urdf`` / ``joint_limits``: where limits come from (a dict per joint wins over the URDF).
    - ``max_steps``: a task's default length.
    - ``realtime``: its process at a control loop's priority (:func:`~embagents.realtime.raise_priority`).
    - ``async_inference``: ask the policy on a worker thread; ticks never wait for it.

    >>> VLAConfig(joint_names_map={"a": "b"}, chunk_merge="average").merge_weight
    0.5
    """

    loop_rate_hz: float = field(default=50.0, converter=positive_float)
    joint_names_map: dict[str, str] = field(factory=dict, converter=_str_map)
    camera_inputs_map: dict[str, str] = field(factory=dict, converter=_str_map)
    observation_rate_hz: float = field(default=10.0, converter=positive_float)
    actions_per_chunk: int = field(default=10, converter=positive_int)
    chunk_merge: str = field(default="newest", converter=_chunk_merge)
    merge_weight: float = field(default=0.5, converter=_weight)
    action_type: str = field(default="position", converter=_action_type)
    input_timeout_s: float = field(default=0.5, converter=positive_float)
    policy_timeout_s: float = field(default=0.2, converter=positive_float)
    urdf: str | None = None
    joint_limits: dict[str, dict[str, float]] = field(factory=dict)
    max_steps: int = field(default=500, converter=positive_int)
    realtime: bool = field(default=False, converter=to_bool)
    async_inference: bool = field(default=False, converter=to_bool)


class _Halt(Exception):
    """Motion must stop this tick; ``status`` and the text go to health."""

    def __init__(self, text: str, status: str = "algorithm", key: str = "") -> None:
        super().__init__(text)
        self.status, self.key = status, key or text  # key: the same cause is logged once, however its text varies


class VLA(Component):
    """Runs a policy in a closed loop on an arm, safely (see the module docstring)."""

    allowed_inputs = {"Required": [JointState], "Optional": [Image, String]}
    allowed_outputs = {"Required": [JointState], "Optional": [JointTrajectory, TaskFeedback, String]}
    config_class = VLAConfig

    def __init__(self, *, name: str, policy: Any = None, stop_event: Event | None = None,
                 done_event: Event | None = None, **kw: Any) -> None:
        self.policy = policy
        self.clients = {"policy": policy} if policy is not None else {}  # the models this run must serve
        self.stop_event, self.done_event = stop_event, done_event
        self.clipper: Clipper | None = None
        self.task: str | None = None
        self.step = 0
        self.task_max_steps = 0
        self.outcome = ""
        self._queue: dict[int, np.ndarray] = {}
        self._tick = 0
        self._next_obs = 0
        self._previous: np.ndarray | None = None  # the last position command sent
        self._halted_for = ""
        self._sent_at = -1  # the tick of the last command
        self.queue_empty = 0  # ticks that found no action, after the task's first chunk
        self.chunks = 0
        self._had_chunk = False
        self._latency_ms: deque[float] = deque(maxlen=200)  # observation sent -> chunk received
        self._worker: ThreadPoolExecutor | None = None
        self._inflight: tuple[Future[np.ndarray], int, int] | None = None  # (answer, its tick, its generation)
        self._generation = 0  # a task's start or a halt makes answers still on their way stale
        super().__init__(name=name, **kw)

    def default_trigger(self) -> float:
        return float(self.config.loop_rate_hz)

    @property
    def joints(self) -> list[str]:
        """The robot's joint names, in the policy's order."""
        return list(self.config.joint_names_map.values())

    def validate(self) -> list[ComponentProblem]:
        problems = super().validate()
        cfg = self.config
        if self.policy is None or not callable(getattr(self.policy, "infer", None)):
            problems.append(("missing-client", f"{self._label()}: needs policy= (a PolicyClient: "
                                               "LocalPolicyClient(PolicyModel(...)) or a LeRobot client)"))
        if not cfg.joint_names_map:
            problems.append(("bad-config", f"{self._label()}: joint_names_map is empty; map the policy's joints "
                                           "to the robot's, e.g. {'joint1': 'panda_joint1', ...}"))
        images = {t.name for t in self.inputs if t.msg_type is Image}
        for cam, topic in cfg.camera_inputs_map.items():
            if topic not in images:
                problems.append(("bad-config", f"{self._label()}: camera_inputs_map[{cam!r}] = {topic!r} is not one of "
                                               f"its Image inputs ({', '.join(sorted(images)) or 'none'})"))
        try:
            limits = merge_limits(cfg.urdf, cfg.joint_limits)
            self.clipper = Clipper(self.joints, limits, 1.0 / (self.rate_hz or cfg.loop_rate_hz), self.logger,
                                   self._label())
        except (ValueError, FileNotFoundError, ModuleNotFoundError) as exc:
            problems.append(("no-limits", f"{self._label()}: {exc} (safety: no command leaves without limits)"))
        for ev in (self.stop_event, self.done_event):
            if ev is not None and not isinstance(ev, Event):
                problems.append(("bad-event", f"{self._label()}: stop_event / done_event must be Events, got {ev!r}"))
        return problems

    @property
    def subscriptions(self) -> tuple[Topic, ...]:
        seen = {t.name: t for t in super().subscriptions}
        for ev in (self.stop_event, self.done_event):
            for t in ev.topics if isinstance(ev, Event) else ():
                seen.setdefault(t.name, t)
        return tuple(seen.values())

    def on_activate(self) -> None:
        if self.config.realtime:

            self.logger.info("%s: action loop at %s", self._label(), raise_priority(whole_process=True))

    # --- tasks ----------------------------------------------------------------------------
    def manipulate(self, task: str, max_steps: int | None = None) -> dict[str, Any]:
        """Start ``task`` (an instruction for the policy) for at most ``max_steps`` steps; returns its status.

        A task already running is replaced.
        """
        if not isinstance(task, str):
            raise ValueError(f"{self._label()}: manipulate needs a task text, got {task!r}")
        steps = self.config.max_steps if max_steps is None else int(max_steps)
        if steps < 1:
            raise ValueError(f"{self._label()}: max_steps must be >= 1, got {max_steps!r}")
        if self.running:
            self._end("replaced")  # its feedback says so; the arm goes on from where it is
        self._reset_motion()
        self.task, self.step, self.task_max_steps, self.outcome = task, 0, steps, "running"
        self.logger.info("%s: task %r started (at most %d steps)", self._label(), task, steps)
        return self.status()

    def stop(self) -> dict[str, Any]:
        """Halt at once: the queue is dropped, a stop command goes out, the task ends as ``stopped``."""
        self._send_stop()
        self._end("stopped")
        return self.status()

    def status(self) -> dict[str, Any]:
        """``{"task", "step", "max_steps", "running", "outcome", "clipped"}`` and the policy's metrics:
        ``chunks``, ``queue_empty``, ``policy_latency_ms`` (p50 of the last 200), ``server_timing``."""
        return {"task": self.task, "step": self.step, "max_steps": self.task_max_steps, "running": self.running,
                "outcome": self.outcome, "clipped": dict(self.clipper.counts) if self.clipper else {},
                **self.policy_metrics()}

    def policy_metrics(self) -> dict[str, Any]:
        """Chunks received, ``queue_empty`` ticks, the policy's latency and the server's own timing."""
        latency = round(float(np.median(self._latency_ms)), 3) if self._latency_ms else None
        timing = getattr(self.policy, "server_timing", None)
        return {"chunks": self.chunks, "queue_empty": self.queue_empty, "policy_latency_ms": latency,
                "server_timing": dict(timing) if isinstance(timing, dict) else {}}

    @property
    def running(self) -> bool:
        return self.outcome == "running"

    def _end(self, outcome: str) -> None:
        was = self.running
        self.outcome = outcome
        self._reset_motion()
        if was:
            self.logger.info("%s: task %r ended: %s after %d steps", self._label(), self.task, outcome, self.step)
            self._feedback()

    def _reset_motion(self) -> None:
        self._queue.clear()
        self._previous = None
        self._next_obs = self._tick
        self._had_chunk = False
        self._generation += 1  # an answer on its way is for what was before

    def _feedback(self) -> None:
        fb = TaskFeedback(task=self.task or "", step=self.step, max_steps=self.task_max_steps, done=not self.running,
                          outcome=self.outcome, stamp=time.time())
        for t in self.outputs:
            if t.msg_type is TaskFeedback:
                self.publish(t, fb)

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if self.stop_event is not None and self.stop_event.check(topic_name, msg, now):
            self.logger.warning("%s: stop event %r fired: halting", self._label(), self.stop_event.name)
            self.stop()
        if self.done_event is not None and self.done_event.check(topic_name, msg, now) and self.running:
            self._send_stop()
            self._end("succeeded")
        if isinstance(msg, String) and any(t.name == topic_name for t in self.inputs):
            self.manipulate(msg.data)
        return super().on_message(topic_name, msg, now)

    # --- the loop -------------------------------------------------------------------------
    def _execution_step(self, **inputs: Any) -> None:
        self._tick += 1
        if not self.running:
            return
        try:
            obs, q = self._observation(inputs)
            if self.config.async_inference:
                if not self._async_tick(obs, q):
                    return
            else:
                self._sync_tick(obs, q)
        except _Halt as halt:
            self._halt(halt, inputs)
            return
        except Exception:
            self._reset_motion()
            self._send_stop(inputs)  # whatever broke, the arm holds; the runtime reports the failure
            raise
        if self._halted_for:
            self.logger.info("%s: moving again (was stopped: %s)", self._label(), self._halted_for)
            self._halted_for = ""
        self.step += 1
        if self.step >= self.task_max_steps:
            self._end("max_steps")
        else:
            self._feedback()

    def _sync_tick(self, obs: dict[str, np.ndarray], q: np.ndarray) -> None:
        if self._tick not in self._queue:  # at the start, or after a halt: nothing to send yet
            self.queue_empty += self._had_chunk
            self._ask(obs)
        self._send(self._queue.pop(self._tick), q)
        for k in [k for k in self._queue if k <= self._tick]:
            del self._queue[k]
        if self._tick >= self._next_obs:
            # After this tick's command went out: the policy's latency never delays a command. The new
            # chunk's first action is for this tick (its observation's), already served: from the next on.
            self._ask(obs)

    def _async_tick(self, obs: dict[str, np.ndarray], q: np.ndarray) -> bool:
        """One tick that never waits on the policy; False when it had no action (the arm held)."""
        inflight = self._inflight
        if inflight is not None and inflight[0].done():
            self._inflight = None
            future, tick, generation = inflight
            if generation == self._generation:
                self._merge(future.result(), tick)  # a _Halt from the worker is raised here, on the loop's thread
        if self._inflight is None and (self._tick >= self._next_obs or self._tick not in self._queue):
            if self._worker is None:
                self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"{self.name}-policy")
            self._inflight = (self._worker.submit(self._request, obs), self._tick, self._generation)
            every = max(1, round((self.rate_hz or self.config.loop_rate_hz) / self.config.observation_rate_hz))
            self._next_obs = self._tick + every
        action = self._queue.pop(self._tick, None)
        for k in [k for k in self._queue if k <= self._tick]:
            del self._queue[k]
        if action is None:
            self.queue_empty += self._had_chunk
            self._send_stop()  # hold (or zero velocity) until the chunk is in
            return False
        self._send(action, q)
        return True

    def _observation(self, inputs: Mapping[str, Any]) -> tuple[dict[str, np.ndarray], np.ndarray]:
        now = time.monotonic()
        timeout = self.config.input_timeout_s
        for t in self.inputs:
            if t.msg_type is String:
                continue
            at = self._received_at.get(t.name)
            if at is None:
                raise _Halt(f"no message on {t.name!r} yet: motion waits for it", "system")
            if now - at > timeout:
                raise _Halt(f"observation on {t.name!r} is {now - at:.2f} s old (input_timeout_s {timeout}): "
                            "motion stopped until it is fresh; is its publisher running?", "system", f"stale {t.name}")
        state_topic = next(t for t in self.inputs if t.msg_type is JointState)
        js: JointState = inputs[state_topic.name]
        index = {n: i for i, n in enumerate(js.name)}
        missing = [j for j in self.joints if j not in index]
        if missing or len(js.position) != len(js.name):
            raise _Halt(f"joint state on {state_topic.name!r} lacks joints {missing or '(positions)'}; it has "
                        f"{js.name} with {len(js.position)} positions: check joint_names_map")
        q = js.position[[index[j] for j in self.joints]]
        obs = {STATE_KEY: q.astype(np.float32)}
        for cam, topic in self.config.camera_inputs_map.items():
            img = inputs.get(topic)
            data = getattr(img, "data", None)
            if not isinstance(data, np.ndarray) or data.ndim != 3 or data.shape[2] != 3 or data.dtype != np.uint8:
                shape = getattr(data, "shape", None)
                raise _Halt(f"image on {topic!r} for camera {cam!r} has shape {shape} dtype "
                            f"{getattr(data, 'dtype', None)}; the policy takes (H, W, 3) uint8 RGB (rgb8)")
            obs[image_key(cam)] = data
        return obs, q

    def _ask(self, obs: dict[str, np.ndarray]) -> None:
        self._merge(self._request(obs), self._tick)
        every = max(1, round((self.rate_hz or self.config.loop_rate_hz) / self.config.observation_rate_hz))
        self._next_obs = self._tick + every

    def _request(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """The policy's chunk for ``obs`` (checked); a _Halt says why there is none. Runs on the worker when async."""
        cfg = self.config
        name = getattr(self.policy, "name", type(self.policy).__name__)
        start = time.monotonic()
        try:
            chunk = self.policy.infer(obs, self.task or "", cfg.policy_timeout_s)
        except PolicyLate as exc:
            raise _Halt(f"policy {name!r} answered late: {exc} (policy_timeout_s {cfg.policy_timeout_s}); "
                        "motion stopped, asking again", "system") from None
        except (ModelUnavailable, ConnectionError, TimeoutError) as exc:
            raise _Halt(f"policy {name!r} unreachable: {exc}; motion stopped, asking again", "system") from None
        except (ModelError, ValueError) as exc:
            raise _Halt(f"policy {name!r} refused the observation: {exc}") from None
        except Exception as exc:  # any other client's failure (a gRPC error, say): stop, say what it was
            raise _Halt(f"policy {name!r} failed: {type(exc).__name__}: {exc}; motion stopped, asking again",
                        "system") from None
        chunk = np.asarray(chunk)
        n = len(self.joints)
        if chunk.ndim != 2 or chunk.shape[1] != n or chunk.shape[0] < 1 or not np.isfinite(chunk).all():
            raise _Halt(f"policy {name!r} answered actions of shape {tuple(chunk.shape)}; expected "
                        f"({cfg.actions_per_chunk}, {n}) = (actions_per_chunk, joints {self.joints}) of finite numbers")
        self._latency_ms.append((time.monotonic() - start) * 1000.0)
        return chunk[: cfg.actions_per_chunk].astype(np.float64)

    def _merge(self, chunk: np.ndarray, base: int) -> None:
        """Chunk action i is for tick ``base + i`` (its observation's tick): those still ahead go in the queue."""
        cfg = self.config
        self.chunks += 1
        self._had_chunk = True
        for i, action in enumerate(chunk):
            k = base + i
            if k < self._tick or (k == self._tick and self._sent_at == self._tick):
                continue  # its time is past
            old = self._queue.get(k)
            if old is None or cfg.chunk_merge == "newest":
                self._queue[k] = action
            else:
                self._queue[k] = cfg.merge_weight * action + (1.0 - cfg.merge_weight) * old
        self._publish_chunk()
        metrics = [t for t in self.outputs if t.msg_type is String]
        if metrics:
            text = json.dumps({"policy": getattr(self.policy, "name", ""), "stamp": time.time(), **self.policy_metrics(),
                               "last_latency_ms": round(self._latency_ms[-1], 3) if self._latency_ms else None})
            for t in metrics:
                self.publish(t, String(data=text))

    def _publish_chunk(self) -> None:
        outs = [t for t in self.outputs if t.msg_type is JointTrajectory]
        if not outs or self.clipper is None:
            return
        keys = sorted(self._queue)
        points = np.array([self._queue[k] for k in keys])
        lo, hi = self.clipper.lower, self.clipper.upper
        points = np.clip(points, lo, hi) if self.config.action_type == "position" else np.clip(
            points, -self.clipper.vmax, self.clipper.vmax)  # observers never see an unsafe point either
        dt = 1.0 / (self.rate_hz or self.config.loop_rate_hz)
        kind = "positions" if self.config.action_type == "position" else "velocities"
        traj = JointTrajectory(joint_names=self.joints, time_from_start=np.array([(k - self._tick) * dt for k in keys]),
                               stamp=time.time(), **{kind: points})
        for t in outs:
            self.publish(t, traj)

    def _send(self, action: np.ndarray, q: np.ndarray) -> None:
        assert self.clipper is not None  # validate() made it, or construction failed
        self._sent_at = self._tick
        if self.config.action_type == "position":
            previous = q if self._previous is None else self._previous
            target = self.clipper.position(action, previous)
            self._previous = target
            cmd = JointState(name=self.joints, position=target, stamp=time.time())
        else:
            cmd = JointState(name=self.joints, velocity=self.clipper.velocity(action, q), stamp=time.time())
        self._command(cmd)

    def _command(self, cmd: JointState) -> None:
        for t in self.outputs:
            if t.msg_type is JointState:
                self.publish(t, cmd)

    def _send_stop(self, inputs: Mapping[str, Any] | None = None) -> None:
        """Hold where the arm is (position) or command zero velocity."""
        if self.config.action_type == "velocity":
            self._command(JointState(name=self.joints, velocity=np.zeros(len(self.joints)), stamp=time.time()))
            return
        hold = self._previous
        js = next((m for m in (inputs or self._latest).values() if isinstance(m, JointState)), None)
        if js is not None and all(j in js.name for j in self.joints) and len(js.position) == len(js.name):
            hold = js.position[[js.name.index(j) for j in self.joints]]
        if hold is not None and self.clipper is not None:
            hold = np.clip(hold, self.clipper.lower, self.clipper.upper)
            self._command(JointState(name=self.joints, position=hold, stamp=time.time()))

    def _halt(self, halt: _Halt, inputs: Mapping[str, Any]) -> None:
        self._reset_motion()
        self._send_stop(inputs)
        if halt.key != self._halted_for:
            self.logger.warning("%s: %s", self._label(), halt)
            self._halted_for = halt.key
        (self.set_system_failure if halt.status == "system" else self.set_algorithm_failure)(str(halt))

    def on_shutdown(self) -> None:
        if self._worker is not None:
            self._worker.shutdown(wait=False, cancel_futures=True)
            self._worker = None
        if self.policy is not None and callable(getattr(self.policy, "close", None)):
            self.policy.close()
