"""A semantic router: a spoken or typed command goes to the planner or to the chat model, by meaning."""

from agents.clients import ChromaClient, OllamaClient
from agents.components import LLM, SemanticRouter
from agents.config import LLMConfig, SemanticRouterConfig
from agents.models import OllamaModel
from agents.ros import Launcher, Route, Topic

query_topic = Topic(name="question", msg_type="String")
goto_query = Topic(name="goto_query", msg_type="String")
llm_query = Topic(name="llm_query", msg_type="String")
llm_answer = Topic(name="llm_answer", msg_type="String")

goto_route = Route(routes_to=goto_query, samples=[
    "Go to the door", "Go to the kitchen", "Get me a glass", "Fetch a ball",
    "Go to hallway", "Take me to the bedroom",
])
llm_route = Route(routes_to=llm_query, samples=[
    "What is the capital of France?", "Is there a god?", "Tell me a joke",
    "Tell me a story", "What is your name?",
])

db_client = ChromaClient()
router_config = SemanticRouterConfig(router_name="go-to-router", distance_func="l2", maximum_distance=1.2)
router = SemanticRouter(
    inputs=[query_topic],
    routes=[llm_route, goto_route],
    default_route=llm_route,
    config=router_config,
    db_client=db_client,
    component_name="router",
)

llama = OllamaModel(name="llama", checkpoint="llama3.2:3b")
chat = LLM(
    inputs=[llm_query],
    outputs=[llm_answer],
    model_client=OllamaClient(llama),
    trigger=llm_query,
    config=LLMConfig(chat_history=True, history_size=4, enable_local_model=True),
    component_name="chat",
)

launcher = Launcher()
launcher.enable_ui(inputs=[query_topic], outputs=[goto_query, llm_answer])
launcher.add_pkg(components=[router, chat], package_name="router_demo")
launcher.bringup()
