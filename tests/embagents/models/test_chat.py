"""The chat shapes every chat client shares: chunks normalised whatever the client returns."""

from __future__ import annotations

from typing import Any

from embagents.models.chat import chat_chunks

DONE = {"done": True, "finish_reason": "stop", "tool_calls": None}


def test_a_chat_only_client_answering_a_dict_is_normalised_to_chunks() -> None:
    class ChatOnly:
        def chat(self, messages: list[dict[str, Any]], **options: Any) -> dict[str, Any]:
            return {"content": "whole", "finish_reason": "length", "tool_calls": None}

    assert list(chat_chunks(ChatOnly(), [{"role": "user", "content": "x"}])) == [
        {"delta": "whole"}, {"done": True, "finish_reason": "length", "tool_calls": None},
    ]


def test_a_stream_without_a_done_chunk_ends_with_one_and_empty_tool_calls_are_none() -> None:
    class Streaming:
        def chat_stream(self, messages: list[dict[str, Any]], **options: Any) -> Any:
            yield {"delta": "a"}
            yield {"delta": ""}
            yield {"delta": "b", "extra": 1}

    assert list(chat_chunks(Streaming(), [])) == [{"delta": "a"}, {"delta": "b"}, DONE]

    class EmptyCalls:
        def chat_stream(self, messages: list[dict[str, Any]], **options: Any) -> Any:
            yield {"done": True, "tool_calls": []}
            yield {"delta": "after the end"}

    assert list(chat_chunks(EmptyCalls(), [])) == [DONE]


def test_options_reach_the_client() -> None:
    seen: dict[str, Any] = {}

    class Plain:
        def chat(self, messages: list[dict[str, Any]], **options: Any) -> str:
            seen.update(options)
            return "ok"

    assert list(chat_chunks(Plain(), [], max_tokens=3)) == [{"delta": "ok"}, DONE]
    assert seen == {"max_tokens": 3}
