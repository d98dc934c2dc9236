"""A token stream that its client abandons stops in the llama.cpp model actor (the next utterance
interrupts the last answer).

Runs in a fresh interpreter: the fork server forks from the process that creates the ActorSystem,
and llama.cpp's OpenMP threads do not survive a fork (see tests/embagents/runtime/test_llm_restart.py).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("llama_cpp")


def test_an_abandoned_stream_is_cancelled_in_the_model_actor(tiny_gguf: str) -> None:
    out = subprocess.run([sys.executable, "-m", "tests.embagents.models.test_stream_cancel", tiny_gguf],
                         capture_output=True, text=True, timeout=180, cwd=Path(__file__).parents[3])
    assert out.returncode == 0 and out.stdout.strip().endswith("OK"), out.stdout + out.stderr[-3000:]


def scenario(model: str) -> None:
    import embagents.msgs  # noqa: F401 - registers the message types
    from actors import ActorSystem
    from embagents.models import LocalModelClient
    from embagents.models.actor import LlamaModelActor
    from tests.helpers import wait_until

    hello = [{"role": "user", "content": "Tell me a long story."}]
    with ActorSystem() as asys:
        asys.spawn(LlamaModelActor, "llm", model, {"n_ctx": 512}, False, wait=120)
        client = LocalModelClient("llm")
        stream = client.chat_stream(hello, max_tokens=400)
        assert "delta" in next(stream) and "delta" in next(stream)
        stream.close()  # the caller moved on: the request is cancelled in the actor
        stats = asys.ref("llm")

        def cancelled() -> bool:
            return bool(stats.ask("stats", timeout=10).get()["cancelled"] == 1)

        wait_until(cancelled, 30, "the model actor to stop the abandoned stream")
        reply = client.chat(hello, max_tokens=3)  # the actor is free at once for the next request
        assert reply["finish_reason"] == "length" and reply["usage"]["completion_tokens"] == 3, reply


if __name__ == "__main__":
    scenario(sys.argv[1])
    print("OK")
