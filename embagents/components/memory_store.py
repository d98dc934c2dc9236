"""The Memory component's database: SQLite (WAL) with sqlite-vec and an R*Tree, one file.

Each item is a row (layer, text, position x/y/z, time, JSON extras) with
its embedding in a ``vec0`` table and its position in an ``rtree``; one
transaction writes all three, so an item is either wholly stored or absent.

Durability: WAL mode with ``synchronous=NORMAL`` (default) makes every
committed item survive a SIGKILL of the process: a commit has written the
item to the WAL file (the OS keeps it, whatever happens to the process);
only a power loss can lose the last commits. ``durability="full"`` adds an
fsync per commit for that too (slower: the numbers are in docs/guides/memory-router.md).

Semantic search runs in RAM over the unit float32 vectors (read back from
the file on open: 150 MB per 100,000 items of 384 dimensions): exact
while the memory is small, then an inverted-file index (:mod:`.memory_index`)
whose cost grows like sqrt(N). Measured here first: sqlite-vec's own
brute-force ``vec0`` k-NN took ~40 ms at 100,000 items, and a 1-bit
quantised ``vec0`` index with float rescoring ~19 ms with only a third of
the true top 10 found on a hard set. sqlite-vec's ``vec_distance_cosine``
still ranks the filtered queries (one layer) inside SQLite. Positions are
in an R*Tree. Python's own ``sqlite3`` here cannot load extensions, so
``apsw`` (which bundles a current SQLite) is the binding.

Example::

    >>> import numpy as np, tempfile, os
    >>> store = MemoryStore(os.path.join(tempfile.mkdtemp(), "m.db"), dim=2, model="toy")
    >>> store.add("notes", "a red cup", np.array([1, 0], np.float32), (1.0, 2.0, 0.0), t=10.0)
    1
    >>> store.semantic(np.array([1, 0], np.float32), k=1)[0]["text"]
    'a red cup'
    >>> store.close()
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from embagents.components.memory_index import VectorIndex

__all__ = ["MemoryDimensionError", "MemoryLocked", "MemoryStore", "MemoryStoreError"]

log = logging.getLogger("embagents.memory")

_INSTALL = "pip install 'embagents[memory]' (or pip install apsw sqlite-vec)"


class MemoryStoreError(RuntimeError):
    """The memory database cannot be used as it is (the message says why and what to do)."""


class MemoryDimensionError(MemoryStoreError, ValueError):
    """The embedding model's vectors do not fit the store (another model made it)."""


class MemoryLocked(MemoryStoreError):
    """Another process holds the database's write lock."""


def _apsw() -> Any:
    try:
        import apsw
        import sqlite_vec
    except ImportError as exc:
        raise ModuleNotFoundError(f"Memory needs apsw and sqlite-vec: {_INSTALL}") from exc
    return apsw, sqlite_vec


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, np.float32).reshape(-1)
    n = float(np.linalg.norm(v))
    return v / n if n > 0 else v


class MemoryStore:
    """One memory database file; see the module docstring.

    ``dim`` and ``model`` (the embedding model's name) are written at creation
    and checked on every open: a store made by another model raises
    :class:`MemoryDimensionError` naming both. A file that is not a readable
    database is renamed to ``<path>.corrupt-<time>`` (never emptied) and a new
    store is made, with an error in the log; a file another process holds
    locked raises :class:`MemoryLocked`.
    """

    def __init__(self, path: str, *, dim: int, model: str, durability: str = "normal",
                 busy_timeout_s: float = 2.0) -> None:
        if durability not in ("normal", "full"):
            raise ValueError(f"durability must be 'normal' or 'full', got {durability!r}")
        self.path, self.dim, self.model = os.path.abspath(path), int(dim), str(model)
        self.set_aside: str | None = None
        os.makedirs(os.path.dirname(self.path), exist_ok=True)
        apsw = _apsw()[0]
        try:
            self.db = self._open(durability, busy_timeout_s)
            self._load_mirror()
        except (apsw.NotADBError, apsw.CorruptError) as exc:
            if getattr(self, "db", None) is not None:
                self.db.close()
            self.set_aside = self._set_aside(exc)
            self.db = self._open(durability, busy_timeout_s)
            self._load_mirror()

    # -- opening -------------------------------------------------------------------------------
    def _open(self, durability: str, busy_timeout_s: float) -> Any:
        apsw, sqlite_vec = _apsw()
        db = apsw.Connection(self.path)
        try:
            db.set_busy_timeout(int(busy_timeout_s * 1000))
            db.enable_load_extension(True)
            db.load_extension(sqlite_vec.loadable_path())
            db.enable_load_extension(False)
            db.execute("PRAGMA journal_mode=WAL")
            db.execute(f"PRAGMA synchronous={durability.upper()}")
            self._schema(db)
        except apsw.BusyError as exc:
            db.close()
            raise MemoryLocked(
                f"memory database {self.path} is locked by another process ({exc}); stop the other process that "
                "uses it (another Memory with the same db_path?) or give this Memory its own db_path"
            ) from None
        except BaseException:
            db.close()
            raise
        return db

    def _schema(self, db: Any) -> None:
        # IMMEDIATE takes the write lock now: a file another process holds is seen at open, not at the first item.
        db.execute("BEGIN IMMEDIATE")
        try:
            self._make_schema(db)
        except BaseException:
            db.execute("ROLLBACK")
            raise
        db.execute("COMMIT")

    def _make_schema(self, db: Any) -> None:
        db.execute("CREATE TABLE IF NOT EXISTS meta(key TEXT PRIMARY KEY, value TEXT NOT NULL)")
        meta = dict(db.execute("SELECT key, value FROM meta"))
        if meta:
            dim, model = int(meta["dim"]), meta["model"]
            if dim != self.dim:
                raise MemoryDimensionError(
                    f"memory database {self.path} holds {dim}-dimensional embeddings of model {model!r}, but "
                    f"model {self.model!r} makes {self.dim}-dimensional ones; use model {model!r} again, or "
                    "give this Memory another db_path (the stored items stay where they are)")
            if model != self.model:
                log.warning("memory database %s was made with embedding model %r; now %r (same dimension %d): "
                            "old and new vectors may not compare well", self.path, model, self.model, dim)
            return
        db.execute("INSERT INTO meta VALUES ('dim', ?), ('model', ?), ('created', ?)",
                   (str(self.dim), self.model, str(time.time())))
        db.execute("CREATE TABLE items(id INTEGER PRIMARY KEY, layer TEXT NOT NULL, text TEXT NOT NULL, "
                   "x REAL, y REAL, z REAL, t REAL NOT NULL, extra TEXT, embedding BLOB NOT NULL)")
        db.execute("CREATE INDEX items_t ON items(t)")
        db.execute("CREATE INDEX items_layer_t ON items(layer, t)")
        db.execute("CREATE VIRTUAL TABLE items_xy USING rtree(id, minx, maxx, miny, maxy)")

    def _set_aside(self, exc: BaseException) -> str:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        target = f"{self.path}.corrupt-{stamp}"
        for suffix in ("", "-wal", "-shm"):
            if os.path.exists(self.path + suffix):
                os.replace(self.path + suffix, target + suffix)
        log.error("memory database %s is not a readable SQLite database (%s): moved it to %s (nothing deleted) "
                  "and started a new one; inspect or restore it from there", self.path, exc, target)
        return target

    # -- writing -------------------------------------------------------------------------------
    def _check_vector(self, v: np.ndarray) -> np.ndarray:
        v = np.asarray(v, np.float32).reshape(-1)
        if v.shape[0] != self.dim:
            raise MemoryDimensionError(f"a {v.shape[0]}-dimensional vector for a store of {self.dim}-dimensional "
                                       f"embeddings (model {self.model!r}); embed with that model")
        return _unit(v)

    def add(self, layer: str, text: str, vector: np.ndarray, position: Sequence[float], t: float | None = None,
            extra: dict[str, Any] | None = None) -> int:
        """Store one item; returns its id once it is committed (it then survives a crash)."""
        return self.add_many([(layer, text, vector, position, t, extra)])[-1]

    def add_many(self, items: Sequence[tuple[str, str, np.ndarray, Sequence[float], float | None,
                                             dict[str, Any] | None]]) -> list[int]:
        """Store items in one transaction; returns their ids (committed)."""
        try:
            return self._add_many(items)
        except _apsw()[0].BusyError as exc:
            raise MemoryLocked(f"memory database {self.path} is locked by another process ({exc}); stop the other "
                               "process that writes it, or give this Memory its own db_path") from None

    def _add_many(self, items: Sequence[tuple[str, str, np.ndarray, Sequence[float], float | None,
                                              dict[str, Any] | None]]) -> list[int]:
        ids: list[int] = []
        vecs: list[np.ndarray] = []
        with self.db:
            for layer, text, vector, position, t, extra in items:
                v = self._check_vector(vector)
                x, y, z = (float(c) for c in (*position, 0.0, 0.0, 0.0)[:3])
                self.db.execute("INSERT INTO items(layer, text, x, y, z, t, extra, embedding) "
                                "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                                (layer, text, x, y, z, time.time() if t is None else float(t),
                                 json.dumps(extra) if extra else None, v.tobytes()))
                rid = self.db.last_insert_rowid()
                self.db.execute("INSERT INTO items_xy VALUES (?, ?, ?, ?, ?)", (rid, x, x, y, y))
                ids.append(rid)
                vecs.append(v)
        self._mirror(ids, vecs)  # after the commit: the RAM copy never holds what the file lacks
        return ids

    def _load_mirror(self) -> None:
        self._index = VectorIndex(self.dim)
        rows = list(self.db.execute("SELECT id, embedding FROM items ORDER BY id"))
        if rows:
            self._mirror([r[0] for r in rows], [np.frombuffer(r[1], np.float32) for r in rows])

    def _mirror(self, ids: list[int], vecs: list[np.ndarray]) -> None:
        self._index.add(np.asarray(ids, np.int64), np.asarray(vecs, np.float32).reshape(len(ids), self.dim))

    # -- reading -------------------------------------------------------------------------------
    _COLS = "i.id, i.layer, i.text, i.x, i.y, i.z, i.t, i.extra"

    @staticmethod
    def _row(r: Sequence[Any], **more: Any) -> dict[str, Any]:
        item = {"id": r[0], "layer": r[1], "text": r[2], "position": [r[3], r[4], r[5]], "time": r[6]}
        if r[7]:
            item["extra"] = json.loads(r[7])
        item.update(more)
        return item

    def count(self, layer: str | None = None) -> int:
        """How many items are stored (of ``layer``)."""
        sql, args = ("SELECT count(*) FROM items", ()) if layer is None else \
            ("SELECT count(*) FROM items WHERE layer = ?", (layer,))
        return int(next(iter(self.db.execute(sql, args)))[0])

    def ids(self) -> list[int]:
        return [r[0] for r in self.db.execute("SELECT id FROM items ORDER BY id")]

    def semantic(self, vector: np.ndarray, k: int = 5, layer: str | None = None) -> list[dict[str, Any]]:
        """The ``k`` items nearest in meaning to ``vector`` (cosine ``distance``, smallest first)."""
        q = self._check_vector(vector)
        if layer is not None:  # filtered: sqlite-vec ranks the layer's items inside SQLite
            rows = self.db.execute(f"SELECT {self._COLS}, vec_distance_cosine(i.embedding, ?) AS d FROM items i "
                                   "WHERE i.layer = ? ORDER BY d LIMIT ?", (q.tobytes(), layer, int(k)))
            return [self._row(r, distance=float(r[8])) for r in rows]
        found, dist = self._index.search(q, int(k))
        ids = [int(i) for i in found]
        if not ids:
            return []
        marks = ",".join("?" * len(ids))
        by_id = {r[0]: r for r in self.db.execute(f"SELECT {self._COLS} FROM items i WHERE i.id IN ({marks})", ids)}
        return [self._row(by_id[i], distance=float(d)) for i, d in zip(ids, dist, strict=True) if i in by_id]

    def within(self, center: Sequence[float], radius: float, layer: str | None = None,
               limit: int = 100) -> list[dict[str, Any]]:
        """Items within ``radius`` (metres, in x/y) of ``center``, nearest first."""
        cx, cy, r = float(center[0]), float(center[1]), float(radius)
        # The R*Tree gives the ids and points in the square; numpy keeps those in the circle, nearest first;
        # only the kept rows are read (the square around a busy place can hold many).
        box = np.array(list(self.db.execute("SELECT id, minx, miny FROM items_xy WHERE minx >= ? AND maxx <= ? "
                                            "AND miny >= ? AND maxy <= ?", (cx - r, cx + r, cy - r, cy + r))),
                       np.float64).reshape(-1, 3)
        if layer is not None and len(box):
            marks = ",".join("?" * len(box))
            keep = {row[0] for row in self.db.execute(f"SELECT id FROM items WHERE layer = ? AND id IN ({marks})",
                                                      [layer, *box[:, 0].astype(int).tolist()])}
            box = box[np.isin(box[:, 0].astype(int), list(keep))]
        d = np.hypot(box[:, 1] - cx, box[:, 2] - cy)
        inside = np.flatnonzero(d <= r)
        order = inside[np.argsort(d[inside], kind="stable")][: int(limit)]
        ids = [int(box[i, 0]) for i in order]
        if not ids:
            return []
        marks = ",".join("?" * len(ids))
        by_id = {row[0]: row for row in self.db.execute(f"SELECT {self._COLS} FROM items i WHERE i.id IN ({marks})", ids)}
        return [self._row(by_id[i], distance_m=float(d[j])) for i, j in zip(ids, order, strict=True)]

    def between(self, t0: float, t1: float, layer: str | None = None, limit: int = 100) -> list[dict[str, Any]]:
        """Items stored in the time window [t0, t1], oldest first."""
        sql = f"SELECT {self._COLS} FROM items i WHERE i.t BETWEEN ? AND ?"
        args: list[object] = [float(t0), float(t1)]
        if layer is not None:
            sql += " AND i.layer = ?"
            args.append(layer)
        sql += " ORDER BY i.t LIMIT ?"
        args.append(int(limit))
        return [self._row(r) for r in self.db.execute(sql, args)]

    def close(self) -> None:
        db, self.db = getattr(self, "db", None), None
        if db is not None:
            db.close()
