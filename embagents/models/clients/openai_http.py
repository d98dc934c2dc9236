"""OpenAI-compatible chat client over HTTP, on the ``openai`` package (its HTTP and SSE, no retries).

Talks to ``POST {base_url}/v1/chat/completions`` with ``stream: true`` and
yields the same chunk shapes as ``embagents.models.backends.llama.LlamaBackend``, so
a component can switch between a local model and a server without caring.
Works with llama.cpp's servers (``python -m llama_cpp.server``,
``llama-server``), Ollama (``http://localhost:11434``), vLLM and OpenAI.
Servers that take images (a vision-language model behind them) get
``images=[array]`` as OpenAI ``image_url`` content parts with PNG ``data:`` URLs.

Example::

    >>> from embagents.models.clients.openai_http import OpenAIHTTPClient
    >>> client = OpenAIHTTPClient("http://127.0.0.1:11434", model="qwen3:0.6b")  # doctest: +SKIP
    >>> client.chat([{"role": "user", "content": "Hi"}], max_tokens=16)["content"]   # doctest: +SKIP
    'Hello! How can I help?'
"""

from __future__ import annotations

import base64
import contextlib
import json
import struct
import time
import zlib
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from embagents.models.chat import (
    ToolCallAccumulator,
    check_messages,
    collect_stream,
    tool_calls_from_text,
    with_images,
)

__all__ = ["OpenAIHTTPClient", "OpenAIHTTPError", "png_data_url"]

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
        self._sdk: Any = None

    def _client(self) -> Any:
        try:
            import openai
        except ImportError as exc:
            raise ModuleNotFoundError("OpenAIHTTPClient needs the openai package: pip install 'embagents[llm]' "
                                      "(or pip install openai)") from exc
        if self._sdk is None:
            # No retries: a robot wants the failure now, and the fallbacks decide what happens next.
            self._sdk = openai.OpenAI(base_url=self.api_root, api_key=self.api_key or "no-key",
                                      timeout=self.timeout, max_retries=0)
        return self._sdk

    def _errors(self, url: str) -> Any:
        """Map the SDK's errors to ours: connection, timeout, HTTP status (with the body excerpted)."""
        import openai

        @contextlib.contextmanager
        def mapping() -> Iterator[None]:
            try:
                yield
            except openai.APITimeoutError as exc:
                raise TimeoutError(f"No answer from {url} within {self.timeout} s") from exc
            except openai.APIConnectionError as exc:
                if _refused(exc):
                    raise ConnectionError(
                        f"Cannot connect to {url}: connection refused. Is the server running on that "
                        f"host and port? (llama.cpp: python -m llama_cpp.server --model M.gguf; "
                        f"Ollama: ollama serve)"
                    ) from exc
                raise ConnectionError(f"Cannot connect to {url}: {exc.__cause__ or exc}") from exc
            except openai.APIStatusError as exc:
                text = exc.response.text.strip()[:_BODY_EXCERPT]
                raise OpenAIHTTPError(f"HTTP {exc.status_code} {exc.response.reason_phrase} from {url}: {text}",
                                      status=exc.status_code, body=text) from exc
            except openai.APIError as exc:  # an error event mid-stream
                raise OpenAIHTTPError(f"Error from {url}: {str(exc)[:_BODY_EXCERPT]}") from exc

        return mapping()

    def list_models(self) -> list[str]:
        """Model ids the server offers (``GET /v1/models``); also a cheap health check.

        Example::

            >>> OpenAIHTTPClient("http://127.0.0.1:8000").list_models()  # doctest: +SKIP
            ['/path/tiny.gguf']
        """
        with self._errors(self.api_root + "/models"):
            return [str(m.id) for m in self._client().models.list()]

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
        images: Sequence[np.ndarray] | None = None,
    ) -> Iterator[dict]:
        """Yield ``{"delta": str}`` chunks, then one ``{"done": True, ...}`` chunk.

        ``images``: (H, W, 3) uint8 RGB arrays, sent before the text of the
        last user message as ``image_url`` parts (PNG ``data:`` URLs), for a
        server with a vision-language model.

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
        if images:
            messages = with_images(messages, [png_data_url(img) for img in images])
        body: dict[str, Any] = {
            "model": self.model,
            "messages": messages,
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
            body["extra_body"] = dict(extra)
        return self._stream(body, tools)

    def _stream(self, body: dict, tools: list[dict] | None) -> Iterator[dict]:
        start = time.perf_counter()
        with self._errors(self.url):
            raw = self._client().chat.completions.with_raw_response.create(stream=True, **body)
        first_token_s: float | None = None
        parts: list[str] = []
        calls = ToolCallAccumulator()
        finish_reason: str | None = None
        usage: dict | None = None
        with contextlib.closing(raw.http_response), self._errors(self.url):  # closed also when abandoned
            if "text/event-stream" in (raw.headers.get("content-type") or ""):
                events: Iterator[dict] = (c.model_dump(exclude_none=True) for c in raw.parse())
            else:  # a server that ignored stream=true: one JSON reply
                events = iter([_json(raw.http_response.read().decode("utf-8"), self.url)])
            for event in events:
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
        if finish_reason is None:
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
        images: Sequence[np.ndarray] | None = None,
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
                images=images,
            )
        )


def png_data_url(image: np.ndarray) -> str:
    """An (H, W, 3) uint8 RGB image as a ``data:image/png;base64,...`` URL (PNG written with zlib alone).

    >>> png_data_url(np.zeros((1, 1, 3), np.uint8))[:30]
    'data:image/png;base64,iVBORw0K'
    """
    if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        got = f"shape {image.shape} dtype {image.dtype}" if isinstance(image, np.ndarray) else type(image).__name__
        raise ValueError(f"an image for the server must be an (H, W, 3) uint8 RGB array, got {got}")
    h, w = image.shape[:2]
    rows = np.concatenate([np.zeros((h, 1), np.uint8), np.ascontiguousarray(image).reshape(h, w * 3)], axis=1)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(rows.tobytes(), 1)) + chunk(b"IEND", b""))
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _json(text: str, url: str) -> dict:
    try:
        return dict(json.loads(text))
    except ValueError as exc:
        raise OpenAIHTTPError(f"Bad JSON from {url}: {text[:_BODY_EXCERPT]!r}") from exc


def _refused(exc: BaseException) -> bool:
    """True when the connection was refused (somewhere in the cause chain)."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, ConnectionRefusedError) or "refused" in str(seen).lower():
            return True
        seen = seen.__cause__ or seen.__context__
    return False
