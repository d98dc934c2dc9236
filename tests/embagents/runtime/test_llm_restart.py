"""A supervised LLM component keeps its chat history across a SIGKILL (snapshot/restore).

The scenario runs in a fresh interpreter: the fork server is forked from the
process that creates the ActorSystem, and llama.cpp's OpenMP threads do not
survive a fork, so a test process that already ran llama.cpp in-process
(other tests do) must not be the one that forks model actors. `embagents
supervise` never runs a model in the root, so it is not exposed to this.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

from actors import ActorSystem
from actors.topics import Publisher
from embagents.models.actor import LlamaModelActor
from embagents.msgs import String
from embagents.requests import Call
from embagents.runtime.component_actor import ComponentActor
from embagents.system import load_system, remember_system
from supervisor import ChildSpec, SupervisorSpec, start_supervisor
from tests.helpers import wait_until

SYSTEM = '''
from embagents import LLM, LLMConfig, LlamaModel, LocalModelClient, String, System, Topic

question, answer = Topic("question", String), Topic("answer", String)
model = LlamaModel(name="tiny_model", local_model_path=MODEL, warmup=False)
system = System(
    [LLM(name="llm", inputs=[question], outputs=[answer], model_client=LocalModelClient(model),
         config=LLMConfig(chat_history=True, temperature=0.0, max_new_tokens=4))],
    models=[model], external=[question],
)
'''


def test_chat_history_survives_a_sigkill(tmp_path: Path, tiny_gguf: str) -> None:
    out = subprocess.run([sys.executable, "-m", "tests.embagents.runtime.test_llm_restart", tiny_gguf, str(tmp_path)],
                         capture_output=True, text=True, timeout=180, cwd=Path(__file__).parents[3])
    assert out.returncode == 0 and out.stdout.strip().endswith("OK"), out.stdout + out.stderr[-3000:]


def scenario(tiny_gguf: str, tmp_path: Path) -> None:
    path = str(tmp_path / "system.py")
    Path(path).write_text(textwrap.dedent(SYSTEM).replace("MODEL", repr(tiny_gguf)))
    remember_system(path, load_system(path))
    with ActorSystem() as asys:
        sup = start_supervisor(asys, SupervisorSpec(intensity=5, period=10, children=[
            ChildSpec("tiny_model", (LlamaModelActor, (tiny_gguf, {}, False))),
            ChildSpec("llm", (ComponentActor, (path, "llm")), lifecycle="active", snapshot_interval=0.0),
        ]))
        try:
            pub = asys.rt.on_client(lambda: Publisher(asys.rt, "question"))
            llm = asys.ref("llm")

            def history() -> list:
                return llm.ask(Call("snapshot"), timeout=10).get()["history"]

            asys.rt.on_client(lambda: pub.publish(String(data="remember me")))
            before = wait_until(lambda: len(history()) >= 2 and history(), 30)
            assert before and before[0]["content"] == "remember me"
            old = [c.pid for c in sup.which_children() if c.id == "llm"][0]
            os.kill(old, signal.SIGKILL)
            wait_until(lambda: [c.pid for c in sup.which_children() if c.id == "llm"][0] not in (old, "restarting", None), 30)
            assert history() == before
        finally:
            sup.stop()


if __name__ == "__main__":
    scenario(sys.argv[1], Path(sys.argv[2]))
    print("OK")
