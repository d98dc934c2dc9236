"""OpenAIEmbeddingClient against llama-cpp-python's own OpenAI-compatible server (a real subprocess, --embedding)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from embagents.models.clients import OpenAIEmbeddingClient
from tests.embagents.models.clients.test_openai_http import SKIP_REASON, _missing
from tests.helpers import free_port, wait_until


@pytest.fixture(scope="module")
def server(tiny_gguf: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    if _missing:
        pytest.skip(SKIP_REASON)
    port = free_port()
    log_path: Path = tmp_path_factory.mktemp("embed_server") / "server.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen([sys.executable, "-m", "llama_cpp.server", "--model", tiny_gguf, "--host", "127.0.0.1",
                                 "--port", str(port), "--n_ctx", "512", "--embedding", "true"],
                                stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"

    def answering() -> bool:
        if proc.poll() is not None:
            pytest.fail(f"llama_cpp.server exited:\n{log_path.read_text()[-3000:]}")
        try:
            OpenAIEmbeddingClient(url, timeout=5).embed(["ping"])
        except ConnectionError:
            return False
        return True

    try:
        wait_until(answering, 60.0, "llama_cpp.server answering", interval=0.1)
        yield url
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_texts_become_unit_vectors_one_row_each(server: str) -> None:
    client = OpenAIEmbeddingClient(server)
    v = client.embed(["hello world", "a red cup", "the kitchen"])
    assert v.shape == (3, 64) and v.dtype == np.float32  # the tiny model's n_embd
    assert np.allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-5)
    assert np.allclose(client.embed(["a red cup"]), client.embed(["a red cup"]))  # the same text, the same vector
    assert not np.allclose(v[0], v[1])


def test_a_server_that_is_not_there_is_a_clear_connection_error() -> None:
    with pytest.raises(ConnectionError, match="connection refused. Is the server running"):
        OpenAIEmbeddingClient(f"http://127.0.0.1:{free_port()}", timeout=5).embed(["hi"])


def test_non_text_input_is_refused_before_sending() -> None:
    with pytest.raises(ValueError, match="embed needs a list of strings"):
        OpenAIEmbeddingClient("http://127.0.0.1:1").embed([1])  # type: ignore[list-item]
