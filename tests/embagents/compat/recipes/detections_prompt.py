"""Prompt engineering: what the detector sees goes into the VLM's prompt through a template."""

from agents.clients import OllamaClient
from agents.components import VLM, Vision
from agents.config import VisionConfig
from agents.models import OllamaModel
from agents.ros import Launcher, Topic

camera = Topic(name="image_raw", msg_type="Image")
seen = Topic(name="detections", msg_type="Detections")

detector = Vision(
    inputs=[camera],
    outputs=[seen],
    trigger=camera,
    config=VisionConfig(threshold=0.4, enable_local_classifier=True),
    component_name="detector",
)

question = Topic(name="question", msg_type="String")
answer = Topic(name="answer", msg_type="String")

describer = VLM(
    inputs=[question, camera, seen],
    outputs=[answer],
    model_client=OllamaClient(OllamaModel(name="qwen_vl", checkpoint="qwen2.5vl:3b")),
    trigger=question,
    component_name="describer",
)
describer.set_component_prompt(
    template="""You are a robot looking through your camera.
    The detector found: {{ detections }}.
    Answer in one sentence: {{ question }}"""
)

launcher = Launcher()
launcher.enable_ui(inputs=[question, camera], outputs=[answer, seen])
launcher.add_pkg(components=[detector, describer], package_name="detections_prompt")
launcher.bringup()
