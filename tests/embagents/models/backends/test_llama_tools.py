"""Grammar-constrained tool calls: even a random-weight model's reply is a valid call of a declared tool."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator

import pytest

pytest.importorskip("llama_cpp")

from llama_cpp import LlamaGrammar  # noqa: E402

from embagents.models.backends.llama import (  # noqa: E402
    LlamaBackend,
    calls_as_text,
    tool_call_schema,
    tool_prompt_messages,
)

pytestmark = pytest.mark.llama_in_process  # see tests/conftest.py


def tool(name: str, **props: str) -> dict:
    return {"type": "function", "function": {"name": name, "description": f"{name} something",
            "parameters": {"type": "object", "properties": {k: {"type": t} for k, t in props.items()},
                           "required": list(props)}}}


TOOLS = [tool("locate", what="string"), tool("near", x="number", y="number")]


@pytest.fixture(scope="module")
def tiny(tiny_gguf: str) -> Iterator[LlamaBackend]:
    backend = LlamaBackend(tiny_gguf, n_ctx=1024)
    backend.load()
    yield backend
    backend.close()


def test_a_required_tool_call_is_always_a_valid_call(tiny: LlamaBackend) -> None:
    for seed_text in ("where is the cup?", "hello", "go"):
        reply = tiny.chat([{"role": "user", "content": seed_text}], tools=TOOLS, tool_choice="required",
                          max_tokens=200, temperature=0.0)
        assert reply["finish_reason"] == "tool_calls", reply
        (call,) = reply["tool_calls"]
        assert call["name"] in ("locate", "near")
        args = call["arguments"]
        assert isinstance(args, dict)
        if call["name"] == "locate":
            assert set(args) == {"what"} and isinstance(args["what"], str) and len(args["what"]) <= 80
        else:
            assert set(args) == {"x", "y"} and all(isinstance(v, (int, float)) for v in args.values())


def test_a_named_tool_choice_calls_that_tool(tiny: LlamaBackend) -> None:
    reply = tiny.chat([{"role": "user", "content": "hi"}], tools=TOOLS, max_tokens=200, temperature=0.0,
                      tool_choice={"type": "function", "function": {"name": "near"}})
    assert [c["name"] for c in reply["tool_calls"]] == ["near"]


def test_the_tools_are_described_before_the_question_and_calls_shown_as_text() -> None:
    dim = tool("dim", room="string", percent="integer")
    dim["function"]["parameters"]["properties"]["room"]["description"] = "the room, as the user names it"
    msgs = tool_prompt_messages([{"role": "system", "content": "Be brief."}, {"role": "user", "content": "Where?"}],
                                [*TOOLS, dim])
    assert msgs[0] == {"role": "system", "content": "Be brief."}
    assert msgs[1]["content"].startswith(
        'Tools:\n- locate: locate something Call: {"name": "locate", "arguments": {"what": "..."}} (what: string)\n'
        '- near: near something Call: {"name": "near", "arguments": {"x": 0, "y": 0}} (x: number, y: number)\n'
        '- dim: dim something Call: {"name": "dim", "arguments": {"room": "...", "percent": 0}} '
        '(room: string (the room, as the user names it), percent: integer)\n')
    assert msgs[1]["content"].endswith("\n\nQuestion: Where?")
    call = {"role": "assistant", "content": "", "tool_calls": [
        {"id": "1", "type": "function", "function": {"name": "near", "arguments": '{"x": 1, "y": 2}'}}]}
    assert calls_as_text([call])[0]["content"] == '{"name": "near", "arguments": {"x": 1, "y": 2}}'
    assert calls_as_text([call], as_json=False)[0]["content"] == "I called near(x=1, y=2)."


def test_the_grammar_refuses_a_placeholder_as_a_string_argument() -> None:
    room = tool("switch_on", room="string")
    colour = tool("paint", colour="string")
    colour["function"]["parameters"]["properties"]["colour"]["enum"] = ["red", "..."]
    options = tool_call_schema([room, colour])["oneOf"]
    pattern = options[0]["properties"]["arguments"]["properties"]["room"]["pattern"]
    for placeholder in ("...", "\u2026", " garage", ""):
        assert re.fullmatch(pattern, placeholder) is None, placeholder
    assert re.fullmatch(pattern, "garage") and re.fullmatch(pattern, "x" * 80) and not re.fullmatch(pattern, "x" * 81)
    assert "pattern" not in options[1]["properties"]["arguments"]["properties"]["colour"]  # the schema's own enum
    LlamaGrammar.from_json_schema(json.dumps({"oneOf": options}), verbose=False)  # llama.cpp takes it

