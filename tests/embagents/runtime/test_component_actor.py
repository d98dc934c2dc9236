"""Components run as actors: topic triggers, rate triggers in Hz, model actors."""

from __future__ import annotations

import os
import textwrap
import time
from pathlib import Path
from typing import Any

import msgpack
import pytest

from actors import ActorSystem
from embagents.requests import Call, HealthQuery
from embagents.runtime.component_actor import ComponentActor
from embagents.system import load_system, remember_system
from tests.helpers import wait_until

SYSTEM = '''
import time
from embagents.components import Component
from embagents.msgs import String
from embagents.system import System
from embagents.topic import Topic

ping = Topic("ping", String)
pong = Topic("pong", String)


class Upper(Component):
    allowed_inputs = {"Required": [String]}
    allowed_outputs = {"Required": [String]}

    def _execution_step(self, **inputs):
        self.publish(pong, String(data=inputs["ping"].data.upper()))


class Ticker(Component):
    allowed_outputs = {"Optional": [String]}

    def on_activate(self):
        self.ticks = []

    def _execution_step(self, **inputs):
        self.ticks.append(time.monotonic())

    def tick_times(self):
        return list(self.ticks)


class Recorder(Component):
    allowed_inputs = {"Required": [String]}

    def on_activate(self):
        self.got = []

    def _execution_step(self, **inputs):
        self.got.append(inputs["pong"].data)

    def received(self):
        return list(self.got)


system = System(
    [
        Recorder(name="recorder", inputs=[pong], trigger=pong),
        Upper(name="upper", inputs=[ping], outputs=[pong], trigger=ping),
        Ticker(name="ticker", trigger=20.0),
    ],
    external=[ping],
)
'''


@pytest.fixture
def running(tmp_path: Path) -> Any:
    path = str(tmp_path / "system.py")
    Path(path).write_text(textwrap.dedent(SYSTEM))
    system = load_system(path)
    remember_system(path, system)
    asys = ActorSystem()
    try:
        for c in system.components:
            asys.spawn(ComponentActor, c.name, path, c.name)
        yield asys
    finally:
        asys.shutdown()




def test_topic_trigger_runs_the_step_and_publishes(running: ActorSystem) -> None:
    from actors.topics import Publisher
    from embagents.msgs import String

    pub = running.rt.on_client(lambda: Publisher(running.rt, "ping"))
    recorder = running.ref("recorder")

    def got() -> list[str]:
        running.rt.on_client(lambda: pub.publish(String(data="hello")))
        return recorder.ask(Call("received"), timeout=5).get()

    assert "HELLO" in wait_until(got)


def test_rate_trigger_holds_its_rate_in_hz(running: ActorSystem) -> None:
    ticker = running.ref("ticker")
    time.sleep(1.5)
    ticks = ticker.ask(Call("tick_times"), timeout=5).get()
    assert len(ticks) >= 10
    span = ticks[-1] - ticks[0]
    rate = (len(ticks) - 1) / span
    # 20 Hz asked; a loose band because CI machines are noisy.
    assert 14 <= rate <= 26, f"measured {rate:.1f} Hz"


def test_unknown_request_names_the_component_and_the_options(running: ActorSystem) -> None:
    from actors import RemoteError

    with pytest.raises(RemoteError, match="component 'upper': unknown request"):
        running.ref("upper").ask("dance", timeout=5).get()
    assert running.ref("upper").ask(HealthQuery(), timeout=5).get()["status"] == 0
    assert os.path.isdir(running.run_dir)


NEEDS_CV2 = '''
from embagents.components import Component
from embagents.system import System


class Eyes(Component):
    def __init__(self, **kw):
        self.tried = 0
        super().__init__(**kw)

    def _execution_step(self, **inputs):
        self.tried += 1
        import cv2  # noqa: F401  (hidden from this process: as if the vision extra were not installed)

    def steps(self):
        return self.tried


system = System([Eyes(name="eyes", trigger=50.0)])
'''

RUN_EYES = '''
import json, sys, time
from actors import ActorSystem
from embagents.msgs import HealthStatus
from embagents.runtime.component_actor import ComponentActor
from embagents.system import remember_system
from embagents.requests import Call, HealthQuery
from embagents.system import load_system
from tests.helpers import wait_until

path = sys.argv[1]
remember_system(path, load_system(path))
with ActorSystem() as asys:
    asys.spawn(ComponentActor, "eyes", path, "eyes", wait=30)
    eyes = asys.ref("eyes")
    health = wait_until(lambda: (h := eyes.ask(HealthQuery(), timeout=5).get())["status"] != HealthStatus.HEALTHY and h,
                        10, "a failure reported")
    time.sleep(0.5)  # 25 more periods of its 50 Hz trigger: no step may run in them
    print(json.dumps({"status": HealthStatus(health["status"]).name, "text": health["text"],
                      "steps": eyes.ask(Call("steps"), timeout=5).get()}))
'''


def test_a_step_missing_a_module_is_one_component_failure_naming_the_extra_and_steps_no_more(tmp_path: Path) -> None:
    import json
    import subprocess
    import sys

    from tests.helpers import hide_modules

    (tmp_path / "system.py").write_text(NEEDS_CV2)
    env = hide_modules(tmp_path / "hide", ["cv2"], {**os.environ, "PYTHONPATH": os.pathsep.join(
        p for p in (str(Path(__file__).parents[3]), os.environ.get("PYTHONPATH", "")) if p)})
    out = subprocess.run([sys.executable, "-c", RUN_EYES, str(tmp_path / "system.py")], capture_output=True,
                         text=True, timeout=120, env=env, cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    got = json.loads(out.stdout.splitlines()[-1])
    assert got["status"] == "COMPONENT_FAILURE" and got["steps"] == 1, got
    assert got["text"].startswith("component 'eyes' (Eyes): its step needs the module 'cv2', which is not installed: "
                                  "pip install 'embagents[vision]'"), got["text"]
    assert got["text"].endswith("it stops stepping (after installing: embagents restart eyes)"), got["text"]
    assert out.stderr.count("needs the module 'cv2'") == 1 and "Traceback" not in out.stderr, out.stderr[-3000:]


def test_a_request_it_cannot_interpret_is_quoted_briefly_and_a_told_one_is_dead_lettered(running: ActorSystem) -> None:
    from actors import RemoteError

    upper = running.ref("upper")
    pid = running.ctrl("upper", "stats")["pid"]
    with pytest.raises(RemoteError) as err:  # a 10 MB request used to come back whole in its error
        upper.ask("x" * 10_000_000, timeout=10).get()
    assert "component 'upper': unknown request 'xxx" in str(err.value) and len(str(err.value)) < 1000
    with pytest.raises(RemoteError, match="Upper has no method 'dance'"):
        upper.ask(Call("dance"), timeout=5).get()
    upper.tell({"what": "y" * 10_000_000})  # used to crash the actor (a told message that raises)
    upper.tell(Call("dance"))
    assert upper.flush(10)
    assert running.ctrl("upper", "stats")["pid"] == pid and upper.ask(HealthQuery(), timeout=5).get()["status"] == 0
    with open(os.path.join(running.run_dir, "deadletters.log"), "rb") as f:
        dead = list(msgpack.Unpacker(f))
    assert [d["kind"] for d in dead] == ["tell", "tell"] and all(len(d["message"]) < 300 for d in dead)
    assert "unknown request {'what': 'yyy" in dead[0]["reason"] and "no method 'dance'" in dead[1]["reason"]
