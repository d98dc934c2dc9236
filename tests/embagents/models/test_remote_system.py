"""A system.py whose LLM component uses a RemoteModelClient: the answer comes over TCP with CURVE.

Runs in a fresh interpreter, like tests/embagents/runtime/test_llm_restart.py:
model actors are forked from the test's process, which must not have run
llama.cpp in-process (its OpenMP threads do not survive a fork).
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from actors import ActorSystem
from actors.curve import write_keypair
from actors.topics import Publisher
from embagents.models.remote import RemoteModelActor
from embagents.msgs import String
from embagents.requests import Call
from embagents.runtime.component_actor import ComponentActor
from embagents.system import load_system, remember_system
from supervisor import ChildSpec, SupervisorSpec, start_supervisor
from tests.helpers import free_port, wait_until

SYSTEM = '''
from embagents import LLM, LLMConfig, RemoteModelClient, String, System, Topic

question, answer = Topic("question", String), Topic("answer", String)
client = RemoteModelClient(ENDPOINT, server_key=SERVER_KEY, key=CLIENT_KEY)
system = System(
    [LLM(name="llm", inputs=[question], outputs=[answer], model_client=client,
         config=LLMConfig(chat_history=True, temperature=0.0, max_new_tokens=4))],
    external=[question],
)
'''


def test_an_llm_component_of_a_system_chats_through_a_remote_model_actor(tmp_path: Path, tiny_gguf: str) -> None:
    out = subprocess.run([sys.executable, "-m", "tests.embagents.models.test_remote_system", tiny_gguf, str(tmp_path)],
                         capture_output=True, text=True, timeout=180, cwd=Path(__file__).parents[3])
    assert out.returncode == 0 and out.stdout.strip().endswith("OK"), out.stdout + out.stderr[-3000:]


def scenario(tiny_gguf: str, tmp_path: Path) -> None:
    tmp_path.chmod(0o700)
    server_pub, server_key = write_keypair(str(tmp_path), "server")
    client_pub, client_key = write_keypair(str(tmp_path), "client")
    endpoint = f"tcp://127.0.0.1:{free_port()}"
    path = str(tmp_path / "system.py")
    Path(path).write_text(textwrap.dedent(SYSTEM).replace("ENDPOINT", repr(endpoint))
                          .replace("SERVER_KEY", repr(server_pub.decode())).replace("CLIENT_KEY", repr(client_key)))
    remember_system(path, load_system(path))
    with ActorSystem() as asys:
        # The "GPU box": a remote model actor that only the client's key may reach, and only over TCP.
        asys.spawn(RemoteModelActor, "gpu_llm", "llama", tiny_gguf, {"n_ctx": 512}, False, None, [endpoint],
                   server_key, [client_pub.decode()], wait=60)
        sup = start_supervisor(asys, SupervisorSpec(children=[
            ChildSpec("llm", (ComponentActor, (path, "llm")), lifecycle="active"),
        ]))
        try:
            pub = asys.rt.on_client(lambda: Publisher(asys.rt, "question"))
            llm = asys.ref("llm")

            def history() -> list:
                return llm.ask(Call("snapshot"), timeout=10).get()["history"]

            asys.rt.on_client(lambda: pub.publish(String(data="hello over there")))
            got = wait_until(lambda: len(history()) >= 2 and history(), 60, "the LLM's answer")
            assert got[0]["content"] == "hello over there" and got[1]["role"] == "assistant", got
            assert asys.ref("gpu_llm").ask("stats", timeout=5).get()["served"] == 1
        finally:
            sup.stop()


if __name__ == "__main__":
    scenario(sys.argv[1], Path(sys.argv[2]))
    print("OK")
