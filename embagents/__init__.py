"""embagents: embodied-AI components as supervised actors, over ZeroMQ.

Importing the package registers every message type (so any process can
decode them) and re-exports what a ``system.py`` uses::

    >>> from embagents import LLM, LlamaModel, LocalModelClient, String, System, Topic
    >>> Topic("text_in", String).name
    'text_in'
"""

from actors.app import set_app_name
from embagents.components import (
    LLM,
    Camera,
    CameraConfig,
    Component,
    Health,
    HealthStatus,
    LLMConfig,
    MapConfig,
    MapEncoding,
    MapLayer,
    Memory,
    MemoryConfig,
    ModelComponent,
    Route,
    SemanticRouter,
    SemanticRouterConfig,
    SpeechToText,
    SpeechToTextConfig,
    TextToSpeech,
    TextToSpeechConfig,
    VideoMakerConfig,
    VideoMessageMaker,
    Vision,
    VisionConfig,
)
from embagents.config import BaseComponentConfig
from embagents.events import Action, Event, Fallback, on
from embagents.llm_tools import register_tools_on, tool
from embagents.manager import Agent, HandshakeRule, Manager, Node, StateMachineHandler
from embagents.models import (
    DetectorModel,
    EmbeddingModel,
    LlamaModel,
    LocalModelClient,
    RemoteModelClient,
    SpeechToTextModel,
    TextToSpeechModel,
)
from embagents.msgs import (
    Audio,
    CompressedImage,
    Detections,
    Image,
    JointState,
    OccupancyGrid,
    Odometry,
    StreamingString,
    String,
    Trackings,
    Twist,
    Video,
)
from embagents.system import System, load_system
from embagents.topic import Topic

# The actors and the supervisor name processes, folders and variables after the app using them.
set_app_name("embagents")

__all__ = [
    "LLM",
    "Action",
    "Agent",
    "Audio",
    "BaseComponentConfig",
    "Camera",
    "CameraConfig",
    "Component",
    "CompressedImage",
    "Detections",
    "DetectorModel",
    "EmbeddingModel",
    "Event",
    "Fallback",
    "HandshakeRule",
    "Health",
    "HealthStatus",
    "Image",
    "JointState",
    "LLMConfig",
    "LlamaModel",
    "MapConfig",
    "MapEncoding",
    "MapLayer",
    "Memory",
    "MemoryConfig",
    "LocalModelClient",
    "Manager",
    "ModelComponent",
    "Node",
    "OccupancyGrid",
    "Odometry",
    "RemoteModelClient",
    "SpeechToText",
    "SpeechToTextConfig",
    "TextToSpeech",
    "TextToSpeechConfig",
    "SpeechToTextModel",
    "TextToSpeechModel",
    "Route",
    "SemanticRouter",
    "SemanticRouterConfig",
    "StreamingString",
    "StateMachineHandler",
    "String",
    "System",
    "Topic",
    "Trackings",
    "Twist",
    "Video",
    "VideoMakerConfig",
    "VideoMessageMaker",
    "Vision",
    "VisionConfig",
    "load_system",
    "on",
    "register_tools_on",
    "tool",
]
