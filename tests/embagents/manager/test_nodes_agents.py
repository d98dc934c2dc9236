"""Nodes (topic cache, typed publishing), attached agents (futures on a thread) and resuming from a snapshot."""

from __future__ import annotations

import os
import threading
from typing import Any

import pytest

from embagents.manager import (
    Agent,
    AgentError,
    AgentNotRunning,
    HandshakeRule,
    Manager,
    Node,
    NodeNotBound,
    State,
    StateMachineHandler,
)
from embagents.msgs import Image, String
from embagents.topic import Topic

text = Topic("text", String)
image = Topic("camera/image_raw", Image)


class Slow:
    def __init__(self, release: threading.Event | None = None) -> None:
        self.release = release or threading.Event()

    def wait_then(self, value: int) -> tuple[int, int]:
        self.release.wait(5)
        return value, threading.get_ident()

    def double(self, value: int) -> int:
        return 2 * value

    def fail(self) -> None:
        raise ValueError("bad frame")


def test_a_node_caches_the_latest_message_per_topic() -> None:
    node = Node("eyes", subscribe=[text, image])
    assert node.latest(text) is None and not node.received("/camera/image_raw")
    node.deliver("text", String(data="a"))
    node.deliver("text", String(data="b"))
    assert node.latest("text").data == "b" and node.count(text) == 2
    with pytest.raises(KeyError, match="does not subscribe to 'odom'; it subscribes to: text, camera/image_raw"):
        node.latest("odom")


def test_a_node_publishing_the_wrong_type_names_topic_expected_and_actual() -> None:
    node = Node("io", publish=[text])
    node.bind(lambda topic, msg: None)
    with pytest.raises(TypeError, match="node 'io': topic 'text' expects String, got Image; publish a String there"):
        node.publish(text, Image())
    with pytest.raises(KeyError, match=r"does not publish on 'other'; declare it in Node\(publish=\[...\]\)"):
        node.publish("other", String(data="x"))


def test_an_unbound_node_says_how_to_run_it() -> None:
    with pytest.raises(NodeNotBound, match=r"System\(managers=\[...\]\).*embagents supervise"):
        Node("io", publish=[text]).publish(text, String(data="x"))


def test_a_node_refuses_topics_that_are_not_declarations() -> None:
    with pytest.raises(TypeError, match="Topic\\(name, msg_type\\) declarations, got 'text'"):
        Node("io", subscribe=["text"])  # type: ignore[list-item]


def test_an_attached_agent_answers_futures_from_its_own_thread() -> None:
    release = threading.Event()
    agent = Agent("slow", Slow, release)
    agent.start()
    try:
        fut = agent.call("wait_then", 7)
        assert not fut.done()  # the caller never waits for a call
        release.set()
        value, thread = fut.result(timeout=5)
        assert value == 7 and thread != threading.get_ident()
        err = agent.call("fail").exception(timeout=5)
        assert isinstance(err, AgentError) and "fail() raised ValueError: bad frame" in str(err)
        err = agent.call("_private").exception(timeout=5)
        assert isinstance(err, AgentError) and "has no method '_private'; its methods: double, fail, wait_then" in str(err)
    finally:
        agent.stop()


def test_calling_an_agent_that_is_not_running_says_what_to_do() -> None:
    with pytest.raises(AgentNotRunning, match=r"add it to a Manager \(agents=\[...\]\)"):
        Agent("slow", Slow).call("double", 1)


def test_calls_queued_when_an_attached_agent_stops_fail_instead_of_hanging() -> None:
    release = threading.Event()
    agent = Agent("slow", Slow, release)
    agent.start()
    first, queued = agent.call("wait_then", 1), agent.call("double", 2)
    threading.Timer(0.1, release.set).start()
    agent.stop()
    assert first.result(timeout=5)[0] == 1
    with pytest.raises(AgentNotRunning, match="stopped before running double"):
        queued.result(timeout=5)


def test_a_standalone_manager_runs_attached_agents_and_refuses_isolated_ones() -> None:
    agent = Agent("slow", Slow)
    seen: list[Any] = []

    def handler(state: State, tick: int) -> None:
        seen.append(agent.call("double", tick).result(timeout=5))

    assert Manager(100, agents=[agent], handlers=[handler]).run(max_ticks=3) == 3
    assert seen == [2, 4, 6]
    with pytest.raises(RuntimeError, match=r"isolated agents \(far\) are actor processes; run the manager in a System"):
        Manager(100, agents=[Agent("far", Slow, isolated=True)]).run(max_ticks=1)


def test_a_first_message_rule_waits_for_a_topic() -> None:
    rule = HandshakeRule.first_message(image)
    state = State()
    assert rule.name == "first_message_on_camera_image_raw" and not rule.check(state)
    state.mark_received("camera/image_raw")
    assert rule.check(state) and "camera/image_raw" not in state  # nothing stored, only marked


class Pick(StateMachineHandler):
    transitions = {"search": {"found": "grasp"}, "grasp": {"held": "lift"}}
    entered: list[str]

    def on_enter_grasp(self, state: State) -> None:
        state["grasps"] = state.get("grasps", 0) + 1


def _snapshot_after_two_moves() -> dict[str, Any]:
    m = Manager(100, name="m", handlers=[Pick()])
    pick = m.handlers[0]
    m.state["target"] = "cup"
    m.state.receive("camera", b"frame")  # a message: stale after a restart, never snapshotted
    m.tick = 41
    pick.fire("found", m.state)  # type: ignore[attr-defined]
    return m.snapshot()


def test_a_snapshot_keeps_state_handlers_and_tick_but_not_messages() -> None:
    snap = _snapshot_after_two_moves()
    assert snap["tick"] == 41 and snap["state"] == {"target": "cup", "grasps": 1}
    assert snap["handlers"] == [["Pick", {"current": "grasp", "history": ["search", "grasp"]}]]


def test_a_restored_manager_resumes_its_state_machine_and_says_so(caplog: Any) -> None:
    m = Manager(100, name="m", handlers=[Pick()])
    with caplog.at_level("WARNING", logger="embagents.manager.m"):
        m.restore(_snapshot_after_two_moves())
    assert "restarted: resuming at tick 41: handler 'Pick' in state 'grasp'" in caplog.text
    pick = m.handlers[0]
    m.run(max_ticks=1)
    assert pick.current == "grasp" and m.tick == 42  # type: ignore[attr-defined]
    assert m.state["grasps"] == 1  # on_enter_grasp did not run again


def test_on_restart_initial_starts_from_the_initial_state(caplog: Any) -> None:
    m = Manager(100, name="m", handlers=[Pick()], on_restart="initial")
    with caplog.at_level("INFO", logger="embagents.manager.m"):
        m.restore(_snapshot_after_two_moves())
    assert "starting from the initial state (on_restart='initial'" in caplog.text
    assert m.handlers[0].current == "search" and m.tick == 0 and "target" not in m.state  # type: ignore[attr-defined]


def test_a_saved_state_the_machine_no_longer_has_starts_it_fresh() -> None:
    pick = Pick()
    assert pick.restore({"current": "dance"}) is None and pick.current == "search"


def test_bad_manager_options_name_the_fix() -> None:
    with pytest.raises(ValueError, match="on_restart must be 'resume' or 'initial'"):
        Manager(10, on_restart="later")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="hang_timeout must be positive seconds"):
        Manager(10, hang_timeout=0)
    with pytest.raises(ValueError, match="already has an agent named 'a'"):
        Manager(10, agents=[Agent("a", Slow), Agent("a", Slow)])


def test_state_revision_counts_writes_not_messages() -> None:
    state = State(a=1)
    before = state.revision
    state.receive("camera", b"x")
    assert state.revision == before
    state.b = 2
    assert state.revision == before + 1 and state.kept() == {"a": 1, "b": 2}


def test_an_agent_builds_its_object_in_the_process_that_runs_it() -> None:
    agent = Agent("pid", os.getpid)  # any callable factory
    assert agent.build() == os.getpid()
