"""A VLM model actor in its own process (the tiny LLaVA-style model), and what `embagents check` says of VLMs."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("llama_cpp")

import embagents.msgs  # noqa: E402,F401 - registers the message types
from actors import ActorSystem  # noqa: E402
from embagents.models import BadRequest, LocalModelClient, VLMModel  # noqa: E402
from embagents.models.actor import ModelActor  # noqa: E402

ASK = [{"role": "user", "content": "What do you see?"}]


@pytest.fixture(scope="module")
def served(tiny_vlm: tuple[str, str], tiny_gguf: str) -> Iterator[tuple[ActorSystem, LocalModelClient]]:
    model = VLMModel(name="eyes", local_model_path=tiny_vlm[0], chat_handler="llava15", n_ctx=512)
    assert model.specs() == tiny_vlm  # the projector is found next to the language model
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "eyes", "vlm", model.resolve(), model.options(), True, wait=60)
        asys.spawn(ModelActor, "talk", "llama", tiny_gguf, {"n_ctx": 512}, False, wait=60)
        yield asys, LocalModelClient("eyes", timeout=60)


def test_a_camera_frame_goes_through_shared_memory_and_the_answer_streams_back(served: Any) -> None:
    _, client = served
    vga = np.full((480, 640, 3), 128, np.uint8)  # 900 KB: over the shared-memory threshold
    chunks = list(client.chat_stream(ASK, images=[vga], max_tokens=5))
    assert chunks[-1]["done"] and chunks[-1]["usage"]["completion_tokens"] == 5
    with_two = client.chat(ASK, images=[vga, vga], max_tokens=1)
    assert with_two["usage"]["prompt_tokens"] - chunks[-1]["usage"]["prompt_tokens"] == 4  # one more image


def test_a_bad_image_is_refused_at_once_and_the_actor_keeps_serving(served: Any) -> None:
    _, client = served
    with pytest.raises(BadRequest, match=r"images\[0\] must be an \(H, W, 3\) uint8 RGB array, got shape \(48, 64\)"):
        client.chat(ASK, images=[np.zeros((48, 64), np.uint8)], max_tokens=2)
    with pytest.raises(BadRequest, match=r"images\[1\] must be an \(H, W, 3\) uint8 RGB array.*float32"):
        client.chat(ASK, images=[np.zeros((8, 8, 3), np.uint8), np.zeros((8, 8, 3), np.float32)], max_tokens=2)
    assert client.chat(ASK, images=[np.zeros((8, 8, 3), np.uint8)], max_tokens=2)["content"]


def test_a_text_only_chat_model_refuses_images_naming_the_fix(served: Any) -> None:
    with pytest.raises(BadRequest, match="takes no images; serve a vision-language model"):
        LocalModelClient("talk", timeout=30).chat(ASK, images=[np.zeros((8, 8, 3), np.uint8)], max_tokens=2)


def test_offline_with_no_model_check_names_both_files_and_how_to_get_them(tmp_path: Path) -> None:
    (tmp_path / "system.py").write_text(textwrap.dedent("""
        from embagents.components import VLM
        from embagents.models import LocalModelClient, VLMModel
        from embagents.msgs import Image, String
        from embagents.system import System
        from embagents.topic import Topic
        question, camera, answer = Topic("question", String), Topic("camera", Image), Topic("answer", String)
        vlm = VLM(name="vlm", inputs=[question, camera], outputs=[answer],
                  model_client=LocalModelClient(VLMModel(name="eyes")))
        system = System([vlm], external=[question, camera])
    """))
    proc = subprocess.run([sys.executable, "-m", "embagents.cli", "check", str(tmp_path / "system.py")],
                          capture_output=True, text=True, timeout=60,
                          env={**os.environ, "HF_HUB_OFFLINE": "1"})
    assert proc.returncode == 1, proc.stdout + proc.stderr
    out = proc.stdout
    assert "[model-file] model 'eyes': a vision-language model needs two GGUF files" in out
    assert "'vikhyatk/moondream2:*text-model*.gguf'" in out and "'vikhyatk/moondream2:*mmproj*.gguf'" in out
    assert "huggingface-cli download vikhyatk/moondream2" in out and "HF_HUB_OFFLINE is set" in out


def test_a_local_model_without_a_projector_beside_it_names_the_missing_file(tmp_path: Path) -> None:
    llm = tmp_path / "llava.gguf"
    llm.write_bytes(b"GGUF")
    problem = VLMModel(name="eyes", local_model_path=str(llm)).file_problem()
    assert problem is not None and f"no *mmproj*.gguf next to {str(llm)!r}" in problem
    assert VLMModel(name="eyes", local_model_path=str(llm), projector_path=str(llm)).file_problem() is None
