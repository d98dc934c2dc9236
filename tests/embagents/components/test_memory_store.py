"""The memory database (SQLite WAL + sqlite-vec, through apsw): real files, real crashes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("apsw")
pytest.importorskip("sqlite_vec")

from embagents.components.memory_store import (  # noqa: E402
    MemoryDimensionError,
    MemoryLocked,
    MemoryStore,
)


def unit(*xs: float) -> np.ndarray:
    v = np.array(xs, np.float32)
    return v / np.linalg.norm(v)


@pytest.fixture()
def store(tmp_path: Path) -> MemoryStore:
    s = MemoryStore(str(tmp_path / "m.db"), dim=3, model="toy")
    s.add("seen", "cup", unit(1, 0, 0), (4.0, 2.0, 0.0), t=100.0)
    s.add("seen", "mug", unit(0.9, 0.1, 0), (8.0, 8.0, 0.0), t=200.0)
    s.add("notes", "kitchen", unit(0, 1, 0), (4.5, 2.0, 0.0), t=150.0)
    return s


def test_semantic_spatial_and_temporal_queries(store: MemoryStore) -> None:
    assert [h["text"] for h in store.semantic(unit(1, 0, 0), k=2)] == ["cup", "mug"]
    assert [h["text"] for h in store.semantic(unit(1, 0, 0), k=5, layer="notes")] == ["kitchen"]
    near = store.within((4.0, 2.0), 1.0)
    assert [h["text"] for h in near] == ["cup", "kitchen"] and near[1]["distance_m"] == pytest.approx(0.5)
    assert [h["text"] for h in store.between(120, 250)] == ["kitchen", "mug"]
    assert store.count() == 3 and store.count("seen") == 2


def test_items_survive_closing_and_reopening(store: MemoryStore) -> None:
    path = store.path
    store.close()
    again = MemoryStore(path, dim=3, model="toy")
    assert again.count() == 3 and again.semantic(unit(0, 1, 0), k=1)[0]["text"] == "kitchen"


def test_a_model_of_another_dimension_is_refused_naming_both(store: MemoryStore) -> None:
    path = store.path
    store.close()
    with pytest.raises(MemoryDimensionError) as err:
        MemoryStore(path, dim=768, model="big-model")
    text = str(err.value)
    assert "3-dimensional" in text and "'toy'" in text and "768-dimensional" in text and "'big-model'" in text
    assert "db_path" in text
    assert MemoryStore(path, dim=3, model="toy").count() == 3  # nothing was touched


def test_a_vector_of_the_wrong_length_is_refused(store: MemoryStore) -> None:
    with pytest.raises(MemoryDimensionError, match="a 2-dimensional vector for a store of 3-dimensional"):
        store.add("seen", "x", np.ones(2, np.float32), (0, 0, 0))


def test_a_corrupt_file_is_set_aside_not_emptied(tmp_path: Path) -> None:
    path = tmp_path / "m.db"
    garbage = b"this is not a database" * 500
    path.write_bytes(garbage)
    s = MemoryStore(str(path), dim=3, model="toy")
    assert s.set_aside is not None and ".corrupt-" in s.set_aside
    assert Path(s.set_aside).read_bytes() == garbage  # kept byte for byte
    assert s.count() == 0
    s.add("notes", "fresh start", unit(1, 1, 1), (0, 0, 0))
    assert s.count() == 1


def test_a_file_locked_by_another_process_is_a_clear_error(tmp_path: Path) -> None:
    path = str(tmp_path / "m.db")
    MemoryStore(path, dim=3, model="toy").close()
    holder = subprocess.Popen([sys.executable, "-c", (
        "import apsw, sys, time\n"
        f"db = apsw.Connection({path!r})\n"
        "db.execute('BEGIN EXCLUSIVE')\n"
        "print('locked', flush=True)\n"
        "time.sleep(60)\n")], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "locked"
        with pytest.raises(MemoryLocked, match=r"locked by another process.*own db_path"):
            MemoryStore(path, dim=3, model="toy", busy_timeout_s=0.2)
    finally:
        holder.kill()
        holder.wait()
    assert MemoryStore(path, dim=3, model="toy").count() == 0  # usable once the other process let go


WRITER = """
import sys, numpy as np
from embagents.components.memory_store import MemoryStore
s = MemoryStore(sys.argv[1], dim=8, model="toy")
rng = np.random.default_rng(0)
i = 0
while True:
    i += 1
    rid = s.add("notes", f"item {i}", rng.standard_normal(8).astype(np.float32), (i, 0, 0))
    print(rid, flush=True)   # acknowledged: committed before this line
"""


def test_every_acknowledged_item_survives_a_sigkill(tmp_path: Path) -> None:
    path = str(tmp_path / "m.db")
    proc = subprocess.Popen([sys.executable, "-c", WRITER, path], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[3])})
    assert proc.stdout is not None
    acked: list[int] = []
    deadline = time.monotonic() + 30
    while len(acked) < 300 and time.monotonic() < deadline:
        acked.append(int(proc.stdout.readline()))
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert len(acked) >= 300
    stored = set(MemoryStore(path, dim=8, model="toy").ids())
    assert set(acked) <= stored  # lost == 0
