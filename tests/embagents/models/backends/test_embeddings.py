"""all-MiniLM-L6-v2 rebuilt from its safetensors as an ONNX graph: the real model, run by onnxruntime."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
pytest.importorskip("tokenizers")

from actors import ActorSystem  # noqa: E402
from embagents.models import BadRequest, EmbeddingModel, LocalModelClient  # noqa: E402
from embagents.models.actor import ModelActor  # noqa: E402
from embagents.models.backends.embeddings import SentenceEncoder  # noqa: E402


@pytest.fixture(scope="module")
def encoder(minilm_dir: str) -> SentenceEncoder:
    return SentenceEncoder(minilm_dir)


def test_embeddings_are_384_dimensional_unit_vectors(encoder: SentenceEncoder) -> None:
    v = encoder.embed(["a cup on the kitchen table", "the robot drives to the door", ""])
    assert v.shape == (3, 384) and v.dtype == np.float32
    assert np.allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-5)


def test_similar_sentences_are_closer_than_unrelated_ones(encoder: SentenceEncoder) -> None:
    a, b, c = encoder.embed(["A man is eating food.", "A man is eating a piece of bread.", "The girl is carrying a baby."])
    # sentence-transformers' own documentation gives 0.7553 for the first pair with this model.
    assert abs(float(a @ b) - 0.7553) < 0.01
    assert float(a @ b) > 0.5 > float(a @ c)


def test_a_batch_gives_the_same_vectors_as_one_by_one_despite_padding(encoder: SentenceEncoder) -> None:
    texts = ["cup", "a much longer sentence about a red cup on the kitchen table near the window"]
    together = encoder.embed(texts)
    alone = np.concatenate([encoder.embed([t]) for t in texts])
    assert np.allclose(together, alone, atol=1e-5)


def test_the_prepared_graph_is_cached_and_says_its_dimension(minilm_dir: str) -> None:
    import onnx

    path = os.path.join(minilm_dir, "model.onnx")
    meta = {p.key: p.value for p in onnx.load(path, load_external_data=False).metadata_props}
    assert meta["embedding_dim"] == "384"
    model = EmbeddingModel(name="minilm")
    assert model.resolve() == minilm_dir  # prepared once: the cache answers


def test_a_folder_without_the_model_files_is_a_clear_problem(tmp_path: Any) -> None:
    problem = EmbeddingModel(name="e", local_model_path=str(tmp_path)).file_problem()
    assert problem and "model.onnx" in problem and "tokenizer.json" in problem and "local_model_path=None" in problem


@pytest.fixture(scope="module")
def served(minilm_dir: str) -> Iterator[ActorSystem]:
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "minilm", "embedding", minilm_dir, {}, True, {"max_batch": 32, "batch_wait_ms": 5},
                   wait=60)
        yield asys


def test_the_model_actor_embeds_like_the_backend(served: ActorSystem, encoder: SentenceEncoder) -> None:
    client = LocalModelClient("minilm", timeout=30)
    got = client.embed(["where is the cup", "hello"])
    assert got.shape == (2, 384) and np.allclose(got, encoder.embed(["where is the cup", "hello"]), atol=1e-5)


def test_concurrent_components_are_batched_in_one_call(served: ActorSystem) -> None:
    results: list[int] = []

    def worker(i: int) -> None:
        c = LocalModelClient("minilm", timeout=30)
        for k in range(15):
            results.append(c.embed([f"sentence {i} {k}"]).shape[0])

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    stats = served.ref("minilm").ask("stats", timeout=5).get()
    assert results == [1] * 60
    assert stats["max_batch_seen"] > 1  # requests of several clients ran as one onnxruntime call


def test_a_bad_embed_request_is_refused_at_once_naming_the_shape(served: ActorSystem) -> None:
    client = LocalModelClient("minilm", timeout=30)
    with pytest.raises(BadRequest, match=r"embed needs inputs \{'texts': \[str, \.\.\.\]\}"):
        client.infer("embed", {"texts": "not a list"})
    assert client.embed(["still serving"]).shape == (1, 384)
