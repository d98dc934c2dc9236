"""Tests for embagents.manager.handler."""

from __future__ import annotations

import logging
import threading

import pytest

from embagents.manager import (
    FunctionHandler,
    Handler,
    InvalidTransition,
    Manager,
    State,
    StateMachineHandler,
)
from embagents.manager.handler import as_handler

pytestmark = pytest.mark.timeout(30)


class Door(StateMachineHandler):
    transitions = {
        "closed": {"open": "opened", "lock": "locked"},
        "opened": {"close": "closed"},
        "locked": {"unlock": "closed"},
    }

    def __init__(self) -> None:
        super().__init__()
        self.calls: list[str] = []

    def on_enter_opened(self, state: State) -> None:
        self.calls.append("enter opened")

    def on_exit_opened(self, state: State) -> None:
        self.calls.append("exit opened")

    def on_enter_closed(self, state: State) -> None:
        self.calls.append("enter closed")


class Approach(StateMachineHandler):
    """Method-driven: tick_<state> returns the next state or an event."""

    transitions = {"idle": {"go": "approach"}, "approach": {"arrived": "done"}}

    def tick_idle(self, state: State) -> str | None:
        return "go" if state.get("target") else None

    def tick_approach(self, state: State) -> str | None:
        return "done" if state.distance < 0.1 else None


def test_events_follow_the_transitions_table_and_run_hooks() -> None:
    door, state = Door(), State()
    assert door.current == "closed"
    assert door.fire("open", state) == "opened"
    door.fire("close", state)
    door.fire("lock", state)
    assert door.history == ["closed", "opened", "closed", "locked"]
    assert door.calls == ["enter closed", "enter opened", "exit opened", "enter closed"]


def test_invalid_event_names_handler_state_and_event() -> None:
    door, state = Door(), State()
    door.fire("lock", state)
    with pytest.raises(InvalidTransition) as caught:
        door.fire("open", state)
    assert str(caught.value) == (
        "handler 'Door' in state 'locked' has no transition for event 'open' "
        "(allowed here: unlock -> closed)"
    )
    assert (caught.value.handler, caught.value.state, caught.value.event) == (
        "Door", "locked", "open",
    )
    assert door.current == "locked"


def test_tick_methods_return_events_or_states() -> None:
    machine, state = Approach(), State(distance=1.0)
    machine.on_tick(state, 1)
    assert machine.current == "idle"  # None: stay
    state.target = "cup"
    machine.on_tick(state, 2)  # "go" is an event of idle
    machine.on_tick(state, 3)
    assert machine.current == "approach"
    state.distance = 0.05
    machine.on_tick(state, 4)  # "done" is a state reachable from approach
    assert machine.history == ["idle", "approach", "done"]


def test_tick_cannot_jump_along_an_undeclared_edge() -> None:
    class Jumpy(Approach):
        def tick_idle(self, state: State) -> str | None:
            return "done"

    with pytest.raises(InvalidTransition, match="cannot move to 'done': no transition leads there"):
        Jumpy().on_tick(State(), 1)


def test_tick_returning_an_unknown_name_is_an_error() -> None:
    class Typo(Approach):
        def tick_idle(self, state: State) -> str | None:
            return "aproach"

    with pytest.raises(InvalidTransition, match="'aproach' from tick_idle, which is neither"):
        Typo().on_tick(State(), 1)


def test_method_only_machine_moves_freely_between_its_states() -> None:
    class Blink(StateMachineHandler):
        initial = "on"

        def tick_on(self, state: State) -> str:
            return "off"

        def tick_off(self, state: State) -> str:
            return "on"

    blink, state = Blink(), State()
    for tick in range(1, 4):
        blink.on_tick(state, tick)
    assert blink.history == ["on", "off", "on", "off"]
    assert blink.known_states == ("on", "off")


def test_declaration_mistakes_fail_at_construction() -> None:
    class HookTypo(Approach):
        def tick_aproach(self, state: State) -> None: ...

    with pytest.raises(ValueError, match="tick_aproach names state 'aproach'"):
        HookTypo()

    class NoStart(StateMachineHandler):
        def tick_a(self, state: State) -> None: ...

    with pytest.raises(TypeError, match="needs `initial`"):
        NoStart()
    with pytest.raises(ValueError, match="initial state 'nope'"):
        Approach(initial="nope")


def test_posted_events_from_other_threads_fire_on_the_next_tick() -> None:
    door, state = Door(), State()
    thread = threading.Thread(target=door.post, args=["open"])
    thread.start()
    thread.join()
    assert door.current == "closed"
    door.on_tick(state, 1)
    assert door.current == "opened"


def test_function_handlers_and_bad_handlers() -> None:
    def watch(state: State, tick: int) -> None: ...

    assert as_handler(watch).name == "watch"
    assert isinstance(as_handler(watch), FunctionHandler)
    with pytest.raises(TypeError, match="fn\\(state, tick\\)"):
        as_handler(42)  # type: ignore[arg-type]


class Recorder(Handler):
    def __init__(self, name: str, log: list[str]) -> None:
        super().__init__(name)
        self.log = log

    def on_start(self, state: State) -> None:
        self.log.append(f"start {self.name}")

    def on_tick(self, state: State, tick: int) -> None:
        self.log.append(f"tick {tick} {self.name}")

    def on_stop(self, state: State) -> None:
        self.log.append(f"stop {self.name}")


def test_manager_runs_handlers_in_registration_order() -> None:
    log: list[str] = []
    manager = Manager(200)
    manager.add_handler(Recorder("a", log))
    manager.add_handler(Recorder("b", log))
    manager.run(max_ticks=2)
    assert log == [
        "start a", "start b",
        "tick 1 a", "tick 1 b", "tick 2 a", "tick 2 b",
        "stop b", "stop a",
    ]


def test_handlers_share_state_within_a_tick() -> None:
    manager = Manager(200)
    manager.add_handler(lambda state, tick: state.update(distance=1.0 - 0.5 * tick))
    machine = manager.add_handler(Approach())
    manager.state.target = "cup"
    manager.run(max_ticks=3)
    assert machine.history == ["idle", "approach", "done"]


def test_invalid_transition_in_the_loop_is_logged_and_the_loop_goes_on(
    caplog: pytest.LogCaptureFixture,
) -> None:
    class Broken(Approach):
        def tick_idle(self, state: State) -> str:
            return "done"

    manager = Manager(200, name="sm")
    manager.add_handler(Broken(name="mission"))
    with caplog.at_level(logging.ERROR, logger="embagents.manager.sm"):
        assert manager.run(max_ticks=3) == 3
    assert "handler 'mission' failed on tick 1" in caplog.text
    assert "InvalidTransition" in caplog.text


def test_handlers_cannot_be_added_while_running() -> None:
    manager = Manager(200)
    errors: list[Exception] = []

    def add_more(state: State, tick: int) -> None:
        try:
            manager.add_handler(lambda s, t: None)
        except RuntimeError as exc:
            errors.append(exc)

    manager.add_handler(add_more)
    manager.run(max_ticks=1)
    assert len(errors) == 1
