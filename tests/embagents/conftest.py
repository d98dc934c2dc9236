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


#: The Panda's ready pose and a reachable target, joints 1..7 (rad).
PANDA_TARGET = [0.3, -0.3, 0.2, -2.0, 0.1, 1.8, 0.9]


@pytest.fixture(scope="session")
def reach_policy(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A real ONNX policy for the Panda's 7 joints: a P controller toward PANDA_TARGET, 10 actions per chunk."""
    pytest.importorskip("onnx")
    from embagents.models.backends.reach_policy import write_reach_policy

    return write_reach_policy(str(tmp_path_factory.mktemp("models") / "reach.onnx"), PANDA_TARGET, gain=0.2, chunk=10)
