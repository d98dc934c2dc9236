"""Fast DDS /dev/shm housekeeping, on real files in /dev/shm (port numbers no DDS run uses here)."""

from __future__ import annotations

import fcntl
import mmap
import os
from collections.abc import Iterator

import pytest

from embagents.ros.fastdds_shm import SHM_DIR, clean_zombie_fastdds_segments, mapped_fastdds_files

PORTS = {"mapped": 65431, "orphan": 65432, "locked": 65433, "zombie": 65434}


def _path(name: str) -> str:
    return os.path.join(SHM_DIR, name)


@pytest.fixture
def ports() -> Iterator[dict[str, str]]:
    names = {k: f"fastdds_port{p}" for k, p in PORTS.items()}
    made = []
    for name in names.values():
        for f in (name, f"sem.{name}_mutex"):
            with open(_path(f), "wb") as fh:
                fh.write(b"\0" * 4096)
            made.append(f)
    for k in ("locked", "zombie"):
        open(_path(names[k] + "_el"), "wb").close()
        made.append(names[k] + "_el")
    yield names
    for f in made:
        if os.path.exists(_path(f)):
            os.unlink(_path(f))


def test_only_files_without_a_live_owner_are_removed(ports: dict[str, str]) -> None:
    with open(_path(ports["mapped"]), "r+b") as seg, open(_path(ports["locked"] + "_el"), "ab") as lock:
        view = mmap.mmap(seg.fileno(), 4096)  # a writer that still has the port open
        fcntl.flock(lock, fcntl.LOCK_EX)  # a listener that is alive
        try:
            assert ports["mapped"] in mapped_fastdds_files()
            removed = clean_zombie_fastdds_segments(min_age=0, names=ports.values())
        finally:
            view.close()
    assert sorted(os.path.basename(p) for p in removed) == [ports["orphan"], ports["zombie"]]
    left = set(os.listdir(SHM_DIR))
    for k in ("orphan", "zombie"):
        assert not {ports[k], ports[k] + "_el", f"sem.{ports[k]}_mutex"} & left
    assert {ports["mapped"], ports["locked"], ports["locked"] + "_el"} <= left


def test_min_age_spares_files_being_created_and_names_limit_the_sweep(ports: dict[str, str]) -> None:
    assert clean_zombie_fastdds_segments(min_age=3600, names=ports.values()) == []
    assert clean_zombie_fastdds_segments(min_age=0, names=["fastdds_port1"]) == []
    assert {ports["orphan"], ports["zombie"]} <= set(os.listdir(SHM_DIR))


def test_a_block_sweeping_dead_peers_removes_only_the_dead_files_made_inside_it(ports: dict[str, str]) -> None:
    from embagents.ros.fastdds_shm import sweeping_dead_peers

    late = "fastdds_port65435"  # made inside the block by a peer that then died (no lock held)
    try:
        with sweeping_dead_peers():
            with open(_path(late), "wb") as fh:
                fh.write(b"\0" * 4096)
        assert not os.path.exists(_path(late))
        assert {ports["orphan"], ports["zombie"]} <= set(os.listdir(SHM_DIR))  # older than the block: not its own
    finally:
        if os.path.exists(_path(late)):
            os.unlink(_path(late))
