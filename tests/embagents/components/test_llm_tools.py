"""Actions as LLM tools: a tool call crosses from the LLM to the events actor to the component's actor."""

from __future__ import annotations

import textwrap
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("onnxruntime")
pytest.importorskip("apsw")

from actors import ActorSystem  # noqa: E402
from embagents.components import LLM, LLMConfig, Memory  # noqa: E402
from embagents.components.llm_tools import RemoteTool, register_tools_on, tool, tool_methods  # noqa: E402
from embagents.models.actor import ModelActor  # noqa: E402
from embagents.msgs import String  # noqa: E402
from embagents.requests import Call  # noqa: E402
from embagents.runtime.component_actor import ComponentActor  # noqa: E402
from embagents.runtime.events_actor import EventsActor  # noqa: E402
from embagents.supervision import build_spec  # noqa: E402
from embagents.system import (
    load_system,  # noqa: E402
    remember_system,  # noqa: E402
)
from embagents.topic import Topic  # noqa: E402

SYSTEM = '''
from embagents import (EmbeddingModel, LLM, LLMConfig, LocalModelClient, MapLayer, Memory, MemoryConfig, Odometry,
                       String, System, Topic, register_tools_on)

class Scripted:
    """A chat client that calls a tool, then answers with what the tool said."""
    name = "scripted"
    def chat_stream(self, messages, **options):
        if messages[-1]["role"] == "tool":
            yield {"delta": "tool said: " + messages[-1]["content"]}
            yield {"done": True, "finish_reason": "stop", "tool_calls": None}
        else:
            yield {"done": True, "finish_reason": "tool_calls",
                   "tool_calls": [{"id": "c1", "name": "locate", "arguments": ARGS}]}

minilm = EmbeddingModel(name="minilm", local_model_path=MODEL)
memory = Memory(name="memory", position=Topic("odom", Odometry), embedding_client=LocalModelClient(minilm),
                layers=[MapLayer(subscribes_to=Topic("notes", String))], config=MemoryConfig(db_path=DB))
llm = LLM(name="llm", inputs=[Topic("q", String)], outputs=[Topic("a", String)], model_client=Scripted(),
          config=LLMConfig(max_tool_rounds=1))
register_tools_on(llm, memory, methods=["locate", "remember"])
system = System([memory, llm], models=[minilm])
'''


@pytest.fixture()
def running(minilm_dir: str, tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[ActorSystem]:
    path = str(tmp_path / "system.py")
    Path(path).write_text(textwrap.dedent(SYSTEM).replace("MODEL", repr(minilm_dir))
                          .replace("DB", repr(str(tmp_path / "m.db"))).replace("ARGS", repr(request.param)))
    system = load_system(path)
    remember_system(path, system)
    assert "_events" in [c.id for c in build_spec(system, path).children]  # remote tools bring the events actor
    with ActorSystem() as asys:
        asys.spawn(ModelActor, "minilm", "embedding", minilm_dir, {}, False, wait=60)
        asys.spawn(ComponentActor, "memory", path, "memory", wait=30)
        asys.spawn(ComponentActor, "llm", path, "llm", wait=30)
        asys.spawn(EventsActor, "_events", path, wait=30)
        yield asys


@pytest.mark.parametrize("running", [{"what": "cup"}], indirect=True)
def test_the_llm_calls_a_memory_query_in_another_process(running: ActorSystem) -> None:
    running.ref("memory").ask(Call("remember", ["a red cup"]), timeout=30).get()
    answer = running.ref("llm").ask(Call("answer", ["where is the cup?"]), timeout=60).get()
    assert answer.startswith("tool said: I last saw a red cup")
    assert RemoteTool("memory", "locate", Memory.locate)(what="cup")["text"] == "a red cup"


@pytest.mark.parametrize("running", [{"where": "cup"}], indirect=True)
def test_bad_arguments_go_back_to_the_model_as_the_tool_result(running: ActorSystem) -> None:
    answer = running.ref("llm").ask(Call("answer", ["where is the cup?"]), timeout=60).get()
    assert answer == ("tool said: error: TypeError: bad arguments for locate(what: str): missing a required "
                      "argument: 'what'; got {'where': 'cup'}")
    assert running.ref("memory").ask(Call("count"), timeout=30).get() == 0  # nothing ran, the memory is fine


def test_marked_methods_and_llm_tools_are_offered_and_get_schemas() -> None:
    class Arm(Memory):
        @tool
        def wave(self, times: int = 1) -> str:
            """Wave the arm."""
            return "waved"

    assert tool_methods(Memory.__new__(Memory)) == ["locate", "query", "near", "between"]
    assert tool_methods(Arm.__new__(Arm))[-1] == "wave"
    llm = LLM(name="llm", inputs=[Topic("q", String)], outputs=[Topic("a", String)], model_client=_Echo(),
              config=LLMConfig())
    mem = Memory.__new__(Memory)
    mem.name = "memory"
    assert register_tools_on(llm, mem) == ["locate", "query", "near", "between"]
    specs = {s["function"]["name"]: s["function"] for s in llm.tool_specs()}
    assert specs["locate"]["description"] == "Where an object was last seen, and when."
    assert specs["near"]["parameters"]["required"] == ["x", "y"]
    assert specs["between"]["parameters"]["properties"]["end"] == {"type": "number"}
    with pytest.raises(ValueError, match="no public method 'fly'"):
        register_tools_on(llm, mem, methods=["fly"])


class _Echo:
    name = "echo"

    def chat_stream(self, messages: list[dict[str, Any]], **options: Any) -> Iterator[dict[str, Any]]:
        yield {"done": True, "finish_reason": "stop", "tool_calls": None}
