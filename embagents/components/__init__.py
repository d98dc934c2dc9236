"""Components: the units of work of a system, each run as an actor in its own process.

Example::

    >>> from embagents.components import LLM, LLMConfig
    >>> LLMConfig(chat_history=True).history_size
    10
"""

from embagents.components.audio_devices import Microphone, MicrophoneConfig, Speaker, SpeakerConfig
from embagents.components.audio_io import (
    WavFileSink,
    WavFileSinkConfig,
    WavFileSource,
    WavFileSourceConfig,
    read_wav,
)
from embagents.components.camera import Camera, CameraConfig
from embagents.components.component import (
    UNSET,
    Component,
    ComponentError,
    Health,
    HealthStatus,
    lenient_construction,
)
from embagents.components.dataset_recorder import DatasetRecorder, DatasetRecorderConfig
from embagents.components.joint_limits import Clipper, JointLimit, limits_from_urdf
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
from embagents.components.sim import Sim, SimConfig
from embagents.components.speech_to_text import SpeechToText, SpeechToTextConfig
from embagents.components.text_to_speech import TextToSpeech, TextToSpeechConfig
from embagents.components.video_maker import VideoMakerConfig, VideoMessageMaker
from embagents.components.vision import Vision, VisionConfig
from embagents.components.vla import VLA, VLAConfig
from embagents.components.vlm import MLLM, VLM, NoImageYet, VLMConfig

__all__ = [
    "LLM",
    "MLLM",
    "VLA",
    "UNSET",
    "VLM",
    "Camera",
    "CameraConfig",
    "ChatClient",
    "Clipper",
    "Component",
    "ComponentError",
    "DatasetRecorder",
    "DatasetRecorderConfig",
    "Health",
    "HealthStatus",
    "JointLimit",
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
    "Microphone",
    "MicrophoneConfig",
    "ModelComponent",
    "NoImageYet",
    "Speaker",
    "SpeakerConfig",
    "SpeechToText",
    "TextToSpeech",
    "TextToSpeechConfig",
    "WavFileSink",
    "WavFileSinkConfig",
    "WavFileSource",
    "WavFileSourceConfig",
    "read_wav",
    "SpeechToTextConfig",
    "Sim",
    "SimConfig",
    "Route",
    "SemanticRouter",
    "SemanticRouterConfig",
    "VideoMakerConfig",
    "VideoMessageMaker",
    "Vision",
    "VisionConfig",
    "VLAConfig",
    "VLMConfig",
    "client_name",
    "lenient_construction",
    "limits_from_urdf",
    "tool_schema",
]
