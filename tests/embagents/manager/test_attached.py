"""Tests for embagents.manager.attached (and the manager's shutdown order)."""

from __future__ import annotations

import logging
import threading

import pykka
import pytest

from embagents.manager import AttachedActor, AttachedNode, Handler, Manager, State

pytestmark = pytest.mark.timeout(30)


class Node(AttachedNode):
    def __init__(self, name: str, log: list[str]) -> None:
        super().__init__(name)
        self.log = log

    def start(self) -> None:
        self.log.append(f"start {self.name}")

    def stop(self) -> None:
        self.log.append(f"stop {self.name}")


class Agent(pykka.ThreadingActor):
    def __init__(self, log: list[str]) -> None:
        super().__init__()
        self.log = log

    def on_start(self) -> None:
        self.log.append("start agent")

    def on_stop(self) -> None:
        self.log.append("stop agent")

    def on_receive(self, message: object) -> object:
        return ("echo", message)


class Plain:
    """Not an AttachedNode: anything with start() and stop() will do."""

    def __init__(self, log: list[str]) -> None:
        self.log = log

    def start(self) -> None:
        self.log.append("start plain")

    def stop(self) -> None:
        self.log.append("stop plain")


def attach_all(manager: Manager, log: list[str]) -> None:
    manager.attach(Node("first", log))
    manager.attach_actor(Agent, log)
    manager.attach(Plain(log))
    manager.attach(Node("last", log))


STARTS = ["start first", "start agent", "start plain", "start last"]
STOPS = ["stop last", "stop plain", "stop agent", "stop first"]


def test_resources_start_on_attach_and_stop_in_reverse_order() -> None:
    log: list[str] = []
    manager = Manager(200)
    attach_all(manager, log)
    assert log == STARTS
    assert manager.attached == ("first", "Agent", "Plain", "last")
    manager.run(max_ticks=2)
    assert log == STARTS + STOPS


def test_reverse_order_shutdown_even_when_a_handler_raised() -> None:
    log: list[str] = []
    manager = Manager(200, on_handler_error="raise")
    attach_all(manager, log)

    def explode(state: State, tick: int) -> None:
        raise RuntimeError("boom")

    manager.add_handler(explode)
    with pytest.raises(RuntimeError, match="boom"):
        manager.run()
    assert log == STARTS + STOPS


def test_context_manager_releases_resources_without_a_run() -> None:
    log: list[str] = []
    with Manager(10) as manager:
        attach_all(manager, log)
    assert log == STARTS + STOPS
    with pytest.raises(RuntimeError, match="shut down"):
        manager.attach(Node("late", log))


def test_handlers_stop_before_the_resources_they_use() -> None:
    log: list[str] = []

    class Driver(Handler):
        def on_stop(self, state: State) -> None:
            log.append("stop handler")

    manager = Manager(200)
    manager.attach(Node("motor", log))
    manager.add_handler(Driver())
    manager.run(max_ticks=1)
    assert log == ["start motor", "stop handler", "stop motor"]


def test_a_failing_stop_is_logged_and_the_rest_still_stop(caplog: pytest.LogCaptureFixture) -> None:
    log: list[str] = []

    class Stuck(Node):
        def stop(self) -> None:
            raise OSError("device busy")

    manager = Manager(200, name="att")
    manager.attach(Node("a", log))
    manager.attach(Stuck("stuck", log))
    manager.attach(Node("c", log))
    with caplog.at_level(logging.ERROR, logger="embagents.manager.att"):
        manager.shutdown()
    assert log == ["start a", "start stuck", "start c", "stop c", "stop a"]
    assert "stopping attached stuck failed" in caplog.text


def test_attached_actor_serves_handlers_and_is_stopped_on_shutdown() -> None:
    log: list[str] = []
    manager = Manager(200)
    ref = manager.attach_actor(Agent, log)
    assert isinstance(ref, pykka.ActorRef)
    manager.add_handler(lambda state, tick: state.update(reply=ref.ask(tick, timeout=1.0)))
    manager.run(max_ticks=2)
    assert manager.state.reply == ("echo", 2)
    assert not ref.is_alive()


def test_bad_attachments_are_refused() -> None:
    manager = Manager(10)
    with pytest.raises(TypeError, match="needs start\\(\\) and stop\\(\\)"):
        manager.attach(object())  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="pykka Actor class"):
        AttachedActor(Plain)  # type: ignore[arg-type]


def test_a_resource_whose_start_fails_is_not_stopped() -> None:
    log: list[str] = []

    class Broken(Node):
        def start(self) -> None:
            raise OSError("no camera")

    manager = Manager(10)
    manager.attach(Node("ok", log))
    with pytest.raises(OSError, match="no camera"):
        manager.attach(Broken("broken", log))
    manager.shutdown()
    assert log == ["start ok", "stop ok"]


def test_on_message_feeds_the_state_from_other_threads() -> None:
    manager = Manager(10)
    callback = manager.on_message("camera")
    thread = threading.Thread(target=callback, args=[b"frame-1"])
    thread.start()
    thread.join()
    assert manager.state.camera == b"frame-1"
    assert manager.state.received["camera"] is True
