"""A templated chat: a jinja2 prompt with the robot's location, chat history, a local transformers model."""

from agents.clients import RoboMLHTTPClient
from agents.components import LLM
from agents.config import LLMConfig
from agents.models import TransformersLLM
from agents.ros import FixedInput, Launcher, Topic

question = Topic(name="text0", msg_type="String")
location = FixedInput(name="location", msg_type="String", fixed="the kitchen")
answer = Topic(name="text1", msg_type="String")

phi = TransformersLLM(name="phi", checkpoint="microsoft/Phi-3-mini-4k-instruct")
phi_client = RoboMLHTTPClient(phi)

config = LLMConfig(chat_history=True, history_size=4, temperature=0.0, max_new_tokens=32, stream=True,
                   break_character=".")
chat = LLM(
    inputs=[question, location],
    outputs=[answer],
    model_client=phi_client,
    trigger=question,
    config=config,
    component_name="chat",
)
chat.set_system_prompt("You are a helpful assistant that answers in one sentence.")
chat.set_topic_prompt(question, template="""{% if location %}You are in {{ location }}. {% endif %}{{ text0 }}""")

launcher = Launcher()
launcher.enable_ui(inputs=[question], outputs=[answer])
launcher.add_pkg(components=[chat], package_name="templated_chat")
launcher.bringup()
