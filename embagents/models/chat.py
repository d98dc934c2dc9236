"""The chat concept, in one place: message checks, the chunk stream, tool calls, the client protocol.

Every chat backend (llama.cpp) and client (a local model actor, an
OpenAI-compatible server) speaks this shape, so a component switches between
them without caring::

    {"delta": "text"}                                  # zero or more
    {"done": True, "finish_reason": "stop" | "length" | "tool_calls",
     "tool_calls": [{"id": str, "name": str, "arguments": dict | str}] | None,
     "usage": {"prompt_tokens": int, "completion_tokens": int, "total_tokens": int},
     "timing": {"first_token_s": float | None, "total_s": float}}   # exactly one, last

Tool calls are normalised one way (:func:`normalize_tool_call`: a flat
``{"id", "name", "arguments"}``); :func:`openai_tool_call` turns one back into
the OpenAI message shape that goes into a chat history.

Example::

    >>> collect_stream([{"delta": "Hi"}, {"done": True, "finish_reason": "stop", "tool_calls": None}])["content"]
    'Hi'
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import Any, Protocol

__all__ = [
    "CHAT_OPTIONS",
    "ChatClient",
    "ToolCallAccumulator",
    "chat_chunks",
    "check_messages",
    "collect_stream",
    "normalize_tool_call",
    "openai_tool_call",
    "tool_calls_from_text",
    "with_images",
]

#: The generation options every chat client takes (backends may take more).
CHAT_OPTIONS = ("max_tokens", "temperature", "stop", "tools", "tool_choice")


class ChatClient(Protocol):
    """What a ModelComponent needs from a chat client: ``chat_stream`` yielding the chunks above."""

    def chat_stream(self, messages: list[dict[str, Any]], **options: Any) -> Iterator[dict[str, Any]]: ...


def collect_stream(chunks: Iterable[dict]) -> dict:
    """Fold a chunk stream into one reply dict (used by both backend and HTTP client).

    Example::

        >>> collect_stream([{"delta": "Hi"}, {"delta": "!"}, {"done": True, "finish_reason": "stop",
        ...                 "tool_calls": None, "usage": {}}])["content"]
        'Hi!'
    """
    parts: list[str] = []
    final: dict = {}
    for chunk in chunks:
        if "delta" in chunk:
            parts.append(chunk["delta"])
        if chunk.get("done"):
            final = chunk
    if not final:
        raise RuntimeError("chat stream ended without a final 'done' chunk")
    return {
        "content": "".join(parts),
        "tool_calls": final.get("tool_calls"),
        "finish_reason": final.get("finish_reason"),
        "usage": final.get("usage", {}),
        "timing": final.get("timing", {}),
    }


def check_messages(messages: list[dict]) -> None:
    """Fail early, with the offending index, on malformed chat messages.

    >>> check_messages([{"content": "hi"}])
    Traceback (most recent call last):
    ...
    ValueError: messages[0] must be a dict with a 'role' string, got {'content': 'hi'}
    """
    if not isinstance(messages, list) or not messages:
        raise ValueError(
            f"messages must be a non-empty list of dicts, got {type(messages).__name__}"
        )
    for i, msg in enumerate(messages):
        if not isinstance(msg, dict) or not isinstance(msg.get("role"), str):
            raise ValueError(f"messages[{i}] must be a dict with a 'role' string, got {msg!r}")
        content = msg.get("content")
        if content is not None and not isinstance(content, (str, list)):
            raise ValueError(
                f"messages[{i}]['content'] must be a string, got {type(content).__name__}"
            )


def _parse_arguments(arguments: Any) -> dict | str:
    """Decode JSON-string arguments to a dict; keep the raw string if they are not JSON."""
    if isinstance(arguments, dict):
        return arguments
    if arguments is None or arguments == "":
        return {}
    if isinstance(arguments, str):
        try:
            value = json.loads(arguments)
        except ValueError:
            return arguments
        return value if isinstance(value, dict) else arguments
    return str(arguments)


def normalize_tool_call(call: dict, index: int = 0) -> dict:
    """OpenAI/Ollama tool call -> ``{"id": str, "name": str, "arguments": dict | str}``.

    Example::

        >>> normalize_tool_call({"id": "c1", "type": "function",
        ...     "function": {"name": "go", "arguments": '{"x": 1}'}})
        {'id': 'c1', 'name': 'go', 'arguments': {'x': 1}}
    """
    function = call.get("function") or call
    return {
        "id": str(call.get("id") or f"call_{index}"),
        "name": str(function.get("name") or ""),
        "arguments": _parse_arguments(function.get("arguments", function.get("parameters"))),
    }


class ToolCallAccumulator:
    """Joins streamed OpenAI tool-call deltas (split ``arguments`` strings) by index."""

    def __init__(self) -> None:
        self._calls: dict[int, dict] = {}

    def add(self, deltas: list[dict]) -> None:
        for pos, delta in enumerate(deltas):
            index = delta.get("index", pos)
            call = self._calls.setdefault(index, {"id": None, "name": "", "arguments": ""})
            if delta.get("id"):
                call["id"] = delta["id"]
            function = delta.get("function") or {}
            if function.get("name"):
                call["name"] = function["name"]
            args = function.get("arguments")
            if isinstance(args, dict):  # Ollama sends whole objects, not fragments
                call["arguments"] = args
            elif args:
                call["arguments"] = (
                    call["arguments"] if isinstance(call["arguments"], str) else ""
                ) + args

    def result(self) -> list[dict] | None:
        if not self._calls:
            return None
        return [
            normalize_tool_call({"id": c["id"], "function": c}, i)
            for i, (_, c) in enumerate(sorted(self._calls.items()))
        ]


_FENCE_RE = re.compile(r"^```(?:json)?\s*(.*?)\s*```$", re.DOTALL)
_TAGGED_RE = re.compile(r"<tool_call>\s*(.*?)\s*</tool_call>", re.DOTALL)


def _tool_names(tools: list[dict] | None) -> set[str]:
    names = set()
    for tool in tools or []:
        function = tool.get("function") or tool
        if isinstance(function.get("name"), str):
            names.add(function["name"])
    return names


def tool_calls_from_text(text: str, tools: list[dict] | None) -> list[dict] | None:
    """Fallback for models without native tool calling: a reply that is only a JSON
    object ``{"name": ..., "arguments": ...}`` (or a list of them, or Hermes-style
    ``<tool_call>...</tool_call>`` blocks) naming a declared tool becomes tool calls.

    Example::

        >>> tools = [{"type": "function", "function": {"name": "go", "parameters": {}}}]
        >>> tool_calls_from_text('{"name": "go", "arguments": {"x": 1}}', tools)
        [{'id': 'call_0', 'name': 'go', 'arguments': {'x': 1}}]
        >>> tool_calls_from_text('go left', tools) is None
        True
    """
    names = _tool_names(tools)
    if not names or not text:
        return None
    stripped = text.strip()
    fenced = _FENCE_RE.match(stripped)
    if fenced:
        stripped = fenced.group(1)
    blobs = _TAGGED_RE.findall(stripped) or [stripped]
    objects: list[Any] = []
    for blob in blobs:
        try:
            value = json.loads(blob)
        except ValueError:
            return None
        objects.extend(value if isinstance(value, list) else [value])
    calls = []
    for i, obj in enumerate(objects):
        if not isinstance(obj, dict) or obj.get("name") not in names:
            return None  # not (only) tool calls: leave it as plain text
        calls.append(normalize_tool_call(obj, i))
    return calls or None


def openai_tool_call(call: Mapping[str, Any], index: int = 0) -> dict[str, Any]:
    """Any tool-call shape -> the OpenAI message shape (arguments as a JSON string) for a chat history.

    >>> openai_tool_call({"name": "go", "arguments": {"x": 1}})
    {'id': 'call_0', 'type': 'function', 'function': {'name': 'go', 'arguments': '{"x": 1}'}}
    """
    flat = normalize_tool_call(dict(call), index)
    args = flat["arguments"]
    return {"id": flat["id"], "type": "function",
            "function": {"name": flat["name"], "arguments": args if isinstance(args, str) else json.dumps(args)}}


def with_images(messages: list[dict[str, Any]], urls: Sequence[str]) -> list[dict[str, Any]]:
    """``messages`` with ``urls`` as OpenAI ``image_url`` parts before the text of the last user message.

    >>> with_images([{"role": "user", "content": "what?"}], ["u0"])[0]["content"]
    [{'type': 'image_url', 'image_url': {'url': 'u0'}}, {'type': 'text', 'text': 'what?'}]
    """
    if not urls:
        return messages
    last = max((i for i, m in enumerate(messages) if m.get("role") == "user"), default=None)
    if last is None:
        raise ValueError("images need a user message to go with; the messages have none")
    out = [dict(m) for m in messages]
    content = out[last].get("content") or ""
    parts = content if isinstance(content, list) else [{"type": "text", "text": content}]
    out[last]["content"] = [{"type": "image_url", "image_url": {"url": u}} for u in urls] + list(parts)
    return out


def chat_chunks(client: Any, messages: list[dict[str, Any]], **options: Any) -> Iterator[dict[str, Any]]:
    """Stream ``client``'s answer as ``{"delta"}``... then one ``{"done": True, "finish_reason", "tool_calls"}``.

    A client with only ``chat()`` may return a str, a dict with ``content``
    (or ``text``), or an iterator of chunks. The last chunk always has ``done``.

    >>> class Plain:
    ...     def chat(self, messages, **options):
    ...         return "hello"
    >>> list(chat_chunks(Plain(), [{"role": "user", "content": "hi"}]))
    [{'delta': 'hello'}, {'done': True, 'finish_reason': 'stop', 'tool_calls': None}]
    """
    if callable(getattr(client, "chat_stream", None)):
        result: Any = client.chat_stream(messages, **options)
    else:
        result = client.chat(messages, **options)
    if isinstance(result, str):
        result = [{"delta": result}]
    elif isinstance(result, Mapping):
        content = result.get("content") or result.get("text") or ""
        result = [{"delta": content}, {"done": True, "finish_reason": result.get("finish_reason", "stop"),
                                       "tool_calls": result.get("tool_calls")}]
    for chunk in result:
        if chunk.get("delta"):
            yield {"delta": chunk["delta"]}
        if chunk.get("done"):
            yield {"done": True, "finish_reason": chunk.get("finish_reason", "stop"),
                   "tool_calls": chunk.get("tool_calls") or None}
            return
    yield {"done": True, "finish_reason": "stop", "tool_calls": None}
