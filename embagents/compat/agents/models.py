"""EmbodiedAgents' model declarations: plain data (a name, a checkpoint, options) that a client maps.

Which embagents model serves one depends on the client (a server's through
:class:`~embagents.models.clients.OpenAIHTTPClient`, a RoboML one as a local model
actor) and on the component using it (an ``OllamaModel`` is a chat model for
an LLM and a vision-language model for a VLM): see :mod:`.clients`.

Example::

    >>> OllamaModel(name="llava", checkpoint="llava:latest").checkpoint
    'llava:latest'
    >>> Whisper(name="whisper").role
    'stt'
"""

from __future__ import annotations

from typing import Any, ClassVar

__all__ = [
    "Bark", "GenericLLM", "GenericMLLM", "GenericSTT", "GenericTTS", "LeRobotPolicy", "Llava", "MeloTTS",
    "OllamaModel", "SpeechT5", "TransformersLLM", "TransformersMLLM", "TransformersTTS", "VisionModel", "Whisper",
]


class _Model:
    """A model declaration: ``name``, ``checkpoint`` and options (kept, shown in warnings)."""

    #: What the model does, when the class says it ("" : the component using it decides).
    role: ClassVar[str] = ""
    default_checkpoint: ClassVar[str] = ""

    def __init__(self, name: str, checkpoint: str | None = None, **options: Any) -> None:
        if not isinstance(name, str) or not name:
            raise ValueError(f"{type(self).__name__}: name must be a non-empty str, got {name!r}")
        self.name = name
        self.checkpoint = checkpoint or self.default_checkpoint
        self.options = options

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, checkpoint={self.checkpoint!r})"


class OllamaModel(_Model):
    """A model an Ollama server runs (chat, or vision-language for a VLM)."""

    default_checkpoint = "llama3.2:3b"


class GenericLLM(_Model):
    """A chat model behind any OpenAI-compatible server."""

    role = "llm"


class GenericMLLM(_Model):
    """A vision-language model behind any OpenAI-compatible server."""

    role = "vlm"


class GenericSTT(_Model):
    """A transcription model behind an OpenAI-compatible server (``/v1/audio/transcriptions``)."""

    role = "stt"


class GenericTTS(_Model):
    """A speech model behind an OpenAI-compatible server (``/v1/audio/speech``)."""

    role = "tts"


class TransformersLLM(_Model):
    """A Hugging Face transformers chat model (RoboML serves it in EmbodiedAgents)."""

    role = "llm"
    default_checkpoint = "microsoft/Phi-3-mini-4k-instruct"


class TransformersMLLM(_Model):
    """A Hugging Face transformers vision-language model."""

    role = "vlm"
    default_checkpoint = "HuggingFaceM4/idefics2-8b"


class Llava(TransformersMLLM):
    """LLaVA."""

    default_checkpoint = "liuhaotian/llava-v1.6-mistral-7b"


class Whisper(_Model):
    """Whisper speech-to-text."""

    role = "stt"
    default_checkpoint = "small.en"


class SpeechT5(_Model):
    """SpeechT5 text-to-speech."""

    role = "tts"
    default_checkpoint = "microsoft/speecht5_tts"


class TransformersTTS(_Model):
    """A Hugging Face transformers text-to-speech model (RoboML serves it in EmbodiedAgents)."""

    role = "tts"
    default_checkpoint = "microsoft/speecht5_tts"


class Bark(_Model):
    """Bark text-to-speech."""

    role = "tts"
    default_checkpoint = "suno/bark-small"


class MeloTTS(_Model):
    """MeloTTS text-to-speech."""

    role = "tts"
    default_checkpoint = "EN"


class VisionModel(_Model):
    """An object detector (MMDetection in RoboML); a ``.onnx`` checkpoint is a YOLO file here."""

    role = "vision"
    default_checkpoint = "dino_4scale_swin_l_16xb2_36e_coco"


class LeRobotPolicy(_Model):
    """A LeRobot policy (ACT, SmolVLA...) served by LeRobot's policy server."""

    role = "policy"
    default_checkpoint = "lerobot/act_aloha_sim_transfer_cube_human"

    def __init__(self, name: str, checkpoint: str | None = None, *, policy_type: str = "act",
                 actions_per_chunk: int = 50, features: dict[str, Any] | None = None, **options: Any) -> None:
        super().__init__(name, checkpoint, **options)
        self.policy_type, self.actions_per_chunk, self.features = policy_type, actions_per_chunk, features
