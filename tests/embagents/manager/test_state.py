"""Tests for embagents.manager.state."""

from __future__ import annotations

import threading

import pytest

from embagents.manager.state import State


def test_attribute_and_key_access_are_the_same_values() -> None:
    state = State({"mode": "idle"}, speed=0.0)
    state.heading = 90
    state["speed"] = 0.3
    assert (state.mode, state["heading"], state.speed) == ("idle", 90, 0.3)
    assert "heading" in state and len(state) == 3
    del state.heading
    assert "heading" not in state


def test_update_sets_several_values_and_snapshot_is_a_detached_dict() -> None:
    state = State()
    state.update({"a": 1}, b=2)
    snap = state.snapshot()
    state.update(a=10)
    assert snap == {"a": 1, "b": 2}
    assert type(snap) is dict
    assert state.snapshot() == {"a": 10, "b": 2}


def test_missing_value_names_the_known_keys() -> None:
    state = State(camera=None)
    with pytest.raises(AttributeError, match=r"state has no value 'lidar' \(keys: camera\)"):
        _ = state.lidar
    with pytest.raises(KeyError):
        _ = state["lidar"]


def test_method_names_are_reserved_as_attributes_but_usable_as_keys() -> None:
    state = State()
    with pytest.raises(AttributeError, match="reserved"):
        state.update = 1  # type: ignore[method-assign]
    state["update"] = 1
    assert state.snapshot() == {"update": 1}


def test_receive_stores_and_marks_the_key() -> None:
    state = State()
    assert not state.received.get("camera")
    state.receive("camera", b"frame")
    assert state.camera == b"frame"
    assert state.received["camera"] is True
    with pytest.raises(TypeError):
        state.received["camera"] = False  # type: ignore[index]


def test_lock_makes_read_modify_write_atomic_across_threads() -> None:
    state = State(count=0)

    def bump() -> None:
        for _ in range(2000):
            with state.lock:
                state.count += 1

    threads = [threading.Thread(target=bump) for _ in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert state.count == 16000
