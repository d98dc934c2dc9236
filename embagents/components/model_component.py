"""Components that run inference through a model client, with hot swap and warmup.

A model client is any object with the method the component calls, named by
the class attribute :attr:`ModelComponent.client_methods` and checked once,
when the client is added: ``chat_stream``/``chat`` for an :class:`~embagents.components.LLM`,
``detect`` for :class:`~embagents.components.Vision`, ``transcribe`` for
:class:`~embagents.components.SpeechToText`, ``speak`` for
:class:`~embagents.components.TextToSpeech`; a local model actor's client, an
HTTP client, or an in-process backend. Each subclass warms its client up its
own way (:meth:`ModelComponent.run_warmup`). Clients are
named by their ``name`` attribute (else their class name); extra clients are
standbys that :meth:`ModelComponent.change_model_client` (or a fallback's
``switch_model_client``) swaps in without a restart. A step that failed
(a dead primary: the question it carried) is run once more on the new
client when the switch comes within ``RETRY_WITHIN_S`` of the failure, so
the request that met the dead client is answered, not lost.

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

import time
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, ClassVar

from embagents.components.component import Component, ComponentProblem
from embagents.events import Fallback
from embagents.models.chat import ChatClient, chat_chunks

__all__ = ["ChatClient", "ModelComponent", "chat_chunks", "client_name"]


def client_name(client: object) -> str:
    """A client's name: its ``name`` attribute when it is a non-empty str, else its class name.

    >>> client_name(object())
    'object'
    """
    name = getattr(client, "name", None)
    return name if isinstance(name, str) and name else type(client).__name__


class ModelComponent(Component):
    """A component with a model client, standby clients, hot swap and warmup.

    ``warmup=True`` sends one tiny request in :meth:`on_configure`, so the
    first real request does not pay for loading the model.
    """

    #: The client methods this component calls: a client needs at least one (checked when it is added).
    client_methods: ClassVar[tuple[str, ...]] = ("chat_stream", "chat")
    #: What the component asks of its client, for the error naming a client that cannot do it.
    client_task: ClassVar[str] = "chat"
    #: The fix that error names: which client to give.
    client_fix: ClassVar[str] = "an object with chat_stream() or chat(), e.g. LocalModelClient(LlamaModel(...))"

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
            self._client_problems.append(("missing-client", f"needs a model_client: {self.client_fix}"))
        else:
            self.client_name = self.add_client(client_name(model_client), model_client)
        extras = extra_clients.items() if isinstance(extra_clients, Mapping) else ((client_name(c), c) for c in extra_clients)
        for key, client in extras:
            self.add_client(key, client)
        self.warmup = bool(warmup)
        #: The inputs, fresh topics and time of the last step that failed (retried once on a new client).
        self._failed_step: tuple[dict[str, Any], frozenset[str], float] | None = None
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

    @classmethod
    def can_serve(cls, client: object) -> bool:
        """Whether ``client`` has one of :attr:`client_methods`."""
        return any(callable(getattr(client, m, None)) for m in cls.client_methods)

    def _cannot(self, key: str) -> str:
        methods = [f"{m}()" for m in self.client_methods]
        has = f"it has no {methods[0]}" if len(methods) == 1 else f"it has neither {' nor '.join(methods)}"
        return f"model client {key!r} cannot {self.client_task} ({has}); give it {self.client_fix}"

    def add_client(self, key: str, client: Any) -> str:
        """Add ``client`` as a standby named ``key``; a client that cannot serve this component is a problem
        :meth:`validate` reports (``bad-client``), as is a second, different client of the same name."""
        if not self.can_serve(client):
            self._client_problems.append(("bad-client", self._cannot(key)))
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
            if not self.can_serve(name_or_client):
                raise TypeError(f"{self._label()}: {self._cannot(client_name(name_or_client))}")
            key = next((k for k, c in self.clients.items() if c is name_or_client), client_name(name_or_client))
            if self.clients.setdefault(key, name_or_client) is not name_or_client:
                raise ValueError(f"{self._label()} already has a different model client named {key!r}")
        previous, self.client_name, self.model_client = self.client_name, key, self.clients[key]
        self.client_switches += 1  # reports from now on are told apart from those before the switch
        self.logger.info("%s: model client %s -> %s", self._label(), previous, key)
        failed, self._failed_step = self._failed_step, None
        if failed is not None and key != previous and time.monotonic() - failed[2] <= self.RETRY_WITHIN_S:
            try:  # after this request is answered: a fallback's tell must not wait on a generation
                self.call_later(0.0, lambda: self._retry(failed))
            except RuntimeError:  # not under a runtime (a test, a script): now
                self._retry(failed)
        return previous

    #: A failed step is retried on a new client switched in at most this many seconds after it failed.
    RETRY_WITHIN_S = 60.0

    def run_step(self, inputs: Mapping[str, Any], fresh: Iterable[str] | None = None) -> bool:
        """:meth:`Component.run_step`, keeping a failed step's inputs for one retry on the next client."""
        fresh_now = self.fresh_inputs if fresh is None else frozenset(fresh)
        ok = super().run_step(inputs, fresh)
        self._failed_step = None if ok else (dict(inputs), fresh_now, time.monotonic())
        return ok

    def _retry(self, failed: tuple[dict[str, Any], frozenset[str], float]) -> None:
        inputs, fresh, _ = failed
        self.logger.info("%s: retrying the step that failed, on model client %s", self._label(), self.client_name)
        self.run_step(inputs, fresh)
        self._failed_step = None  # once: a failure now is reported, not retried again

    def run_warmup(self) -> None:
        """Send one tiny request through the active client (loads the model): each modality its own."""
        raise NotImplementedError(f"{type(self).__name__} has warmup=True but no run_warmup(): define it "
                                  "(one tiny request through self.model_client)")

    def on_configure(self) -> None:
        """Warm the client up when ``warmup`` is set."""
        if self.warmup:
            self.run_warmup()
