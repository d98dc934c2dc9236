"""The memory's vector index: exact while small, an inverted file once large, rebuilt as it grows."""

from __future__ import annotations

import numpy as np

from embagents.components.memory_index import VectorIndex


def unit_rows(rng: np.random.Generator, n: int, dim: int = 32) -> np.ndarray:
    v = rng.standard_normal((n, dim)).astype(np.float32)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_small_is_exact_and_large_uses_lists_that_find_the_same_neighbours() -> None:
    rng = np.random.default_rng(1)
    centers = unit_rows(rng, 20)
    data = centers[rng.integers(0, 20, 3000)] + 0.1 * unit_rows(rng, 3000)
    data /= np.linalg.norm(data, axis=1, keepdims=True)
    idx = VectorIndex(32, exact_below=500)
    idx.add(np.arange(400), data[:400])
    assert idx.centroids is None  # still exact
    for start in range(400, 3000, 100):
        idx.add(np.arange(start, start + 100), data[start:start + 100])
    assert idx.centroids is not None and idx.built_at >= 2000  # rebuilt as the count doubled
    assert sum(g.n for g in idx.lists) == len(idx) == 3000  # every vector is in exactly one list
    hits = 0
    for q in data[rng.integers(0, 3000, 50)]:
        exact = set(np.argsort(1.0 - data @ q)[:5].tolist())
        ids, dist = idx.search(q, 5)
        assert list(dist) == sorted(dist) and dist[0] < 1e-5  # the query itself, nearest first
        hits += len(exact & set(ids.tolist()))
    assert hits / 250 > 0.9


def test_an_empty_index_finds_nothing() -> None:
    ids, dist = VectorIndex(4).search(np.ones(4, np.float32) / 2, 3)
    assert ids.size == 0 and dist.size == 0


def test_within_finds_every_vector_as_close_as_asked_exact_or_through_lists() -> None:
    rng = np.random.default_rng(2)
    data = unit_rows(rng, 1000)
    q = data[7]
    want = set(np.flatnonzero(1.0 - data @ q <= 0.8).tolist())
    for exact_below in (5000, 100):  # exact, then the probed lists (approximate: a subset, with q's own group)
        idx = VectorIndex(32, exact_below=exact_below)
        idx.add(np.arange(1000), data)
        got = set(idx.within(q, 0.8).tolist())
        assert 7 in got and got <= want and (idx.centroids is not None or got == want)
