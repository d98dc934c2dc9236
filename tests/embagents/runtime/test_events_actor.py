"""Events fire on real topic traffic between processes and run their actions."""

from __future__ import annotations

import textwrap
from pathlib import Path

from actors import ActorSystem
from actors.topics import Publisher
from embagents.msgs import String
from embagents.requests import Call
from embagents.runtime.component_actor import ComponentActor
from embagents.runtime.events_actor import EventsActor
from embagents.system import load_system, remember_system
from tests.helpers import wait_until

SYSTEM = '''
from embagents import events
from embagents.components import Component
from embagents.msgs import String
from embagents.system import System
from embagents.topic import Topic

cmd = Topic("cmd", String)
alarm = Topic("alarm", String)


class Sink(Component):
    allowed_inputs = {"Optional": [String]}

    def on_activate(self):
        self.log = []

    def note(self, what):
        self.log.append(what)

    def notes(self):
        return list(self.log)

    def _execution_step(self, **inputs):
        if inputs.get("alarm") is not None:
            self.log.append("alarm:" + inputs["alarm"].data)


sink = Sink(name="sink", inputs=[alarm], trigger=alarm)
halt = events.Event("halt", events.on(cmd).field("data") == "halt")
system = System(
    [sink],
    events={halt: [events.publish(alarm, String(data="halted")), events.call(sink, "note", "called")]},
    external=[cmd],
)
'''




def test_an_event_publishes_and_calls_a_component_method(tmp_path: Path) -> None:
    path = str(tmp_path / "system.py")
    Path(path).write_text(textwrap.dedent(SYSTEM))
    remember_system(path, load_system(path))
    with ActorSystem() as asys:
        asys.spawn(ComponentActor, "sink", path, "sink")
        ev = asys.spawn(EventsActor, "_events", path)
        pub = asys.rt.on_client(lambda: Publisher(asys.rt, "cmd"))
        for word in ("go", "halt", "halt"):
            asys.rt.on_client(lambda w=word: pub.publish(String(data=w)))
        sink = asys.ref("sink")
        notes = wait_until(lambda: len(sink.ask(Call("notes"), timeout=5).get()) >= 2 and
                       sink.ask(Call("notes"), timeout=5).get())
        assert sorted(notes) == ["alarm:halted", "called"]
        # Rising edge: the second "halt" did not fire again.
        assert [f["kind"] for f in ev.ask("fired", timeout=5).get()] == ["publish", "call"]


FALLBACK_SYSTEM = '''
from embagents import events
from embagents.components import LLM, Component
from embagents.msgs import String
from embagents.system import System
from embagents.topic import Topic

question = Topic("question", String)
answer = Topic("answer", String)


class DeadPrimary:
    name = "primary"

    def chat_stream(self, messages, **options):
        raise ConnectionError("the model actor 'primary' is gone")


class Backup:
    name = "backup"

    def chat_stream(self, messages, **options):
        yield {"delta": "backup heard: " + messages[-1]["content"]}
        yield {"done": True, "finish_reason": "stop", "tool_calls": None}


class Sink(Component):
    allowed_inputs = {"Optional": [String]}

    def on_activate(self):
        self.log = []

    def notes(self):
        return list(self.log)

    def _execution_step(self, **inputs):
        self.log.append(inputs["answer"].data)


llm = LLM(name="llm", inputs=[question], outputs=[answer], model_client=DeadPrimary(), extra_clients=[Backup()],
          fallback=events.Fallback(on_algorithm_fail=events.switch_model_client("backup")))
sink = Sink(name="sink", inputs=[answer], trigger=answer)
system = System([llm, sink], external=[question])
'''


def test_the_question_that_met_a_dead_client_is_answered_by_the_fallbacks_client(tmp_path: Path) -> None:
    path = str(tmp_path / "system.py")
    Path(path).write_text(textwrap.dedent(FALLBACK_SYSTEM))
    remember_system(path, load_system(path))
    with ActorSystem() as asys:
        asys.spawn(ComponentActor, "sink", path, "sink")
        asys.spawn(ComponentActor, "llm", path, "llm")
        ev = asys.spawn(EventsActor, "_events", path)
        pub = asys.rt.on_client(lambda: Publisher(asys.rt, "question"))
        asys.rt.on_client(lambda: pub.publish(String(data="where is the cup?")))
        sink = asys.ref("sink")
        notes = wait_until(lambda: sink.ask(Call("notes"), timeout=5).get())
        assert notes == ["backup heard: where is the cup?"]
        assert [f["kind"] for f in ev.ask("fired", timeout=5).get()] == ["switch_model_client"]
