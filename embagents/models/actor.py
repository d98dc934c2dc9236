"""A model actor: one backend in its own process, serving the inference protocol.

Requests arrive on a ROUTER at ``<run>/<name>.inf`` from any number of
clients. Each is checked on arrival: a bad one (or a frame that is not a
request at all) is answered with an :class:`InferError` at once. Good ones
wait in one queue per client and are served round-robin, so a busy client
cannot starve a quiet one. A batching backend (a detector) takes up to
``max_batch`` requests of different clients in one call; when fewer are
queued than clients were recently active, it waits at most ``batch_wait_ms``
for the others. Streams (tokens) go out chunk by chunk; a cancel from the
client stops the stream between two chunks. Answers are small and travel
inline; request arrays are views of shared memory, let go of before the
answer is sent: the client's own, or a camera's topic frame the client
forwarded (written once, by the camera). A topic ring may reuse a frame's
segment meanwhile, so a request whose forwarded frame was overwritten
before the model read it, or while it ran (before the answer, or a
stream's first chunk, goes out), is answered ``kind="stale"``: its result
would be of a torn frame.
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict, deque
from typing import Any, cast

import zmq

from actors import Actor
from actors.errors import StaleFrame, UnknownMessage
from actors.runtime import current
from embagents.models.protocol import (
    BadRequest,
    InferAnswer,
    InferCancel,
    InferError,
    InferRequest,
    inference_endpoint,
)

__all__ = ["LlamaModelActor", "ModelActor"]

log = logging.getLogger("embagents.model")

#: A client counts as active (worth a batch wait) this long after its last request.
_ACTIVE_S = 1.0


class ModelActor(Actor):
    """Hosts ``make_serving(kind, path, options)``; args are plain data (msgpack).

    ``batch``: ``{"max_batch": int, "batch_wait_ms": float}`` for batching backends.
    """

    def __init__(self, kind: str, path: str, options: dict[str, Any] | None = None, warmup: bool = True,
                 batch: dict[str, Any] | None = None) -> None:
        self.kind, self.path = kind, path
        self.options = options or {}
        self.do_warmup = warmup
        batch = batch or {}
        self.max_batch = max(1, int(batch.get("max_batch", 8)))
        self.batch_wait = max(0.0, float(batch.get("batch_wait_ms", 3.0))) / 1000.0

    def _load(self) -> None:
        from embagents.models.serving import make_serving  # lazy: a cycle

        t0 = time.monotonic()
        self.serving = make_serving(self.kind, self.path, self.options)
        self.serving.load()
        if self.do_warmup:
            self.serving.warmup()
        log.info("loaded %s in %.2f s", self.path, time.monotonic() - t0)

    def on_standby(self) -> None:
        # A warm standby (supervisor.standby) loads and warms the model while the active one serves.
        self._load()

    def on_start(self) -> None:
        if getattr(self, "serving", None) is None:  # not loaded ahead by a standby
            self._load()
        rt = current()
        s = rt.ctx.socket(zmq.ROUTER)
        s.setsockopt(zmq.LINGER, 0)
        s.bind(inference_endpoint(rt.run_dir, self.name))
        self.sock = s
        self.codec, self.reader = rt.codec, rt.reader
        self.queues: OrderedDict[bytes, deque[InferRequest]] = OrderedDict()
        self.last_seen: dict[bytes, float] = {}
        self.cancelled: set[tuple[bytes, int]] = set()
        self.streaming: tuple[bytes, int] | None = None  # the request whose chunks are going out
        self.frames: dict[tuple[bytes, int], list[list[Any]]] = {}  # shared-memory inputs, checked after use
        # cancels_late: a cancel that came after its answer went out (the client drops that answer);
        # stale: requests whose forwarded frame was overwritten before the model was done with it.
        self.stats = {"served": 0, "batches": 0, "max_batch_seen": 0, "bad_requests": 0, "cancelled": 0,
                      "cancels_late": 0, "stale": 0}
        self.context.watch(s, self._on_readable)

    # -- receiving ---------------------------------------------------------------------------
    def _send(self, ident: bytes, answer: Any) -> None:
        self.sock.send_multipart([ident, self.codec.encode(answer, shm=False)[0]])

    def _refuse(self, ident: bytes, rid: int, text: str) -> None:
        self.stats["bad_requests"] += 1
        log.warning("refused a request: %s", text)
        self._send(ident, InferError(id=rid, error=text, kind="bad_request"))

    def _drain(self) -> None:
        """Take every frame waiting on the socket (requests queue, cancels apply at once)."""
        sock = self.sock
        # EVENTS, not a NOBLOCK recv that raises Again: an exception per drain is a cost on every request.
        while cast(int, sock.getsockopt(zmq.EVENTS)) & zmq.POLLIN:  # EVENTS is an int option
            frames = sock.recv_multipart(zmq.NOBLOCK, copy=False)
            parts = [f.bytes for f in frames]
            ident = parts[0]
            if len(parts) != 2:
                self._refuse(ident, 0, f"expected one frame per request, got {len(parts) - 1}")
                continue
            mapped: list[list[Any]] = []
            try:
                msg = self._decode(frames[1], mapped)
            except StaleFrame as exc:  # a forwarded frame reused before we got to it: drop, as a topic would
                try:
                    rid = int(getattr(self.codec.peek(frames[1].bytes), "id", 0))
                except Exception:  # noqa: BLE001 - the frame's handle was fine, so this should not happen
                    rid = 0
                self._stale(ident, rid, str(exc))
                continue
            except Exception as exc:  # garbage: say what was expected, keep serving
                self._refuse(ident, 0, f"undecodable frame ({exc}); send an actors-codec encoded InferRequest")
                continue
            if isinstance(msg, InferCancel):
                self._cancel(ident, msg.id)
            elif not isinstance(msg, InferRequest):
                self._refuse(ident, 0, f"expected an InferRequest or InferCancel, got {type(msg).__name__}")
            else:
                try:
                    self.serving.check(msg.task, msg.inputs, msg.options)
                except BadRequest as exc:
                    self._refuse(ident, msg.id, str(exc))
                    continue
                self.queues.setdefault(ident, deque()).append(msg)
                self.last_seen[ident] = time.monotonic()
                if mapped:
                    self.frames[(ident, msg.id)] = mapped

    def _decode(self, frame: zmq.Frame, mapped: list[list[Any]]) -> Any:
        """One request frame (a subclass may pick the codec by the frame's peer); ``mapped`` gets the
        handles of its shared-memory arrays."""
        return self.codec.decode(frame.bytes, mapped=mapped)

    def _stale(self, ident: bytes, rid: int, why: str) -> None:
        self.stats["stale"] += 1
        log.debug("dropped request %d: %s", rid, why)
        self._send(ident, InferError(id=rid, kind="stale", error=(
            f"{why}: its publisher's topic ring reused the frame before the model was done with it; the "
            "answer is dropped as the frame would be (keep frames longer with a bigger ring on the publisher)")))

    def _whole(self, ident: bytes, req: InferRequest) -> bool:
        """Whether every shared-memory input of ``req`` still holds what was sent; the request's record goes."""
        handles = self.frames.pop((ident, req.id), None)
        if not handles:
            return True
        for h in handles:
            if not self.reader.unchanged(h):
                self._stale(ident, req.id, f"shared-memory frame {h[0]} was overwritten while the model used it")
                return False
        return True

    def _cancel(self, ident: bytes, rid: int) -> None:
        q = self.queues.get(ident, deque())
        for req in q:
            if req.id == rid:
                q.remove(req)
                self.frames.pop((ident, rid), None)
                self._send(ident, InferError(id=rid, error="cancelled by the client", kind="cancelled"))
                self.stats["cancelled"] += 1
                return
        if self.streaming == (ident, rid):
            self.cancelled.add((ident, rid))  # the stream stops at its next chunk
        else:
            self.stats["cancels_late"] += 1  # answered already (or never asked): nothing to stop, nothing kept

    # -- serving -----------------------------------------------------------------------------
    def _next(self) -> tuple[bytes, InferRequest] | None:
        """The next request, round-robin over clients."""
        while self.queues:
            ident, q = next(iter(self.queues.items()))
            self.queues.move_to_end(ident)
            if q:
                return ident, q.popleft()
            del self.queues[ident]
        return None

    def _on_readable(self) -> None:
        self._drain()
        while (item := self._next()) is not None:
            if self.serving.batchable and self.max_batch > 1:
                self._serve_batch([item])
            else:
                self._serve_stream(*item)
            self._drain()

    def _active_clients(self) -> int:
        now = time.monotonic()
        return sum(1 for t in self.last_seen.values() if now - t < _ACTIVE_S)

    def _take_batch(self, batch: list[tuple[bytes, InferRequest]]) -> None:
        key = (batch[0][1].task, sorted(batch[0][1].options.items()))
        for ident, q in list(self.queues.items()):
            if len(batch) >= self.max_batch:
                return
            if q and (q[0].task, sorted(q[0].options.items())) == key:
                batch.append((ident, q.popleft()))
                self.queues.move_to_end(ident)

    def _serve_batch(self, batch: list[tuple[bytes, InferRequest]]) -> None:
        self._take_batch(batch)
        deadline = time.monotonic() + self.batch_wait
        # Wait (bounded) only for clients that were active lately and are not in the batch yet.
        while len(batch) < min(self.max_batch, self._active_clients()):
            left = deadline - time.monotonic()
            if left <= 0 or not self.sock.poll(int(left * 1000)):  # what pyzmq does with a float
                break
            self._drain()
            self._take_batch(batch)
        task, options = batch[0][1].task, batch[0][1].options
        try:
            outputs = self.serving.run_batch(task, [r.inputs for _, r in batch], options)
        except Exception as exc:
            log.exception("%s failed", task)
            for ident, req in batch:
                self.frames.pop((ident, req.id), None)
                self._send(ident, InferError(id=req.id, error=f"{type(exc).__name__}: {exc}"))
            return
        for (ident, req), out in zip(batch, outputs, strict=True):
            if self._whole(ident, req):
                self._send(ident, InferAnswer(id=req.id, outputs=out, done=True))
        self.stats["served"] += len(batch)
        self.stats["batches"] += 1
        self.stats["max_batch_seen"] = max(self.stats["max_batch_seen"], len(batch))
        self.context.beat()

    def _serve_stream(self, ident: bytes, req: InferRequest) -> None:
        chunks = None
        self.streaming = (ident, req.id)
        first = True
        try:
            chunks = self.serving.run(req.task, req.inputs, req.options)
            for chunk in chunks:
                done = bool(chunk.get("done")) if isinstance(chunk, dict) else False
                # A backend has read its input arrays by its first chunk (a VLM encodes its images first).
                if first and not self._whole(ident, req):
                    return
                first = False
                self._send(ident, InferAnswer(id=req.id, outputs=chunk, done=done))
                self.context.beat()  # long generations are work, not a hang
                if done:
                    break
                self._drain()  # a cancel (or new requests) between two chunks
                if (ident, req.id) in self.cancelled:
                    self.cancelled.discard((ident, req.id))
                    self.stats["cancelled"] += 1
                    self._send(ident, InferError(id=req.id, error="cancelled by the client", kind="cancelled"))
                    return
            else:
                self._send(ident, InferAnswer(id=req.id, outputs={}, done=True))
        except Exception as exc:
            log.exception("%s failed", req.task)
            self._send(ident, InferError(id=req.id, error=f"{type(exc).__name__}: {exc}"))
        finally:
            if chunks is not None and hasattr(chunks, "close"):
                chunks.close()
            self.frames.pop((ident, req.id), None)
            self.streaming = None
            self.cancelled.discard((ident, req.id))
        self.stats["served"] += 1

    def on_receive(self, message: Any) -> Any:
        if message == "stats":
            return {**self.stats, "model": self.path, "kind": self.kind}
        raise UnknownMessage(f"model actor {self.name!r}", message, "send 'stats' (inference goes to its .inf socket)")

    def on_stop(self) -> None:
        self.sock.close(0)
        self.serving.close()


class LlamaModelActor(ModelActor):
    """A model actor serving a GGUF file with llama.cpp (the ``chat`` task): the form that
    callers starting one by hand use (tests, ``embagents bench``)."""

    def __init__(self, model_path: str, options: dict[str, Any] | None = None, warmup: bool = True) -> None:
        super().__init__("llama", model_path, options, warmup)
