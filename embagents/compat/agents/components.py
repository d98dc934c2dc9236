"""EmbodiedAgents' components, built as embagents components (each its own supervised process).

Each takes EmbodiedAgents' arguments (``component_name=``, ``model_client=``
of :mod:`.clients`, ``db_client=``, a :mod:`.config` object) and its methods:
``set_topic_prompt`` / ``set_component_prompt`` (jinja2 templates),
``set_system_prompt``, ``register_tool(tool, tool_description,
send_tool_response_to_model=...)``, ``add_publisher_preprocessor``,
``on_algorithm_fail`` / ``on_component_fail`` / ``on_system_fail`` /
``on_fail``, ``additional_model_clients = {...}`` and
``change_model_client``. The objects are embagents components: anything
native works on them too.

Example::

    >>> from embagents.compat.agents.ros import Topic
    >>> from embagents.compat.agents.clients import OllamaClient
    >>> from embagents.compat.agents.models import OllamaModel
    >>> q, a = Topic(name="text0", msg_type="String"), Topic(name="text1", msg_type="String")
    >>> llm = LLM(inputs=[q], outputs=[a], model_client=OllamaClient(OllamaModel(name="qwen", checkpoint="qwen3:0.6b")),
    ...           trigger=q, component_name="brain")
    >>> llm.set_topic_prompt(q, template="Answer briefly: {{ text0 }}")
    >>> llm.name, llm.question_text(q, {"text0": type("M", (), {"data": "hi"})()})
    ('brain', 'Answer briefly: hi')
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import attrs
import numpy as np

from embagents import components as native
from embagents.compat._core import CompatError, note, unsupported
from embagents.compat.agents.clients import build_client, local_default
from embagents.compat.agents.config import CortexConfig, _Config
from embagents.compat.agents.ros import FunctionAction
from embagents.components.llm_tools import register_tools_on, tool_methods
from embagents.components.memory import embedding_dim
from embagents.components.memory_store import MemoryStore
from embagents.events import Action, Fallback
from embagents.models.files.wheels import cache_dir
from embagents.msgs import (
    Audio,
    CompressedImage,
    Detections,
    Image,
    Pose,
    PoseStamped,
    StreamingString,
    String,
)
from embagents.topic import Topic

__all__ = ["LLM", "MLLM", "VLA", "VLM", "Cortex", "MapEncoding", "Memory", "SemanticRouter", "SpeechToText",
           "TextToSpeech", "Vision"]


def _translate(cls: type, role: str, kw: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """EmbodiedAgents' keyword arguments -> ours, and the compat-only config fields."""
    kw = dict(kw)
    if "component_name" in kw:
        if "name" in kw:
            raise CompatError(f"{cls.__name__}: give component_name= or name=, not both")
        kw["name"] = kw.pop("component_name")
    if "name" not in kw:
        raise CompatError(f"{cls.__name__}: needs component_name= (the component's name)")
    kw.pop("callback_group", None)  # each component is its own process here
    if "fallbacks" in kw:  # Sugarcoat's ComponentFallbacks (an embagents Fallback already)
        kw["fallback"] = kw.pop("fallbacks")
    extras: dict[str, Any] = {}
    config = kw.get("config")
    if isinstance(config, _Config):
        extras, kw["config"] = dict(config.extras), config.native
    wanted = getattr(cls, "config_class", None)
    given = kw.get("config")
    if wanted is not None and given is not None and not isinstance(given, wanted) and isinstance(wanted, type) \
            and issubclass(wanted, type(given)):
        kw["config"] = wanted(**attrs.asdict(given, recurse=False))  # an LLMConfig given to a VLM: its VLMConfig
    name = str(kw["name"])
    if kw.get("model_client") is not None:
        kw["model_client"] = build_client(kw["model_client"], role, name, bool(extras.get("enable_local_model")))
    elif role and (extras.get("enable_local_model") or extras.get("enable_local_classifier")):
        what = "enable_local_classifier=True" if role == "vision" else "enable_local_model=True"
        kw["model_client"] = local_default(role, f"{name}_model", f"{cls.__name__}'s local model", what)
    return kw, extras


def _supervisor_action(fn: Callable[..., Any]) -> Callable[..., Any]:
    fn._supervisor_action = True  # type: ignore[attr-defined]
    return fn


class _Lifecycle:
    """``start`` / ``stop`` / ``restart`` for ``Action(method=component.restart)``: the supervisor's actions.

    Last in each class's bases, so a component's own method of that name (VLA's ``stop``) wins.
    """

    @_supervisor_action
    def start(self) -> None:
        """Under supervision an Action runs this as the supervisor's start of the component."""
        raise CompatError("start() is the supervisor's: use it in an Action(method=component.start)")

    @_supervisor_action
    def stop(self) -> None:
        """Under supervision an Action runs this as the supervisor's stop of the component."""
        raise CompatError("stop() is the supervisor's: use it in an Action(method=component.stop)")

    @_supervisor_action
    def restart(self) -> None:
        """Under supervision an Action runs this as the supervisor's restart of the component."""
        raise CompatError("restart() is the supervisor's: use it in an Action(method=component.restart)")


class _Fallbacks:
    """EmbodiedAgents' ``on_*_fail`` methods, building the component's :class:`~embagents.events.Fallback`."""

    fallback: Fallback | None

    def _add_rule(self, key: str, action: Action | list[Action], max_retries: int | None) -> None:
        rules = dict(getattr(self, "_compat_rules", {}))
        rules[key] = action
        self._compat_rules = rules
        retries = max_retries if max_retries is not None else getattr(self, "_compat_retries", 3)
        self._compat_retries = retries
        self.fallback = Fallback(**rules, max_retries=retries)

    def on_algorithm_fail(self, action: Action | list[Action], max_retries: int | None = None) -> None:
        """Run ``action`` when a step fails (up to ``max_retries`` times in a row, then give up)."""
        self._add_rule("on_algorithm_fail", action, max_retries)

    def on_component_fail(self, action: Action | list[Action], max_retries: int | None = None) -> None:
        """Run ``action`` when the component reports itself broken."""
        self._add_rule("on_component_fail", action, max_retries)

    def on_system_fail(self, action: Action | list[Action], max_retries: int | None = None) -> None:
        """Run ``action`` when something outside the component is broken."""
        self._add_rule("on_system_fail", action, max_retries)

    def on_fail(self, action: Action | list[Action], max_retries: int | None = None) -> None:
        """Run ``action`` on any failure."""
        for key in ("on_algorithm_fail", "on_component_fail", "on_system_fail"):
            self._add_rule(key, action, max_retries)


class _Clients(_Fallbacks):
    """``additional_model_clients = {...}``: standby clients a fallback switches to by name."""

    _role = ""
    clients: dict[str, Any]

    @property
    def additional_model_clients(self) -> dict[str, Any]:
        return {k: c for k, c in self.clients.items() if k != getattr(self, "client_name", None)}

    @additional_model_clients.setter
    def additional_model_clients(self, value: Mapping[str, Any]) -> None:
        if not isinstance(value, Mapping):
            raise CompatError(f"additional_model_clients must be a dict of name -> client, got {value!r}")
        for key, client in value.items():
            built = build_client(client, self._role, str(getattr(self, "name", "")))
            self.add_client(str(key), built)  # type: ignore[attr-defined]
            if self._client_problems:  # type: ignore[attr-defined]
                raise CompatError("; ".join(text for _, text in self._client_problems))  # type: ignore[attr-defined]

    def fallback_to_local(self) -> str:
        """EmbodiedAgents' switch to the built-in local model: ``Action(method=component.fallback_to_local)``
        switches the component to the offline default model (a standby client here)."""
        raise CompatError("fallback_to_local() is an action here: use Action(method=component.fallback_to_local)")

    def local_fallback_client(self) -> str:
        """The name of the standby local client ``fallback_to_local`` switches to (added on the first call)."""
        key = f"{getattr(self, 'name', '')}_local"
        if key not in self.clients:
            client = local_default(self._role, key, f"{type(self).__name__} {getattr(self, 'name', '')!r}'s model "
                                   "after fallback_to_local", "a standby client the fallback switches to")
            self.add_client(key, client)  # type: ignore[attr-defined]
        return key


def _pose(value: Any) -> PoseStamped | None:
    """A preprocessor's result for a PoseStamped topic: a pose, x/y/z coordinates, or a dict with them."""
    if value is None or isinstance(value, PoseStamped):
        return value
    if isinstance(value, Pose):
        return PoseStamped(value)
    if isinstance(value, Mapping):
        value = value.get("position", [value.get("x", 0.0), value.get("y", 0.0), value.get("z", 0.0)])
    xyz = [float(v) for v in np.asarray(value, dtype=np.float64).ravel()[:3]]
    return PoseStamped(Pose((*xyz, *[0.0] * (3 - len(xyz)))))


class _Rag:
    """EmbodiedAgents' RAG: the items of the Memory database ``collection`` (a Memory or MapEncoding with
    ``MemoryConfig(map_name=collection)``) closest in meaning to the question, put before it."""

    def __init__(self, client: Any, collection: str, n_results: int, add_metadata: bool) -> None:
        self.client, self.collection, self.n_results, self.add_metadata = client, collection, n_results, add_metadata
        self.store: Any = None

    @property
    def path(self) -> str:
        return str(cache_dir() / "memory" / f"{self.collection}.db")  # where a Memory of that map_name keeps it

    def context(self, question: str) -> str:
        """The retrieved items as lines (with position, layer and time when ``add_metadata``); "" for none."""
        import json


        if self.store is None:
            name = getattr(self.client, "name", None) or type(self.client).__name__
            self.store = MemoryStore(self.path, dim=embedding_dim(self.client), model=str(name))
        items = self.store.semantic(self.client.embed([question])[0], k=self.n_results)
        if not self.add_metadata:
            return "\n".join(str(it["text"]) for it in items)
        return "\n".join(f"{it['text']} " + json.dumps({"position": [round(float(v), 3) for v in it["position"]],
                                                        "layer": it["layer"], "time": it["time"]}) for it in items)


class _NeedsPreprocessor:
    """The converter of a typed output until ``add_publisher_preprocessor`` gives one (check says so)."""

    def __init__(self, topic: Topic) -> None:
        self.topic = topic

    def __call__(self, text: str) -> None:
        raise RuntimeError(f"output {self.topic.name!r} ({self.topic.type_name}) has no publisher preprocessor")


class LLM(_Clients, native.LLM, _Lifecycle):
    """EmbodiedAgents' LLM (see the module docstring)."""

    _role = "llm"

    def __init__(self, *, component_name: str | None = None, db_client: Any = None, **kw: Any) -> None:
        if component_name is not None:
            kw["component_name"] = component_name
        kw, self._extras = _translate(type(self), self._role, kw)
        self.rag: _Rag | None = None
        if self._extras.get("enable_rag"):
            if db_client is None:
                raise CompatError(f"{type(self).__name__} {kw['name']!r}: LLMConfig(enable_rag=True) needs "
                                  "db_client= (the vector database the answers come from)")
            self.rag = _Rag(build_client(db_client, "embedding", str(kw["name"])),
                            str(self._extras.get("collection_name", "map")), int(self._extras.get("n_results", 1)),
                            bool(self._extras.get("add_metadata", False)))

            note(f"{kw['name']}: RAG reads the memory database {self.rag.collection!r} (a Memory or MapEncoding "
                 f"with MemoryConfig(map_name={self.rag.collection!r}) writes it); its {self.rag.n_results} closest "
                 "items come before each question")
        elif db_client is not None:

            note(f"{kw['name']}: db_client= is unused without LLMConfig(enable_rag=True) (as in EmbodiedAgents)")
        self._templates: dict[str, str] = {}
        self._component_template: str | None = None
        self._raw_tool_result: Any = None
        config = kw.get("config")
        if config is not None and getattr(config, "stream", False) and not any(t.msg_type is StreamingString for t in kw.get("outputs") or ()):
            # EmbodiedAgents streams chunks on a String topic; here a stream is a StreamingString topic.

            note(f"{kw['name']}: stream=True streams on a StreamingString output here; its String outputs get "
                 "the whole answer (add Topic(..., msg_type='StreamingString') for the stream)")
            kw["config"] = attrs.evolve(config, stream=False)
        typed = [t for t in kw.get("outputs") or () if t.msg_type not in (String, StreamingString)]
        converters = dict(kw.pop("output_converters", None) or {})
        for t in typed:
            converters.setdefault(t.name, _NeedsPreprocessor(t))
        self._declared = False
        super().__init__(output_converters=converters, **kw)
        self._declared = True  # from here on, validate() (embagents check) asks for the missing preprocessors

    def validate(self) -> list[tuple[str, str]]:
        problems = super().validate()
        for name, fn in getattr(self, "output_converters", {}).items():
            if isinstance(fn, _NeedsPreprocessor) and getattr(self, "_declared", False):
                problems.append(("needs-preprocessor", f"{self._label()}: output {name!r} carries "
                                 f"{fn.topic.type_name}, but an LLM answers in text: give it "
                                 f"add_publisher_preprocessor({name}, fn) turning the answer into one"))
        return problems

    # --- prompts ---------------------------------------------------------------------------

    @staticmethod
    def _parse(template: str) -> str:
        import jinja2

        try:
            jinja2.Environment().parse(template)
        except jinja2.TemplateSyntaxError as exc:
            raise CompatError(f"template {template!r}: {exc.message} (line {exc.lineno})") from None
        return template

    def set_topic_prompt(self, input_topic: Topic, template: str) -> None:
        """Wrap each question from ``input_topic`` in a jinja2 ``template`` (``{{ topic_name }}``: its text)."""
        if input_topic.name not in {t.name for t in self.inputs}:
            raise CompatError(f"{self._label()}: set_topic_prompt: {input_topic.name!r} is not one of its inputs")
        self._templates[input_topic.name] = self._parse(template)

    def set_component_prompt(self, template: str) -> None:
        """Wrap every question in a jinja2 ``template`` naming the input topics."""
        self._component_template = self._parse(template)

    def set_system_prompt(self, prompt: str) -> None:
        """The system message."""
        self.config = attrs.evolve(self.config, system_prompt=prompt)

    def question_text(self, topic: Topic, inputs: Mapping[str, Any]) -> str:
        text = self._templated(topic, inputs)
        if self.rag is None:
            return text
        found = self.rag.context(str(getattr(inputs.get(topic.name), "data", "")) or text)
        return f"{found}\n\n{text}" if found else text

    def _templated(self, topic: Topic, inputs: Mapping[str, Any]) -> str:
        template = self._templates.get(topic.name) or self._component_template
        if template is None:
            return super().question_text(topic, inputs)
        import jinja2

        values = {t.name: _prompt_value(inputs.get(t.name)) for t in self.inputs}
        values.update({k.replace("/", "_"): v for k, v in values.items()})
        return jinja2.Template(template).render(values)

    # --- tools and outputs -----------------------------------------------------------------

    def register_tool(self, tool: Callable[..., Any], tool_description: Mapping[str, Any] | None = None,  # type: ignore[override]
                      send_tool_response_to_model: bool = False, **kw: Any) -> None:
        """EmbodiedAgents' register_tool: ``tool_description`` is OpenAI's ``{"type": "function", "function": {...}}``."""
        function = dict((tool_description or {}).get("function", tool_description or {}))
        name = function.get("name") or tool.__name__

        def keep(*args: Any, **kwargs: Any) -> Any:
            result = tool(*args, **kwargs)
            if not send_tool_response_to_model:  # the result is the answer: a preprocessor gets it as it is
                self._raw_tool_result = result
            return result.tolist() if isinstance(result, np.ndarray) else result

        keep.__name__, keep.__doc__ = name, function.get("description") or tool.__doc__
        super().register_tool(keep, function.get("parameters"), name=name,
                              send_tool_response_to_model=send_tool_response_to_model)
        if not send_tool_response_to_model:  # EmbodiedAgents publishes the tool's own result on a typed output
            for out in self.outputs:
                if isinstance(self.output_converters.get(out.name), _NeedsPreprocessor):
                    self.add_publisher_preprocessor(out, lambda value: value)

    def add_publisher_preprocessor(self, topic: Topic, fn: Callable[[Any], Any]) -> None:
        """Publish ``fn(output)`` on ``topic`` (``None``: nothing); the output is a tool's own result when the
        answer is one (``send_tool_response_to_model=False``), else the text."""
        out = self.output(topic)

        def convert(text: str) -> Any:
            raw, self._raw_tool_result = self._raw_tool_result, None
            value = fn(raw if raw is not None else text)
            if out.msg_type is PoseStamped:
                return _pose(value)
            if isinstance(value, str) and out.msg_type in (String, StreamingString):
                return out.msg_type(data=value)
            if value is not None and not isinstance(value, out.msg_type):
                raise TypeError(f"{self._label()}: the publisher preprocessor of {out.name!r} returned {value!r}, "
                                f"not a {out.type_name}")
            return value

        self.output_converters[out.name] = convert


def _prompt_value(msg: Any) -> str:
    """A message as a prompt template shows it: a text's data, detections as their labels ("cup, chair")."""
    if isinstance(msg, Detections):
        return ", ".join(dict.fromkeys(str(label) for label in msg.labels))
    data = getattr(msg, "data", "")
    return data if isinstance(data, str) else ""  # an image is the model's to see, not the prompt's text


class VLM(LLM, native.VLM, _Lifecycle):
    """EmbodiedAgents' VLM (MLLM); a Detections input fills its prompt template with the labels seen."""

    _role = "vlm"
    allowed_inputs = {"Required": [String], "Optional": [String, Image, CompressedImage, Detections]}
    #: What a Cortex may ask it (EmbodiedAgents' Cortex discovers the components' actions).
    llm_tools: tuple[str, ...] = ("describe",)


MLLM = VLM


class SpeechToText(_Clients, native.SpeechToText, _Lifecycle):
    """EmbodiedAgents' SpeechToText."""

    _role = "stt"

    def __init__(self, *, component_name: str | None = None, **kw: Any) -> None:
        if component_name is not None:
            kw["component_name"] = component_name
        kw, self._extras = _translate(type(self), self._role, kw)
        super().__init__(**kw)


class TextToSpeech(_Clients, native.TextToSpeech, _Lifecycle):
    """EmbodiedAgents' TextToSpeech: with no outputs it publishes ``<name>_audio``; ``play_on_device=True``
    adds a Speaker component playing it."""

    _role = "tts"

    def __init__(self, *, component_name: str | None = None, **kw: Any) -> None:
        if component_name is not None:
            kw["component_name"] = component_name
        kw, self._extras = _translate(type(self), self._role, kw)
        if not kw.get("outputs"):
            kw["outputs"] = [Topic(f"{kw['name']}_audio", Audio, queue_size=1000, keep="all")]
        #: More components the launcher adds with this one (the speaker).
        self.companions: list[native.Component] = []
        super().__init__(**kw)
        if self._extras.get("play_on_device"):
            self.companions.append(native.Speaker(name=f"{self.name}_speaker", inputs=[self.outputs[0]]))


class Vision(_Clients, native.Vision, _Lifecycle):
    """EmbodiedAgents' Vision; ``enable_local_classifier=True`` without a model client: the offline detector."""

    _role = "vision"

    def __init__(self, *, component_name: str | None = None, **kw: Any) -> None:
        if component_name is not None:
            kw["component_name"] = component_name
        kw, self._extras = _translate(type(self), self._role, kw)
        super().__init__(**kw)


class SemanticRouter(_Fallbacks, native.SemanticRouter, _Lifecycle):
    """EmbodiedAgents' SemanticRouter: ``db_client`` gives the embeddings (all-MiniLM-L6-v2 here)."""

    def __init__(self, *, component_name: str | None = None, db_client: Any = None, **kw: Any) -> None:
        if component_name is not None:
            kw["component_name"] = component_name
        kw, self._extras = _translate(type(self), "", kw)
        if db_client is not None:
            kw["embedding_client"] = build_client(db_client, "embedding", str(kw["name"]))
        if kw.get("model_client") is not None:
            kw["model_client"] = build_client(kw["model_client"], "llm", str(kw["name"]))
            kw["config"] = kw.get("config") or native.SemanticRouterConfig(mode="llm")
        super().__init__(**kw)


class MapEncoding(_Fallbacks, native.MapEncoding, _Lifecycle):
    """EmbodiedAgents' MapEncoding: ``db_client`` gives the embeddings; the database is built in."""

    def __init__(self, *, component_name: str | None = None, name: str | None = None, db_client: Any = None,
                 **kw: Any) -> None:
        kw, self._extras = _translate(type(self), "", {**kw, "name": component_name or name or "map_encoding"})
        name = kw.pop("name")
        super().__init__(component_name=name, db_client=build_client(db_client, "embedding", name), **kw)


class VLA(_Fallbacks, native.VLA, _Lifecycle):
    """EmbodiedAgents' VLA: ``model_client`` (a LeRobotClient) is the policy."""

    def __init__(self, *, component_name: str | None = None, model_client: Any = None, **kw: Any) -> None:
        if component_name is not None:
            kw["component_name"] = component_name
        kw, self._extras = _translate(type(self), "", kw)
        if model_client is not None:
            kw["policy"] = build_client(model_client, "policy", str(kw["name"]))
        super().__init__(**kw)


def _where(item: Mapping[str, Any]) -> str:
    pos = [float(v) for v in item.get("position", ())][:3]
    pos += [0.0] * (3 - len(pos))
    ago = time.time() - float(item.get("time", time.time()))
    return f"[{item.get('layer', '')}] {item.get('text', '')} ({ago:.0f} s ago) Location: ({pos[0]:.2f}, {pos[1]:.2f}, {pos[2]:.2f})"


class Memory(_Fallbacks, native.Memory, _Lifecycle):
    """EmbodiedAgents' Memory (eMEM), built on embagents' Memory (SQLite, sqlite-vec index).

    Its tools keep eMEM's names and answer in text, a place as ``Location: (x, y, z)``:
    ``locate(concept)``, ``recall(concept)``, ``semantic_search(query, n_results)``,
    ``spatial_query(x, y, radius)``, ``temporal_query(seconds_ago)``, ``body_status()``
    (the latest item of each ``is_internal_state`` layer). eMEM's episodes, gists and
    entities (consolidation by ``model_client``) are not done here: items are kept as they came.
    """

    llm_tools: tuple[str, ...] = ("locate", "recall", "semantic_search", "spatial_query", "temporal_query",
                                  "body_status")

    def __init__(self, *, layers: list[Any], position: Topic | None = None, model_client: Any = None,
                 embedding_client: Any = None, config: Any = None, trigger: Any = 10.0,
                 component_name: str | None = None, **kw: Any) -> None:

        if component_name is not None:
            kw["component_name"] = component_name
        kw, self._extras = _translate(type(self), "", {**kw, "config": config, "trigger": trigger})
        name = str(kw.pop("name"))
        if kw.get("config") is None:
            kw.pop("config")
        if model_client is not None:
            note(f"Memory {name!r}: model_client (eMEM's consolidation into gists and entities) is not used here: "
                 "items are kept as they came")
        if embedding_client is None:
            embedding = local_default("embedding", "minilm", f"Memory {name!r}'s sentence-transformers embeddings",
                                      "no embedding_client given")
        else:
            embedding = build_client(embedding_client, "embedding", name)
        self.internal_layers = [layer.name for layer in layers if getattr(layer, "is_internal_state", False)]
        super().__init__(name=name, layers=layers, position=position, embedding_client=embedding, **kw)

    def locate(self, concept: str) -> str:  # type: ignore[override]  # eMEM's tool: text, not the native dict
        """Where something (a ``concept``: "cup", "kitchen") was last seen: its text and ``Location: (x, y, z)``."""
        found = native.Memory.locate(self, concept)
        if not found.get("found"):
            return str(found["summary"])
        near = f"; near {'; '.join(found['near'])}" if found.get("near") else ""
        return _where({**found, "layer": found.get("layer", "")}) + near

    def recall(self, concept: str, n_results: int = 5) -> str:
        """Everything remembered about a ``concept``, closest in meaning first."""
        return self.semantic_search(concept, n_results)

    def semantic_search(self, query: str, n_results: int = 5, layer: str | None = None) -> str:
        """The ``n_results`` remembered items closest in meaning to ``query``, one a line."""
        items = native.Memory.query(self, query, k=n_results, layer=layer)
        return "\n".join(_where(it) for it in items) or f"nothing is remembered about {query!r}"

    def spatial_query(self, x: float, y: float, radius: float = 2.0, layer: str | None = None) -> str:
        """What was seen within ``radius`` metres of (``x``, ``y``), nearest first, one a line."""
        items = self.near(x, y, radius, layer)
        return "\n".join(_where(it) for it in items) or f"nothing is remembered within {radius} m of ({x}, {y})"

    def temporal_query(self, seconds_ago: float = 300.0, layer: str | None = None) -> str:
        """What was seen in the last ``seconds_ago`` seconds, one a line."""
        items = self.between(-abs(float(seconds_ago)), None, layer)
        return "\n".join(_where(it) for it in items) or f"nothing was stored in the last {seconds_ago} s"

    def body_status(self) -> str:
        """The latest reading of each internal-state layer (battery...)."""
        lines = []
        for name in self.internal_layers:
            items = self.between(0.0, None, name)
            if items:
                lines.append(_where(max(items, key=lambda it: float(it.get("time", 0.0)))))
        return "\n".join(lines) or "no internal-state reading is stored yet"

    def register_tools_on(self, llm: Any, tools: Sequence[str] | None = None,
                          send_tool_response_to_model: bool = True) -> None:
        """Offer this memory's tools (all, or ``tools``) to ``llm``; ``send_tool_response_to_model=False``:
        the tool's text is the answer (a publisher preprocessor turns it into the output)."""

        for t in tools or ():
            if t not in self.llm_tools:
                unsupported(f"Memory tool {t!r} (eMEM's episodes, gists and entities)",
                            f"one of {', '.join(self.llm_tools)}")
        names = register_tools_on(llm, self, methods=list(tools) if tools else list(self.llm_tools))
        if not send_tool_response_to_model:
            direct = [*llm.config.tools_answer_directly, *(n for n in names if n not in llm.config.tools_answer_directly)]
            llm.config = attrs.evolve(llm.config, tools_answer_directly=direct)


class Cortex(LLM):
    """EmbodiedAgents' Cortex, mapped to an LLM that plans and acts through tools.

    Its tools are the ``actions`` (``Action(method=fn, description=...)`` of plain
    functions, run in its own process) and, at ``bringup()``, the tools every
    other component of the launcher offers (a Memory's ``locate``, ``recall``...,
    a VLM's ``describe``), called in their own processes. A goal sent on ``ui_main_action_input``
    (``<name>_input``) is answered on ``output``; ``CortexConfig(max_execution_steps=)``
    bounds the tool rounds. EmbodiedAgents' separate planning and per-step confirmation
    calls are one tool loop here.
    """

    def __init__(self, *, actions: Sequence[Any] | None = None, output: Topic | None = None, model_client: Any = None,
                 db_client: Any = None, config: Any = None, component_name: str | None = None, **kw: Any) -> None:

        name = str(component_name or kw.pop("name", "") or "")
        if not name:
            raise CompatError("Cortex: needs component_name= (the component's name)")
        config = config if config is not None else CortexConfig()
        if model_client is None and not getattr(config, "enable_local_model", False):
            raise CompatError("Cortex: needs a model_client or CortexConfig(enable_local_model=True)")
        self.ui_main_action_input = Topic(f"{name}_input", String)
        out = output if output is not None else Topic(f"{name}_output", String)
        super().__init__(inputs=[self.ui_main_action_input], outputs=[out], model_client=model_client,
                         db_client=db_client, config=config, trigger=self.ui_main_action_input,
                         component_name=name, **kw)
        if not self.config.system_prompt:
            self.set_system_prompt("You are the robot's planner. Reach the user's goal by calling the tools you are "
                                   "given, one step at a time; when it is reached or cannot be, say so briefly.")
        for action in actions or ():
            if not isinstance(action, FunctionAction):
                raise CompatError(f"Cortex {name!r}: actions must be Action(method=function, description=...), "
                                  f"got {action!r}")
            fn = action.method
            self.register_tool(fn, {"name": fn.__name__, "description": action.description},
                               send_tool_response_to_model=True)

    def discover_tools(self, components: Sequence[native.Component]) -> list[str]:
        """Offer ``components``' tools (their ``llm_tools``) to this Cortex; returns the tool names added."""

        offering = [c for c in components if tool_methods(c) and not isinstance(c, Cortex)]
        return register_tools_on(self, *offering) if offering else []
