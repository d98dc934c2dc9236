"""Go to X with Memory: detections and scene notes are remembered where they were seen; the LLM's
locate tool finds the place, and its "Location: (x, y, z)" becomes the goal pose."""

import re

import numpy as np
from agents.clients import ChromaClient, OllamaClient
from agents.components import LLM, Memory, Vision
from agents.config import LLMConfig, MemoryConfig, VisionConfig
from agents.models import OllamaModel
from agents.ros import Launcher, MemLayer, Topic
from agents.vectordbs import ChromaDB

camera = Topic(name="image_raw", msg_type="Image")
seen = Topic(name="detections", msg_type="Detections")
notes = Topic(name="notes", msg_type="String")
odom = Topic(name="odom", msg_type="Odometry")

eyes = Vision(
    inputs=[camera],
    outputs=[seen],
    trigger=1.0,
    config=VisionConfig(threshold=0.5, enable_local_classifier=True),
    component_name="eyes",
)

memory = Memory(
    layers=[MemLayer(subscribes_to=seen, temporal_change=True), MemLayer(subscribes_to=notes)],
    position=odom,
    embedding_client=ChromaClient(db=ChromaDB()),
    config=MemoryConfig(db_path="/tmp/memory_go_to.db", consolidation_window=600.0),
    trigger=5.0,
    component_name="memory",
)

goto_in = Topic(name="goto_in", msg_type="String")
goal = Topic(name="goal_point", msg_type="PoseStamped")
goto = LLM(
    inputs=[goto_in],
    outputs=[goal],
    model_client=OllamaClient(OllamaModel(name="qwen", checkpoint="qwen3:1.7b")),
    trigger=goto_in,
    config=LLMConfig(temperature=0.0),
    component_name="go_to_x",
)
goto.set_component_prompt(template="Find where to go with the locate tool (concept: the place). User: {{ goto_in }}")
memory.register_tools_on(goto, tools=["locate"], send_tool_response_to_model=False)

LOCATION = re.compile(r"Location:\s*\(([^)]+)\)")


def to_goal(output):
    """The coordinates in locate's answer; None (nothing published) when it found nothing."""
    match = LOCATION.search(str(output))
    return np.array([float(v) for v in match.group(1).split(",")]) if match else None


goto.add_publisher_preprocessor(goal, to_goal)

launcher = Launcher()
launcher.enable_ui(inputs=[goto_in, notes, camera, odom], outputs=[goal])
launcher.add_pkg(components=[eyes, memory, goto], package_name="memory_go_to")
launcher.bringup()
