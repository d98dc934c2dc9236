"""A model actor with a warm standby: the standby loads the model ahead and takes over its endpoint."""

from __future__ import annotations

import os
import signal
import threading
from typing import Any

from actors import ActorSystem
from embagents.models import LocalModelClient
from embagents.models.actor import LlamaModelActor
from supervisor import ChildSpec, SupervisorSpec, start_supervisor
from supervisor.rootio import on_root
from supervisor.tree import Tree


def test_a_killed_model_actor_is_replaced_by_its_loaded_standby(tiny_gguf: str) -> None:
    # Spawned (not forked) processes: llama.cpp's threads never cross a fork here.
    with ActorSystem() as asys:
        seen: list[dict[str, Any]] = []
        ready = threading.Event()

        def on_event(ev: dict[str, Any]) -> None:
            seen.append(ev)
            if ev["event"] in ("standby_ready", "restarted"):
                ready.set()

        on_root(asys, lambda: Tree.of(asys).events.listeners.append(on_event))
        sup = start_supervisor(asys, SupervisorSpec(children=[
            ChildSpec("tiny_model", (LlamaModelActor, (tiny_gguf, {}, False)), standby=True, start_timeout=120)]),
            timeout=180)
        try:
            assert ready.wait(120), seen
            standby = next(e["pid"] for e in seen if e["event"] == "standby_ready")
            client = LocalModelClient("tiny_model", timeout=60)
            messages = [{"role": "user", "content": "hi"}]
            assert client.chat(messages, max_tokens=2)["finish_reason"]
            ready.clear()
            os.kill(next(c.pid for c in sup.which_children() if c.id == "tiny_model"), signal.SIGKILL)
            assert ready.wait(60), seen
            restarted = next(e for e in seen if e["event"] == "restarted")
            assert restarted["standby"] is True and restarted["pid"] == standby
            assert client.chat(messages, max_tokens=2)["finish_reason"]  # served by the standby
            assert asys.ref("tiny_model").ask("stats", timeout=10).get()["served"] >= 1
        finally:
            sup.stop()
            Tree.of(asys).close()
