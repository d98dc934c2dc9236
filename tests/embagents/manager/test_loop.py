"""Tests for embagents.manager.loop: rate, stopping, error policy, the example.

Timing bounds are deliberately loose: CI machines are noisy.
"""

from __future__ import annotations

import logging
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from embagents.manager import Manager, State
from tests.helpers import wait_until

pytestmark = pytest.mark.timeout(30)

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "manager_loop.py"


def test_run_counts_ticks_from_one() -> None:
    manager = Manager(200)
    seen: list[int] = []
    manager.add_handler(lambda state, tick: seen.append(tick))
    assert manager.tick == 0
    assert manager.run(max_ticks=5) == 5
    assert seen == [1, 2, 3, 4, 5]
    assert manager.tick == 5


def test_rate_is_held_at_50_hz() -> None:
    manager = Manager(50)
    stamps: list[float] = []
    manager.add_handler(lambda state, tick: stamps.append(time.monotonic()))
    manager.run(max_ticks=51)
    rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
    assert 35 < rate < 65


def test_rate_is_held_when_handlers_take_part_of_the_period() -> None:
    # Absolute deadlines: 8 ms of work per 20 ms tick must not slow the loop.
    manager = Manager(50)
    stamps: list[float] = []

    def work(state: State, tick: int) -> None:
        stamps.append(time.monotonic())
        time.sleep(0.008)

    manager.add_handler(work)
    manager.run(max_ticks=41)
    rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
    assert 35 < rate < 65


def test_a_slow_tick_counts_as_an_overrun() -> None:
    manager = Manager(50)
    manager.add_handler(lambda state, tick: time.sleep(0.07 if tick == 2 else 0))
    assert manager.run(max_ticks=5) == 5
    assert manager.overruns >= 1


def test_idle_loop_uses_almost_no_cpu() -> None:
    manager = Manager(10)
    manager.add_handler(lambda state, tick: None)
    manager.run_in_thread()
    time.sleep(0.2)
    cpu, wall = time.process_time(), time.monotonic()
    time.sleep(1.0)
    cpu, wall = time.process_time() - cpu, time.monotonic() - wall
    manager.stop()
    manager.join(timeout=2.0)
    assert cpu / wall < 0.05, f"idle 10 Hz loop used {cpu / wall:.1%} of a core"


def test_stop_from_another_thread_wakes_the_loop_at_once() -> None:
    manager = Manager(0.5)  # a 2 s period
    manager.run_in_thread()
    wait_until(lambda: manager.tick == 1)
    started = time.monotonic()
    manager.stop()
    manager.join(timeout=2.0)
    assert time.monotonic() - started < 0.5
    assert manager.tick == 1


@pytest.mark.skipif(not hasattr(signal, "setitimer"), reason="needs POSIX timers")
def test_stop_from_a_signal_handler_wakes_the_loop_at_once() -> None:
    manager = Manager(0.2)  # a 5 s period
    previous = signal.signal(signal.SIGALRM, lambda *_: manager.stop())
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.2)
        started = time.monotonic()
        assert manager.run() == 1
        assert time.monotonic() - started < 2.0
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def test_stop_from_a_handler_ends_after_that_tick() -> None:
    manager = Manager(200)
    after: list[int] = []
    manager.add_handler(lambda state, tick: manager.stop() if tick == 3 else None)
    manager.add_handler(lambda state, tick: after.append(tick))
    assert manager.run() == 3
    assert after == [1, 2, 3]


def fail_on_2(state: State, tick: int) -> None:
    if tick == 2:
        raise ValueError("bad reading")


def test_error_policy_log_keeps_going(caplog: pytest.LogCaptureFixture) -> None:
    manager = Manager(200, name="pol")
    manager.add_handler(fail_on_2)
    later: list[int] = []
    manager.add_handler(lambda state, tick: later.append(tick))
    with caplog.at_level(logging.INFO, logger="embagents.manager.pol"):
        assert manager.run(max_ticks=4) == 4
    assert later == [1, 2, 3, 4]
    assert "handler 'fail_on_2' failed on tick 2" in caplog.text
    assert "ValueError: bad reading" in caplog.text
    assert "handler 'fail_on_2' recovered after 1 failed ticks" in caplog.text


def test_error_policy_raise_propagates_with_the_handler_named() -> None:
    manager = Manager(200, on_handler_error="raise")
    manager.add_handler(fail_on_2)
    with pytest.raises(ValueError, match="bad reading") as caught:
        manager.run(max_ticks=4)
    if hasattr(caught.value, "__notes__"):
        assert caught.value.__notes__ == ["in handler 'fail_on_2' on tick 2"]
    assert manager.tick == 2


def test_error_policy_stop_ends_the_loop(caplog: pytest.LogCaptureFixture) -> None:
    manager = Manager(200, on_handler_error="stop", name="pol")
    manager.add_handler(fail_on_2)
    later: list[int] = []
    manager.add_handler(lambda state, tick: later.append(tick))
    with caplog.at_level(logging.ERROR, logger="embagents.manager.pol"):
        assert manager.run(max_ticks=10) == 2
    assert later == [1]
    assert "stopping: handler 'fail_on_2' failed" in caplog.text


def test_a_handler_failing_every_tick_does_not_flood_the_log(
    caplog: pytest.LogCaptureFixture,
) -> None:
    manager = Manager(500, name="flood")

    def always(state: State, tick: int) -> None:
        raise KeyError("camera")

    manager.add_handler(always)
    with caplog.at_level(logging.ERROR, logger="embagents.manager.flood"):
        manager.run(max_ticks=50)
    assert len(caplog.records) == 1


def test_rate_logging_reports_the_achieved_rate(caplog: pytest.LogCaptureFixture) -> None:
    manager = Manager(50, log_rate_every=0.2, name="rate")
    with caplog.at_level(logging.INFO, logger="embagents.manager.rate"):
        manager.run(max_ticks=30)
    lines = [r.getMessage() for r in caplog.records if "target 50 Hz" in r.getMessage()]
    assert lines and "overruns in the last" in lines[0]
    assert manager.achieved_rate is not None and 35 < manager.achieved_rate < 65


def test_a_manager_runs_once() -> None:
    manager = Manager(200)
    manager.run(max_ticks=1)
    with pytest.raises(RuntimeError, match="shut down"):
        manager.run(max_ticks=1)


def test_shutdown_from_another_thread_waits_for_the_loop() -> None:
    released: list[str] = []

    class Res:
        def start(self) -> None: ...

        def stop(self) -> None:
            released.append("res")

    manager = Manager(100)
    manager.attach(Res())
    manager.run_in_thread()
    wait_until(lambda: manager.tick >= 1)
    manager.shutdown()
    assert released == ["res"]
    manager.join(timeout=1.0)


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(ValueError, match="rate_hz"):
        Manager(0)
    with pytest.raises(ValueError, match="on_handler_error"):
        Manager(10, on_handler_error="ignore")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="handshake_timeout"):
        Manager(10, handshake_timeout=0)
    with pytest.raises(ValueError, match="max_ticks"):
        Manager(10).run(max_ticks=-1)


def test_the_example_runs_and_exits_0() -> None:
    done = subprocess.run(
        [sys.executable, str(EXAMPLE)], capture_output=True, text=True, timeout=25
    )
    assert done.returncode == 0, done.stderr
    assert "states visited: idle -> approach -> done" in done.stdout
    assert "handshake complete" in done.stderr
    assert "Hz (target 20 Hz)" in done.stderr
