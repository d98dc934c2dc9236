"""Go to X: a map memory of what was seen where; the LLM looks the place up with a tool and publishes the goal."""

import json

import numpy as np
from agents.clients import ChromaClient, OllamaClient
from agents.components import LLM, MapEncoding
from agents.config import LLMConfig, MapConfig
from agents.models import OllamaModel
from agents.ros import Launcher, MapLayer, Topic

detections = Topic(name="detections", msg_type="Detections")
introspection = Topic(name="introspection", msg_type="String")
position = Topic(name="odom", msg_type="Odometry")
map_topic = Topic(name="map", msg_type="OccupancyGrid")

layer1 = MapLayer(subscribes_to=detections, temporal_change=True)
layer2 = MapLayer(subscribes_to=introspection, resolution_multiple=3)

map_config = MapConfig(map_name="map")
map_encoder = MapEncoding(
    layers=[layer1, layer2],
    position=position,
    map_topic=map_topic,
    config=map_config,
    db_client=ChromaClient(),
    trigger=15.0,
    component_name="map_encoder",
)

goto_in = Topic(name="goto_in", msg_type="String")
goal_point = Topic(name="goal_point", msg_type="PoseStamped")

KNOWN_PLACES = {"kitchen": [4.0, 2.0, 0.0], "door": [0.0, 0.0, 0.0], "bedroom": [-3.0, 4.0, 0.0]}


def get_coordinates(place: str):
    """The x, y, z coordinates of a named place on the map."""
    return np.array(KNOWN_PLACES.get(place.lower().strip(), [0.0, 0.0, 0.0]))


coordinates_description = {
    "type": "function",
    "function": {
        "name": "get_coordinates",
        "description": "The coordinates of a place the robot knows, by its name.",
        "parameters": {
            "type": "object",
            "properties": {"place": {"type": "string", "description": "the place, e.g. kitchen"}},
            "required": ["place"],
        },
    },
}

llama = OllamaModel(name="llama", checkpoint="llama3.2:3b")
goto = LLM(
    inputs=[goto_in],
    outputs=[goal_point],
    model_client=OllamaClient(llama),
    trigger=goto_in,
    config=LLMConfig(temperature=0.0),
    component_name="go_to_x",
)
goto.set_topic_prompt(goto_in, template="""From the given metadata, extract the place the user wants to go
to and call get_coordinates with it. Question: {{ goto_in }}""")
goto.register_tool(tool=get_coordinates, tool_description=coordinates_description,
                   send_tool_response_to_model=False)


def as_goal(output):
    """The tool's coordinates (or a JSON list in the text) as the goal; None when there are none."""
    if isinstance(output, np.ndarray):
        return output
    if isinstance(output, (list, tuple)):
        return np.array(output)
    try:
        return np.array(json.loads(output))
    except (TypeError, ValueError):
        return None


goto.add_publisher_preprocessor(goal_point, as_goal)

launcher = Launcher()
launcher.enable_ui(inputs=[goto_in, detections, introspection, position, map_topic])
launcher.add_pkg(components=[map_encoder, goto], package_name="goto_x")
launcher.bringup()
