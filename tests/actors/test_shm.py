from __future__ import annotations

import gc
import os

import numpy as np
import pytest

from actors import shm
from actors.errors import CorruptFrame, StaleFrame
from actors.shm import SHM_DIR, ShmPool, ShmReader, sweep


@pytest.fixture
def pool() -> ShmPool:
    p = ShmPool(f"eatest{os.getpid()}_1_")
    yield p
    p.close()
    assert sweep(f"eatest{os.getpid()}_") == 0


def test_view_is_zero_copy_and_read_only(pool: ShmPool) -> None:
    a = np.random.default_rng(0).integers(0, 255, (480, 640, 3), dtype=np.uint8)
    v = ShmReader().view(pool.put(a), None)
    assert (v == a).all() and not v.flags.writeable
    with pytest.raises(ValueError):
        v[0, 0, 0] = 1


def test_segment_is_reused_only_after_ack_and_release(pool: ShmPool) -> None:
    reader, released = ShmReader(), []
    h = pool.put(np.ones(100_000, np.uint8))
    pool.sent([h[0]], "link")
    v = reader.view(h, lambda n, g: released.append(n))
    pool.acked([h[0]])
    h2 = pool.put(np.ones(100_000, np.uint8))
    assert h2[0] != h[0], "a segment still viewed must not be reused"
    del v
    gc.collect()
    assert released == [h[0]]
    pool.released(h[0], "link")
    pool.acked([h2[0]])
    h3 = pool.put(np.full(100_000, 7, np.uint8))
    assert h3[0] in (h[0], h2[0]) and pool.segment_count == 2


def test_lost_link_frees_its_views(pool: ShmPool) -> None:
    h = pool.put(np.ones(100_000, np.uint8))
    pool.sent([h[0]], "link")
    pool.acked([h[0]])
    pool.link_lost("link")
    assert pool.put(np.ones(100_000, np.uint8))[0] == h[0]


def test_ring_reuse_makes_old_handles_stale(pool: ShmPool) -> None:
    reader = ShmReader()
    first = pool.put_ring("cam", np.zeros(70_000, np.uint8), ring=2, min_age=0.0)
    for i in range(3):
        pool.put_ring("cam", np.full(70_000, i, np.uint8), ring=2, min_age=0.0)
    with pytest.raises(StaleFrame):
        reader.view(first, None)


def test_sweep_removes_a_prefix() -> None:
    p = ShmPool(f"easweep{os.getpid()}_9_")
    p.put(np.ones(70_000, np.uint8))
    assert sweep(f"easweep{os.getpid()}_") == 1
    p.close()


def test_a_topic_frame_reused_after_it_was_read_is_no_longer_unchanged(pool: ShmPool) -> None:
    reader = ShmReader()
    first = pool.put_ring("cam", np.zeros(70_000, np.uint8), ring=1, min_age=0.0)
    view = reader.view(first, None)
    assert reader.unchanged(first)
    pool.put_ring("cam", np.full(70_000, 9, np.uint8), ring=1, min_age=0.0)  # the ring comes round
    assert not reader.unchanged(first)
    assert int(view[0]) == 9, "the view shows the new frame: a result computed from it meanwhile is torn"


def test_only_topic_frames_of_other_processes_may_be_forwarded(pool: ShmPool) -> None:
    own = ShmPool(f"eatest{os.getpid()}_2_")
    try:
        reader = ShmReader(pool=own)
        topic = reader.view(pool.put_ring("cam", np.zeros(70_000, np.uint8)), None)
        told = reader.view(pool.put(np.zeros(70_000, np.uint8)), lambda n, g: None)
        mine = reader.view(own.put(np.zeros(70_000, np.uint8)), None)
        assert reader.origin(topic, forwardable=True) is not None
        assert reader.origin(told, forwardable=True) is None  # its sender counts views: a third one it cannot see
        assert reader.origin(told) is not None
        assert reader.origin(mine, forwardable=True) is None
        assert reader.origin(topic[:10], forwardable=True) is None  # a part is not the frame that was sent
        del topic, told, mine
    finally:
        own.close()


def _plant(name: str, *, uid: int | None = None, mode: int = 0o600, like: list | None = None) -> None:
    """A segment made by someone else under ``name`` (a valid frame header, so only its owner or mode is wrong)."""
    fd = os.open(os.path.join(SHM_DIR, name), os.O_CREAT | os.O_EXCL | os.O_RDWR, mode)
    try:
        os.ftruncate(fd, 1 << 16)
        if like is not None:  # copy a real frame's header and generation
            with open(os.path.join(SHM_DIR, like[0]), "rb") as f:
                os.write(fd, f.read(64))
        os.fchmod(fd, mode)
        if uid is not None:
            os.fchown(fd, uid, uid)
    finally:
        os.close(fd)


@pytest.mark.skipif(os.getuid() != 0, reason="making a segment of another user needs root")
def test_a_segment_of_another_user_or_open_to_others_or_of_another_run_is_refused(pool: ShmPool) -> None:
    real = pool.put(np.ones(70_000, np.uint8))
    reader = ShmReader(prefix=f"eatest{os.getpid()}_")
    assert int(reader.view(real, None)[0]) == 1
    cases = {f"{pool.prefix}90r0": {"uid": 65534}, f"{pool.prefix}91r0": {"mode": 0o666}}
    try:
        for name, how in cases.items():
            _plant(name, like=real, **how)
            with pytest.raises(CorruptFrame, match=f"refused shared-memory frame {name}: owned by uid"):
                reader.view([name, *real[1:]], None)
        with pytest.raises(CorruptFrame, match="is not of this run"):
            ShmReader(prefix="eaother_").view(real, None)
    finally:
        sweep(f"{pool.prefix}9")


def test_a_taken_segment_name_is_not_used_and_another_is_tried(pool: ShmPool, monkeypatch: pytest.MonkeyPatch) -> None:
    # Another local user can list /dev/shm and make the name a writer will take next: the first of
    # the old names (prefix + a counter), and a name whose random part it guessed.
    tokens = iter(["guessed", "guessed", "fresh"])
    monkeypatch.setattr(shm, "_token", lambda: next(tokens))
    planted = [f"{pool.prefix}1", f"{pool.prefix}1rguessed", f"{pool.prefix}2rguessed"]
    for name in planted:
        _plant(name)
    try:
        h = pool.put(np.full(70_000, 5, np.uint8))
        assert h[0] == f"{pool.prefix}3rfresh"
        assert int(ShmReader().view(h, None)[-1]) == 5
    finally:
        for name in planted:
            os.unlink(os.path.join(SHM_DIR, name))
