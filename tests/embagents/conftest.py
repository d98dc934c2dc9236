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
def tiny_vlm(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, str]:
    """(language model, projector) of a tiny random LLaVA-style VLM in one folder (tests/embagents/tiny_vlm.py)."""
    from tests.embagents.tiny_llama import make_tiny_llama_gguf
    from tests.embagents.tiny_vlm import make_tiny_mmproj_gguf

    folder = tmp_path_factory.mktemp("vlm")
    return (make_tiny_llama_gguf(str(folder / "tiny-llava-text.gguf")),
            make_tiny_mmproj_gguf(str(folder / "tiny-llava-mmproj.gguf")))
