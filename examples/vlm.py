"""Ask a vision-language model what the camera sees.

    pip install -e ".[llm,vision,hub]"
    embagents check examples/vlm.py          # offline with no VLM: says which two files to get, and how
    EMBAGENTS_VLM_MODEL=moondream2/moondream2-text-model-f16.gguf \\
    EMBAGENTS_VLM_PROJECTOR=moondream2/moondream2-mmproj-f16.gguf \\
        embagents supervise examples/vlm.py

The ``camera`` publishes a real photo (scikit-image's coffee.png) at 2 Hz; the
``asker`` asks its question once the first frame is out; ``vlm`` sends the
frame to the ``eyes`` model actor through shared memory and publishes the
answer (and, with boxes in it, Detections); the ``printer`` prints it and
stops the system (``EMBAGENTS_KEEP_RUNNING=1`` keeps it serving; then ask
from another terminal)::

    embagents call vlm describe camera "What is on the table?"
    embagents publish question "Where is the cup? Answer with a bounding box."
    embagents publish look "look"      # an event: call(vlm, "describe", "camera", ...)

The model: ``EMBAGENTS_VLM_MODEL`` / ``EMBAGENTS_VLM_PROJECTOR`` (paths or Hugging
Face ``owner/name:glob`` ids), ``EMBAGENTS_VLM_HANDLER`` (default ``moondream``);
unset, moondream2 from the hub (as EmbodiedAgents), which needs a reachable hub once.
"""

from __future__ import annotations

import os
from typing import Any

from embagents.components import VLM, Component, VLMConfig
from embagents.events import Event, call, on
from embagents.models import LocalModelClient, VLMModel
from embagents.msgs import Detections, Image, String
from embagents.system import SYSTEM_STOP, System
from embagents.topic import Topic

QUESTION = os.environ.get("EMBAGENTS_QUESTION", "What is on the table?")

frames = Topic("camera", Image)
question = Topic("question", String)
answer = Topic("answer", String, queue_size=100, keep="all")
found = Topic("found", Detections, queue_size=100, keep="all")
look = Topic("look", String)  # any message on it: the event below asks the VLM to describe the camera
stop = Topic(SYSTEM_STOP, String)


class PhotoCamera(Component):
    """Publishes one real photo (coffee.png, 400x600) at its trigger's rate."""

    allowed_outputs = {"Required": [Image]}

    def on_configure(self) -> None:
        from skimage import data

        self.photo = data.coffee()

    def _execution_step(self, **inputs: Any) -> None:
        self.publish(frames, Image(data=self.photo, encoding="rgb8", frame_id="camera"))


class Asker(Component):
    """Asks the question once, when the first frame has gone out."""

    allowed_inputs = {"Required": [Image]}
    allowed_outputs = {"Required": [String]}

    def __init__(self, **kw: Any) -> None:
        self.asked = False
        super().__init__(**kw)

    def _execution_step(self, **inputs: Any) -> None:
        if not self.asked:
            self.asked = True
            print(f"Q: {QUESTION}", flush=True)
            self.publish(question, String(data=QUESTION))


class Printer(Component):
    """Prints each answer (and boxes); stops the system after the first unless EMBAGENTS_KEEP_RUNNING is set."""

    allowed_inputs = {"Optional": [String, Detections]}
    allowed_outputs = {"Optional": [String]}

    def _execution_step(self, **inputs: Any) -> None:
        if "found" in self.fresh_inputs and inputs.get("found") is not None:
            det = inputs["found"]
            for label, box in zip(det.labels, det.boxes.round().astype(int).tolist(), strict=True):
                print(f"box: {label} {tuple(box)}", flush=True)
        if "answer" in self.fresh_inputs and inputs.get("answer") is not None:
            print(f"A: {inputs['answer'].data}", flush=True)
            if not os.environ.get("EMBAGENTS_KEEP_RUNNING"):
                self.publish(stop, String(data="answered"))


model = VLMModel(
    name="eyes",
    local_model_path=os.environ.get("EMBAGENTS_VLM_MODEL") or None,
    projector_path=os.environ.get("EMBAGENTS_VLM_PROJECTOR") or None,
    chat_handler=os.environ.get("EMBAGENTS_VLM_HANDLER", "moondream"),
)

vlm = VLM(name="vlm", inputs=[question, frames], outputs=[answer, found], model_client=LocalModelClient(model),
          config=VLMConfig(max_new_tokens=64, temperature=0.0))

system = System(
    [
        PhotoCamera(name="camera", outputs=[frames], trigger=2.0),
        Asker(name="asker", inputs=[frames], outputs=[question], trigger=frames),
        vlm,
        Printer(name="printer", inputs=[answer, found], outputs=[stop], trigger=[answer, found]),
    ],
    models=[model],
    events={Event("look", on(look).field("data") != "", on_change=False):
            call(vlm, "describe", "camera", "Describe what you see.")},
    external=[look],
    name="vlm",
)
