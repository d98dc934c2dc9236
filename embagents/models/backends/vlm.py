"""Vision-language models on llama.cpp: llama-cpp-python's multimodal chat handlers, frames from arrays.

A VLM is two GGUF files: the language model and its vision projector
(``mmproj``), joined by one of llama-cpp-python's chat handlers (LLaVA-1.5,
Moondream, Qwen2.5-VL...: :data:`~embagents.models.vlm_handlers.VLM_HANDLERS`,
whichever the installed version offers). Images arrive as (H, W, 3) uint8
arrays (in a model actor: views of the client's shared memory); each is copied
once into a binary PPM that llama.cpp decodes itself, so no image is encoded
to PNG or base64 and no URL is ever fetched: a handler here loads only the
frames of the request (and ``data:`` URLs).

Answers are the chat chunks of :mod:`embagents.models.chat`.

Example::

    >>> vlm = VLMBackend("moondream2-text-model-f16.gguf", projector="moondream2-mmproj-f16.gguf",
    ...                  chat_handler="moondream")                                    # doctest: +SKIP
    >>> vlm.chat([{"role": "user", "content": "What is on the table?"}], images=[frame])["content"]  # doctest: +SKIP
    'A red cup.'
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from embagents.models.backends.llama import LlamaBackend
from embagents.models.chat import collect_stream, with_images
from embagents.models.files.hub import resolve_model_path
from embagents.models.vlm_handlers import VLM_HANDLERS

__all__ = ["VLMBackend", "handler_class", "ppm_bytes"]

_FRAME_URL = "embagents://frame/{}/{}/"  # request, index: no key is a prefix of another
_requests = itertools.count(1)


def ppm_bytes(image: np.ndarray) -> bytes:
    """A binary PPM (P6) of an (H, W, 3) uint8 RGB image: what llama.cpp's image loader reads without a codec.

    >>> ppm_bytes(np.zeros((1, 2, 3), np.uint8))[:11]
    b'P6\\n2 1\\n255\\n'
    """
    h, w = image.shape[:2]
    return b"P6\n%d %d\n255\n" % (w, h) + np.ascontiguousarray(image, np.uint8).tobytes()


def handler_class(name: str) -> type:
    """llama-cpp-python's chat handler ``name`` (a key of VLM_HANDLERS), made to load request frames.

    Raises ``ValueError`` naming the handlers the installed version offers.
    """
    from llama_cpp import llama_chat_format

    offered = [k for k, cls in VLM_HANDLERS.items() if hasattr(llama_chat_format, cls)]
    base = getattr(llama_chat_format, VLM_HANDLERS.get(name, ""), None)
    if base is None:
        raise ValueError(f"chat_handler {name!r} is not offered by the installed llama-cpp-python; "
                         f"it offers {', '.join(offered) or 'none'} (upgrade it for more)")
    return type(f"Frames{base.__name__}", (_FramesMixin, base), {})


class _FramesMixin:
    """Loads the request's frames (by their ``embagents://frame/...`` URL) and ``data:`` URLs, never the network."""

    frames: dict[str, bytes] = {}

    def load_image(self, image_url: str) -> bytes:
        if image_url in self.frames:
            return self.frames[image_url]
        if image_url.startswith("data:"):
            return super().load_image(image_url)  # type: ignore[misc]
        raise ValueError(f"image {image_url[:80]!r} is neither a frame of this request nor a data: URL; "
                         "a model actor fetches no URLs: send the pixels (images=[array])")


def _check_image(image: object, i: int) -> np.ndarray:
    if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8 \
            or min(image.shape[:2]) < 1:
        got = f"shape {image.shape} dtype {image.dtype}" if isinstance(image, np.ndarray) else type(image).__name__
        raise ValueError(f"images[{i}] must be an (H, W, 3) uint8 RGB array, got {got}")
    return image


def _quiet_mtmd() -> None:
    """Route llama.cpp's multimodal logs through llama-cpp-python's logger (quiet unless verbose).

    mtmd logs each image it encodes straight to stderr by default: a dozen lines per request.
    """
    from llama_cpp import _logger, mtmd_cpp

    for setter in ("mtmd_log_set", "mtmd_helper_log_set"):
        if hasattr(mtmd_cpp, setter):
            getattr(mtmd_cpp, setter)(_logger.llama_log_callback, None)


class VLMBackend:
    """A llama.cpp VLM in this process: ``chat_stream(messages, images=[...])`` (see the module docstring).

    ``projector``: the mmproj GGUF (a path, or a spec :func:`embagents.models.files.hub.resolve_model_path`
    takes); ``chat_handler``: a key of VLM_HANDLERS. Other arguments are :class:`LlamaBackend`'s.
    """

    def __init__(self, model_path: str, *, projector: str, chat_handler: str = "llava15", n_ctx: int = 2048,
                 n_threads: int | None = None, seed: int = 0, verbose: bool = False) -> None:
        self.model_path, self.projector, self.handler_name = model_path, projector, chat_handler
        self.llm_options: dict[str, Any] = {"n_ctx": n_ctx, "n_threads": n_threads, "seed": seed, "verbose": verbose}
        self.handler: Any = None
        self.llm: LlamaBackend | None = None

    def load(self) -> None:
        """Load both files (idempotent)."""
        if self.llm is not None:
            return

        try:
            cls = handler_class(self.handler_name)
        except ImportError as exc:
            raise ModuleNotFoundError("VLMBackend needs llama-cpp-python: pip install 'embagents[llm]'") from exc
        projector = resolve_model_path(self.projector, filename_glob="*mmproj*.gguf")
        _quiet_mtmd()
        try:
            handler = cls(clip_model_path=projector, verbose=bool(self.llm_options["verbose"]))
        except ValueError as exc:
            raise ValueError(f"llama.cpp cannot use projector {projector!r}: {exc}") from exc
        llm = LlamaBackend(self.model_path, chat_handler=handler, **self.llm_options)
        llm.load()
        self.handler, self.llm = handler, llm

    def warmup(self) -> None:
        """One tiny generation with a tiny image: the projector's first-call costs paid up front."""
        self.chat([{"role": "user", "content": "Hi"}], images=[np.zeros((8, 8, 3), np.uint8)], max_tokens=1)

    def chat_stream(self, messages: list[dict[str, Any]], *, images: Sequence[np.ndarray] = (),
                    **options: Any) -> Iterator[dict[str, Any]]:
        """Chat chunks about ``images`` (placed before the text of the last user message).

        Each image is copied here, before the first chunk: a caller's buffer
        (shared memory) may go as soon as this returns.
        """
        self.load()
        assert self.llm is not None
        rid = next(_requests)
        frames = {_FRAME_URL.format(rid, i): ppm_bytes(_check_image(img, i)) for i, img in enumerate(images)}
        stream = self.llm.chat_stream(with_images(messages, list(frames)), **options)
        return self._with_frames(frames, stream)

    def _with_frames(self, frames: dict[str, bytes], stream: Iterator[dict[str, Any]]) -> Iterator[dict[str, Any]]:
        self.handler.frames = frames
        try:
            yield from stream
        finally:
            self.handler.frames = {}

    def chat(self, messages: list[dict[str, Any]], *, images: Sequence[np.ndarray] = (), **options: Any) -> dict:
        """The whole reply (``{"content", "tool_calls", "finish_reason", "usage", "timing"}``)."""
        return collect_stream(self.chat_stream(messages, images=images, **options))

    def close(self) -> None:
        """Free both models (idempotent)."""
        llm, self.llm, self.handler = self.llm, None, None
        if llm is not None:
            llm.close()
