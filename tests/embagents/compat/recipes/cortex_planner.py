"""A Cortex planner: it answers goals with its own actions and the Memory's tools; Memory also keeps
the battery level as body state."""

from agents.clients import OllamaClient
from agents.components import Cortex, Memory, TextToSpeech
from agents.config import CortexConfig, MemoryConfig, TextToSpeechConfig
from agents.models import OllamaModel
from agents.ros import Action, Launcher, MemLayer, Topic

odom = Topic(name="odom", msg_type="Odometry")
notes = Topic(name="notes", msg_type="String")
battery = Topic(name="battery_level", msg_type="Float32")

memory = Memory(
    layers=[MemLayer(subscribes_to=notes), MemLayer(subscribes_to=battery, is_internal_state=True)],
    position=odom,
    config=MemoryConfig(db_path="/tmp/cortex_planner.db"),
    trigger=5.0,
    component_name="memory",
)

lights = {"on": False}


def toggle_light():
    """Toggle the robot's head light."""
    lights["on"] = not lights["on"]
    return f"the light is {'on' if lights['on'] else 'off'}"


said = Topic(name="cortex_output", msg_type="StreamingString")
cortex = Cortex(
    actions=[Action(method=toggle_light, description="Toggle the robot's head light on or off.")],
    output=said,
    model_client=OllamaClient(OllamaModel(name="qwen", checkpoint="qwen3:1.7b")),
    config=CortexConfig(max_planning_steps=4, max_execution_steps=6),
    component_name="cortex",
)

voice = TextToSpeech(
    inputs=[said],
    trigger=said,
    config=TextToSpeechConfig(enable_local_model=True),
    component_name="voice",
)

launcher = Launcher()
launcher.enable_ui(inputs=[cortex.ui_main_action_input, notes, odom, battery], outputs=[said])
launcher.add_pkg(components=[memory, cortex, voice], package_name="cortex_planner", multiprocessing=True)
launcher.on_process_fail(max_retries=3)
launcher.bringup()
