"""The SemanticRouter component: a text goes to the output topic whose route it means.

Routes are output topics, each with example phrases (``samples``) and,
optionally, actions fired when a text goes that way (run by the events
actor, like an event's). Two modes (EmbodiedAgents' config shape):

- vector (the default): the text and every sample are embedded (an
  embedding client); the route of the nearest sample wins if its distance
  (``distance_func``: ``"l2"`` or ``"cosine"`` on unit vectors) is at most
  ``maximum_distance``; otherwise the ``default_route`` (or nothing, logged).
- llm: each route is offered to a chat client (``model_client``) as a tool
  whose description is its samples; the model must call one (with
  llama.cpp, a grammar holds its reply to a valid call).

Routes can change at run time: ``reconfigure({"routes": {"goto": ["go to the
kitchen", ...]}})`` (an event's ``reconfigure`` action, or ``embagents``' Call)
re-embeds them; a route's topic must be one of the router's outputs.

Example::

    >>> from embagents.msgs import String
    >>> from embagents.topic import Topic
    >>> goto, chat = Topic("goto", String), Topic("chat", String)
    >>> class Toy:
    ...     def embed(self, texts):
    ...         import numpy as np
    ...         return np.array([[1.0, 0.0] if "go" in t else [0.0, 1.0] for t in texts], np.float32)
    >>> router = SemanticRouter(name="router", inputs=[Topic("heard", String)], embedding_client=Toy(),
    ...     routes=[Route(routes_to=goto, samples=["go to the door"]), Route(routes_to=chat, samples=["hello"])])
    >>> router.route("please go left")
    'goto'
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import attrs
import numpy as np
from attrs import define, field

from actors import ActorRef
from embagents.components.component import Component, ComponentProblem
from embagents.config import BaseComponentConfig, ConfigError, one_of, positive_float
from embagents.events import Action
from embagents.models.chat import collect_stream
from embagents.msgs import String
from embagents.requests import EVENTS_ACTOR, RouteFired
from embagents.topic import Topic

__all__ = ["Route", "SemanticRouter", "SemanticRouterConfig"]


@define(kw_only=True)
class Route:
    """A route: texts like ``samples`` go to topic ``routes_to``, and fire ``actions``."""

    routes_to: Topic
    samples: list[str] = field(factory=list)
    actions: Sequence[Action] = ()


def _routes(value: object) -> dict[str, list[str]]:
    if not isinstance(value, Mapping):
        raise ConfigError(f"routes must map output topic names to example phrases, got {value!r}")
    out = {}
    for name, samples in value.items():
        items = [samples] if isinstance(samples, str) else list(samples)
        if not all(isinstance(s, str) for s in items):
            raise ConfigError(f"route {name!r}: samples must be strings, got {samples!r}")
        out[str(name)] = [s for s in items if s.strip()]
    return out


def _mode(value: object) -> str:
    return one_of("mode", "vector", "llm")(value)


def _distance_func(value: object) -> str:
    return one_of("distance_func", "l2", "cosine")(value)


@define(kw_only=True)
class SemanticRouterConfig(BaseComponentConfig):
    """Settings of :class:`SemanticRouter`.

    - ``router_name``: a name for the routing table (logs).
    - ``mode``: ``"vector"`` (embeddings) or ``"llm"`` (routes as tools of a chat model).
    - ``distance_func``: ``"l2"`` or ``"cosine"``; ``maximum_distance``: farther than
      this from every sample goes to the default route (EmbodiedAgents' defaults: l2, 0.4).
    - ``routes``: output topic name -> example phrases (filled from ``routes=[Route(...)]``;
      changed at run time with ``reconfigure``).

    >>> SemanticRouterConfig(distance_func="cosine").maximum_distance
    0.4
    """

    router_name: str = "router"
    mode: str = field(default="vector", converter=_mode)
    distance_func: str = field(default="l2", converter=_distance_func)
    maximum_distance: float = field(default=0.4, converter=positive_float)
    routes: dict[str, list[str]] = field(factory=dict, converter=_routes)
    system_prompt: str = "Pick the route for the user's text by calling one tool."


def _tool_name(topic: str) -> str:
    name = "".join(c if c.isalnum() else "_" for c in topic).strip("_") or "route"
    return name if name[0].isalpha() else f"to_{name}"


class SemanticRouter(Component):
    """Routes each input ``String`` to an output topic by meaning (see the module docstring)."""

    allowed_inputs = {"Required": [String]}
    allowed_outputs = {"Required": [String], "Optional": [String]}
    config_class = SemanticRouterConfig

    def __init__(self, *, name: str, routes: Sequence[Route] = (), default_route: Route | None = None,
                 embedding_client: Any = None, model_client: Any = None, **kw: Any) -> None:
        self.embedding_client, self.model_client = embedding_client, model_client
        self.default_route = default_route
        all_routes = list(routes) + ([default_route] if default_route and default_route not in routes else [])
        #: Route actions by topic name; the events actor runs them (RouteFired).
        self.route_actions: dict[str, tuple[Action, ...]] = {r.routes_to.name: tuple(r.actions) for r in all_routes
                                                             if r.actions}
        self.clients = {getattr(c, "name", type(c).__name__): c for c in (embedding_client, model_client) if c}
        self._vectors: np.ndarray | None = None
        self._owners: list[str] = []
        outputs = kw.pop("outputs", None) or list({r.routes_to.name: r.routes_to for r in all_routes}.values())
        config = kw.pop("config", None) or SemanticRouterConfig()
        if routes and not config.routes:
            config = attrs.evolve(config, routes={r.routes_to.name: list(r.samples) for r in routes})
        super().__init__(name=name, outputs=outputs, config=config, **kw)

    def default_trigger(self) -> Topic | None:
        return self.inputs[0] if self.inputs else None

    def validate(self) -> list[ComponentProblem]:
        problems = super().validate()
        cfg = self.config
        outputs = {t.name for t in self.outputs}
        if not cfg.routes:
            problems.append(("bad-config", f"{self._label()}: no routes; give routes=[Route(routes_to=topic, "
                                           "samples=['an example phrase', ...]), ...]"))
        for topic, samples in cfg.routes.items():
            if topic not in outputs:
                problems.append(("bad-config", f"{self._label()}: route {topic!r} is not an output topic; "
                                               f"outputs: {', '.join(sorted(outputs))}"))
            if not samples:
                problems.append(("bad-config", f"{self._label()}: route {topic!r} has no example phrases; give it "
                                               "samples=['a phrase that should go there', ...] (a few, varied)"))
        if self.default_route is not None and self.default_route.routes_to.name not in outputs:
            problems.append(("bad-config", f"{self._label()}: the default route's topic is not an output"))
        if cfg.mode == "vector" and not callable(getattr(self.embedding_client, "embed", None)):
            problems.append(("missing-client", f"{self._label()}: vector mode needs an embedding_client with "
                                               "embed(texts), e.g. LocalModelClient(EmbeddingModel(name='minilm'))"))
        if cfg.mode == "llm" and not callable(getattr(self.model_client, "chat_stream", None)):
            problems.append(("missing-client", f"{self._label()}: llm mode needs a model_client with chat_stream "
                                               "(e.g. LocalModelClient(LlamaModel(name='smollm2')))"))
        return problems

    # --- routing ------------------------------------------------------------------------------
    def on_configure(self) -> None:
        if self.config.mode == "vector":
            self._embed_routes()

    def on_reconfigure(self, old_config: Any) -> None:
        self._vectors = None  # new samples: embedded again before the next text
        self.logger.info("%s: routes now %s", self._label(), {k: len(v) for k, v in self.config.routes.items()})
        if self.config.mode == "vector":
            self._embed_routes()

    def _embed_routes(self) -> None:
        owners = [topic for topic, samples in self.config.routes.items() for _ in samples]
        texts = [s for samples in self.config.routes.values() for s in samples]
        self._vectors = np.asarray(self.embedding_client.embed(texts), np.float32)
        self._owners = owners

    def distances(self, text: str) -> dict[str, float]:
        """Each route's distance to ``text`` (its nearest sample), in the configured metric."""
        if self._vectors is None:
            self._embed_routes()
        assert self._vectors is not None
        v = np.asarray(self.embedding_client.embed([text]), np.float32)[0]
        cos = self._vectors @ v
        d = np.sqrt(np.maximum(2.0 - 2.0 * cos, 0.0)) if self.config.distance_func == "l2" else 1.0 - cos
        out: dict[str, float] = {}
        for topic, dist in zip(self._owners, d.tolist(), strict=True):
            out[topic] = min(out.get(topic, np.inf), dist)
        return out

    def route(self, text: str) -> str | None:
        """The topic name ``text`` goes to (the default route's, or None when nothing matches)."""
        if self.config.mode == "llm":
            return self._route_by_llm(text)
        dist = self.distances(text)
        best = min(dist, key=dist.__getitem__)
        if dist[best] <= self.config.maximum_distance:
            return best
        return self.default_route.routes_to.name if self.default_route else None

    def _route_by_llm(self, text: str) -> str | None:
        tools = [{"type": "function", "function": {
            "name": _tool_name(topic), "description": "For texts like: " + "; ".join(samples),
            "parameters": {"type": "object", "properties": {}}}} for topic, samples in self.config.routes.items()]
        by_tool = {_tool_name(topic): topic for topic in self.config.routes}
        messages = [{"role": "system", "content": self.config.system_prompt}, {"role": "user", "content": text}]
        reply = collect_stream(self.model_client.chat_stream(messages, tools=tools, tool_choice="required",
                                                             max_tokens=48, temperature=0.0))
        for call in reply.get("tool_calls") or []:
            if call.get("name") in by_tool:
                return by_tool[call["name"]]
        self.logger.info("%s: the model picked no route for %r", self._label(), text)
        return self.default_route.routes_to.name if self.default_route else None

    def _execution_step(self, **inputs: Any) -> None:
        msg = inputs.get(self.inputs[0].name)
        if msg is None or self.inputs[0].name not in self.fresh_inputs:
            return
        topic = self.route(msg.data)
        if topic is None:
            self.logger.info("%s: %r matches no route (farther than %s) and there is no default route",
                             self._label(), msg.data, self.config.maximum_distance)
            return
        self.publish(topic, String(data=msg.data))
        if topic in self.route_actions:
            self._fire(topic, msg.data)

    def _fire(self, topic: str, text: str) -> None:
        ActorRef(EVENTS_ACTOR).tell(RouteFired(str(self.name), topic, text))
