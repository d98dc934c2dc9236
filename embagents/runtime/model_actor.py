"""A local model actor: llama.cpp in its own process, serving streamed requests.

Requests arrive on a ROUTER at ``<run>/<name>.inf`` as ``[id, "chat_stream",
messages, options]`` from any number of components; each token goes back
as its own frame ``[id, chunk]`` the moment llama.cpp yields it. Requests
are served one at a time in arrival order (llama.cpp holds one context).
"""

from __future__ import annotations

import logging
import time
from typing import Any

import msgpack
import zmq

from actors import Actor
from actors.runtime import current

__all__ = ["LlamaModelActor"]

log = logging.getLogger("embagents.model")


class LlamaModelActor(Actor):
    """Hosts ``LlamaBackend(model_path)``; args are plain data (msgpack)."""

    def __init__(self, model_path: str, options: dict[str, Any] | None = None, warmup: bool = True) -> None:
        self.model_path = model_path
        self.options = options or {}
        self.do_warmup = warmup

    def on_start(self) -> None:
        from embagents.backends.llama import LlamaBackend

        t0 = time.monotonic()
        self.backend = LlamaBackend(self.model_path, **self.options)
        self.backend.load()
        if self.do_warmup:
            self.backend.warmup()
        log.info("loaded %s in %.2f s", self.model_path, time.monotonic() - t0)
        rt = current()
        s = rt.ctx.socket(zmq.ROUTER)
        s.setsockopt(zmq.LINGER, 0)
        s.bind(f"ipc://{rt.run_dir}/{self.name}.inf")
        self.sock = s
        self.served = 0
        self.context.watch(s, self._serve)

    def _serve(self) -> None:
        while True:
            try:
                ident, frame = self.sock.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            except ValueError:
                continue
            try:
                rid, op, messages, options = msgpack.unpackb(frame)
                if op != "chat_stream":
                    raise ValueError(f"unknown operation {op!r}")
            except Exception as exc:
                log.warning("dropped a bad inference request: %s", exc)
                continue
            try:
                for chunk in self.backend.chat_stream(messages, **options):
                    self.sock.send_multipart([ident, msgpack.packb([rid, chunk])])
                    self.context.beat()  # long generations are work, not a hang
            except Exception as exc:
                log.exception("generation failed")
                self.sock.send_multipart([ident, msgpack.packb([rid, {"error": f"{type(exc).__name__}: {exc}", "done": True}])])
            self.served += 1

    def on_receive(self, message: Any) -> Any:
        if message == "stats":
            return {"served": self.served, "model": self.model_path}
        if isinstance(message, dict) and message.get("op") == "chat":
            return self.backend.chat(message["messages"], **message.get("options", {}))
        raise ValueError(f"unknown message {message!r}: send 'stats' or {{'op': 'chat', 'messages': [...]}}")

    def on_stop(self) -> None:
        self.sock.close(0)
        self.backend.close()
