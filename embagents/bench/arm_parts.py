"""The systems and in-process baselines the arm bench cases run (:mod:`embagents.bench.cases_arm`).

``vla_system(policy)`` is the closed loop as users run it: the Sim (its own
process, 240 Hz physics), the VLA (its own process, 50 Hz actions, a chunk of 10
every 5 ticks from the ``bench_reach`` policy actor) and the policy's model
actor, all three ``realtime=True``; the Sim notes when each command arrives. The
in-process baseline raises its one loop's priority alike. ``gil_system()`` is a 100 Hz
:class:`Ticker` next to a :class:`Busy` component that runs pure Python on
request. The ``*_SCRIPT`` strings are the baselines, run with ``python -c``
(onnxruntime and extra threads never load in the bench process, whose later
ActorSystems fork from it).

Example::

    >>> jitter_ms([0.0, 0.02, 0.041, 0.06], period_s=0.02)
    [0.0, 1.0, 1.0]
"""

from __future__ import annotations

import time
from typing import Any

from embagents.components import VLA, Component, Sim, SimConfig, VLAConfig
from embagents.components.sim import PANDA_READY
from embagents.models import LocalPolicyClient, PolicyModel
from embagents.models.openpi import OpenPIPolicyClient
from embagents.msgs import JointState
from embagents.realtime import next_deadline, raise_priority
from embagents.system import System
from embagents.topic import Topic

__all__ = [
    "GIL_SCRIPT", "INPROCESS_VLA_SCRIPT", "Busy", "Ticker", "TimedSim", "gil_system", "jitter_ms", "vla_openpi_system",
    "vla_system",
]

#: Far enough from the ready pose that the arm moves during the whole measurement.
TARGET = [2.0, 1.0, 2.0, -0.5, 2.0, 3.0, 2.0]


def jitter_ms(stamps: list[float], period_s: float) -> list[float]:
    """``|interval - period|`` in ms for each pair of consecutive ``stamps`` (seconds)."""
    return [round(abs(b - a - period_s) * 1000.0, 6) for a, b in zip(stamps, stamps[1:], strict=False)]


class TimedSim(Sim):
    """The Sim, noting when each joint command arrives (``arrivals()`` hands them over)."""

    def __init__(self, **kw: Any) -> None:
        self._arrivals: list[float] = []
        super().__init__(**kw)

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if isinstance(msg, JointState) and topic_name == "bench_arm/command":
            self._arrivals.append(time.monotonic())
        return super().on_message(topic_name, msg, now)

    def arrivals(self) -> list[float]:
        out, self._arrivals = self._arrivals, []
        return out


def vla_system(policy: str) -> Any:
    """The Sim + VLA + policy system of ``vla_control_loop`` (``policy``: the ONNX file)."""

    states, command = Topic("bench_arm/joint_states", JointState), Topic("bench_arm/command", JointState)
    model = PolicyModel(name="bench_reach", local_model_path=policy, threads=1, realtime=True)
    joints = list(PANDA_READY)
    return System([
        TimedSim(name="bench_sim", inputs=[command], outputs=[states], trigger=240.0,
                 config=SimConfig(joint_state_hz=50.0, realtime=True)),
        VLA(name="bench_vla", inputs=[states], outputs=[command], policy=LocalPolicyClient(model), trigger=50.0,
            config=VLAConfig(joint_names_map={f"j{i}": j for i, j in enumerate(joints)}, urdf="franka_panda/panda.urdf",
                             actions_per_chunk=10, observation_rate_hz=10.0, max_steps=10**9, realtime=True)),
    ], models=[model], name="bench_arm")


def vla_openpi_system(url: str, chunk: int = 10, observation_rate_hz: float = 10.0, async_inference: bool = False,
                      policy_timeout_s: float = 0.2) -> Any:
    """``vla_system`` with its policy behind ``url`` (openpi's protocol: ``embagents serve-policy``)."""

    states, command = Topic("bench_arm/joint_states", JointState), Topic("bench_arm/command", JointState)
    joints = list(PANDA_READY)
    return System([
        TimedSim(name="bench_sim", inputs=[command], outputs=[states], trigger=240.0,
                 config=SimConfig(joint_state_hz=50.0, realtime=True)),
        VLA(name="bench_vla", inputs=[states], outputs=[command], trigger=50.0,
            policy=OpenPIPolicyClient(url, name="bench_openpi"),
            config=VLAConfig(joint_names_map={f"j{i}": j for i, j in enumerate(joints)}, urdf="franka_panda/panda.urdf",
                             actions_per_chunk=chunk, observation_rate_hz=observation_rate_hz, max_steps=10**9,
                             realtime=True, async_inference=async_inference, policy_timeout_s=policy_timeout_s)),
    ], name="bench_arm")


class Ticker(Component):
    """A 100 Hz control loop that notes when each tick runs and how late it was (``ticks()`` hands them over).

    Lateness is measured against the loop's own deadlines, kept by the rule the component actor
    follows (:func:`embagents.realtime.next_deadline`, from the deadline it sets on activation): a delay
    the same on every tick (a thread that always waits its turn for the GIL) counts, where the
    period between two ticks would not show it.
    """

    allowed_inputs = {"Optional": []}
    allowed_outputs = {"Optional": []}

    def __init__(self, **kw: Any) -> None:
        self._ticks: list[tuple[float, float]] = []
        self.priority = "normal"
        self._deadline = self._period = 0.0
        super().__init__(**kw)

    def on_activate(self) -> None:
        self.priority = raise_priority()  # on the actor's loop thread, which runs the ticks
        # The actor sets its first deadline one period after this, a few us later: ours is that much
        # earlier, so the lateness measured is that much larger, never smaller.
        self._period = 1.0 / float(self.rate_hz or 100.0)
        self._deadline = time.monotonic() + self._period

    def got_priority(self) -> str:
        return self.priority

    def _execution_step(self, **inputs: Any) -> None:
        now = time.monotonic()
        self._ticks.append((now, now - self._deadline))
        self._deadline, _ = next_deadline(self._deadline, self._period, now)

    def ticks(self) -> list[tuple[float, float]]:
        """``(time, lateness)`` of each tick since the last call, in seconds."""
        out, self._ticks = self._ticks, []
        return out


def spin(seconds: float) -> int:
    """Pure-Python work that holds the GIL (an SDK's Python side, a tokenizer) for ``seconds``."""
    end, n = time.monotonic() + seconds, 0
    while time.monotonic() < end:
        for i in range(1000):
            n += i * i % 7
    return n


class Busy(Component):
    """A GIL-heavy neighbour: ``spin(seconds)`` runs pure Python."""

    allowed_inputs = {"Optional": []}
    allowed_outputs = {"Optional": []}

    def spin(self, seconds: float) -> int:
        return spin(float(seconds))


def gil_system() -> Any:
    """The Ticker (100 Hz) and Busy components of ``gil_isolation``, each in its own process."""

    return System([Ticker(name="bench_ticker", trigger=100.0), Busy(name="bench_busy")], name="bench_gil")


#: The same closed loop in one process: physics at 240 Hz and the policy (onnxruntime here) at 50 Hz, on
#: absolute deadlines; prints one command time per line. argv: policy path, seconds.
INPROCESS_VLA_SCRIPT = """
import sys, time
import numpy as np
from embagents.bench.arm_parts import jitter_ms
from embagents.components import Clipper, Sim
from embagents.components.joint_limits import limits_from_urdf
from embagents.components.sim import PANDA_READY
from embagents.models.policy import PolicyServing
from embagents.msgs import JointState
from embagents.realtime import raise_priority
from embagents.topic import Topic
policy, seconds = sys.argv[1], float(sys.argv[2])
from embagents.realtime import raise_priority
raise_priority(whole_process=True)  # as the Sim and the VLA of the runtime's loop get (realtime=True)
joints = list(PANDA_READY)
sim = Sim(name="sim", inputs=[Topic("c", JointState)], outputs=[Topic("s", JointState)])
sim.attach(lambda t, m: None); sim.on_configure(); sim.on_activate()
serving = PolicyServing(policy, {"threads": 1}); serving.warmup()
clip = Clipper(joints, limits_from_urdf("franka_panda/panda.urdf"), 0.02)
queue, previous, tick, stamps = [], None, 0, []
start = time.monotonic(); next_physics, next_action = start, start + 0.02
while time.monotonic() - start < seconds:
    now = time.monotonic()
    if now >= next_action:
        js = sim.joint_state(); q = js.position[:7]
        if tick % 5 == 0 or not queue:
            queue = list(serving._run({"observation.state": q.astype(np.float32)}))
        target = clip.position(queue.pop(0), q if previous is None else previous); previous = target
        sim.on_message("c", JointState(name=joints, position=target)); stamps.append(time.monotonic())
        tick += 1; next_action += 0.02
    if now >= next_physics:
        sim.execute(); next_physics += 1 / 240
    time.sleep(max(0.0, min(next_physics, next_action) - time.monotonic()))
print(" ".join(map(str, stamps)))
"""

#: A 100 Hz ticker and a pure-Python busy loop as two pykka threads of one process (how a single-process
#: framework runs them); prints the ticker thread's priority, then "time:lateness" per tick (seconds). argv: seconds.
GIL_SCRIPT = """
import sys, time
import pykka
from embagents.bench.arm_parts import spin
from embagents.realtime import raise_priority
seconds = float(sys.argv[1])

class Ticker(pykka.ThreadingActor):
    def on_start(self):
        self.priority = raise_priority()  # this thread only, as the actor process's loop thread

    def run(self, seconds):
        stamps, deadline, end = [], time.monotonic(), time.monotonic() + seconds
        while time.monotonic() < end:
            deadline += 0.01
            time.sleep(max(0.0, deadline - time.monotonic()))
            now = time.monotonic()
            stamps.append(f"{now}:{now - deadline}")
        return stamps

class Busy(pykka.ThreadingActor):
    def spin(self, seconds):
        return spin(seconds)

ticker, busy = Ticker.start().proxy(), Busy.start().proxy()
work = busy.spin(seconds + 0.5)
stamps = ticker.run(seconds).get()
priority = ticker.priority.get()
work.get()
pykka.ActorRegistry.stop_all()
print(priority.replace(" ", "+"), " ".join(map(str, stamps)))
"""
