"""The supervision tree of a System: config.step_timeout_s is a component's hang deadline."""

from __future__ import annotations

import textwrap
from pathlib import Path

from actors import ActorSystem
from embagents.supervision import HEARTBEAT_S, build_spec
from embagents.system import load_system, remember_system
from supervisor import start_supervisor
from tests.helpers import wait_until

SYSTEM = '''
import time
from embagents.components import Component
from embagents.system import System


class Stuck(Component):
    def _execution_step(self, **inputs):
        time.sleep(60)  # never done in time


class Fine(Component):
    def _execution_step(self, **inputs):
        pass


system = System([Stuck(name="stuck", trigger=5.0, step_timeout_s=0.5), Fine(name="fine", trigger=5.0)])
'''


def test_a_step_longer_than_step_timeout_s_gets_its_component_killed_and_restarted(tmp_path: Path) -> None:
    path = str(tmp_path / "system.py")
    Path(path).write_text(textwrap.dedent(SYSTEM))
    system = load_system(path)
    remember_system(path, system)  # forked actor processes find it in memory
    spec = build_spec(system, path)
    assert {c.id: c.heartbeat for c in spec.children} == {"stuck": 0.5, "fine": HEARTBEAT_S}
    with ActorSystem() as asys:
        sup = start_supervisor(asys, spec)
        try:
            def pid(name: str) -> object:
                return next(c.pid for c in sup.which_children() if c.id == name)

            first, fine = pid("stuck"), pid("fine")
            # Its first step starts 0.2 s after activation and never ends: 0.5 s later it is a hang.
            wait_until(lambda: pid("stuck") not in (first, "restarting", None), 20, "a new incarnation of 'stuck'")
            assert pid("fine") == fine  # one_for_one: the others keep running
        finally:
            sup.stop()


def test_standby_and_start_method_of_components_and_models_reach_their_child_specs(tmp_path: Path) -> None:
    path = tmp_path / "system.py"
    path.write_text(textwrap.dedent('''
        from embagents import LLM, LlamaModel, LocalModelClient, String, System, Topic
        from embagents.components import Component

        q, a = Topic("q", String), Topic("a", String)
        model = LlamaModel(name="m", local_model_path="/models/m.gguf", standby=True)
        system = System([
            LLM(name="llm", inputs=[q], outputs=[a], model_client=LocalModelClient(model), start_method="spawn"),
            Component(name="plain"),
        ], models=[model], external=[q])
    '''))
    spec = build_spec(load_system(str(path)), str(path))
    got = {c.id: (c.standby, c.start_method) for c in spec.children}
    assert got == {"m": (True, "spawn"), "llm": (False, "spawn"), "plain": (False, "fork")}
