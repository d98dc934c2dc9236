"""Components that run inference through a model client, with hot swap and warmup.

A model client is any object with ``chat_stream(messages, **options)``
(yielding ``{"delta": str}`` chunks then ``{"done": True, "finish_reason":
str, "tool_calls": list | None}``) or ``chat(messages, **options)``: a local
model actor's client, an HTTP client, or an in-process backend. Clients are
named by their ``name`` attribute (else their class name); extra clients are
standbys that :meth:`ModelComponent.change_model_client` (or a fallback's
``switch_model_client``) swaps in without a restart.

Example::

    >>> class Echo:
    ...     name = "echo"
    ...     def chat_stream(self, messages, **options):
    ...         yield {"delta": messages[-1]["content"]}
    ...         yield {"done": True, "finish_reason": "stop", "tool_calls": None}
    >>> class Upper(Echo):
    ...     name = "upper"
    >>> mc = ModelComponent(name="m", model_client=Echo(), extra_clients=[Upper()])
    >>> mc.change_model_client("upper")
    'echo'
    >>> mc.client_name
    'upper'
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from typing import Any

from embagents.components.component import Component, ComponentProblem
from embagents.events import Fallback
from embagents.models.chat import ChatClient

__all__ = ["ChatClient", "ModelComponent", "client_name"]


def client_name(client: object) -> str:
    """A client's name: its ``name`` attribute when it is a non-empty str, else its class name.

    >>> client_name(object())
    'object'
    """
    name = getattr(client, "name", None)
    return name if isinstance(name, str) and name else type(client).__name__


def _is_client(client: object) -> bool:
    return callable(getattr(client, "chat_stream", None)) or callable(getattr(client, "chat", None))


class ModelComponent(Component):
    """A component with a model client, standby clients, hot swap and warmup.

    ``warmup=True`` sends one tiny request in :meth:`on_configure`, so the
    first real request does not pay for loading the model.
    """

    def __init__(
        self,
        *,
        name: str,
        model_client: Any = None,
        extra_clients: Sequence[Any] | Mapping[str, Any] = (),
        warmup: bool = False,
        **kw: Any,
    ) -> None:
        self.clients: dict[str, Any] = {}
        self._client_problems: list[tuple[str, str]] = []
        self.model_client = model_client
        self.client_name: str | None = None
        if model_client is None:
            self._client_problems.append(("missing-client", "needs a model_client (an object with chat_stream or chat)"))
        else:
            self.client_name = self._add_client(client_name(model_client), model_client)
        extras = extra_clients.items() if isinstance(extra_clients, Mapping) else ((client_name(c), c) for c in extra_clients)
        for key, client in extras:
            self._add_client(key, client)
        self.warmup = bool(warmup)
        super().__init__(name=name, **kw)

    @property
    def additional_model_clients(self) -> dict[str, Any]:
        """EmbodiedAgents' spelling, refused when set: standby clients are ``extra_clients=`` here."""
        return {k: c for k, c in self.clients.items() if k != self.client_name}

    @additional_model_clients.setter
    def additional_model_clients(self, value: Any) -> None:
        raise AttributeError(f"{self._label()}: additional_model_clients does nothing here; give standby clients "
                             f"as {type(self).__name__}(..., extra_clients={{'name': client}}) and switch with "
                             "a Fallback(on_algorithm_fail=switch_model_client('name'))")

    def _add_client(self, key: str, client: Any) -> str:
        if not _is_client(client):
            self._client_problems.append(("bad-client", f"model client {client!r} has neither chat_stream() nor chat()"))
        elif key in self.clients and self.clients[key] is not client:
            self._client_problems.append(("duplicate-client", f"two different model clients are named {key!r}; give them distinct names"))
        else:
            self.clients[key] = client
        return key

    def validate(self) -> list[ComponentProblem]:
        problems = super().validate()
        return problems + [(code, f"{self._label()}: {text}") for code, text in self._client_problems]

    def _validate_fallback(self, fallback: Fallback) -> list[ComponentProblem]:
        known = ", ".join(self.clients) or "none"
        return [
            ("unknown-client", f"{self._label()}: fallback switches to model client {a.args['client']!r}, "
                               f"which it does not have; known clients: {known}")
            for a in fallback.actions
            if a.kind == "switch_model_client" and a.args["client"] not in self.clients
        ]

    def change_model_client(self, name_or_client: str | Any) -> str | None:
        """Swap the active client (by name, or a client object, added if new); returns the previous name."""
        if isinstance(name_or_client, str):
            if name_or_client not in self.clients:
                known = ", ".join(self.clients) or "none"
                raise ValueError(f"{self._label()} has no model client {name_or_client!r}; known clients: {known}")
            key = name_or_client
        else:
            if not _is_client(name_or_client):
                raise TypeError(f"{self._label()}: {name_or_client!r} is not a model client (needs chat_stream or chat)")
            key = next((k for k, c in self.clients.items() if c is name_or_client), client_name(name_or_client))
            if self.clients.setdefault(key, name_or_client) is not name_or_client:
                raise ValueError(f"{self._label()} already has a different model client named {key!r}")
        previous, self.client_name, self.model_client = self.client_name, key, self.clients[key]
        self.client_switches += 1  # reports from now on are told apart from those before the switch
        self.logger.info("%s: model client %s -> %s", self._label(), previous, key)
        return previous

    def chat_stream(self, messages: list[dict[str, Any]], **options: Any) -> Iterator[dict[str, Any]]:
        """Stream chunks from the active client, normalised to ``{"delta"}``... ``{"done": True, ...}``.

        A client with only ``chat()`` may return a str, a dict with ``content``
        (or ``text``), or an iterator of chunks. The last chunk always has ``done``.
        """
        client = self.model_client
        if client is None:
            raise RuntimeError(f"{self._label()} has no model client")
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

    def run_warmup(self) -> None:
        """Send one tiny request through the active client (loads the model)."""
        for _ in self.chat_stream([{"role": "user", "content": "Hi"}], max_tokens=1):
            pass

    def on_configure(self) -> None:
        """Warm the client up when ``warmup`` is set."""
        if self.warmup:
            self.run_warmup()
