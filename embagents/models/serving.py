"""What a model actor serves: a backend behind the inference protocol's tasks.

A :class:`Serving` checks a request (a bad one is answered at once, naming
what is wrong) and runs it: one answer, a stream of chunks, or (``batchable``)
a batch of requests of several clients in one backend call.

Example::

    >>> serving_kinds()
    ['detector', 'embedding', 'llama', 'policy', 'stt', 'tts', 'turn', 'vlm']
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any, Protocol

import numpy as np

from embagents.models.backends.detectors import make_detector
from embagents.models.backends.embeddings import SentenceEncoder
from embagents.models.backends.llama import LlamaBackend
from embagents.models.backends.vlm import VLMBackend
from embagents.models.chat import CHAT_OPTIONS, check_messages
from embagents.models.openpi_server import OpenPIPolicyServing
from embagents.models.policy import PolicyServing
from embagents.models.protocol import BadRequest
from embagents.models.speech_serving import SpeechToTextServing, TextToSpeechServing, TurnServing

__all__ = ["ChatServing", "DetectorServing", "EmbeddingServing", "Serving", "VLMServing", "check_image", "make_serving",
           "serving_kinds"]


class Serving(Protocol):
    """A backend as a model actor serves it."""

    batchable: bool

    def load(self) -> None: ...
    def warmup(self) -> None: ...
    def check(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> None: ...
    def run(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> Iterator[dict[str, Any]]: ...
    def run_batch(self, task: str, batch: list[dict[str, Any]], options: dict[str, Any]) -> list[dict[str, Any]]: ...
    def close(self) -> None: ...


def _check_task(task: str, tasks: tuple[str, ...], what: str) -> None:
    if task not in tasks:
        raise BadRequest(f"{what} serves task {' or '.join(map(repr, tasks))}, not {task!r}")


def _check_options(options: dict[str, Any], allowed: tuple[str, ...]) -> None:
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise BadRequest(f"unknown option(s) {', '.join(unknown)}; this model takes {', '.join(allowed) or 'none'}")


class ChatServing:
    """llama.cpp behind the ``chat`` task (streamed chunks of :mod:`embagents.models.chat`), and the
    ``end_of_turn`` task on a transcript (``{"text": str}`` -> ``{"probability": float}``: the text
    end-of-turn check, :meth:`~embagents.models.backends.llama.LlamaBackend.end_of_turn_probability`)."""

    batchable = False

    def __init__(self, path: str, options: dict[str, Any]) -> None:
        self.backend = LlamaBackend(path, **options)

    def load(self) -> None:
        self.backend.load()

    def warmup(self) -> None:
        self.backend.warmup()

    def check(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> None:
        _check_task(task, ("chat", "end_of_turn"), "a chat model")
        if task == "end_of_turn":
            if not isinstance(inputs.get("text"), str) or set(inputs) != {"text"}:
                raise BadRequest(f"end_of_turn on a chat model reads a transcript: inputs {{'text': str}}, got "
                                 f"{sorted(inputs)} (audio goes to a TurnDetectorModel)")
            _check_options(options, ())
            return
        if inputs.get("images"):
            raise BadRequest("this chat model takes no images; serve a vision-language model (VLMModel) for them")
        try:
            check_messages(inputs.get("messages"))  # type: ignore[arg-type]
        except ValueError as exc:
            raise BadRequest(str(exc)) from None
        _check_options(options, CHAT_OPTIONS)
        max_tokens = options.get("max_tokens", 1)
        if not isinstance(max_tokens, int) or max_tokens < 1:
            raise BadRequest(f"max_tokens must be an integer >= 1, got {max_tokens!r}")

    def run(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> Iterator[dict[str, Any]]:
        if task == "end_of_turn":
            return iter([{"probability": self.backend.end_of_turn_probability(inputs["text"]), "done": True}])
        return self.backend.chat_stream(inputs["messages"], **options)

    def run_batch(self, task: str, batch: list[dict[str, Any]], options: dict[str, Any]) -> list[dict[str, Any]]:
        raise NotImplementedError("llama.cpp serves one chat at a time")

    def close(self) -> None:
        self.backend.close()


def check_image(image: object, what: str = "image") -> np.ndarray:
    """``image`` as an (H, W, 3) uint8 array, or :class:`BadRequest` naming what it is instead.

    >>> check_image(np.zeros((4, 4), np.uint8))
    Traceback (most recent call last):
    ...
    embagents.models.protocol.BadRequest: image must be an (H, W, 3) uint8 RGB array, got shape (4, 4) dtype uint8; convert it (e.g. cv2.cvtColor(img, cv2.COLOR_GRAY2RGB))
    """
    if not isinstance(image, np.ndarray):
        raise BadRequest(f"{what} must be a numpy array, got {type(image).__name__}")
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8 or min(image.shape[:2]) < 1:
        raise BadRequest(f"{what} must be an (H, W, 3) uint8 RGB array, got shape {image.shape} dtype {image.dtype}; "
                         "convert it (e.g. cv2.cvtColor(img, cv2.COLOR_GRAY2RGB))")
    return image


_DETECT_OPTIONS = ("threshold",)


class DetectorServing:
    """An ONNX detector behind the ``detect`` task; concurrent requests run as one batch."""

    batchable = True

    def __init__(self, path: str, options: dict[str, Any]) -> None:
        self.detector = make_detector(path, **options)

    def load(self) -> None:
        pass  # the detector loads its sessions when it is made

    def warmup(self) -> None:
        self.detector.detect_batch([np.zeros((64, 64, 3), np.uint8)])

    def check(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> None:
        _check_task(task, ("detect",), "a detector")
        check_image(inputs.get("image"))
        _check_options(options, _DETECT_OPTIONS)

    def run(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> Iterator[dict[str, Any]]:
        yield self.run_batch(task, [inputs], options)[0]

    def run_batch(self, task: str, batch: list[dict[str, Any]], options: dict[str, Any]) -> list[dict[str, Any]]:
        return self.detector.detect_batch([b["image"] for b in batch], **options)

    def close(self) -> None:
        pass


class VLMServing(ChatServing):
    """A llama.cpp vision-language model behind the ``chat`` task: ``inputs["images"]`` ride shared memory."""

    def __init__(self, path: str, options: dict[str, Any]) -> None:
        self.backend = VLMBackend(path, **options)  # type: ignore[assignment]

    def check(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> None:
        _check_task(task, ("chat",), "a vision-language model")
        images = inputs.get("images", [])
        if not isinstance(images, list):
            raise BadRequest(f"images must be a list of (H, W, 3) uint8 arrays, got {type(images).__name__}")
        for i, image in enumerate(images):
            check_image(image, f"images[{i}]")
        super().check(task, {k: v for k, v in inputs.items() if k != "images"}, options)

    def run(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> Iterator[dict[str, Any]]:
        return self.backend.chat_stream(inputs["messages"], images=inputs.get("images", []), **options)  # type: ignore[call-arg]


def _stt(path: str, options: dict[str, Any]) -> Any:
    return SpeechToTextServing(path, options)


def _tts(path: str, options: dict[str, Any]) -> Any:
    return TextToSpeechServing(path, options)


def _turn(path: str, options: dict[str, Any]) -> Any:
    return TurnServing(path, options)


def _policy(path: str, options: dict[str, Any]) -> Any:
    if options.get("openpi"):  # also served over openpi's WebSocket protocol (embagents serve-policy)

        return OpenPIPolicyServing(path, options)

    return PolicyServing(path, options)


_EMBED_OPTIONS = ()


class EmbeddingServing:
    """A sentence encoder behind the ``embed`` task (``{"texts": [str]}`` -> ``{"vectors": (N, dim)}``);
    requests of several components run as one onnxruntime call."""

    batchable = True

    def __init__(self, path: str, options: dict[str, Any]) -> None:
        self.encoder = SentenceEncoder(path, **options)

    def load(self) -> None:
        pass  # the session loads when the encoder is made

    def warmup(self) -> None:
        self.encoder.embed(["warm up"])

    def check(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> None:
        _check_task(task, ("embed",), "an embedding model")
        texts = inputs.get("texts")
        if not isinstance(texts, list) or not all(isinstance(t, str) for t in texts):
            raise BadRequest(f"embed needs inputs {{'texts': [str, ...]}}, got {type(texts).__name__}: {texts!r:.80}")
        _check_options(options, _EMBED_OPTIONS)

    def run(self, task: str, inputs: dict[str, Any], options: dict[str, Any]) -> Iterator[dict[str, Any]]:
        yield self.run_batch(task, [inputs], options)[0]

    def run_batch(self, task: str, batch: list[dict[str, Any]], options: dict[str, Any]) -> list[dict[str, Any]]:
        texts = [t for b in batch for t in b["texts"]]
        vectors = self.encoder.embed(texts)
        out, start = [], 0
        for b in batch:
            n = len(b["texts"])
            out.append({"vectors": vectors[start:start + n], "dim": self.encoder.dim})
            start += n
        return out

    def close(self) -> None:
        pass


_KINDS: dict[str, Callable[[str, dict[str, Any]], Any]] = {
    "llama": ChatServing, "detector": DetectorServing, "embedding": EmbeddingServing, "policy": _policy, "stt": _stt,
    "tts": _tts, "vlm": VLMServing, "turn": _turn,
}


def serving_kinds() -> list[str]:
    return sorted(_KINDS)


def make_serving(kind: str, path: str, options: dict[str, Any]) -> Serving:
    """The serving of a model declaration's ``kind`` for the file at ``path``."""
    try:
        factory = _KINDS[kind]
    except KeyError:
        raise ValueError(f"no backend serves model kind {kind!r}; known: {', '.join(serving_kinds())}") from None
    return factory(path, options)
