"""The memory's vector index in RAM: exact search while small, an inverted file (IVF) when large.

Below ``exact_below`` vectors a query is one matrix-vector product over all
of them (exact). From there on, the vectors are also grouped by their
nearest of ``nlist = 2 sqrt(N)`` centroids (spherical k-means on a sample,
rebuilt each time the count doubles); a query scores the centroids and
scans only the ``nprobe`` nearest groups, so its cost grows like sqrt(N)
instead of N. What this costs in recall is measured by the bench
(``memory_scale``'s ``recall_at_10``); ``nprobe`` trades it back for time.

Example::

    >>> idx = VectorIndex(2)
    >>> idx.add(np.array([7, 8]), np.array([[1, 0], [0, 1]], np.float32))
    >>> idx.search(np.array([1, 0], np.float32), 1)
    (array([7]), array([0.], dtype=float32))
"""

from __future__ import annotations

import numpy as np

__all__ = ["VectorIndex"]


class _Grow:
    """An (n, dim) float32 array (and ids) that grows by doubling."""

    def __init__(self, dim: int) -> None:
        self.ids = np.zeros(0, np.int64)
        self.mat = np.zeros((0, dim), np.float32)
        self.n = 0

    def add(self, ids: np.ndarray, vecs: np.ndarray) -> None:
        need = self.n + len(ids)
        if need > len(self.ids):
            cap = max(need, 2 * len(self.ids), 16)
            mat = np.zeros((cap, self.mat.shape[1]), np.float32)
            mat[: self.n] = self.mat[: self.n]
            idv = np.zeros(cap, np.int64)
            idv[: self.n] = self.ids[: self.n]
            self.mat, self.ids = mat, idv
        self.mat[self.n:need] = vecs
        self.ids[self.n:need] = ids
        self.n = need


class VectorIndex:
    """Top-k cosine search over unit vectors (see the module docstring)."""

    def __init__(self, dim: int, *, exact_below: int = 4096, nprobe: int = 12, seed: int = 0) -> None:
        self.dim, self.exact_below, self.nprobe = dim, exact_below, nprobe
        self.all = _Grow(dim)
        self.centroids: np.ndarray | None = None
        self.lists: list[_Grow] = []
        self.built_at = 0
        self.rng = np.random.default_rng(seed)

    def __len__(self) -> int:
        return self.all.n

    def add(self, ids: np.ndarray, vecs: np.ndarray) -> None:
        """Add unit vectors ``vecs`` (one row per id)."""
        ids, vecs = np.asarray(ids, np.int64), np.asarray(vecs, np.float32).reshape(len(ids), self.dim)
        self.all.add(ids, vecs)
        if self.all.n >= self.exact_below and self.all.n >= 2 * self.built_at:
            self._build()
        elif self.centroids is not None:
            self._assign(ids, vecs)

    def _build(self) -> None:
        n = self.all.n
        nlist = int(np.clip(2 * np.sqrt(n), 16, 2048))  # measured: 2 sqrt(N) lists beat sqrt(N) in recall and time
        sample = self.all.mat[self.rng.choice(n, min(n, 40 * nlist), replace=False)]
        cent = sample[self.rng.choice(len(sample), nlist, replace=False)].copy()
        for _ in range(4):  # spherical k-means: a few rounds are enough for a coarse quantiser
            near = np.argmax(sample @ cent.T, axis=1)
            for c in range(nlist):
                members = sample[near == c]
                if len(members):
                    v = members.sum(0)
                    cent[c] = v / max(float(np.linalg.norm(v)), 1e-12)
        self.centroids = cent
        self.lists = [_Grow(self.dim) for _ in range(nlist)]
        self._assign(self.all.ids[:n], self.all.mat[:n])
        self.built_at = n

    def _assign(self, ids: np.ndarray, vecs: np.ndarray) -> None:
        assert self.centroids is not None
        for start in range(0, len(ids), 8192):  # bounded temporaries
            part = slice(start, start + 8192)
            near = np.argmax(vecs[part] @ self.centroids.T, axis=1)
            for c in np.unique(near):
                sel = near == c
                self.lists[int(c)].add(ids[part][sel], vecs[part][sel])

    def search(self, q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest ids and their cosine distances (1 - cos), nearest first."""
        if self.all.n == 0 or k <= 0:
            return np.zeros(0, np.int64), np.zeros(0, np.float32)
        if self.centroids is None:
            ids, mat = self.all.ids[: self.all.n], self.all.mat[: self.all.n]
        else:
            probe = np.argpartition(-(self.centroids @ q), self.nprobe)[: self.nprobe]
            groups = [self.lists[int(c)] for c in probe if self.lists[int(c)].n]
            ids = np.concatenate([g.ids[: g.n] for g in groups])
            dist_parts = [1.0 - g.mat[: g.n] @ q for g in groups]
            dist = np.concatenate(dist_parts)
            return self._top(ids, dist, k)
        return self._top(ids, 1.0 - mat @ q, k)

    def within(self, q: np.ndarray, max_distance: float) -> np.ndarray:
        """Every id whose cosine distance to ``q`` is at most ``max_distance`` (the groups :meth:`search` scans)."""
        if self.all.n == 0:
            return np.zeros(0, np.int64)
        if self.centroids is None:
            ids, mat = self.all.ids[: self.all.n], self.all.mat[: self.all.n]
            return ids[1.0 - mat @ q <= max_distance]
        probe = np.argpartition(-(self.centroids @ q), self.nprobe)[: self.nprobe]
        groups = [self.lists[int(c)] for c in probe if self.lists[int(c)].n]
        return np.concatenate([g.ids[: g.n][1.0 - g.mat[: g.n] @ q <= max_distance] for g in groups])

    @staticmethod
    def _top(ids: np.ndarray, dist: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        k = min(k, len(ids))
        top = np.argpartition(dist, k - 1)[:k] if k < len(ids) else np.arange(len(ids))
        top = top[np.argsort(dist[top], kind="stable")]
        return ids[top], dist[top].astype(np.float32)
