"""The system tests/embagents/runtime/test_manager_actor.py runs: managers with nodes and agents.

- ``camera`` publishes a numbered frame on ``frames`` at 50 Hz;
- ``main`` (policy "log") waits for a first frame, runs ``Mission`` and obeys
  commands on ``<name>_cmd`` (call its isolated ``worker`` agent or attached
  ``helper``, crash the worker mid-call, raise, publish a wrong type, hang);
- ``stopper`` (policy "stop") and ``crasher`` (policy "crash") fail on command;
- ``waiter``'s handshake waits for a topic nobody publishes.
"""

from __future__ import annotations

import os
import time
from typing import Any

from embagents.components import Component
from embagents.manager import Agent, HandshakeRule, Manager, Node, State, StateMachineHandler
from embagents.msgs import String
from embagents.system import System
from embagents.topic import Topic

frames = Topic("frames", String)
status = Topic("status", String)
never = Topic("never", String)


class FakeCamera(Component):
    allowed_outputs = {"Required": [String]}

    def on_activate(self) -> None:
        self.n = 0

    def _execution_step(self, **inputs: Any) -> None:
        self.n += 1
        self.publish(frames, String(data=f"frame {self.n}"))


class Worker:
    def double(self, x: int) -> int:
        return 2 * x

    def pid(self) -> int:
        return os.getpid()

    def crash(self) -> None:
        time.sleep(0.05)  # mid-call
        os._exit(3)

    def boom(self) -> None:
        raise ValueError("no good")


class Commands(Node):
    """Queues every command; handlers take them one by one."""

    def __init__(self, name: str, cmd: Topic) -> None:
        super().__init__(name, subscribe=[cmd, frames], publish=[status])
        self.cmd = cmd.name
        self.queue: list[str] = []

    def on_message(self, topic: str, msg: Any) -> None:
        if topic == self.cmd:
            self.queue.append(msg.data)


class Mission(StateMachineHandler):
    """idle -> working (first frame seen) -> finished (on the 'finish' command)."""

    transitions = {"idle": {"seen": "working"}, "working": {"finish": "finished"}}

    def __init__(self, node: Commands) -> None:
        super().__init__()
        self.node = node

    def tick_idle(self, state: State) -> str | None:
        return "seen" if self.node.latest(frames) is not None else None


class Obey:
    """Carries out the node's commands and keeps the agents' answers in the state."""

    def __init__(self, node: Commands, mission: Mission, worker: Agent, helper: Agent) -> None:
        self.node, self.mission, self.worker, self.helper = node, mission, worker, helper
        self.futures: dict[str, Any] = {}
        self.__name__ = "obey"

    def __call__(self, state: State, tick: int) -> None:
        for key, fut in list(self.futures.items()):
            if fut.done():
                del self.futures[key]
                exc = fut.exception()
                state[key] = f"error: {type(exc).__name__}: {exc}" if exc else fut.result()
                state[key + "_at_tick"] = tick
        while self.node.queue:
            self.do(self.node.queue.pop(0), state)

    def do(self, command: str, state: State) -> None:
        if command == "double":
            self.futures["double"] = self.worker.call("double", 21)
            self.futures["worker_pid"] = self.worker.call("pid")
        elif command == "helper":
            self.futures["helper"] = self.helper.call("double", 4)
            self.futures["helper_pid"] = self.helper.call("pid")
        elif command == "crash_agent":
            state["crash_sent_at_tick"] = int(state.get("ticks", 0))
            self.futures["crash"] = self.worker.call("crash")
        elif command == "boom":
            self.futures["boom"] = self.worker.call("boom")
        elif command == "blocking":
            state["blocking"] = self.worker.call("double", 50).result(timeout=10)
        elif command == "finish":
            self.mission.post("finish")
        elif command == "raise":
            raise RuntimeError("asked to raise")
        elif command == "wrong_type":
            try:
                self.node.publish(status, 42)
            except TypeError as exc:
                state["wrong_type"] = str(exc)
                raise
        elif command == "hang":
            time.sleep(60)
        elif command.startswith("say "):
            self.node.publish(status, String(data=command[4:]))


def count(state: State, tick: int) -> None:
    state["ticks"] = tick


def build(name: str, policy: Any) -> Manager:
    node = Commands(f"{name}_io", commands[name])
    worker = Agent("worker", Worker, isolated=True)
    helper = Agent("helper", Worker)
    mission = Mission(node)
    return Manager(
        50, name=name, on_handler_error=policy, hang_timeout=1.0, log_rate_every=0.5,
        handshake=[HandshakeRule.first_message(frames)], handshake_timeout=10,
        nodes=[node], agents=[worker, helper],
        handlers=[count, mission, Obey(node, mission, worker, helper)],
    )


commands = {n: Topic(f"{n}_cmd", String, queue_size=100, keep="all") for n in ("main", "stopper", "crasher")}
main = build("main", "log")
stopper = build("stopper", "stop")
crasher = build("crasher", "crash")
waiter = Manager(20, name="waiter", handshake=[HandshakeRule.first_message(never)], handshake_timeout=0.3,
                 nodes=[Node("ears", subscribe=[never])])

system = System(
    [FakeCamera(name="camera", outputs=[frames], trigger=50.0)],
    managers=[main, stopper, crasher, waiter],
    external=[*commands.values(), never],
    supervision={"intensity": 20, "period": 10},
)
