"""Local fallback: the LLM asks a server; when it fails, the built-in local model answers instead."""

from agents.clients import OllamaClient
from agents.components import LLM
from agents.config import LLMConfig
from agents.models import OllamaModel
from agents.ros import Action, Launcher, Topic

question = Topic(name="text0", msg_type="String")
answer = Topic(name="text1", msg_type="String")

# Nothing listens on this port: every request fails, and the fallback takes over.
server = OllamaClient(OllamaModel(name="qwen", checkpoint="qwen3:1.7b"), port=9)

brain = LLM(
    inputs=[question],
    outputs=[answer],
    model_client=server,
    trigger=question,
    config=LLMConfig(temperature=0.0, max_new_tokens=32),
    component_name="brain",
)
brain.set_system_prompt("You are a helpful assistant that answers in one sentence.")

switch_to_local = Action(method=brain.fallback_to_local)
brain.on_component_fail(action=switch_to_local, max_retries=3)
brain.on_algorithm_fail(action=switch_to_local, max_retries=3)

launcher = Launcher()
launcher.enable_ui(inputs=[question], outputs=[answer])
launcher.add_pkg(components=[brain], package_name="local_fallback_demo", multiprocessing=True)
launcher.bringup()
