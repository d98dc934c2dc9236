"""``llm_stream_overhead``: tokens per second through the runtime vs llama.cpp in-process.

The runtime path is the real one: a model actor (llama.cpp in its own
process) streams to an LLM component (in a second process) that publishes
each token as a StreamingString, received by a subscriber actor in a third
process. The baseline calls llama-cpp-python in this process on the same
model, prompt and settings. ``ratio`` = runtime tokens/s ÷ in-process tokens/s.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import time
from typing import Any

import embagents.msgs  # noqa: F401 - registers the message types this case decodes
from actors import Actor, ActorSystem
from embagents.bench.registry import BenchOptions, case
from embagents.components import LLM, LLMConfig
from embagents.models import LocalModelClient
from embagents.models.actor import LlamaModelActor
from embagents.models.files.hub import default_llm_path
from embagents.msgs import StreamingString, String
from embagents.topic import Topic

__all__ = ["StreamCounter", "StreamingLLM"]

PROMPT = "List the planets of the solar system, one per line."
MODEL_ACTOR = "bench_llm_model"


class StreamingLLM(Actor):
    """An LLM component (the real class) hosted in an actor, asked to answer one question."""

    def on_start(self) -> None:
        self.llm = LLM(
            name="bench_llm",
            inputs=[Topic("bench_in", String)],
            outputs=[Topic("bench_stream", StreamingString)],
            model_client=LocalModelClient(MODEL_ACTOR),
            config=LLMConfig(stream=True, temperature=0.0, max_new_tokens=self.max_tokens),
        )
        self.llm.attach(lambda topic, msg: self.context.publish(topic, msg))

    def __init__(self, max_tokens: int) -> None:
        self.max_tokens = max_tokens

    def on_receive(self, message: Any) -> Any:
        t0 = time.monotonic()
        self.llm.answer(message)
        return t0


class StreamCounter(Actor):
    """Counts streamed chunks and notes when the last one arrived."""

    def on_start(self) -> None:
        self.chunks = 0
        self.last = 0.0
        self.done = False
        self.context.subscribe("bench_stream", self._on_chunk, queue_size=10000, keep="all")

    def _on_chunk(self, chunk: Any) -> None:
        if chunk.data:
            self.chunks += 1
            self.last = time.monotonic()
        if chunk.done:
            self.done = True

    def on_receive(self, message: Any) -> Any:
        if message == "reset":
            self.chunks, self.last, self.done = 0, 0.0, False
            return None
        return {"chunks": self.chunks, "last": self.last, "done": self.done}


def _inprocess(path: str, max_tokens: int) -> tuple[int, float]:
    """llama-cpp-python called in a fresh interpreter (same settings), so this process never
    runs llama.cpp: its OpenMP threads would not survive the fork of a later ActorSystem."""
    code = (
        "import json, sys, time\n"
        "from embagents.models.backends.llama import LlamaBackend\n"
        "b = LlamaBackend(sys.argv[1]); b.load(); b.warmup()\n"
        "t0 = time.monotonic(); n = 0\n"
        "for c in b.chat_stream([{'role': 'user', 'content': sys.argv[3]}], max_tokens=int(sys.argv[2]), temperature=0.0):\n"
        "    n += 1 if c.get('delta') else 0\n"
        "print(json.dumps([n, time.monotonic() - t0]))\n"
    )
    out = subprocess.run([sys.executable, "-c", code, path, str(max_tokens), PROMPT],
                         capture_output=True, text=True, timeout=600, check=True)
    n, dt = json.loads(out.stdout.strip().splitlines()[-1])
    return int(n), float(dt)


@case("llm_stream_overhead", transport="embagents", kind="llm", needs="llama_cpp")
def llm_stream_overhead(opts: BenchOptions) -> dict[str, Any]:
    path = default_llm_path()
    max_tokens = 24 if opts.quick else 64
    rounds = 1 if opts.quick else 5
    runtime_tps: list[float] = []
    baseline_tps: list[float] = []
    with ActorSystem() as asys:
        asys.spawn(LlamaModelActor, MODEL_ACTOR, path, {}, True, wait=300, heartbeat=None)
        counter = asys.spawn(StreamCounter, "bench_llm_counter")
        llm = asys.spawn(StreamingLLM, "bench_llm_component", max_tokens)
        llm.ask("Hi", timeout=120).get()  # warm the whole path once
        for _ in range(rounds):  # interleaved, so drifts of the machine hit both alike
            counter.ask("reset", timeout=10).get()
            t0 = llm.ask(PROMPT, timeout=300).get()
            deadline = time.monotonic() + 10
            while not (got := counter.ask("stats", timeout=10).get())["done"] and time.monotonic() < deadline:
                time.sleep(0.01)
            runtime_tps.append(got["chunks"] / (got["last"] - t0))
            n, dt = _inprocess(path, max_tokens)  # the model actor idles meanwhile
            baseline_tps.append(n / dt)
    ours, base = statistics.median(runtime_tps), statistics.median(baseline_tps)
    return {
        "p50_us": 1e6 / ours,
        "p99_us": 1e6 / min(runtime_tps),
        "msgs_per_s": ours,
        "ratio": ours / base,
        "baseline_tokens_per_s": base,
        "note": f"{max_tokens} tokens, SmolLM2-135M, median of {rounds}; bar: ratio >= 0.95",
    }
