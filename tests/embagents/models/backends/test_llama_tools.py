"""Grammar-constrained tool calls: even a random-weight model's reply is a valid call of a declared tool."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

pytest.importorskip("llama_cpp")

from embagents.models.backends.llama import LlamaBackend, calls_as_text, tool_prompt_messages  # noqa: E402

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
    msgs = tool_prompt_messages([{"role": "system", "content": "Be brief."}, {"role": "user", "content": "Where?"}],
                                TOOLS)
    assert msgs[0] == {"role": "system", "content": "Be brief."}
    assert msgs[1]["content"].startswith("Tools:\n- locate: locate something Call: "
                                         '{"name": "locate", "arguments": {"what": "..."}}')
    assert msgs[1]["content"].endswith("\n\nQuestion: Where?")
    shown = calls_as_text([{"role": "assistant", "content": "", "tool_calls": [
        {"id": "1", "type": "function", "function": {"name": "near", "arguments": '{"x": 1, "y": 2}'}}]}])
    assert shown[0]["content"] == '{"name": "near", "arguments": {"x": 1, "y": 2}}'
