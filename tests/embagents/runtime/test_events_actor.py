"""Events fire on real topic traffic between processes and run their actions."""

from __future__ import annotations

import textwrap
from pathlib import Path

from actors import ActorSystem
from actors.topics import Publisher
from embagents.msgs import String
from embagents.runtime.component_actor import ComponentActor, remember_system
from embagents.runtime.events_actor import EventsActor
from embagents.runtime.requests import Call
from embagents.system import load_system
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
