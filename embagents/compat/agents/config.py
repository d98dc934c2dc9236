"""EmbodiedAgents' ``*Config`` classes with their field names, mapped to embagents' configs.

A field is renamed where ours differs (``min_silence_duration_ms`` ->
``min_silence_ms``, ``observation_sending_rate`` -> ``observation_rate_hz``,
``robot_urdf_file`` -> ``urdf``...), kept where it is the same, refused in one
line where embagents does not have the feature (``stream_to_ip``), and said once
on stderr where it has no effect here (``device_local_model``). An unknown
field is refused naming the fields EmbodiedAgents' spelling and ours accept.

Example::

    >>> SpeechToTextConfig(enable_vad=True, min_silence_duration_ms=300).native.min_silence_ms
    300.0
    >>> TextToSpeechConfig(stream_to_ip="10.0.0.2")
    Traceback (most recent call last):
    embagents.compat._core.CompatError: EmbodiedAgents' TextToSpeechConfig(stream_to_ip='10.0.0.2') (streaming audio to an IP) is not supported by embagents; use a Speaker component, or RosOutput of the Audio topic
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

from embagents import components as native
from embagents.compat._core import CompatError, note, unsupported
from embagents.config import config_fields

__all__ = ["CortexConfig", "LLMConfig", "MapConfig", "MemoryConfig", "SemanticRouterConfig", "SpeechToTextConfig", "TextToSpeechConfig",
           "VLAConfig", "VLMConfig", "VisionConfig"]

#: Fields only the compat components read (they decide which client a component gets, or what it adds).
_COMPAT_FIELDS = ("enable_local_model", "enable_local_classifier", "play_on_device")

#: RAG (EmbodiedAgents' LLM with a db_client): the LLM reads the Memory database named collection_name.
_RAG_FIELDS = {"enable_rag": False, "collection_name": "map", "n_results": 1, "add_metadata": False}
_LOCAL_MODEL = "embagents runs every model in its own model actor process: nothing to place"


class _Config:
    """A native config built from EmbodiedAgents' field names; ``native`` is it, ``extras`` the compat fields."""

    native_class: ClassVar[type]
    #: EmbodiedAgents' name -> ours, or (ours, converter of the value).
    renames: ClassVar[dict[str, str | tuple[str, Callable[[Any], Any]]]] = {}
    #: Refused when set to a truthy value: name -> (the feature, what to use here).
    refused: ClassVar[dict[str, tuple[str, str]]] = {}
    #: Accepted, without effect here: name -> why.
    inert: ClassVar[dict[str, str]] = {}
    #: This class's own fields that only the compat component reads: name -> default.
    compat_fields: ClassVar[dict[str, Any]] = {}

    def __init__(self, **fields: Any) -> None:
        name = type(self).__name__
        ours = config_fields(self.native_class)
        mapped: dict[str, Any] = {}
        self.extras: dict[str, Any] = {}
        for key, value in fields.items():
            if key in self.refused:
                if value:
                    feature, instead = self.refused[key]
                    unsupported(f"{name}({key}={value!r}) ({feature})", instead)
                continue
            if key in _COMPAT_FIELDS or key in self.compat_fields:
                self.extras[key] = value
            elif key in self.inert:
                note(f"{name}({key}=...) has no effect here: {self.inert[key]}")
            elif key in self.renames:
                target = self.renames[key]
                if isinstance(target, tuple):
                    mapped[target[0]] = target[1](value)
                else:
                    mapped[target] = value
            elif key in ours:
                mapped[key] = value
            else:
                theirs = sorted({*self.renames, *self.refused, *self.inert, *_COMPAT_FIELDS, *self.compat_fields})
                raise CompatError(f"{name}: unknown field {key!r}; EmbodiedAgents' fields mapped here: "
                                  f"{', '.join(theirs)}; embagents' own: {', '.join(ours)}")
        self.native = self.native_class(**mapped)

    def __getattr__(self, key: str) -> Any:
        if key in _COMPAT_FIELDS:
            return self.__dict__.get("extras", {}).get(key, False)
        if key in type(self).compat_fields:
            return self.__dict__.get("extras", {}).get(key, type(self).compat_fields[key])
        return getattr(self.__dict__["native"], key)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.native!r}, extras={self.extras!r})"


_LLM_REFUSED: dict[str, tuple[str, str]] = {}
_LLM_INERT = {
    "distance_func": "the memory's vector index uses cosine distance",
    "break_character": "TextToSpeech splits a stream into sentences itself",
    "response_terminator": "a stream ends with a StreamingString(done=True)",
    "device_local_model": _LOCAL_MODEL,
    "ncpu_local_model": _LOCAL_MODEL,
    "local_model_path": "a local model is the offline default here (LlamaModel(local_model_path=...) natively)",
    "_system_prompt": "use LLM.set_system_prompt",
}
_LLM_RENAMES: dict[str, str | tuple[str, Callable[[Any], Any]]] = {"max_tokens": "max_new_tokens"}


class LLMConfig(_Config):
    """EmbodiedAgents' LLMConfig -> :class:`embagents.components.LLMConfig`."""

    native_class = native.LLMConfig
    renames = _LLM_RENAMES
    refused = _LLM_REFUSED
    inert = _LLM_INERT
    compat_fields = _RAG_FIELDS


class VLMConfig(LLMConfig):
    """EmbodiedAgents' VLMConfig (MLLMConfig) -> :class:`embagents.components.VLMConfig`."""

    native_class = native.VLMConfig


MLLMConfig = VLMConfig


def _ms_from_s(value: Any) -> float:
    return float(value) * 1000.0


class SpeechToTextConfig(_Config):
    """EmbodiedAgents' SpeechToTextConfig -> :class:`embagents.components.SpeechToTextConfig`."""

    native_class = native.SpeechToTextConfig
    renames = {
        "min_silence_duration_ms": "min_silence_ms",
        "min_speech_duration_ms": "min_speech_ms",
        "max_speech_duration_s": ("max_utterance_ms", _ms_from_s),
        "threshold": "vad_threshold",
        "wakeword_threshold": "wake_word_threshold",
        "wakeword_model_path": "wake_word_model",
        "vad_model_path": "vad_model",
    }
    refused = {"stream": ("streaming transcription over a WebSocket",
                          "a StreamingString output of SpeechToText (partial transcripts every partial_interval_ms)")}
    inert = {
        "device_audio": "audio comes on an Audio topic (a Microphone component, or ROS)",
        "sample_rate": "the Audio message carries its rate",
        "speech_buffer_max_len": "max_utterance_ms bounds an utterance",
        "device_vad": _LOCAL_MODEL, "device_wakeword": _LOCAL_MODEL, "ncpu_vad": _LOCAL_MODEL,
        "initial_prompt": "the Whisper here takes no prompt",
        "language": "set SpeechToTextModel(language=...) natively",
        "enable_wakeword": "set wake_phrase= or wakeword_model_path=",
    }


class TextToSpeechConfig(_Config):
    """EmbodiedAgents' TextToSpeechConfig -> :class:`embagents.components.TextToSpeechConfig`.

    ``play_on_device=True`` adds a Speaker component playing the voice's Audio output.
    """

    native_class = native.TextToSpeechConfig
    refused = {"stream_to_ip": ("streaming audio to an IP", "a Speaker component, or RosOutput of the Audio topic"),
               "get_bytes": ("audio as bytes on a ROS topic", "the Audio output topic (samples and rate)")}
    inert = {
        "device": "a Speaker component plays audio (play_on_device=True adds one)",
        "buffer_size": "a Speaker component buffers audio itself",
        "block_size": "a Speaker component buffers audio itself",
        "thread_shutdown_timeout": "playback runs in the Speaker's own process",
        "stream": "a StreamingString input is spoken sentence by sentence",
    }


class VisionConfig(_Config):
    """EmbodiedAgents' VisionConfig -> :class:`embagents.components.VisionConfig`.

    ``enable_local_classifier=True`` with no model client runs the offline default detector.
    """

    native_class = native.VisionConfig
    renames = {"labels_to_track": "track_labels"}
    inert = {
        "input_height": "the detector model resizes frames itself",
        "input_width": "the detector model resizes frames itself",
        "dataset_labels": "class names come from the detector model's file",
        "device_local_classifier": _LOCAL_MODEL,
        "ncpu_local_classifier": _LOCAL_MODEL,
        "get_dataset_labels": "class names come from the detector model's file",
    }


class SemanticRouterConfig(_Config):
    """EmbodiedAgents' SemanticRouterConfig -> :class:`embagents.components.SemanticRouterConfig`."""

    native_class = native.SemanticRouterConfig
    inert = {"collection_name": "the routes live in the router (router_name names them in logs)"}


class MapConfig(_Config):
    """EmbodiedAgents' MapConfig -> :class:`embagents.components.MapConfig` (``MemoryConfig``)."""

    native_class = native.MapConfig
    renames = {"db_path": "db_path"}
    inert = {"distance_func": "the memory's vector index uses cosine distance"}


_EMEM = "eMEM's consolidation (gists, entities, archival) is not done here: every item is kept as it came"


class MemoryConfig(_Config):
    """EmbodiedAgents' MemoryConfig (eMEM) -> :class:`embagents.components.MemoryConfig`."""

    native_class = native.MemoryConfig
    inert = {
        "embedding_checkpoint": "without an embedding_client, embeddings come from all-MiniLM-L6-v2 locally",
        "auto_store": "each layer's message is stored on the step it triggers",
        "working_memory_size": "an item is committed to SQLite on the step that stores it",
        "flush_interval": "an item is committed to SQLite on the step that stores it",
        "flush_batch_size": "an item is committed to SQLite on the step that stores it",
        "consolidation_window": _EMEM,
        "consolidation_spatial_eps": _EMEM,
        "consolidation_min_samples": _EMEM,
        "archive_after_seconds": _EMEM,
        "entity_extract_flush_interval": _EMEM,
        "entity_extract_time_interval": _EMEM,
        "entity_similarity_threshold": _EMEM,
        "entity_spatial_radius": _EMEM,
        "recency_weight": "locate returns the latest close match; query orders by meaning",
    }


class CortexConfig(_Config):
    """EmbodiedAgents' CortexConfig -> :class:`embagents.components.LLMConfig` of the planning LLM:
    ``max_execution_steps`` is its ``max_tool_rounds``; the chat history is kept."""

    native_class = native.LLMConfig
    renames = {**_LLM_RENAMES, "max_execution_steps": "max_tool_rounds"}
    refused = _LLM_REFUSED
    compat_fields = _RAG_FIELDS
    inert = {
        **_LLM_INERT,
        "max_planning_steps": "the model plans and acts in one tool loop of max_execution_steps rounds",
        "confirmation_temperature": "there is no separate confirmation call here",
        "confirmation_max_tokens": "there is no separate confirmation call here",
        "strip_think_tokens": "the answer is published as the model gives it",
    }

    def __init__(self, **fields: Any) -> None:
        super().__init__(**{"chat_history": True, **fields})


class VLAConfig(_Config):
    """EmbodiedAgents' VLAConfig -> :class:`embagents.components.VLAConfig`."""

    native_class = native.VLAConfig
    renames = {
        "observation_sending_rate": "observation_rate_hz",
        "action_sending_rate": "loop_rate_hz",
        "robot_urdf_file": "urdf",
        "input_timeout": "input_timeout_s",
        "robot_joints_limits": "joint_limits",
    }
    inert = {
        "state_input_type": "the state is a JointState topic",
        "action_output_type": "action_type ('position' or 'velocity') says what the JointState output carries",
        "robot_urdf_file_from_ros_param": "give robot_urdf_file",
    }
