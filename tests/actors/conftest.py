"""Fixtures for actor tests: a fresh ActorSystem per test, and leak checks."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from actors import ActorSystem


def shm_names(run_id: str) -> list[str]:
    return sorted(f for f in os.listdir("/dev/shm") if f.startswith(f"ea{run_id}_"))


@pytest.fixture
def system() -> Iterator[ActorSystem]:
    s = ActorSystem()
    try:
        yield s
    finally:
        s.shutdown()
        assert shm_names(s.run_id) == [], "shared-memory segments leaked"
        assert not os.path.exists(s.run_dir), "run directory left behind"
