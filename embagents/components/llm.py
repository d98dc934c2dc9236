"""The LLM component: text in, text (or a token stream) out, with history and tools.

Each new message on the text input is answered through the model client.
The answer goes to every ``String`` output whole, and to every
``StreamingString`` output as chunks of one stream (``stream=True``: one
chunk per token delta; else one chunk) closed by ``StreamingString(data="",
done=True)`` with the same ``stream_id``.

Tool calling: ``LLMConfig(tools={"get_time": get_time})`` offers Python
functions to the model (JSON schemas are derived from their signatures or
given in ``tool_schemas``); tool calls the model makes are run and their
results fed back, for at most ``max_tool_rounds`` rounds (one with
``tool_choice="required"``), then the model must answer in text
(``tool_choice="none"``: the answer published is a sentence, not a call).

Example::

    >>> from embagents.msgs import String
    >>> from embagents.topic import Topic
    >>> class Parrot:
    ...     def chat_stream(self, messages, **options):
    ...         yield {"delta": "You said: " + messages[-1]["content"]}
    ...         yield {"done": True, "finish_reason": "stop", "tool_calls": None}
    >>> question, answer = Topic("question", String), Topic("answer", String)
    >>> llm = LLM(name="llm", inputs=[question], outputs=[answer], model_client=Parrot(),
    ...           config=LLMConfig(prompt_template="Q: {text}"))
    >>> sent = []
    >>> llm.attach(lambda topic, msg: sent.append(msg))
    >>> llm.on_message("question", String("hi")) and llm.execute()
    True
    >>> sent
    [String(data='You said: Q: hi')]
"""

from __future__ import annotations

import copy
import inspect
import json
import re
import string
import time
import uuid
from collections.abc import Callable, Generator, Iterator, Mapping, Sequence
from typing import Any

import attrs
from attrs import define, field

from embagents.components.component import ComponentProblem
from embagents.components.model_component import ModelComponent
from embagents.components.voice_stages import publish_stage
from embagents.config import (
    BaseComponentConfig,
    ConfigError,
    int_at_least,
    one_of,
    positive_int,
    to_bool,
)
from embagents.models.chat import chat_chunks, openai_tool_call, tool_calls_from_text
from embagents.msgs import BargeIn, StreamingString, String, VoiceStage
from embagents.topic import Topic

__all__ = ["LLM", "LLMConfig", "template_fields", "tool_schema"]


def _temperature(value: object) -> float:
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        out = -1.0
    if isinstance(value, bool) or not 0.0 <= out <= 5.0:
        raise ConfigError(f"temperature must be a number in [0, 5], got {value!r}")
    return out


def _optional_str(_inst: object, attr: Any, value: object) -> None:
    if value is not None and not isinstance(value, str):
        raise ConfigError(f"{attr.name} must be a str or None, got {value!r}")


def _str_list(value: object) -> list[str]:
    items = [value] if isinstance(value, str) else list(value)  # type: ignore[call-overload]
    if not all(isinstance(s, str) and s for s in items):
        raise ConfigError(f"stop must be a list of non-empty strings, got {value!r}")
    return items


def template_fields(template: str) -> list[str]:
    """The placeholder names of a prompt template; raises ConfigError if it is malformed.

    >>> template_fields("Context: {location}. Question: {text}")
    ['location', 'text']
    """
    try:
        parsed = list(string.Formatter().parse(template))
    except ValueError as exc:
        raise ConfigError(f"prompt_template {template!r} is not a valid format string: {exc}") from None
    names = []
    for _, name, _, _ in parsed:
        if name is None:
            continue
        if not name.isidentifier():
            raise ConfigError(
                f"prompt_template {template!r}: placeholder {{{name}}} must be a plain name such as "
                "{text} (no positional {}, indexes or attributes); write {{ }} for literal braces"
            )
        names.append(name)
    return names


def _check_template(_inst: object, _attr: object, value: str | None) -> None:
    if value is None:
        return
    if not isinstance(value, str):
        raise ConfigError(f"prompt_template must be a str or None, got {value!r}")
    if "text" not in template_fields(value):
        raise ConfigError(f"prompt_template {value!r} must contain the {{text}} placeholder (the input text)")




def _check_tools(_inst: object, _attr: object, value: dict[str, Any]) -> None:
    if not isinstance(value, Mapping):
        raise ConfigError(f"tools must be a dict of name -> function, got {value!r}")
    for name, fn in value.items():
        if not isinstance(name, str) or not name.isidentifier() or not callable(fn):
            raise ConfigError(f"tools must map identifier names to callables; got {name!r}: {fn!r}")


_JSON_TYPES = {str: "string", int: "integer", float: "number", bool: "boolean", list: "array", dict: "object"}
_JSON_TYPE_NAMES = {t.__name__: j for t, j in _JSON_TYPES.items()}


_ARGS_HEADER = re.compile(r"^(Args|Arguments|Parameters):$")
_ARG_LINE = re.compile(r"^\s*(?::param\s+)?(\w+)(?:\s*\([^)]*\))?\s*:\s*(.+)$")


def _argument_docs(doc: str) -> dict[str, str]:
    """Argument descriptions in a docstring: ``Args:`` lines (``name: text``, ``name (type): text``), ``:param name: text``."""
    out: dict[str, str] = {}
    in_args = False
    for line in doc.splitlines():
        if _ARGS_HEADER.match(line.strip()):
            in_args = True
            continue
        if in_args and line.strip() and not line.startswith((" ", "\t")):
            in_args = False  # the next section
        match = _ARG_LINE.match(line)
        if match and (in_args or line.strip().startswith(":param")):
            out[match.group(1)] = match.group(2).strip()
    return out


def tool_schema(name: str, fn: Callable[..., Any], parameters: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """An OpenAI-style tool description of ``fn``: parameters from its signature, their descriptions
    from its docstring's ``Args:`` section (the model is shown them: what to fill in, not a sample).

    >>> def turn(angle: float, unit: str = "deg"):
    ...     '''Turn the robot in place.
    ...
    ...     Args:
    ...         angle: how far, in the unit
    ...     '''
    >>> params = tool_schema("turn", turn)["function"]["parameters"]
    >>> params["required"], params["properties"]["angle"]
    (['angle'], {'type': 'number', 'description': 'how far, in the unit'})
    """
    if parameters is None:
        told = _argument_docs(inspect.getdoc(fn) or "")
        props: dict[str, Any] = {}
        required = []
        for p in inspect.signature(fn).parameters.values():
            if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
                continue
            ann = p.annotation
            # With `from __future__ import annotations` the annotation is a string.
            # "float | None" (an optional number) is a number.
            first = ann.split("|")[0].strip() if isinstance(ann, str) else ""
            jtype = _JSON_TYPES.get(ann) or _JSON_TYPE_NAMES.get(first, "string")
            props[p.name] = {"type": jtype, **({"description": told[p.name]} if p.name in told else {})}
            if p.default is p.empty:
                required.append(p.name)
        parameters = {"type": "object", "properties": props, "required": required}
    doc = inspect.getdoc(fn) or ""
    return {
        "type": "function",
        "function": {"name": name, "description": doc.split("\n\n")[0], "parameters": dict(parameters)},
    }


def _tool_rounds(value: object) -> int:
    return int_at_least(0)(value)


def _tool_choice(value: object) -> str:
    return one_of("tool_choice", "auto", "required", meanings={"required": "the first reply must call a tool"})(value)


@define(kw_only=True)
class LLMConfig(BaseComponentConfig):
    """Settings of :class:`LLM`.

    - ``chat_history``: keep the conversation; ``history_size``: turns kept
      (a turn is a question, its tool calls and its answer).
    - ``system_prompt``: the system message; ``prompt_template``: a format
      string wrapping the input text, e.g. ``"Answer briefly: {text}"``; other
      String inputs fill placeholders named after their topic (``/`` -> ``_``).
    - ``stream``: publish token deltas on the StreamingString output.
    - ``max_new_tokens``, ``temperature``, ``stop``: generation options.
    - ``tools``: name -> Python function the model may call; ``tool_schemas``:
      name -> JSON schema of its parameters (else derived from the signature);
      ``max_tool_rounds``: tool rounds before the model must answer;
      ``tool_choice``: ``"auto"`` (the model decides, each round until ``max_tool_rounds``)
      or ``"required"`` (its first reply must be a tool call: with llama.cpp, held to a
      JSON schema by a grammar, so even SmolLM2-135M makes a valid call). The reply that
      ends the tool rounds is asked with ``tool_choice="none"``: text, never a call;
      ``tools_answer_directly``: tools whose result is the answer itself (published
      as is, the model is not asked again: EmbodiedAgents' ``send_tool_response_to_model=False``).

    >>> LLMConfig(history_size="4", stream="true").history_size
    4
    """

    chat_history: bool = field(default=False, converter=to_bool)
    history_size: int = field(default=10, converter=positive_int)
    system_prompt: str | None = field(default=None, validator=_optional_str)
    prompt_template: str | None = field(default=None, validator=_check_template)
    stream: bool = field(default=False, converter=to_bool)
    max_new_tokens: int = field(default=256, converter=positive_int)
    temperature: float = field(default=0.7, converter=_temperature)
    stop: list[str] = field(factory=list, converter=_str_list)
    tools: dict[str, Callable[..., Any]] = field(factory=dict, validator=_check_tools)
    tool_schemas: dict[str, dict[str, Any]] = field(factory=dict)
    max_tool_rounds: int = field(default=3, converter=_tool_rounds)
    tool_choice: str = field(default="auto", converter=_tool_choice)
    tools_answer_directly: list[str] = field(factory=list, converter=list)

    def __attrs_post_init__(self) -> None:
        extra = sorted(set(self.tool_schemas) - set(self.tools))
        if extra:
            raise ConfigError(f"tool_schemas names tools that are not in tools: {', '.join(extra)}")
        extra = sorted(set(self.tools_answer_directly) - set(self.tools))
        if extra:
            raise ConfigError(f"tools_answer_directly names tools that are not in tools: {', '.join(extra)}")


def _placeholder(topic: Topic) -> str:
    return topic.name.replace("/", "_")


class LLM(ModelComponent):
    """Answers text with a language model (see the module docstring).

    The trigger defaults to the first input topic; a step answers the newest
    message of the first fresh trigger topic. ``output_converters`` maps an output
    topic (or its name) to a function of the answer's text returning the message to
    publish there (``None``: nothing this time), so an answer can become a typed
    message, a goal ``PoseStamped`` say, without a component of its own. :meth:`answer` is also callable
    directly (e.g. by a ``call(llm, "answer", "...")`` action on a server LLM).
    ``snapshot()`` / ``restore()`` carry the chat history across restarts.

    Barge-in: with a ``BargeIn`` input (SpeechToText's), a question is answered
    token by token between turns of the component's loop, so an ``interrupt``
    (or :meth:`interrupt`) cancels the generation where it is (the model actor
    stops at once) and the answer goes into the chat history cut short
    (``"interrupted": True``, for the application; the model reads the words kept, unmarked).
    With a ``StreamingString`` input, the Speaker's words played (its text
    output; TextToSpeech passes each sentence on with its audio), the answer cut
    short is kept as the words the user heard, not what the model had written
    (which runs ahead of the voice): ``history[-1]["content"]`` is the played
    prefix. Words the speaker tells after the interrupt (it may stop after the
    LLM hears of it) still go into that entry. Without that input it is the
    text written so far.
    """

    allowed_inputs = {"Required": [String], "Optional": [String, BargeIn, StreamingString]}
    allowed_outputs = {"Required": [[String, StreamingString]], "Optional": [String, StreamingString, VoiceStage]}
    config_class = LLMConfig

    def __init__(self, *, name: str, output_converters: Mapping[Topic | str, Callable[[str], Any]] | None = None,
                 **kw: Any) -> None:
        self._history: list[dict[str, Any]] = []
        self._stream_count = 0
        self.output_converters: dict[str, Callable[[str], Any]] = {
            (k.name if isinstance(k, Topic) else str(k).lstrip("/")): fn for k, fn in (output_converters or {}).items()}
        self._live: dict[str, Any] | None = None  # the answer being generated between loop turns (barge-in)
        self._played: dict[str, str] = {}  # stream_id -> its words the speaker has played (newest answers)
        self._last_stream = ""  # the stream of the answer last put into the history
        self._cut: tuple[str, dict[str, Any]] | None = None  # the answer cut short: its stream, its history entry
        self.interrupted = 0  # answers cut short
        self._began = 0.0  # wall time the latest answer began
        super().__init__(name=name, **kw)

    def _typed_outputs(self) -> tuple[Topic, ...]:
        # A converted output carries whatever its converter makes: not held to allowed_outputs.
        return tuple(t for t in self.outputs if t.name not in self.output_converters)

    def register_tool(self, tool: Callable[..., Any], schema: Mapping[str, Any] | None = None, *,
                      name: str | None = None, send_tool_response_to_model: bool = True) -> None:
        """Offer ``tool`` to the model (``schema``: the JSON schema of its parameters, else its signature's).

        ``send_tool_response_to_model=False``: the tool's result is the answer (published, no second request).
        """
        key = name or tool.__name__
        cfg = self.config
        tools, schemas = {**cfg.tools, key: tool}, dict(cfg.tool_schemas)
        if schema is not None:
            schemas[key] = dict(schema)
        direct = [t for t in cfg.tools_answer_directly if t != key] + ([] if send_tool_response_to_model else [key])
        self.config = attrs.evolve(cfg, tools=tools, tool_schemas=schemas, tools_answer_directly=direct)

    def chat_stream(self, messages: list[dict[str, Any]], **options: Any) -> Iterator[dict[str, Any]]:
        """The active client's answer as ``{"delta"}``... then ``{"done": True, ...}`` (:func:`~embagents.models.chat.chat_chunks`)."""
        if self.model_client is None:
            raise RuntimeError(f"{self._label()} has no model client")
        return chat_chunks(self.model_client, messages, **options)

    def run_warmup(self) -> None:
        """One token of an answer to "Hi" (loads the model)."""
        for _ in self.chat_stream([{"role": "user", "content": "Hi"}], max_tokens=1):
            pass

    def default_trigger(self) -> Topic | Sequence[Topic] | None:  # VLM's: all its inputs
        return self.inputs[0] if self.inputs else None

    def validate(self) -> list[ComponentProblem]:
        problems = super().validate()
        if self.output_converters:  # a converted output is an output: no text topic is required then
            problems = [p for p in problems if p[0] != "missing-output"]
        cfg = self.config
        if cfg.prompt_template is not None:
            allowed = ["text", *(_placeholder(t) for t in self.inputs)]
            for name in template_fields(cfg.prompt_template):
                if name not in allowed:
                    problems.append(("bad-config", f"{self._label()}: prompt_template placeholder {{{name}}} is "
                                                   f"not an input; allowed: {', '.join(dict.fromkeys(allowed))}"))
        if cfg.stream and not any(t.msg_type is StreamingString for t in self.outputs):
            problems.append(("bad-config", f"{self._label()}: stream=True needs a StreamingString output topic"))
        outputs = {t.name for t in self.outputs}
        for topic, fn in self.output_converters.items():
            if topic not in outputs or not callable(fn):
                problems.append(("bad-converter", f"{self._label()}: output_converters[{topic!r}] must be a function "
                                 f"of an output topic; outputs: {', '.join(sorted(outputs)) or 'none'}"))
        return problems

    # --- history ----------------------------------------------------------------------------

    @property
    def history(self) -> list[dict[str, Any]]:
        """A copy of the chat history (user, assistant and tool messages)."""
        return copy.deepcopy(self._history)

    def reset_history(self) -> None:
        """Forget the conversation."""
        self._history.clear()

    def _trim_history(self) -> None:
        starts = [i for i, m in enumerate(self._history) if m.get("role") == "user"]
        excess = len(starts) - self.config.history_size
        if excess > 0:
            del self._history[: starts[excess]]

    def snapshot(self) -> dict[str, Any]:
        """``{"history": [...]}``: plain dicts, msgpack-able."""
        return {"history": copy.deepcopy(self._history)}

    def restore(self, state: Any) -> None:
        """Take back a :meth:`snapshot` (``None`` is ignored)."""
        if state is None:
            return
        history = state.get("history") if isinstance(state, Mapping) else None
        if not isinstance(history, list) or not all(isinstance(m, Mapping) and "role" in m for m in history):
            raise ValueError(f"{self._label()}: restore() expects {{'history': [{{'role': ..., ...}}, ...]}}, got {state!r}")
        self._history = [dict(m) for m in history]
        self._trim_history()

    # --- prompting --------------------------------------------------------------------------

    def build_messages(self, text: str, context: Mapping[str, str] | None = None) -> list[dict[str, Any]]:
        """The messages sent for ``text``: system prompt, history (if kept), the templated question.

        ``context`` fills the template's other placeholders (missing ones are "").
        """
        cfg = self.config
        content = text
        if cfg.prompt_template is not None:
            values = dict.fromkeys(template_fields(cfg.prompt_template), "")
            values.update(context or {})
            values["text"] = text
            content = cfg.prompt_template.format(**values)
        messages: list[dict[str, Any]] = []
        if cfg.system_prompt:
            messages.append({"role": "system", "content": cfg.system_prompt})
        if cfg.chat_history:
            for m in copy.deepcopy(self._history):
                # An answer cut short reads as the words the user heard, unmarked (as Pipecat and LiveKit send
                # it): a small model copies a marker ("...") into its next answer (SmolLM2-135M, measured).
                m.pop("interrupted", None)
                messages.append(m)
        messages.append({"role": "user", "content": content})
        return messages

    def tool_specs(self) -> list[dict[str, Any]]:
        """The tool descriptions offered to the model."""
        cfg = self.config
        return [tool_schema(name, fn, cfg.tool_schemas.get(name)) for name, fn in cfg.tools.items()]

    # --- steps ------------------------------------------------------------------------------

    def _execution_step(self, **inputs: Any) -> None:
        candidates = self.trigger_topics if self.trigger_kind == "topics" else self.inputs
        question = next((t for t in candidates if t.name in self.fresh_inputs and inputs.get(t.name) is not None), None)
        if question is None:
            return  # nothing new to answer (e.g. a rate tick with no new question)
        context = {_placeholder(t): inputs[t.name].data for t in self.inputs
                   if t is not question and t.msg_type is String and inputs.get(t.name) is not None}
        text = self.question_text(question, inputs)
        if self._interruptible:
            self._answer_live(text, context)
        else:
            self.answer(text, context)

    def question_text(self, topic: Topic, inputs: Mapping[str, Any]) -> str:
        """The text a step asks about when ``topic`` brought the question: its message's ``data``."""
        return str(inputs[topic.name].data)

    @property
    def _interruptible(self) -> bool:
        return any(t.msg_type is BargeIn for t in self.inputs)

    @property
    def _hears_itself(self) -> bool:
        """The speaker's words played come in (a ``StreamingString`` input)."""
        return any(t.msg_type is StreamingString for t in self.inputs)

    def _words_played(self, msg: StreamingString) -> None:
        """The speaker played more of an answer: keep it; an answer already cut short gets them too."""
        played = self._played.pop(msg.stream_id, "") + msg.data
        self._played[msg.stream_id] = played  # newest last
        while len(self._played) > 8:  # a few answers back: what an interrupt may still be about
            del self._played[next(iter(self._played))]
        if self._cut is not None and self._cut[0] == msg.stream_id:
            self._cut[1]["content"] = played

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if isinstance(msg, StreamingString) and topic_name in self._subscribed:
            self._words_played(msg)  # not a question: no step
            return False
        if isinstance(msg, BargeIn) and topic_name in self._subscribed:
            if msg.action == "interrupt" and msg.stamp and msg.stamp < self._began:
                # The speech began before this answer did: this answer is the reply to it (the interrupt came
                # in after the question, as a busy loop may take them), not one it cuts short.
                self.logger.info("%s: an interrupt of speech before the answer in progress began: ignored",
                                 self._label())
            elif msg.action == "interrupt":
                self.interrupt()
            return False
        return super().on_message(topic_name, msg, now)

    def _begin(self, text: str, context: Mapping[str, str] | None) -> dict[str, Any]:
        messages = self.build_messages(text, context)
        self._stream_count += 1
        self._began = time.time()
        return {"messages": messages, "turn": [messages[-1]], "said": [],
                "stream_id": f"{self.name}-{uuid.uuid4().hex[:8]}-{self._stream_count}",
                "streams": [t for t in self.outputs
                            if t.msg_type is StreamingString and t.name not in self.output_converters]}

    def _end(self, live: dict[str, Any], answer: str | None, *, interrupted: bool = False) -> None:
        """Close the stream (even on failure: listeners never wait forever); publish and keep a whole answer."""
        stream_id = live["stream_id"]
        if answer is not None and not self.config.stream and not interrupted:
            for t in live["streams"]:
                self.publish(t, StreamingString(data=answer, done=False, stream_id=stream_id))
        for t in live["streams"]:
            self.publish(t, StreamingString(data="", done=True, stream_id=stream_id))
        if answer is None:
            return
        if not interrupted:
            for t in self.outputs:
                if t.name in self.output_converters:
                    self._publish_converted(t, answer)
                elif t.msg_type is String:
                    self.publish(t, String(data=answer))
        if self.config.chat_history:
            said: dict[str, Any] = {"role": "assistant", "content": answer}
            if interrupted:
                said["interrupted"] = True
            self._history += live["turn"] + [said]
            self._last_stream = stream_id
            self._trim_history()

    def answer(self, text: str, context: Mapping[str, str] | None = None) -> str:
        """Answer ``text``: query the model (running tools), publish, update history; returns the answer."""
        live = self._begin(text, context)
        answer: str | None = None
        try:
            answer = self._converse(live["messages"], live["turn"], live["streams"] if self.config.stream else [],
                                    live["stream_id"])
        finally:
            self._end(live, answer)
        return answer if answer is not None else ""

    def _answer_live(self, text: str, context: Mapping[str, str] | None) -> None:
        """Answer ``text`` a chunk per turn of the loop, so that an interrupt gets in between (barge-in)."""
        if self._live is not None:
            self.interrupt()  # a new question while the last answer is still written: that one is cut short
        live = self._live = self._begin(text, context)
        live["steps"] = self._conversing(live["messages"], live["turn"],
                                         live["streams"] if self.config.stream else [], live["stream_id"], live["said"])
        self.call_later(0.0, self._live_step)

    def _live_step(self) -> None:
        live = self._live
        if live is None:
            return  # interrupted since
        try:
            next(live["steps"])
        except StopIteration as done:
            self._live = None
            self._end(live, done.value)
            return
        except BaseException:
            self._live = None
            self._end(live, None)
            raise
        self.call_later(0.0, self._live_step)

    def interrupt(self) -> str:
        """Cut the answer short: stop its generation and keep it in the history as interrupted; returns it.

        With no answer being generated, the last answer (still being spoken) is the one marked. Kept
        is what the user heard of it when the speaker's words played come in (see the class docstring),
        else what the model wrote.
        """
        live, self._live = self._live, None
        if live is not None:
            live["steps"].close()  # closes the model stream: the model actor stops generating
            stream_id = live["stream_id"]
            said = self._played.get(stream_id, "") if self._hears_itself else "".join(live["said"])
            self._end(live, said, interrupted=True)
            last = self._history[-1] if self.config.chat_history and self._history else None
        else:
            last = self._history[-1] if self._history else None
            if last is None or last.get("role") != "assistant":
                return ""
            stream_id = self._last_stream
            last["interrupted"] = True
            if self._hears_itself:
                last["content"] = self._played.get(stream_id, "")
            said = str(last.get("content") or "")
        self._cut = (stream_id, last) if last is not None and self._hears_itself else None
        self.interrupted += 1
        self.logger.info("%s: interrupted after %r", self._label(), said[-60:])
        return said

    def _publish_converted(self, topic: Topic, answer: str) -> None:
        msg = self.output_converters[topic.name](answer)
        if msg is None:
            return  # the converter found nothing to publish in this answer
        if isinstance(msg, str) and topic.msg_type in (String, StreamingString):
            msg = topic.msg_type(data=msg)
        self.publish(topic, msg)

    def _converse(self, messages: list[dict[str, Any]], turn: list[dict[str, Any]],
                  streams: list[Topic], stream_id: str) -> str:
        steps = self._conversing(messages, turn, streams, stream_id, [])
        while True:
            try:
                next(steps)
            except StopIteration as done:
                return str(done.value)

    def _conversing(self, messages: list[dict[str, Any]], turn: list[dict[str, Any]], streams: list[Topic],
                    stream_id: str, said: list[str]) -> Generator[None, None, str]:
        """The conversation as a generator: it yields after each chunk of the model's stream; returns the answer.

        ``said`` gets every delta of the text answer as it comes.
        """
        cfg = self.config
        specs = self.tool_specs() or None
        rounds = 0
        first = True  # the answer's first token: a stage of a voice turn (ttft)
        while True:
            # Tools are offered in the first round, and in later ones only with tool_choice="auto" (the model
            # may chain calls) until max_tool_rounds. The reply after a tool result otherwise is the answer:
            # text, with tool_choice="none" (a small model shown its own call would copy it as the answer).
            offered = specs is not None and rounds < cfg.max_tool_rounds and (rounds == 0 or cfg.tool_choice == "auto")
            tools = specs if offered or rounds > 0 else None
            extra: dict[str, Any] = {}
            if offered and rounds == 0 and cfg.tool_choice == "required":
                extra["tool_choice"] = "required"
            elif tools is not None and not offered:
                extra["tool_choice"] = "none"
            parts: list[str] = []
            tool_calls = None
            shown = [] if extra.get("tool_choice") == "required" else streams  # a forced call is no answer to stream
            stream = self.chat_stream(messages, max_tokens=cfg.max_new_tokens, temperature=cfg.temperature,
                                      stop=cfg.stop or None, tools=tools, **self._model_inputs(), **extra)
            try:
                for chunk in stream:
                    delta = chunk.get("delta")
                    if delta:
                        if first:
                            first = False
                            publish_stage(self, "llm_first_token")
                        parts.append(delta)
                        said.append(delta)
                        for t in shown:
                            self.publish(t, StreamingString(data=delta, done=False, stream_id=stream_id))
                    if chunk.get("done"):
                        tool_calls = chunk.get("tool_calls")
                    yield
            finally:
                close = getattr(stream, "close", None)
                if close is not None:
                    close()  # an interrupt closes this generator here: the model's stream is cancelled
            text = "".join(parts)
            if not tool_calls or not offered:
                return text
            calls = [openai_tool_call(c, i) for i, c in enumerate(tool_calls)]
            # A reply that is only the calls' JSON (a model without native tool calls) has no content besides them.
            content = "" if tool_calls_from_text(text, tools) else text
            new: list[dict[str, Any]] = [{"role": "assistant", "content": content, "tool_calls": calls}]
            new += [{"role": "tool", "tool_call_id": c["id"], "name": c["function"]["name"],
                     "content": self._run_tool(c)} for c in calls]
            messages += new
            turn += new
            said.clear()  # what the user hears is the answer after the tools
            rounds += 1
            direct = [m["content"] for c, m in zip(calls, new[1:], strict=True)
                      if c["function"]["name"] in cfg.tools_answer_directly]
            if direct and len(direct) == len(calls):
                return "\n".join(direct)  # the tools' results are the answer: the model is not asked again

    def _model_inputs(self) -> dict[str, Any]:
        """More inputs of each model request besides the messages (a VLM's images); none here."""
        return {}

    def _run_tool(self, call: Mapping[str, Any]) -> str:
        """Run one tool call; errors become the tool's answer so the model can recover."""
        name = call["function"]["name"]
        fn = self.config.tools.get(name)
        if fn is None:
            return f"error: unknown tool {name!r}; available tools: {', '.join(self.config.tools) or 'none'}"
        try:
            args = json.loads(call["function"]["arguments"] or "{}")
            if not isinstance(args, dict):
                raise TypeError(f"arguments must be a JSON object, got {args!r}")
            result = fn(**args)
        except Exception as exc:
            self.logger.warning("%s: tool %s failed: %s", self._label(), name, exc)
            return f"error: {type(exc).__name__}: {exc}"
        self.logger.info("%s: tool call %s(%s) -> %.200s", self._label(), name, call["function"]["arguments"], result)
        if isinstance(result, Mapping) and isinstance(result.get("summary"), str):
            return str(result["summary"])  # a tool's own words read better to a small model than JSON
        return result if isinstance(result, str) else json.dumps(result, default=str)
