"""Tests for embagents.manager.handshake (and how the manager waits on it)."""

from __future__ import annotations

import threading
import time

import pytest

from embagents.manager import HandshakeRule, HandshakeTimeout, Manager, State

pytestmark = pytest.mark.timeout(30)

CAMERA = HandshakeRule.message_received(
    "camera", name="first_camera_frame", description="a frame on /camera/image"
)


def test_rule_constructors_check_the_state() -> None:
    state = State()
    goal = HandshakeRule.has_value("goal")
    assert not CAMERA.check(state) and not goal.check(state)
    state.goal = (1.0, 0.0)
    state.receive("camera", b"jpeg")
    assert CAMERA.check(state) and goal.check(state)
    assert goal.name == "goal_set"
    assert HandshakeRule.message_received("imu").name == "imu_received"


def test_a_raising_predicate_counts_as_unmet_and_is_reported() -> None:
    rule = HandshakeRule("battery_ok", lambda s: s.battery > 0.2, "battery above 20 %")
    ok, error = rule.evaluate(State())
    assert not ok and isinstance(error, AttributeError)
    assert "its check raised AttributeError" in rule.explain(error)


def test_first_tick_waits_until_all_rules_hold() -> None:
    manager = Manager(100, handshake=[CAMERA, HandshakeRule.has_value("goal")])
    seen: list[tuple[bool, object]] = []
    manager.add_handler(lambda state, tick: seen.append((state.received["camera"], state.goal)))
    feed = manager.on_message("camera")
    threading.Timer(0.1, feed, args=[b"frame"]).start()
    threading.Timer(0.2, manager.state.update, kwargs={"goal": "door"}).start()
    started = time.monotonic()
    assert manager.run(max_ticks=1) == 1
    assert time.monotonic() - started >= 0.15
    assert seen == [(True, "door")]


def test_timeout_names_the_unmet_rules_only() -> None:
    met = HandshakeRule("always", lambda s: True, "nothing")
    manager = Manager(100, handshake=[met, CAMERA], handshake_timeout=0.2)
    ticks: list[int] = []
    manager.add_handler(lambda state, tick: ticks.append(tick))
    started = time.monotonic()
    with pytest.raises(HandshakeTimeout) as caught:
        manager.run()
    assert 0.15 <= time.monotonic() - started < 5.0
    message = str(caught.value)
    assert "waiting for: first_camera_frame (a frame on /camera/image)" in message
    assert "always" not in message
    assert caught.value.unmet == (CAMERA,)
    assert isinstance(caught.value, TimeoutError)
    assert ticks == []


def test_rules_are_checked_at_the_loop_rate_not_in_a_busy_loop() -> None:
    calls = 0

    def never(state: State) -> bool:
        nonlocal calls
        calls += 1
        return False

    manager = Manager(10, handshake=[HandshakeRule("never", never)], handshake_timeout=0.5)
    with pytest.raises(HandshakeTimeout, match="waiting for: never"):
        manager.run()
    assert 3 <= calls <= 10  # about one check per 100 ms tick, plus the final one


def test_stop_during_the_handshake_ends_run_without_ticking() -> None:
    manager = Manager(1, handshake=[CAMERA], handshake_timeout=None)
    manager.add_handler(lambda state, tick: pytest.fail("ticked"))
    manager.run_in_thread()
    time.sleep(0.1)
    started = time.monotonic()
    manager.stop()
    manager.join(timeout=2.0)
    assert time.monotonic() - started < 0.5
    assert manager.tick == 0


def test_join_reraises_a_timeout_from_the_loop_thread() -> None:
    manager = Manager(50, handshake=[CAMERA], handshake_timeout=0.1)
    manager.run_in_thread()
    with pytest.raises(HandshakeTimeout, match="first_camera_frame"):
        manager.join(timeout=5.0)


def test_manager_rejects_things_that_are_not_rules() -> None:
    with pytest.raises(TypeError, match="HandshakeRule"):
        Manager(10, handshake=[lambda s: True])  # type: ignore[list-item]
