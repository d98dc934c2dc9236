"""LLM: prompts, history, streaming shapes, tools, snapshot; one run on a real tiny llama."""

from __future__ import annotations

import importlib.util
import json

import pytest

from actors.codec import Codec
from embagents.components import LLM, ComponentError, HealthStatus, LLMConfig
from embagents.config import ConfigError
from embagents.models.chat import tool_calls_from_text
from embagents.msgs import StreamingString, String
from embagents.topic import Topic

QUESTION = Topic("question", String)
CONTEXT = Topic("robot/place", String)
ANSWER = Topic("answer", String)
STREAM = Topic("answer_stream", StreamingString)


class ScriptedClient:
    """Replies with the next scripted reply: a str, or a dict {"text", "tool_calls"}."""

    def __init__(self, *replies):
        self.replies = list(replies)
        self.calls: list[tuple[list[dict], dict]] = []

    def chat_stream(self, messages, **options):
        self.calls.append((json.loads(json.dumps(messages)), options))
        reply = self.replies.pop(0) if len(self.replies) > 1 else self.replies[0]
        if isinstance(reply, Exception):
            yield {"delta": "par"}
            raise reply
        text, calls = (reply, None) if isinstance(reply, str) else (reply["text"], reply["tool_calls"])
        for word in text.split(" "):
            if word:
                yield {"delta": word + " "}
        yield {"done": True, "finish_reason": "tool_calls" if calls else "stop", "tool_calls": calls}


def make(client=None, outputs=(ANSWER,), inputs=(QUESTION,), **cfg) -> tuple[LLM, list]:
    llm = LLM(name="llm", inputs=list(inputs), outputs=list(outputs),
              model_client=client or ScriptedClient("ok"), config=LLMConfig(**cfg))
    sent: list = []
    llm.attach(lambda topic, msg: sent.append((topic, msg)))
    return llm, sent


def ask(llm: LLM, text: str, topic: str = "question") -> bool:
    return llm.on_message(topic, String(text)) and llm.execute()


# --- config and templates -------------------------------------------------------------


@pytest.mark.parametrize(
    ("template", "match"),
    [("Answer: {}", "plain name"), ("Answer: {question}", "must contain the {text}"),
     ("{text", "not a valid format string"), ("{text.upper}", "plain name")],
)
def test_bad_templates(template, match):
    with pytest.raises(ConfigError, match=match):
        LLMConfig(prompt_template=template)


def test_template_placeholder_must_be_an_input():
    with pytest.raises(ComponentError, match=r"component 'llm'.*\{place\} is not an input; allowed: text, question"):
        make(prompt_template="{place}: {text}")


def test_template_filled_with_text_and_other_inputs():
    client = ScriptedClient("fine")
    llm, _ = make(client, inputs=(QUESTION, CONTEXT), prompt_template="At {robot_place}: {text}",
                  system_prompt="Be brief.")
    assert llm.on_message("robot/place", String("kitchen")) is False  # context does not trigger
    assert ask(llm, "where am I?")
    assert client.calls[0][0] == [
        {"role": "system", "content": "Be brief."},
        {"role": "user", "content": "At kitchen: where am I?"},
    ]


def test_generation_options_are_passed():
    client = ScriptedClient("x")
    llm, _ = make(client, max_new_tokens=7, temperature=0.1, stop=["\n"])
    ask(llm, "hi")
    assert client.calls[0][1] == {"max_tokens": 7, "temperature": 0.1, "stop": ["\n"], "tools": None}


def test_llmconfig_converters_and_validation():
    cfg = LLMConfig(history_size="3", chat_history="yes", temperature="0.2")
    assert (cfg.history_size, cfg.chat_history, cfg.temperature) == (3, True, 0.2)
    for bad in ({"history_size": 0}, {"temperature": -1}, {"chat_history": "maybe"}, {"max_new_tokens": 1.5}):
        with pytest.raises(ConfigError):
            LLMConfig(**bad)


# --- history --------------------------------------------------------------------------


def test_history_is_kept_to_history_size_turns():
    client = ScriptedClient("a1", "a2", "a3")
    llm, _ = make(client, chat_history=True, history_size=2)
    for q in ("q1", "q2", "q3"):
        ask(llm, q)
    assert [m["content"] for m in llm.history] == ["q2", "a2 ", "q3", "a3 "]
    assert [m["content"] for m in client.calls[2][0]] == ["q1", "a1 ", "q2", "a2 ", "q3"]
    llm.reset_history()
    ask(llm, "q4")
    assert [m["content"] for m in client.calls[3][0]] == ["q4"]


def test_without_chat_history_nothing_is_remembered():
    client = ScriptedClient("a")
    llm, _ = make(client)
    ask(llm, "q1")
    ask(llm, "q2")
    assert client.calls[1][0] == [{"role": "user", "content": "q2"}] and llm.history == []


def test_snapshot_restore_roundtrips_through_msgpack():
    llm, _ = make(ScriptedClient("a1", "a2"), chat_history=True)
    ask(llm, "q1")
    codec = Codec()
    state = codec.decode(codec.encode(llm.snapshot())[0])
    fresh, _ = make(ScriptedClient("b"), chat_history=True, history_size=1)
    fresh.restore(state)
    assert fresh.history == llm.history
    with pytest.raises(ValueError, match="restore"):
        fresh.restore({"history": "nope"})


# --- publishing -----------------------------------------------------------------------


def test_non_streaming_publishes_one_string():
    llm, sent = make(ScriptedClient("Paris is nice"))
    assert ask(llm, "capital?")
    assert sent == [("answer", String("Paris is nice "))]


def test_streaming_publishes_deltas_then_done_with_one_stream_id():
    llm, sent = make(ScriptedClient("one two"), outputs=(STREAM, ANSWER), stream=True)
    ask(llm, "count")
    stream = [m for t, m in sent if t == "answer_stream"]
    assert [(m.data, m.done) for m in stream] == [("one ", False), ("two ", False), ("", True)]
    assert len({m.stream_id for m in stream}) == 1 and stream[0].stream_id.startswith("llm-")
    assert sent[-1] == ("answer", String("one two "))
    ask(llm, "again")
    assert sent[-2][1].stream_id != stream[0].stream_id


def test_not_streaming_to_a_streaming_output_sends_one_chunk_and_done():
    llm, sent = make(ScriptedClient("all at once"), outputs=(STREAM,))
    ask(llm, "q")
    assert [(m.data, m.done) for _, m in sent] == [("all at once ", False), ("", True)]


def test_stream_true_needs_a_streaming_output():
    with pytest.raises(ComponentError, match="component 'llm'.*stream=True needs a StreamingString output"):
        make(stream=True)


def test_client_failure_closes_the_stream_and_reports_algorithm_failure():
    llm, sent = make(ScriptedClient(RuntimeError("model gone")), outputs=(STREAM,), stream=True)
    assert ask(llm, "q") is False
    assert [(m.data, m.done) for _, m in sent] == [("par", False), ("", True)]
    assert llm.health_status is HealthStatus.ALGORITHM_FAILURE and "model gone" in llm.health.text


def test_rate_triggered_llm_answers_each_question_once():
    client = ScriptedClient("a")
    llm = LLM(name="llm", inputs=[QUESTION], outputs=[ANSWER], model_client=client, trigger=2.0)
    llm.attach(lambda t, m: None)
    assert llm.rate_hz == 2.0
    llm.on_message("question", String("q"))
    assert llm.execute() and llm.execute()
    assert len(client.calls) == 1


def test_default_trigger_is_first_input_and_none_makes_a_server():
    llm, _ = make()
    assert llm.trigger_topics == (QUESTION,)
    server = LLM(name="s", inputs=[QUESTION], outputs=[ANSWER], model_client=ScriptedClient("a"), trigger=None)
    assert server.trigger_kind == "none"
    server.attach(lambda t, m: None)
    assert server.answer("direct") == "a "


# --- tools ----------------------------------------------------------------------------


def test_tool_call_is_run_and_result_fed_back():
    calls = []

    def get_weather(city: str, unit: str = "C") -> dict:
        """Weather in a city."""
        calls.append((city, unit))
        return {"temp": 21, "unit": unit}

    client = ScriptedClient(
        {"text": "", "tool_calls": [{"id": "c1", "name": "get_weather", "arguments": {"city": "Oslo"}}]},
        "It is 21 C.",
    )
    llm, sent = make(client, tools={"get_weather": get_weather}, chat_history=True)
    ask(llm, "weather in Oslo?")
    assert calls == [("Oslo", "C")]
    spec = client.calls[0][1]["tools"][0]["function"]
    assert spec["name"] == "get_weather" and spec["parameters"]["required"] == ["city"]
    second = client.calls[1][0]
    assert second[1]["tool_calls"][0]["function"] == {"name": "get_weather", "arguments": '{"city": "Oslo"}'}
    assert second[2] == {"role": "tool", "tool_call_id": "c1", "name": "get_weather",
                         "content": '{"temp": 21, "unit": "C"}'}
    assert sent == [("answer", String("It is 21 C. "))]
    assert [m["role"] for m in llm.history] == ["user", "assistant", "tool", "assistant"]


def test_unknown_tool_and_tool_errors_are_fed_back_not_raised():
    def boom() -> str:
        raise OSError("sensor offline")

    client = ScriptedClient(
        {"text": "", "tool_calls": [{"function": {"name": "nope", "arguments": "{}"}},
                                    {"function": {"name": "boom", "arguments": "{}"}}]},
        "sorry",
    )
    llm, _ = make(client, tools={"boom": boom})
    ask(llm, "q")
    results = [m["content"] for m in client.calls[1][0] if m["role"] == "tool"]
    assert results[0] == "error: unknown tool 'nope'; available tools: boom"
    assert results[1] == "error: OSError: sensor offline"


def test_tool_rounds_are_bounded():
    looping = {"text": "", "tool_calls": [{"name": "ping", "arguments": {}}]}
    client = ScriptedClient(looping)
    llm, _ = make(client, tools={"ping": lambda: "pong"}, max_tool_rounds=2)
    ask(llm, "q")
    assert [c[1]["tools"] is not None for c in client.calls] == [True, True, True]
    assert [c[1].get("tool_choice") for c in client.calls] == [None, None, "none"]  # the last answers in text


class CallsWheneverAllowed(ScriptedClient):
    """A model that answers every request with a tool call unless tool_choice="none" (what SmolLM2 did)."""

    def chat_stream(self, messages, **options):
        if options.get("tool_choice") == "none":
            return super().chat_stream(messages, **options)
        call = {"name": "open_gate", "arguments": {"gate": "north"}}
        self.calls.append((json.loads(json.dumps(messages)), options))
        return iter([{"delta": json.dumps(call)}, {"done": True, "finish_reason": "tool_calls", "tool_calls": [call]}])


def test_the_answer_after_a_tool_result_is_text_not_a_tool_call():
    opened = []

    def open_gate(gate: str) -> str:
        """Open a gate of the yard."""
        opened.append(gate)
        return f"the {gate} gate is open"

    client = CallsWheneverAllowed("The north gate is open now.")
    llm, sent = make(client, tools={"open_gate": open_gate}, tool_choice="required")
    ask(llm, "Open the north gate, please.")
    assert opened == ["north"]  # called once: the reply after the result was not another call
    assert [c[1].get("tool_choice") for c in client.calls] == ["required", "none"]
    answer = sent[-1][1].data
    assert answer == "The north gate is open now. " and tool_calls_from_text(answer, llm.tool_specs()) is None


def test_tool_schemas_must_name_tools():
    with pytest.raises(ConfigError, match="not in tools: ghost"):
        LLMConfig(tools={}, tool_schemas={"ghost": {}})


# --- a real model ---------------------------------------------------------------------

_HAVE_LLAMA = (
    importlib.util.find_spec("embagents.models.backends.llama") is not None
    and importlib.util.find_spec("llama_cpp") is not None
    and importlib.util.find_spec("gguf") is not None
)


@pytest.mark.skipif(not _HAVE_LLAMA, reason="needs embagents.models.backends.llama, llama-cpp-python and gguf")
@pytest.mark.llama_in_process  # see tests/conftest.py
def test_llm_streams_from_a_real_llama_backend(tiny_gguf):
    from embagents.models.backends.llama import LlamaBackend

    backend = LlamaBackend(tiny_gguf)
    try:
        llm, sent = make(backend, outputs=(STREAM, ANSWER), stream=True, max_new_tokens=2,
                         temperature=0.0, chat_history=True, system_prompt="You are tiny.")
        llm.warmup = True
        llm.on_configure()
        assert ask(llm, "Hello there")
        stream = [m for t, m in sent if t == "answer_stream"]
        assert stream[-1].done and stream[-1].data == "" and not any(m.done for m in stream[:-1])
        full = sent[-1][1].data
        assert sent[-1][0] == "answer" and full == "".join(m.data for m in stream)
        assert llm.history[-1] == {"role": "assistant", "content": full}
        assert ask(llm, "And again")  # the history goes through the real chat template
        assert len(llm.history) == 4
    finally:
        backend.close()


def switch_on(room: str) -> str:
    """Switch on the lights in a room.

    Args:
        room: the room, as the user names it
    """
    return f"the lights in the {room} are on"


def set_heating(room: str, celsius: float) -> str:
    """Set the heating of a room to a temperature."""
    return "ok"


@pytest.mark.skipif(not _HAVE_LLAMA, reason="needs embagents.models.backends.llama, llama-cpp-python and gguf")
@pytest.mark.llama_in_process  # see tests/conftest.py
def test_smollm2_fills_a_held_out_request_and_answers_the_tool_result_in_a_sentence():
    from embagents.models.backends.llama import LlamaBackend
    from embagents.models.files.hub import default_llm_path

    backend = LlamaBackend(default_llm_path(progress=False))
    calls: list[str] = []

    def lights(room: str) -> str:
        calls.append(room)
        return switch_on(room)

    lights.__doc__ = switch_on.__doc__
    try:
        llm, sent = make(backend, tools={"switch_on": lights, "set_heating": set_heating}, tool_choice="required",
                         max_tool_rounds=1, temperature=0.0, max_new_tokens=48)
        phrasings = ["Please switch on the lights in the garage.", "Switch on the garage lights.",
                     "Turn the lights on in the garage, please.", "Can you switch the light on in the garage?"]
        for text in phrasings:
            assert ask(llm, text)
        # The prompt showed a sample call with "..." for strings: SmolLM2 copied it in every phrasing.
        assert calls == ["garage"] * 4
        for _, msg in sent:
            assert tool_calls_from_text(msg.data, llm.tool_specs()) is None and not msg.data.lstrip().startswith("{")
            assert "garage" in msg.data, msg.data
    finally:
        backend.close()
