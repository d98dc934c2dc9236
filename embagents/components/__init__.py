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
from embagents.components.memory import MapConfig, MapEncoding, MapLayer, Memory, MemoryConfig
from embagents.components.memory_store import (
    MemoryDimensionError,
    MemoryLocked,
    MemoryStore,
    MemoryStoreError,
)
from embagents.components.model_component import ChatClient, ModelComponent, client_name
from embagents.components.router import Route, SemanticRouter, SemanticRouterConfig
from embagents.components.video_maker import VideoMakerConfig, VideoMessageMaker
from embagents.components.vision import Vision, VisionConfig

__all__ = [
    "LLM",
    "UNSET",
    "Camera",
    "CameraConfig",
    "ChatClient",
    "Component",
    "ComponentError",
    "Health",
    "HealthStatus",
    "LLMConfig",
    "MapConfig",
    "MapEncoding",
    "MapLayer",
    "Memory",
    "MemoryConfig",
    "MemoryDimensionError",
    "MemoryLocked",
    "MemoryStore",
    "MemoryStoreError",
    "ModelComponent",
    "Route",
    "SemanticRouter",
    "SemanticRouterConfig",
    "VideoMakerConfig",
    "VideoMessageMaker",
    "Vision",
    "VisionConfig",
    "client_name",
    "lenient_construction",
    "tool_schema",
]
