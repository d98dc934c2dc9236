"""The model actor as the supervision tree starts it (see :mod:`embagents.models.actor`).

``LlamaModelActor(path, options, warmup)`` is the llama.cpp form, kept for
callers that start one by hand (tests, ``embagents bench``).
"""

from __future__ import annotations

from typing import Any

from embagents.models.actor import ModelActor

__all__ = ["LlamaModelActor", "ModelActor"]


class LlamaModelActor(ModelActor):
    """A model actor serving a GGUF file with llama.cpp (the ``chat`` task)."""

    def __init__(self, model_path: str, options: dict[str, Any] | None = None, warmup: bool = True) -> None:
        super().__init__("llama", model_path, options, warmup)
