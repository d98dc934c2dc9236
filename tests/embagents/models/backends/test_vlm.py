"""The llama.cpp VLM backend on a real (generated, tiny) LLaVA-style model: language model + mmproj."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

pytest.importorskip("llama_cpp")

from embagents.models.backends.vlm import VLMBackend, handler_class  # noqa: E402

pytestmark = pytest.mark.llama_in_process  # see tests/conftest.py

ASK = [{"role": "user", "content": "What is on the table?"}]


@pytest.fixture(scope="module")
def vlm(tiny_vlm: tuple[str, str]) -> Iterator[VLMBackend]:
    backend = VLMBackend(tiny_vlm[0], projector=tiny_vlm[1], chat_handler="llava15", n_ctx=512)
    backend.load()
    yield backend
    backend.close()


def frame(seed: int = 0, shape: tuple[int, ...] = (48, 64, 3)) -> np.ndarray:
    return (np.random.default_rng(seed).random(shape) * 255).astype(np.uint8)


def test_each_image_is_encoded_by_the_projector_into_prompt_tokens(vlm: VLMBackend) -> None:
    # The tiny projector turns a 28x28 image into 2x2 patches: 4 embeddings in the prompt per image.
    one = vlm.chat(ASK, images=[frame(1)], max_tokens=4)
    two = vlm.chat(ASK, images=[frame(1), frame(2, (300, 200, 3))], max_tokens=4)
    assert two["usage"]["prompt_tokens"] - one["usage"]["prompt_tokens"] == 4
    assert one["finish_reason"] == "length" and one["content"]


def test_the_answer_streams_token_by_token(vlm: VLMBackend) -> None:
    chunks = list(vlm.chat_stream(ASK, images=[frame()], max_tokens=6))
    assert [set(c) for c in chunks[:-1]] == [{"delta"}] * (len(chunks) - 1) and len(chunks) > 2
    assert chunks[-1]["done"] is True and chunks[-1]["usage"]["completion_tokens"] == 6


def test_an_image_of_the_wrong_shape_names_what_it_got(vlm: VLMBackend) -> None:
    with pytest.raises(ValueError, match=r"images\[0\] must be an \(H, W, 3\) uint8 RGB array, got shape \(48, 64\)"):
        vlm.chat(ASK, images=[frame()[:, :, 0]], max_tokens=2)
    assert vlm.chat(ASK, images=[frame()], max_tokens=2)["content"]  # still serving


def test_no_url_is_fetched_only_the_request_frames(vlm: VLMBackend) -> None:
    asked = [{"role": "user", "content": [{"type": "image_url", "image_url": {"url": "http://127.0.0.1:9/x.png"}},
                                          {"type": "text", "text": "what?"}]}]
    with pytest.raises(ValueError, match="a model actor fetches no URLs: send the pixels"):
        vlm.chat(asked, max_tokens=2)


def test_a_handler_the_installed_version_lacks_is_named_with_those_it_offers() -> None:
    with pytest.raises(ValueError, match=r"not offered by the installed llama-cpp-python; it offers .*llava15"):
        handler_class("nosuch")
    assert handler_class("moondream").__name__ == "FramesMoondreamChatHandler"
