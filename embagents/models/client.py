"""The client a component holds to reach a local model actor (any modality).

``infer`` sends one request and returns its answer; ``stream`` yields the
chunks of a streamed one; ``chat_stream`` / ``chat`` / ``detect`` are the
task-shaped forms. Waiting uses ``poll`` (no busy loop) and beats the
heartbeat (waiting on a model is work, not a hang). A socket monitor sees the
model actor's process go away: every waiting request then fails at once with
:class:`ModelCrashed`. Closing a stream early (or timing out) cancels the
request in the model actor.

Example::

    >>> client = LocalModelClient("smollm2")
    >>> client.name
    'smollm2'
"""

from __future__ import annotations

import itertools
import os
import threading
import time
from collections.abc import Callable, Iterator
from functools import partial
from typing import Any, cast

import zmq
from zmq.utils.monitor import recv_monitor_message

from actors import wire
from actors.link import monitor_socket
from actors.runtime import current
from embagents.models.chat import collect_stream
from embagents.models.declarations import Model
from embagents.models.protocol import (
    BadRequest,
    InferCancel,
    InferError,
    InferRequest,
    ModelCrashed,
    ModelError,
    ModelUnavailable,
    StaleInput,
    inference_endpoint,
)

__all__ = ["LocalModelClient", "PendingAnswer"]

_req_ids = itertools.count(1)
#: Handshake outcomes: a remote client (CURVE) tells a refused key from a dead server by them.
_HANDSHAKE = (zmq.EVENT_HANDSHAKE_SUCCEEDED | zmq.EVENT_HANDSHAKE_FAILED_AUTH | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
              | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL)


class _Conn:
    """One thread's DEALER to the model actor and the monitor that sees it disconnect."""

    def __init__(self, rt: Any, endpoint: str, configure: Callable[[zmq.Socket], None] | None = None) -> None:
        self.pid = os.getpid()
        self.sock = rt.ctx.socket(zmq.DEALER)
        self.sock.setsockopt(zmq.LINGER, 0)
        if configure is not None:
            configure(self.sock)  # e.g. CURVE keys (embagents.models.remote)
        self.monitor = monitor_socket(self.sock, zmq.EVENT_CONNECTED | zmq.EVENT_DISCONNECTED | _HANDSHAKE)
        self.sock.connect(endpoint)
        self.poller = zmq.Poller()
        self.poller.register(self.sock, zmq.POLLIN)
        self.poller.register(self.monitor, zmq.POLLIN)
        self.orphans: dict[int, list[str]] = {}  # cancelled requests whose frames the actor may still read

    def close(self) -> None:
        self.sock.disable_monitor()
        self.monitor.close(0)
        self.sock.close(0)


class PendingAnswer:
    """A request sent with :meth:`LocalModelClient.submit`: take its answer once, or cancel it."""

    def __init__(self, answers: Iterator[dict[str, Any]], abandon: Callable[[], None]) -> None:
        self._answers, self._abandon = answers, abandon
        self.state = "sent"  # "taken", "cancelled"

    def result(self) -> dict[str, Any]:
        """The answer (the outputs of its ``done`` frame), waited for; raises as :meth:`LocalModelClient.infer` does."""
        if self.state != "sent":
            raise RuntimeError(f"this answer was {self.state} already: a pending answer is taken once")
        self.state = "taken"
        last: dict[str, Any] = {}
        for last in self._answers:  # noqa: B007
            pass
        return last

    def cancel(self) -> None:
        """Not wanted any more: the model actor drops it (if it has not begun) and its answer is not read."""
        if self.state == "sent":
            self.state = "cancelled"
            self._abandon()


class LocalModelClient:
    """Talks to the model actor serving ``model`` (in whatever process it runs)."""

    #: Served by a model actor of this run (``embagents supervise`` starts one for it).
    in_run = True

    def __init__(self, model: Model | str, *, timeout: float = 120.0) -> None:
        self.name = model.name if isinstance(model, Model) else wire.check_name(model)
        self.model = model if isinstance(model, Model) else None
        self.timeout = timeout
        self._local = threading.local()

    def __repr__(self) -> str:
        return f"LocalModelClient({self.name!r})"

    def _conn(self) -> _Conn:
        conn: _Conn | None = getattr(self._local, "conn", None)
        if conn is None or conn.pid != os.getpid():
            conn = self._local.conn = self._connect(current())
        return conn

    def _connect(self, rt: Any) -> _Conn:
        """A new connection of this thread to the model actor."""
        return _Conn(rt, inference_endpoint(rt.run_dir, self.name))

    def _codec(self, rt: Any) -> Any:
        """The codec of requests and answers: the run's, so large arrays go through shared memory."""
        return rt.codec

    def _drop_conn(self) -> None:
        conn = getattr(self._local, "conn", None)
        if conn is not None and conn.pid == os.getpid():
            conn.close()
        self._local.conn = None

    # -- the protocol ----------------------------------------------------------------------
    def stream(self, task: str, inputs: dict[str, Any], *, forward_frames: bool = False,
               **options: Any) -> Iterator[dict[str, Any]]:
        """Yield the outputs of each answer frame of ``task``; the last one came with ``done``.

        Raises :class:`BadRequest` / :class:`ModelError` for an error answer,
        :class:`ModelCrashed` if the actor dies meanwhile, :class:`ModelUnavailable`
        after ``timeout`` seconds of silence. Closing the iterator early cancels the request.

        ``forward_frames``: a topic frame this process received (a camera's
        ``Image`` data) goes to the model as its shared-memory handle, not
        copied: written once, by the camera. For short work (a detection): the
        camera's ring may reuse the frame meanwhile (after ``ring`` newer
        frames and 0.5 s), and then the answer is :class:`StaleInput`.
        """

        rt, conn, codec, rid, segments, asked = self._ask(task, inputs, forward_frames, options)
        yield from self._answers(rt, conn, codec, rid, segments, asked)

    def submit(self, task: str, inputs: dict[str, Any], **options: Any) -> PendingAnswer:
        """Send a request of ``task`` now and return at once: its answer is waited for later.

        While the model works, the caller does other things (asks another model): the
        SpeechToText transcribes a pause's speech this way while the turn model decides.
        Take the answer with :meth:`PendingAnswer.result`, or :meth:`PendingAnswer.cancel`
        it, before this thread sends this client another request (an answer is read only
        by the request waiting for it).
        """
        rt, conn, codec, rid, segments, asked = self._ask(task, inputs, False, options)
        return PendingAnswer(self._answers(rt, conn, codec, rid, segments, asked),
                             partial(self._abandon, conn, codec, rid, segments))

    def _ask(self, task: str, inputs: dict[str, Any], forward_frames: bool,
             options: dict[str, Any]) -> tuple[Any, _Conn, Any, int, list[str], float]:
        rt = current()
        conn = self._conn()
        self._drain_monitor(conn)
        rid = next(_req_ids)
        codec = self._codec(rt)
        data, segments = codec.encode(InferRequest(id=rid, task=task, inputs=inputs, options=options),
                                      forward=forward_frames)
        asked = time.monotonic()  # the first answer is due within timeout of the ask, not of the end of the send
        self._send(rt, conn, data)
        return rt, conn, codec, rid, segments, asked

    def _abandon(self, conn: _Conn, codec: Any, rid: int, segments: list[str]) -> None:
        """Cancel request ``rid`` in the actor; its shared memory is freed when the actor lets go of it."""
        if not conn.sock.closed:
            conn.sock.send(codec.encode(InferCancel(id=rid), shm=False)[0])
            conn.orphans[rid] = segments

    def _answers(self, rt: Any, conn: _Conn, codec: Any, rid: int, segments: list[str],
                 asked: float | None) -> Iterator[dict[str, Any]]:
        """The outputs of request ``rid``'s answer frames; the first is due within ``timeout`` of ``asked``."""
        finished = False
        try:
            while True:
                answer = self._next(rt, conn, rid, asked)
                asked = None  # each later frame: within timeout of the one before
                if isinstance(answer, InferError):
                    finished = True
                    if answer.kind == "bad_request":
                        raise BadRequest(f"model {self.name!r} refused the request: {answer.error}")
                    if answer.kind == "stale":
                        raise StaleInput(f"model {self.name!r} dropped the request: {answer.error}")
                    raise ModelError(f"model {self.name!r} failed: {answer.error}", answer.kind)
                rt.beat()
                if answer.done:
                    finished = True
                    yield answer.outputs
                    return
                yield answer.outputs
        except ModelCrashed:
            finished = True
            raise
        finally:
            if finished:
                rt.pool.acked(segments)
            else:
                self._abandon(conn, codec, rid, segments)

    def infer(self, task: str, inputs: dict[str, Any], *, forward_frames: bool = False,
              **options: Any) -> dict[str, Any]:
        """One answer (the outputs of the ``done`` frame) of ``task``.

        Example::

            >>> LocalModelClient("faces").infer("detect", {"image": frame})  # doctest: +SKIP
            {'boxes': array(...), 'scores': array(...), 'labels': ['face']}
        """
        last: dict[str, Any] = {}
        for last in self.stream(task, inputs, forward_frames=forward_frames, **options):  # noqa: B007
            pass
        return last

    def _send(self, rt: Any, conn: _Conn, data: bytes) -> None:
        """Send a request without ever blocking for good.

        A socket with no usable peer (a remote server that refused our key just now)
        would block a plain send forever; this one reads the connection's events meanwhile
        (a refusal raises) and gives up after ``timeout``.
        """
        waited = 0.0
        while True:
            try:
                conn.sock.send(data, zmq.NOBLOCK)
                return
            except zmq.Again:
                pass
            if waited >= self.timeout:
                raise ModelUnavailable(
                    f"model {self.name!r} took no request for {self.timeout} s: is its actor running? "
                    "(`embagents status`)"
                )
            if conn.monitor.poll(100):
                self._on_event(conn, recv_monitor_message(conn.monitor)["event"], before=True)
            waited += 0.1
            rt.beat()  # waiting on the model is work, not a hang

    def _drain_monitor(self, conn: _Conn) -> None:
        # Events from before this request (an old incarnation's exit) say nothing about it.
        while cast(int, conn.monitor.getsockopt(zmq.EVENTS)) & zmq.POLLIN:  # EVENTS is an int option; no poll per request
            self._on_event(conn, recv_monitor_message(conn.monitor)["event"], before=True)

    def _on_event(self, conn: _Conn, event: int, before: bool = False) -> bool:
        """See a monitor event first (``before``: from before the request); True: it says nothing about it."""
        return False

    def _next(self, rt: Any, conn: _Conn, rid: int, since: float | None = None) -> Any:
        deadline = (time.monotonic() if since is None else since) + self.timeout
        while True:
            # Waits in steps of at most 1 s (beats between them); a sub-second timeout is kept to the ms.
            left = deadline - time.monotonic()
            ready = dict(conn.poller.poll(int(min(1.0, max(0.0, left)) * 1000))) if left > 0 else {}
            if conn.monitor in ready:
                event = recv_monitor_message(conn.monitor)
                if self._on_event(conn, event["event"]):
                    continue  # it says nothing about this request
                if event["event"] == zmq.EVENT_DISCONNECTED:
                    for segs in conn.orphans.values():
                        rt.pool.acked(segs)
                    conn.orphans.clear()
                    raise ModelCrashed(
                        f"model actor {self.name!r} went away while request {rid} was waiting: its process "
                        "died or stopped; the supervisor restarts it (see `embagents status`); ask again"
                    )
                continue
            if conn.sock not in ready:
                rt.beat()  # waiting on the model is work, not a hang
                if time.monotonic() >= deadline:  # the caller's finally cancels the request in the actor
                    raise ModelUnavailable(
                        f"model {self.name!r} sent nothing for {self.timeout} s: is its actor running? "
                        "(see `embagents status`)"
                    )
                continue
            try:
                answer = self._codec(rt).decode(conn.sock.recv())
            except Exception as exc:  # an answer this process cannot read: say so, not hang
                raise ModelError(f"model {self.name!r} sent an unreadable answer: {exc}") from exc
            if getattr(answer, "id", None) == rid:
                return answer
            orphan = conn.orphans.get(getattr(answer, "id", -1))
            if orphan is not None and (isinstance(answer, InferError) or getattr(answer, "done", False)):
                rt.pool.acked(conn.orphans.pop(answer.id))

    # -- task-shaped forms -----------------------------------------------------------------
    def chat_stream(self, messages: list[dict[str, Any]], *, images: list[Any] | None = None,
                    **options: Any) -> Iterator[dict[str, Any]]:
        """Chat chunks (:mod:`embagents.models.chat` shapes), token by token.

        ``images``: (H, W, 3) uint8 RGB arrays for a vision-language model
        (:class:`~embagents.models.VLMModel`); they travel through shared memory.
        """
        inputs: dict[str, Any] = {"messages": messages}
        if images:
            inputs["images"] = list(images)
        return self.stream("chat", inputs, **options)

    def chat(self, messages: list[dict[str, Any]], *, images: list[Any] | None = None,
             **options: Any) -> dict[str, Any]:
        """The whole reply: ``{"content", "tool_calls", "finish_reason", "usage", "timing"}``."""
        return collect_stream(self.chat_stream(messages, images=images, **options))

    def detect(self, image: Any, **options: Any) -> dict[str, Any]:
        """Detections in ``image`` (H, W, 3 uint8, RGB): ``{"boxes", "scores", "labels"}``.

        A camera frame received on a topic is forwarded, not copied (see :meth:`stream`);
        :class:`StaleInput` if the camera overwrote it before the detector was done.
        """
        return self.infer("detect", {"image": image}, forward_frames=True, **options)

    def transcribe(self, audio: Any, **options: Any) -> dict[str, Any]:
        """The text said in ``audio`` (1-D 16 kHz float32 or int16 samples): ``{"text", "seconds"}``."""
        return self.infer("transcribe", {"audio": audio}, **options)

    def end_of_turn(self, audio: Any) -> dict[str, Any]:
        """Whether the user has finished, from their speech so far (1-D 16 kHz): ``{"probability", "complete"}``."""
        return self.infer("end_of_turn", {"audio": audio})

    def end_of_turn_text(self, text: str) -> dict[str, Any]:
        """Whether the user has finished, from the transcript of their speech so far: ``{"probability"}``
        (a chat model's end-of-turn token after ``text``: :meth:`~embagents.models.backends.llama.LlamaBackend.end_of_turn_probability`)."""
        return self.infer("end_of_turn", {"text": text})

    def speak(self, text: str, **options: Any) -> Iterator[dict[str, Any]]:
        """Speech for ``text``, a chunk per sentence: ``{"audio": float32 samples, "sample_rate", "text"}``.

        The last chunk is ``{"done": True, "seconds": ...}``; closing the iterator early cancels the rest.
        """
        return self.stream("speak", {"text": text}, **options)

    def embed(self, texts: list[str]) -> Any:
        """Unit-length sentence embeddings of ``texts``: a float32 (N, dim) array."""
        return self.infer("embed", {"texts": list(texts)})["vectors"]

