"""Model-client fallback: the LLM answers from a server; when the server fails, a local model takes over."""

from agents.clients import OllamaClient, RoboMLHTTPClient
from agents.components import LLM
from agents.config import LLMConfig
from agents.models import OllamaModel, TransformersLLM
from agents.ros import Action, Launcher, Topic

text_in = Topic(name="text0", msg_type="String")
text_out = Topic(name="text1", msg_type="String")

primary = OllamaClient(OllamaModel(name="qwen", checkpoint="qwen3:1.7b"), port=11434)
backup = RoboMLHTTPClient(TransformersLLM(name="phi", checkpoint="microsoft/Phi-3-mini-4k-instruct"))

llm = LLM(
    inputs=[text_in],
    outputs=[text_out],
    model_client=primary,
    trigger=text_in,
    config=LLMConfig(temperature=0.0, max_new_tokens=32),
    component_name="brain",
)
llm.set_system_prompt("You are a helpful assistant that answers in one sentence.")
llm.additional_model_clients = {"local_phi": backup}

switch_to_backup = Action(method=llm.change_model_client, args=("local_phi",))
llm.on_algorithm_fail(action=switch_to_backup, max_retries=3)
llm.on_component_fail(action=[Action(method=llm.restart), switch_to_backup], max_retries=2)

launcher = Launcher()
launcher.enable_ui(inputs=[text_in], outputs=[text_out])
launcher.add_pkg(components=[llm], package_name="fallback_demo", multiprocessing=True)
launcher.bringup()
