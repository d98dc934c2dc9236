"""embagents: embodied-AI components as supervised actors, over ZeroMQ.

Importing the package registers every message type (so any process can
decode them) and re-exports what a ``system.py`` uses::

    >>> from embagents import LLM, LlamaModel, LocalModelClient, String, System, Topic
    >>> Topic("text_in", String).name
    'text_in'
"""

import importlib
import importlib.abc
import importlib.machinery
import sys
import types
import warnings

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
from embagents.components.llm_tools import register_tools_on, tool
from embagents.config import BaseComponentConfig
from embagents.events import Action, Event, Fallback, on
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

#: Module paths of the release before the layout of packages (old -> new). They keep working for one
#: release: importing one warns (FutureWarning, which Python shows) and gives the new module's names.
MOVED_MODULES = {
    "embagents.launch": "embagents.cli.supervise",
    "embagents.serve_model": "embagents.cli.serve_model",
    "embagents.keys": "embagents.cli.keys",
    "embagents.call": "embagents.tools.call",
    "embagents.publish": "embagents.tools.publish",
    "embagents.graph": "embagents.tools.graph",
    "embagents.tools.topic_cli": "embagents.cli.topic",
    "embagents.tools.logs_cli": "embagents.cli.logs",
    "embagents.tools.record_cli": "embagents.cli.record",
    "embagents.tools.serve_policy_cli": "embagents.cli.serve_policy",
    "embagents.tools.play": "embagents.cli.play",
    "embagents.tools.foxglove_view": "embagents.cli.view",
    "embagents.modelfiles": "embagents.models.files.hub",
    "embagents.wheelfiles": "embagents.models.files.wheels",
    "embagents.speechfiles": "embagents.models.files.speech",
    "embagents.models.vlm_files": "embagents.models.files.vlm",
    "embagents.progress": "embagents.models.progress",
    "embagents.whisper_onnx": "embagents.models.convert.whisper",
    "embagents.piper_voice": "embagents.models.convert.piper",
    "embagents.models.backends.bert_onnx": "embagents.models.convert.bert",
    "embagents.phonemes": "embagents.models.backends.phonemes",
    "embagents.llm_tools": "embagents.components.llm_tools",
    "embagents.clients": "embagents.models.clients",
    "embagents.rate": "embagents.realtime",
    "embagents.priority": "embagents.realtime",
    "embagents.toolcalls": "embagents.requests",
    "embagents.runtime.requests": "embagents.requests",
    "embagents.runtime.model_actor": "embagents.models.actor",
    "embagents.ros.bench_peer": "embagents.ros.bench.peer",
    "embagents.ros.recovery_peer": "embagents.ros.bench.recovery_peer",
}
#: Names that moved to another module than the rest of their old module.
_MOVED_NAMES = {("embagents.cli.supervise", "SYSTEM_STOP"): "embagents.system"}
_WHERE = {"embagents.launch": "embagents.launch moved: import SYSTEM_STOP from embagents.system "
                              "(the launcher is embagents.cli.supervise)"}


def _new_name(fullname: str) -> str | None:
    for old, new in MOVED_MODULES.items():
        if fullname == old or fullname.startswith(old + "."):
            return new + fullname[len(old):]
    return None


class _MovedModule(importlib.abc.Loader):
    """Loads an old module path as a module whose names are the new module's, with a FutureWarning."""

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> types.ModuleType:
        new = _new_name(spec.name)
        assert new is not None
        target = importlib.import_module(new)
        where = _WHERE.get(spec.name, f"{spec.name} moved to {new}: import it from there")
        warnings.warn(f"{where} ({spec.name} goes in the next release)", FutureWarning, stacklevel=2)
        module = types.ModuleType(spec.name, target.__doc__)
        if hasattr(target, "__all__"):
            module.__all__ = list(target.__all__)  # type: ignore[attr-defined]

        def __getattr__(name: str) -> object:
            moved = _MOVED_NAMES.get((new, name))
            return getattr(importlib.import_module(moved) if moved else target, name)

        module.__getattr__ = __getattr__  # type: ignore[method-assign]
        if hasattr(target, "__path__"):
            module.__path__ = []  # a package: its old submodules are found by this finder too
        return module

    def exec_module(self, module: types.ModuleType) -> None:
        pass


class _MovedFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname: str, path: object = None, target: object = None) -> importlib.machinery.ModuleSpec | None:
        if not fullname.startswith("embagents.") or _new_name(fullname) is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, _MovedModule())


if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
    # First: an old folder left with only __pycache__ (a checkout updated in place) would else be
    # found as an empty namespace package.
    sys.meta_path.insert(0, _MovedFinder())
