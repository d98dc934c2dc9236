"""Seeing and acting, offline: a simulated Franka Panda driven by a VLA running an ONNX policy.

    embagents supervise examples/arm.py

``sim`` (PyBullet in its own process, physics at 240 Hz) publishes the arm's
joint states at 50 Hz and a 320x240 camera image at 5 Hz. ``vla`` runs the
``reach`` policy, a proportional controller toward a target pose written as
an ONNX graph (:mod:`embagents.models.backends.reach_policy`; it also takes
the camera image) and served by its own model actor on onnxruntime, at 50
actions per second, 10 actions per chunk, a new chunk 10 times per second,
every command clipped to the Panda's limits from its URDF. An event starts
the task when the first joint state arrives. ``report`` prints the largest
joint error each second; within ``TOLERANCE`` it saves the camera frame
(``$EMBAGENTS_ARM_OUT``, default ``./arm_out``) and stops the system (exit 0).
A ``describe`` of the camera needs a VLM and its model files; without them it
prints why it is skipped.
"""

from __future__ import annotations

import importlib.util
import os
import time
from typing import Any

import numpy as np

from embagents.components import VLA, Component, Sim, SimConfig, VLAConfig
from embagents.components.sim import PANDA_READY
from embagents.events import Event, call, on
from embagents.launch import SYSTEM_STOP
from embagents.models import LocalPolicyClient, PolicyModel
from embagents.msgs import Image, JointState, String, TaskFeedback
from embagents.system import System
from embagents.topic import Topic
from embagents.wheelfiles import cache_dir

OUT = os.path.abspath(os.environ.get("EMBAGENTS_ARM_OUT", "arm_out"))
JOINTS = list(PANDA_READY)  # panda_joint1..7
TARGET = [1.0, 0.4, -0.5, -1.4, 0.5, 2.3, 0.2]  # rad, inside every limit
TOLERANCE = 0.01  # rad
GIVE_UP_S = 60.0


def reach_policy() -> str:
    """The policy file, built once into the cache (a few KB, under a second)."""
    from embagents.models.backends.reach_policy import write_reach_policy

    tag = "_".join(f"{q:+.2f}" for q in TARGET)
    path = os.path.join(cache_dir(), "policies", f"reach_panda_{tag}.onnx")
    if not os.path.exists(path):
        write_reach_policy(path, TARGET, gain=0.03, chunk=10, camera="front", image_size=(240, 320))
    return path


class Report(Component):
    """Prints the joint error each second; saves the frame and stops the system within tolerance."""

    allowed_inputs = {"Required": [JointState], "Optional": [Image, TaskFeedback]}
    allowed_outputs = {"Required": [String]}

    def __init__(self, **kw: Any) -> None:
        self.started = time.monotonic()
        self.done = False
        super().__init__(**kw)

    def on_activate(self) -> None:
        self.started = time.monotonic()
        print(f"arm example: reaching {TARGET} (tolerance {TOLERANCE} rad); writing to {OUT}", flush=True)
        if importlib.util.find_spec("embagents.components.vlm") is None:
            print("describe: skipped: this embagents has no VLM component yet (issue 15, VLM part)", flush=True)
        elif not os.environ.get("EMBAGENTS_VLM_MODEL"):
            print("describe: skipped: no VLM model present; set EMBAGENTS_VLM_MODEL (a GGUF) and "
                  "EMBAGENTS_VLM_PROJECTOR (its mmproj GGUF), or run `embagents check` on a VLM system", flush=True)

    def _execution_step(self, **inputs: Any) -> None:
        if self.done:
            return
        js: JointState = inputs["arm/joint_states"]
        q = np.array([js.position[js.name.index(j)] for j in JOINTS])
        error = float(np.abs(q - TARGET).max())
        fb = inputs.get("vla/feedback")
        step = f", step {fb.step}/{fb.max_steps} ({fb.outcome})" if fb is not None else ""
        print(f"joint error: {error:.4f} rad (max over 7 joints){step}", flush=True)
        waited = time.monotonic() - self.started
        if error <= TOLERANCE or waited > GIVE_UP_S:
            self.done = True
            frame = inputs.get("camera/image")
            if frame is not None:
                import cv2

                os.makedirs(OUT, exist_ok=True)
                path = os.path.join(OUT, "arm.png")
                cv2.imwrite(path, cv2.cvtColor(frame.data, cv2.COLOR_RGB2BGR))
                print(f"camera frame: {path}", flush=True)
            verdict = "reached the target" if error <= TOLERANCE else f"FAILED: error {error:.4f} rad after {waited:.0f} s"
            print(f"done: {verdict}", flush=True)
            self.publish(stop, String(data=verdict))


joint_states = Topic("arm/joint_states", JointState)
command = Topic("arm/command", JointState)
image = Topic("camera/image", Image)
feedback = Topic("vla/feedback", TaskFeedback)
task = Topic("vla/task", String)  # `embagents publish vla/task "reach again"` starts a task too
stop = Topic(SYSTEM_STOP, String)

reach = PolicyModel(name="reach", local_model_path=reach_policy())
vla = VLA(
    name="vla", inputs=[joint_states, image, task], outputs=[command, feedback], policy=LocalPolicyClient(reach),
    config=VLAConfig(joint_names_map={f"joint{i + 1}": j for i, j in enumerate(JOINTS)},
                     camera_inputs_map={"front": image.name}, urdf="franka_panda/panda.urdf",
                     observation_rate_hz=10.0, actions_per_chunk=10, chunk_merge="newest", max_steps=3000),
    trigger=50.0,
)
first_state = Event("arm_ready", on(joint_states).field("stamp") > 0, once=True)

system = System(
    [
        Sim(name="sim", inputs=[command], outputs=[joint_states, image], config=SimConfig(camera_hz=5.0), trigger=240.0),
        vla,
        Report(name="report", inputs=[joint_states, image, feedback], outputs=[stop], trigger=1.0),
    ],
    events={first_state: call(vla, "manipulate", "reach the target pose", 3000)},
    models=[reach],
    external=[task],  # published from outside: the CLI, another system
    name="arm",
)
