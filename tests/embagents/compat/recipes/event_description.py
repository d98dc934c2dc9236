"""Event-driven visual description: when the detector sees a person, the VLM describes the scene."""

from agents.clients import OllamaClient
from agents.components import VLM, Vision
from agents.config import VisionConfig, VLMConfig
from agents.models import OllamaModel
from agents.ros import Event, FixedInput, Launcher, Topic

image0 = Topic(name="image_raw", msg_type="Image")
detections = Topic(name="detections", msg_type="Detections")
description = Topic(name="description", msg_type="String")

detection_config = VisionConfig(threshold=0.5, enable_local_classifier=True)
vision = Vision(
    inputs=[image0],
    outputs=[detections],
    trigger=image0,
    config=detection_config,
    component_name="detection_component",
)

person_seen = Event(event_condition=detections.msg.labels.contains("person"), on_change=True)

prompt = FixedInput(name="prompt", msg_type="String",
                    fixed="Someone just walked in. Describe the person you see in one sentence.")

qwen_vl = OllamaModel(name="qwen_vl", checkpoint="qwen2.5vl:3b")
describer = VLM(
    inputs=[prompt, image0],
    outputs=[description],
    model_client=OllamaClient(qwen_vl),
    trigger=person_seen,
    config=VLMConfig(temperature=0.2, max_new_tokens=80),
    component_name="describer",
)

launcher = Launcher()
launcher.add_pkg(components=[vision, describer], package_name="visual_description")
launcher.bringup()
