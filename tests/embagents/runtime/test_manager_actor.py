"""A Manager inside a System: supervised, on topics, with attached and isolated agents.

One supervised run of tests/embagents/runtime/manager_system.py serves the
module (real processes, real topics): commands are published on each
manager's ``<name>_cmd`` topic and its state is read with asks.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from typing import Any

import pytest

from actors import ActorCrashed, ActorNotFound, ActorSystem
from actors.errors import Timeout
from actors.topics import Publisher, Subscription
from embagents.msgs import HealthStatus, String
from embagents.requests import Call, HealthQuery
from embagents.supervision import build_spec
from embagents.system import load_system, remember_system
from supervisor import lifecycle, start_supervisor
from tests.helpers import wait_until

PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "manager_system.py")


class Run:
    def __init__(self, asys: ActorSystem, sup: Any) -> None:
        self.asys, self.sup = asys, sup
        self.pubs: dict[str, Publisher] = {}
        self.status_msgs: list[str] = []
        self.health: list[Any] = []
        asys.rt.on_client(lambda: (
            Subscription(asys.rt, asys.loop, "status", lambda m: self.status_msgs.append(m.data), queue_size=100),
            Subscription(asys.rt, asys.loop, "_health", self.health.append, queue_size=100, keep="all"),
        ))

    def send(self, manager: str, command: str) -> None:
        topic = f"{manager}_cmd"
        if topic not in self.pubs:
            self.pubs[topic] = self.asys.rt.on_client(lambda: Publisher(self.asys.rt, topic))
            wait_until(lambda: self.asys.rt.on_client(lambda: self.pubs[topic].subscribers), 5, "a subscriber")
        self.asys.rt.on_client(lambda: self.pubs[topic].publish(String(data=command)))

    def status(self, manager: str) -> dict[str, Any]:
        return self.asys.ref(manager).ask(Call("status"), timeout=5).get()

    def restarted(self, manager: str, incarnation: int) -> dict[str, Any] | None:
        """Its status once a newer incarnation ticks (None while it is down or restarting)."""
        try:
            s = self.status(manager)
        except (ActorCrashed, ActorNotFound, Timeout):
            return None
        return s if s["incarnation"] > incarnation and s["ticking"] else None

    def state(self, manager: str) -> dict[str, Any]:
        return self.asys.ref(manager).ask(Call("state"), timeout=5).get()

    def pid(self, name: str) -> Any:
        return next(c.pid for c in self.sup.which_children() if c.id == name)


@pytest.fixture(scope="module")
def run() -> Iterator[Run]:
    system = load_system(PATH)
    remember_system(PATH, system)
    with ActorSystem() as asys:
        sup = start_supervisor(asys, build_spec(system, PATH))
        try:
            yield Run(asys, sup)
        finally:
            sup.stop()


def test_the_manager_ticks_in_its_own_supervised_process(run: Run) -> None:
    first = wait_until(lambda: run.status("main")["tick"] > 5 and run.status("main"), 10, "ticks")
    assert first["states"]["Mission"] == "working"  # the handshake saw a frame, the machine moved
    assert run.pid("main") not in (os.getpid(), None)
    time.sleep(0.5)
    assert run.status("main")["tick"] > first["tick"] + 10  # 50 Hz: about 25 more


def test_the_achieved_rate_is_logged_and_reported(run: Run) -> None:
    rate = wait_until(lambda: run.status("main")["rate_hz"], 5, "a rate window")
    assert 0 < rate < 60  # 50 Hz asked: never faster (missed periods are skipped, not caught up); the bench times it


def test_a_node_publishes_on_a_system_topic(run: Run) -> None:
    run.send("main", "say hello")
    wait_until(lambda: "hello" in run.status_msgs, 5, "the node's message on 'status'")


def test_attached_and_isolated_agents_are_called_the_same_way(run: Run) -> None:
    run.send("main", "double")
    run.send("main", "helper")
    state = wait_until(lambda: (s := run.state("main")).get("double") and s.get("helper") and s, 10, "answers")
    assert state["double"] == 42 and state["helper"] == 8
    main_pid = run.pid("main")
    assert state["worker_pid"] == run.pid("main.worker") != main_pid  # isolated: its own process
    assert state["helper_pid"] == main_pid  # attached: the loop's process


def test_a_handler_may_wait_on_an_isolated_agents_future(run: Run) -> None:
    run.send("main", "blocking")
    assert wait_until(lambda: run.state("main").get("blocking"), 10, "a blocking result") == 100


def test_an_agent_that_raises_fails_the_future_with_its_error(run: Run) -> None:
    run.send("main", "boom")
    text = wait_until(lambda: run.state("main").get("boom"), 10, "the failed future")
    assert "AgentError" in text and "boom()" in text and "no good" in text


def test_an_isolated_agent_crashing_mid_call_fails_the_future_at_once_and_restarts(run: Run) -> None:
    old = run.pid("main.worker")
    before = run.status("main")
    run.send("main", "crash_agent")
    state = wait_until(lambda: (s := run.state("main")).get("crash") and s, 10, "the crashed call's future")
    assert "AgentCrashed" in state["crash"] and "'worker' crashed during crash()" in state["crash"]
    # At once: within ticks of the call (it sleeps 50 ms, then dies), not never (no timeout was given).
    assert state["crash_at_tick"] - state["crash_sent_at_tick"] < 100
    wait_until(lambda: run.pid("main.worker") not in (old, None, "restarting"), 10, "the restarted agent")
    run.send("main", "double")
    wait_until(lambda: run.state("main").get("worker_pid") == run.pid("main.worker"), 10, "a call to the new one")
    after = run.status("main")
    assert after["incarnation"] == before["incarnation"]  # the loop itself never stopped
    assert after["tick"] > before["tick"]


def test_a_handler_that_raises_is_logged_and_the_loop_goes_on_with_policy_log(run: Run) -> None:
    tick = run.status("main")["tick"]
    run.send("main", "raise")
    wait_until(lambda: run.status("main")["tick"] > tick + 20, 5, "ticks after the error")
    assert run.status("main")["status"] == HealthStatus.HEALTHY


def test_a_node_publishing_the_wrong_type_names_topic_and_types(run: Run) -> None:
    tick = run.status("main")["tick"]
    run.send("main", "wrong_type")  # the handler keeps the error's text, then re-raises it (policy "log")
    text = wait_until(lambda: run.state("main").get("wrong_type"), 5, "the refused publish")
    assert text == "node 'main_io': topic 'status' expects String, got int; publish a String there"
    wait_until(lambda: run.status("main")["tick"] > tick + 20, 5, "ticks after the error")


def test_policy_stop_stops_the_loop_and_reports_it_on_health(run: Run) -> None:
    wait_until(lambda: run.status("stopper")["ticking"], 10, "stopper ticking")
    run.send("stopper", "raise")
    status = wait_until(lambda: (s := run.status("stopper")) and not s["ticking"] and s, 5, "a stopped loop")
    assert status["status"] == HealthStatus.COMPONENT_FAILURE and "on_handler_error='stop'" in status["text"]
    tick = status["tick"]
    time.sleep(0.2)
    assert run.status("stopper")["tick"] == tick
    assert any(h.component == "stopper" and h.status == HealthStatus.COMPONENT_FAILURE for h in run.health)


def test_policy_crash_restarts_the_manager_which_resumes_its_state_machine(run: Run) -> None:
    wait_until(lambda: run.status("crasher")["tick"] > 5, 10, "crasher ticking")
    run.send("crasher", "finish")
    wait_until(lambda: run.status("crasher")["states"]["Mission"] == "finished", 5, "Mission finished")
    before = run.status("crasher")
    run.send("crasher", "raise")
    after = wait_until(lambda: run.restarted("crasher", before["incarnation"]), 10, "the restarted manager ticking")
    assert after["states"]["Mission"] == "finished"  # not back to 'idle'
    assert after["tick"] >= before["tick"]  # the tick counter carried on


def test_a_hanging_handler_is_a_hang_killed_and_restarted(run: Run) -> None:
    wait_until(lambda: run.status("main")["ticking"], 10, "main ticking")
    before = run.status("main")
    run.send("main", "hang")  # hang_timeout=1.0: killed about 1 s later
    after = wait_until(lambda: run.restarted("main", before["incarnation"]), 15, "the restarted manager")
    assert after["states"]["Mission"] == before["states"]["Mission"]


def test_an_unmet_handshake_times_out_naming_the_rule_on_health(run: Run) -> None:
    health = wait_until(lambda: (h := run.asys.ref("waiter").ask(HealthQuery(), timeout=5).get())["status"]
                        == HealthStatus.SYSTEM_FAILURE and h, 5, "the handshake timeout")
    assert "handshake not complete after 0.3 s" in health["text"]
    assert "first_message_on_never (a first message on never)" in health["text"]
    status = run.status("waiter")
    assert status["unmet"] == ["first_message_on_never"] and status["tick"] == 0
    pub = run.asys.rt.on_client(lambda: Publisher(run.asys.rt, "never"))
    wait_until(lambda: run.status("waiter")["tick"] > 0, 5, "the late handshake",
               poke=lambda: run.asys.rt.on_client(lambda: pub.publish(String(data="late"))))
    assert run.asys.ref("waiter").ask(HealthQuery(), timeout=5).get()["status"] == HealthStatus.HEALTHY


def test_inactive_pauses_the_loop_and_active_resumes_it(run: Run) -> None:
    wait_until(lambda: run.status("main")["ticking"], 10, "main ticking")
    assert lifecycle.transition(run.asys, "main", "deactivate") == "inactive"
    tick = run.status("main")["tick"]
    time.sleep(0.2)
    assert run.status("main")["tick"] == tick
    assert lifecycle.transition(run.asys, "main", "activate") == "active"
    wait_until(lambda: run.status("main")["tick"] > tick + 5, 5, "ticks again")


def test_sigkill_resumes_the_state_machine_from_the_snapshot(run: Run) -> None:
    wait_until(lambda: run.status("main")["ticking"], 10, "main ticking")
    run.send("main", "finish")
    wait_until(lambda: run.status("main")["states"]["Mission"] == "finished", 5, "Mission finished")
    before = run.status("main")
    os.kill(run.pid("main"), signal.SIGKILL)
    after = wait_until(lambda: run.restarted("main", before["incarnation"]), 10, "the restarted manager")
    assert after["states"]["Mission"] == "finished"
    assert after["tick"] >= before["tick"]
