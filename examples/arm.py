"""Seeing and acting, offline: a simulated Franka Panda driven by a VLA running an ONNX policy.

    pip install -e ".[sim]"
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
With ``EMBAGENTS_POLICY=openpi`` (``pip install -e ".[sim,vla]"``) the same policy runs behind openpi's
WebSocket protocol, as a policy server on a GPU box would: its model actor serves it on
``ws://127.0.0.1:$EMBAGENTS_POLICY_PORT`` (default 8765), as ``embagents serve-policy`` does, and the VLA
reaches it with an ``OpenPIPolicyClient``, asking on a worker thread (``async_inference``) so no tick waits.
With ``EMBAGENTS_ARM_DATASET=DIR`` (``pip install -e ".[sim,dataset]"``) a ``DatasetRecorder`` records the
reach as a LeRobot dataset (v3 layout: joint states, commands as actions, the camera as a video) in DIR,
replacing it; ``embagents call recorder start_episode "another"`` / ``end_episode`` record more.
With a VLM (``pip install -e ".[sim,llm]"``; ``EMBAGENTS_VLM_MODEL``, ``EMBAGENTS_VLM_PROJECTOR``,
``EMBAGENTS_VLM_HANDLER`` as in examples/vlm.py) an event asks the VLM on its question topic when the first camera
frame comes (the VLM answers about its latest frame, holding the question until it has one)
and ``report`` prints the answer before it stops; without one it prints why it is skipped.
"""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

from embagents.components import (
    VLA,
    VLM,
    Component,
    DatasetRecorder,
    DatasetRecorderConfig,
    Sim,
    SimConfig,
    VLAConfig,
    VLMConfig,
)
from embagents.components.sim import PANDA_READY
from embagents.events import Event, call, on, publish
from embagents.models import (
    LocalModelClient,
    LocalPolicyClient,
    OpenPIPolicyClient,
    PolicyModel,
    VLMModel,
)
from embagents.models.files.wheels import cache_dir
from embagents.msgs import Image, JointState, String, TaskFeedback
from embagents.system import SYSTEM_STOP, System
from embagents.topic import Topic

OUT = os.path.abspath(os.environ.get("EMBAGENTS_ARM_OUT", "arm_out"))
JOINTS = list(PANDA_READY)  # panda_joint1..7
TARGET = [1.0, 0.4, -0.5, -1.4, 0.5, 2.3, 0.2]  # rad, inside every limit
TOLERANCE = 0.01  # rad
GIVE_UP_S = 60.0
VLM_FILE = os.environ.get("EMBAGENTS_VLM_MODEL")  # a VLM's language model (its projector beside it, or named)
DESCRIBE_WAIT_S = 120.0  # after the reach, wait at most this long for the VLM's answer
DATASET = os.environ.get("EMBAGENTS_ARM_DATASET")  # a directory: the reach recorded as a LeRobot dataset
POLICY = os.environ.get("EMBAGENTS_POLICY", "local")  # local: a model actor of this run; openpi: over WebSocket
if POLICY not in ("local", "openpi"):
    raise ValueError(f"EMBAGENTS_POLICY={POLICY!r}: use 'local' (a model actor) or 'openpi' (openpi's WebSocket)")


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

    allowed_inputs = {"Required": [JointState], "Optional": [Image, TaskFeedback, String]}
    allowed_outputs = {"Required": [String]}

    def __init__(self, **kw: Any) -> None:
        self.started = time.monotonic()
        self.done = False
        self.verdict: str | None = None
        self.finished_at = 0.0
        self.described = False
        super().__init__(**kw)

    def on_activate(self) -> None:
        self.started = time.monotonic()
        print(f"arm example: reaching {TARGET} (tolerance {TOLERANCE} rad); writing to {OUT}", flush=True)
        if VLM_FILE:
            print("describe: asking the VLM about the first camera frame", flush=True)
        else:
            print("describe: skipped: no VLM model present; set EMBAGENTS_VLM_MODEL (a GGUF) and "
                  "EMBAGENTS_VLM_PROJECTOR (its mmproj GGUF), or run `embagents check examples/vlm.py` to see "
                  "which files to get", flush=True)

    def _execution_step(self, **inputs: Any) -> None:
        said = inputs.get("vlm/answer")
        if said is not None and "vlm/answer" in self.fresh_inputs and not self.described:
            self.described = True
            print(f"describe: {said.data.strip()}", flush=True)
        if self.done:
            return
        if self.verdict is None:
            self._measure(inputs)
        waited = time.monotonic() - self.finished_at
        if self.verdict is not None and (self.described or not VLM_FILE or waited > DESCRIBE_WAIT_S):
            if VLM_FILE and not self.described:
                print(f"describe: no answer from the VLM within {DESCRIBE_WAIT_S:.0f} s", flush=True)
            self.done = True
            print(f"done: {self.verdict}", flush=True)
            self.publish(stop, String(data=self.verdict))

    def _measure(self, inputs: dict[str, Any]) -> None:
        js: JointState = inputs["arm/joint_states"]
        q = np.array([js.position[js.name.index(j)] for j in JOINTS])
        error = float(np.abs(q - TARGET).max())
        fb = inputs.get("vla/feedback")
        step = f", step {fb.step}/{fb.max_steps} ({fb.outcome})" if fb is not None else ""
        print(f"joint error: {error:.4f} rad (max over 7 joints){step}", flush=True)
        waited = time.monotonic() - self.started
        if error <= TOLERANCE or waited > GIVE_UP_S:
            frame = inputs.get("camera/image")
            if frame is not None:
                import cv2

                os.makedirs(OUT, exist_ok=True)
                path = os.path.join(OUT, "arm.png")
                cv2.imwrite(path, cv2.cvtColor(frame.data, cv2.COLOR_RGB2BGR))
                print(f"camera frame: {path}", flush=True)
            self.verdict = "reached the target" if error <= TOLERANCE else f"FAILED: error {error:.4f} rad after {waited:.0f} s"
            self.finished_at = time.monotonic()


joint_states = Topic("arm/joint_states", JointState)
command = Topic("arm/command", JointState)
image = Topic("camera/image", Image)
feedback = Topic("vla/feedback", TaskFeedback)
task = Topic("vla/task", String)  # `embagents publish vla/task "reach again"` starts a task too
stop = Topic(SYSTEM_STOP, String)

if POLICY == "openpi":  # served over openpi's protocol by its model actor, as `embagents serve-policy` serves it
    url = f"ws://127.0.0.1:{int(os.environ.get('EMBAGENTS_POLICY_PORT', '8765'))}"
    reach = PolicyModel(name="reach", local_model_path=reach_policy(), openpi_bind=url)
    policy: Any = OpenPIPolicyClient(url, name="reach")  # observation.state -> observation/state, task -> prompt
else:
    reach = PolicyModel(name="reach", local_model_path=reach_policy())
    policy = LocalPolicyClient(reach)
vla = VLA(
    name="vla", inputs=[joint_states, image, task], outputs=[command, feedback], policy=policy,
    config=VLAConfig(joint_names_map={f"joint{i + 1}": j for i, j in enumerate(JOINTS)},
                     camera_inputs_map={"front": image.name}, urdf="franka_panda/panda.urdf",
                     observation_rate_hz=10.0, actions_per_chunk=10, chunk_merge="newest", max_steps=3000,
                     async_inference=POLICY == "openpi"),
    trigger=50.0,
)
first_state = Event("arm_ready", on(joint_states).field("stamp") > 0, once=True)
events: dict[Event, Any] = {first_state: call(vla, "manipulate", "reach the target pose", 3000)}
models: list[Any] = [reach]
said = Topic("vlm/answer", String)
question = Topic("vlm/question", String)  # `embagents publish vlm/question "..."` asks the VLM too
seeing: list[Component] = []
if VLM_FILE:  # a describe of the camera by a vision-language model (examples/vlm.py has the details)
    eyes = VLMModel(name="eyes", local_model_path=VLM_FILE,
                    projector_path=os.environ.get("EMBAGENTS_VLM_PROJECTOR") or None,
                    chat_handler=os.environ.get("EMBAGENTS_VLM_HANDLER", "moondream"))
    vlm = VLM(name="vlm", inputs=[question, image], outputs=[said],
              model_client=LocalModelClient(eyes), config=VLMConfig(max_new_tokens=48, temperature=0.0))
    seeing, models = [vlm], [reach, eyes]
    # A question, not call(vlm, "describe", ...): the events actor may see the first frame before the VLM
    # does, and describe() refuses without a frame, while a question waits in the VLM for its first frame.
    events[Event("first_frame", on(image).field("stamp") >= 0, once=True)] = publish(
        question, String(data="Describe what you see."))

recording: list[Component] = []
if DATASET:  # joint states, commands and the camera, 10 frames a second, from the first joint state on
    recorder = DatasetRecorder(name="recorder", inputs=[joint_states, command, image], trigger=10.0,
                               config=DatasetRecorderConfig(root=DATASET, fps=10.0, camera_inputs_map={"front": image.name},
                                                            overwrite=True, robot_type="franka_panda"))
    recording = [recorder]
    events[Event("record_ready", on(joint_states).field("stamp") > 0, once=True)] = call(
        recorder, "start_episode", "reach the target pose")

system = System(
    [
        Sim(name="sim", inputs=[command], outputs=[joint_states, image], config=SimConfig(camera_hz=5.0), trigger=240.0),
        vla,
        *seeing,
        *recording,
        Report(name="report", inputs=[joint_states, image, feedback, said], outputs=[stop], trigger=1.0),
    ],
    events=events,
    models=models,
    external=[task, question if VLM_FILE else said],  # published from outside (the CLI, another system), or not at all
    name="arm",
)
