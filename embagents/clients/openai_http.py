"""OpenAI-compatible chat client over HTTP, stdlib only (urllib + SSE parsing).

Talks to ``POST {base_url}/v1/chat/completions`` with ``stream: true`` and
yields the same chunk shapes as ``embagents.models.backends.llama.LlamaBackend``, so
a component can switch between a local model and a server without caring.
Works with llama.cpp's servers (``python -m llama_cpp.server``,
``llama-server``), Ollama (``http://localhost:11434``), vLLM and OpenAI.

Example::

    >>> from embagents.clients.openai_http import OpenAIHTTPClient
    >>> client = OpenAIHTTPClient("http://127.0.0.1:11434", model="qwen3:0.6b")  # doctest: +SKIP
    >>> client.chat([{"role": "user", "content": "Hi"}], max_tokens=16)["content"]   # doctest: +SKIP
    'Hello! How can I help?'
"""

from __future__ import annotations

import json
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from typing import Any

from embagents.models.chat import (
    ToolCallAccumulator,
    check_messages,
    collect_stream,
    tool_calls_from_text,
)

__all__ = ["OpenAIHTTPClient", "OpenAIHTTPError"]

_BODY_EXCERPT = 500


class OpenAIHTTPError(RuntimeError):
    """The server answered with an HTTP error (or an error event mid-stream)."""

    def __init__(self, message: str, *, status: int | None = None, body: str = "") -> None:
        super().__init__(message)
        self.status = status
        self.body = body


def _api_root(base_url: str) -> str:
    """``http://h:p`` or ``http://h:p/v1`` -> ``http://h:p/v1`` (both spellings are common)."""
    root = base_url.rstrip("/")
    if not root.startswith(("http://", "https://")):
        raise ValueError(f"base_url must start with http:// or https://, got {base_url!r}")
    return root if root.endswith("/v1") else root + "/v1"


class OpenAIHTTPClient:
    """Chat with an OpenAI-compatible server; ``chat_stream`` yields token chunks.

    ``base_url`` may or may not end in ``/v1``. ``api_key`` is sent as a
    Bearer token when given (local servers do not need one).

    Example::

        >>> c = OpenAIHTTPClient("http://127.0.0.1:8000")
        >>> c.url
        'http://127.0.0.1:8000/v1/chat/completions'
    """

    def __init__(
        self,
        base_url: str,
        model: str = "local",
        api_key: str | None = None,
        timeout: float = 60.0,
    ) -> None:
        self.base_url = base_url
        self.model = model
        self.api_key = api_key
        self.timeout = timeout
        self.api_root = _api_root(base_url)
        self.url = self.api_root + "/chat/completions"

    def _request(self, url: str, body: dict | None = None) -> Any:
        """Open ``url`` (POST JSON if ``body``) and map failures to clear errors."""
        headers = {"Accept": "text/event-stream, application/json"}
        data = None
        if body is not None:
            data = json.dumps(body).encode("utf-8")
            headers["Content-Type"] = "application/json"
        if self.api_key:
            headers["Authorization"] = f"Bearer {self.api_key}"
        request = urllib.request.Request(
            url, data=data, headers=headers, method="POST" if data else "GET"
        )
        try:
            return urllib.request.urlopen(request, timeout=self.timeout)
        except urllib.error.HTTPError as exc:
            text = _read_excerpt(exc)
            raise OpenAIHTTPError(
                f"HTTP {exc.code} {exc.reason} from {url}: {text}", status=exc.code, body=text
            ) from exc
        except urllib.error.URLError as exc:
            reason = exc.reason
            if isinstance(reason, ConnectionRefusedError):
                raise ConnectionError(
                    f"Cannot connect to {url}: connection refused. Is the server running on that "
                    f"host and port? (llama.cpp: python -m llama_cpp.server --model M.gguf; "
                    f"Ollama: ollama serve)"
                ) from exc
            if isinstance(reason, TimeoutError):
                raise TimeoutError(f"No answer from {url} within {self.timeout} s") from exc
            raise ConnectionError(f"Cannot connect to {url}: {reason}") from exc
        except TimeoutError as exc:
            raise TimeoutError(f"No answer from {url} within {self.timeout} s") from exc

    def list_models(self) -> list[str]:
        """Model ids the server offers (``GET /v1/models``); also a cheap health check.

        Example::

            >>> OpenAIHTTPClient("http://127.0.0.1:8000").list_models()  # doctest: +SKIP
            ['/path/tiny.gguf']
        """
        with self._request(self.api_root + "/models") as response:
            payload = json.loads(response.read().decode("utf-8"))
        return [str(m.get("id")) for m in payload.get("data", []) if isinstance(m, dict)]

    def chat_stream(
        self,
        messages: list[dict],
        *,
        max_tokens: int = 128,
        temperature: float = 0.0,
        stop: list[str] | None = None,
        tools: list[dict] | None = None,
        tool_choice: str | dict | None = None,
        extra: dict | None = None,
    ) -> Iterator[dict]:
        """Yield ``{"delta": str}`` chunks, then one ``{"done": True, ...}`` chunk.

        Same shapes as ``LlamaBackend.chat_stream``; ``usage`` comes from the
        server when it reports it (``stream_options.include_usage``), else it
        counts streamed chunks and says ``"estimated": True``. ``extra`` adds
        server-specific request fields (e.g. llama.cpp's ``repeat_penalty``,
        whose server default 1.1 differs from in-process llama-cpp-python's 1.0).

        Example::

            >>> for c in client.chat_stream([{"role": "user", "content": "Hi"}]):  # doctest: +SKIP
            ...     print(c.get("delta", ""), end="", flush=True)
        """
        check_messages(messages)
        body: dict[str, Any] = {
            "model": self.model,
            "messages": messages,
            "stream": True,
            "max_tokens": max_tokens,
            "temperature": temperature,
            "stream_options": {"include_usage": True},
        }
        if stop:
            body["stop"] = list(stop)
        if tools:
            body["tools"] = tools
            if tool_choice is not None:
                body["tool_choice"] = tool_choice
        if extra:
            body.update(extra)
        return self._stream(body, tools)

    def _stream(self, body: dict, tools: list[dict] | None) -> Iterator[dict]:
        start = time.perf_counter()
        response = self._request(self.url, body)
        first_token_s: float | None = None
        parts: list[str] = []
        calls = ToolCallAccumulator()
        finish_reason: str | None = None
        usage: dict | None = None
        saw_done = False
        with response:
            if "text/event-stream" in (response.headers.get("Content-Type") or ""):
                events = _sse_events(response, self.url)
            else:  # a server that ignored stream=true: one JSON reply
                events = iter([response.read().decode("utf-8"), "[DONE]"])
            for data in events:
                if data == "[DONE]":
                    saw_done = True
                    break
                try:
                    event = json.loads(data)
                except ValueError as exc:
                    raise OpenAIHTTPError(
                        f"Bad JSON in stream from {self.url}: {data[:_BODY_EXCERPT]!r}"
                    ) from exc
                if "error" in event:
                    raise OpenAIHTTPError(
                        f"Error from {self.url}: {json.dumps(event['error'])[:_BODY_EXCERPT]}"
                    )
                if event.get("usage"):
                    usage = event["usage"]
                for choice in event.get("choices") or []:
                    delta = choice.get("delta") or choice.get("message") or {}
                    content = delta.get("content")
                    if content:
                        if first_token_s is None:
                            first_token_s = time.perf_counter() - start
                        parts.append(content)
                        yield {"delta": content}
                    if delta.get("tool_calls"):
                        calls.add(delta["tool_calls"])
                    if choice.get("finish_reason"):
                        finish_reason = choice["finish_reason"]
        if not saw_done and finish_reason is None:
            raise ConnectionError(f"Stream from {self.url} ended before the reply was complete")
        tool_calls = calls.result() or tool_calls_from_text("".join(parts), tools)
        if tool_calls:
            finish_reason = "tool_calls"
        if usage is None:
            usage = {"completion_tokens": len(parts), "estimated": True}
        yield {
            "done": True,
            "finish_reason": finish_reason or "stop",
            "tool_calls": tool_calls,
            "usage": {k: v for k, v in usage.items() if isinstance(v, (int, float, bool))},
            "timing": {"first_token_s": first_token_s, "total_s": time.perf_counter() - start},
        }

    def chat(
        self,
        messages: list[dict],
        *,
        max_tokens: int = 128,
        temperature: float = 0.0,
        stop: list[str] | None = None,
        tools: list[dict] | None = None,
        tool_choice: str | dict | None = None,
        extra: dict | None = None,
    ) -> dict:
        """Whole reply as ``{"content", "tool_calls", "finish_reason", "usage", "timing"}``.

        Example::

            >>> client.chat([{"role": "user", "content": "Hi"}])["finish_reason"]  # doctest: +SKIP
            'stop'
        """
        return collect_stream(
            self.chat_stream(
                messages,
                max_tokens=max_tokens,
                temperature=temperature,
                stop=stop,
                tools=tools,
                tool_choice=tool_choice,
                extra=extra,
            )
        )


def _read_excerpt(exc: urllib.error.HTTPError) -> str:
    try:
        raw = exc.read()
    except OSError:
        return ""
    return raw.decode("utf-8", errors="replace").strip()[:_BODY_EXCERPT]


def _sse_events(response: Any, url: str) -> Iterator[str]:
    """The ``data`` payloads of a server-sent-events stream, one string per event."""
    lines: list[str] = []
    while True:
        try:
            raw = response.readline()
        except TimeoutError as exc:
            raise TimeoutError(f"Stream from {url} stalled (read timeout)") from exc
        if not raw:  # end of body
            if lines:
                yield "\n".join(lines)
            return
        line = raw.decode("utf-8").rstrip("\r\n")
        if not line:  # blank line ends an event
            if lines:
                yield "\n".join(lines)
                lines = []
        elif line.startswith("data:"):
            lines.append(line[5:].removeprefix(" "))
        # other fields (event:, id:, retry:) and ':' comments are not used by this protocol
