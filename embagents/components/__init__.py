"""Components: the units of work of a system, each run as an actor in its own process.

Example::

    >>> from embagents.components import LLM, LLMConfig
    >>> LLMConfig(chat_history=True).history_size
    10
"""

from embagents.components.camera import Camera, CameraConfig
from embagents.components.component import (
    UNSET,
    Component,
    ComponentError,
    Health,
    HealthStatus,
    lenient_construction,
)
from embagents.components.llm import LLM, LLMConfig, tool_schema
from embagents.components.model_component import ChatClient, ModelComponent, client_name
from embagents.components.video_maker import VideoMakerConfig, VideoMessageMaker
from embagents.components.vision import Vision, VisionConfig
from embagents.components.vlm import MLLM, VLM, NoImageYet, VLMConfig

__all__ = [
    "LLM",
    "MLLM",
    "UNSET",
    "VLM",
    "Camera",
    "CameraConfig",
    "ChatClient",
    "Component",
    "ComponentError",
    "Health",
    "HealthStatus",
    "LLMConfig",
    "ModelComponent",
    "NoImageYet",
    "VideoMakerConfig",
    "VideoMessageMaker",
    "Vision",
    "VisionConfig",
    "VLMConfig",
    "client_name",
    "lenient_construction",
    "tool_schema",
]
