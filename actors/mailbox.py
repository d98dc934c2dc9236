"""The receiving side of a mailbox: the actor's ROUTER socket.

Messages are drained into a local queue and handled one at a time, in the
order each sender sent them. After a batch, every sender gets one ACK for
the highest sequence number handled; an ASK gets its REPLY (which also
acknowledges it). Before a message is handled its id is written to the
actor's journal; if the process dies while handling it, the next
incarnation counts that against the message, and past ``poison_limit``
crashes it is dead-lettered with the reason instead of handled again.

On a clean stop the mailbox writes, per sender, the last sequence number it
handled to ``seen_path``, and the next incarnation starts from that table: a
told message whose acknowledgement was lost with the closing connection (the
actor exits right after it) is re-sent by its sender, and is then
acknowledged, not handled a second time.
"""

from __future__ import annotations

import functools
import logging
import os
import struct
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import msgpack
import zmq

from actors import wire
from actors.errors import CodecError, StaleFrame, UnknownMessage, quote
from actors.runtime import shm_prefix
from actors.wire import ASK, CTRL, RELEASE, TELL

if TYPE_CHECKING:
    from actors.journal import Journal
    from actors.loop import Loop
    from actors.runtime import Runtime

__all__ = ["Deferred", "Mailbox"]

log = logging.getLogger("actors.mailbox")

Handler = Callable[[int, Any], Any]

# Plain ints: zmq's constants are IntFlags, and `int & IntFlag` costs ~1 us in enum code.
_POLLIN, _EVENTS, _NOBLOCK, _SNDMORE = int(zmq.POLLIN), int(zmq.EVENTS), int(zmq.NOBLOCK), int(zmq.SNDMORE)
_KINDS = frozenset((TELL, ASK, CTRL))


class Deferred:
    """An ask's answer that comes later: ``on_receive`` returns one and the actor goes on.

    ``resolve(value)`` or ``fail(exc)`` it later, from any thread (a driver's
    callback): the reply goes out from the actor's thread. The asker waits as
    for any answer, within its own timeout; if the actor dies first, the ask
    fails with ActorCrashed as for any answer. Only the first outcome counts.
    A ``tell`` that returns one has nobody to answer: the outcome is dropped.

    Example::

        def on_receive(self, message):
            answer = Deferred()
            self.driver.start(message, on_done=answer.resolve)  # answers when the driver is done
            return answer
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._sink: Callable[[bool, Any], None] | None = None
        self._outcome: tuple[bool, Any] | None = None

    def resolve(self, value: Any) -> None:
        """Answer with ``value``."""
        self._settle(True, value)

    def fail(self, exc: BaseException) -> None:
        """Answer with the error ``exc`` (the asker gets a RemoteError of its type and message)."""
        self._settle(False, [type(exc).__name__, _bounded(str(exc)), ""])

    def _settle(self, ok: bool, value: Any) -> None:
        with self._lock:
            if self._outcome is not None:
                return
            self._outcome = (ok, value)
            sink = self._sink
        if sink is not None:
            sink(ok, value)

    def _bind(self, sink: Callable[[bool, Any], None]) -> None:
        with self._lock:
            self._sink, outcome = sink, self._outcome
        if outcome is not None:
            sink(*outcome)


class Mailbox:
    """Bind ``endpoint`` and feed ``handler(kind, body)`` one message at a time."""

    def __init__(
        self,
        rt: Runtime,
        name: str,
        endpoint: str,
        handler: Handler,
        journal: Journal | None = None,
        *,
        poison_limit: int = 3,
        dead_letter: Callable[[dict[str, Any]], None] | None = None,
        seen_path: str | None = None,
    ) -> None:
        self.rt = rt
        self.name = name
        self.handler = handler
        self.journal = journal
        self.poison_limit = poison_limit
        self.dead_letter = dead_letter
        s = rt.ctx.socket(zmq.ROUTER)
        s.setsockopt(zmq.LINGER, 500)  # let final acks and replies go out on stop
        s.setsockopt(zmq.SNDHWM, 0)
        s.setsockopt(zmq.RCVHWM, 0)
        s.setsockopt(zmq.ROUTER_MANDATORY, 0)
        s.setsockopt(zmq.MAXMSGSIZE, rt.codec.max_frame_bytes + 1024)
        s.bind(endpoint)
        self.sock = s
        self.queue: deque[tuple[bytes, Any]] = deque()
        self.seen_path = seen_path
        self.last_seq: dict[bytes, int] = _load_seen(seen_path)
        self._owners: dict[bytes, str] = {}  # asker ident -> its shared-memory prefix
        self._releasers: dict[bytes, Callable[[str, int], None]] = {}  # one per sender, not per frame
        self.to_ack: dict[bytes, int] = {}
        self.releases: dict[bytes, list[str]] = {}
        self.crashed = journal.crashes() if journal is not None else {}
        self.undecodable = journal.undecodable() if journal is not None else set()
        self.received = 0
        self.handled = 0
        self.dropped = 0
        self.dead_lettered = 0
        self.busy_since = 0.0
        self.stopping = False
        self.loop: Loop | None = None  # set by the host: Deferred answers are sent from its thread

    @property
    def depth(self) -> int:
        return len(self.queue)

    def on_readable(self) -> None:
        """Drain the socket, then handle what came in (acks go out per batch)."""
        self._drain()
        jr = self.journal
        while self.queue and not self.stopping:
            ident, frame = self.queue.popleft()
            self._handle(ident, frame)
            if jr is not None:
                jr.beat()
            if self.handled % 32 == 0:  # a crash under load re-delivers at most a batch
                self.flush()
        self.flush()

    def _drain(self) -> None:
        # The hot path: an EVENTS check is cheaper than a zmq.Again exception, and two
        # recv calls are cheaper than recv_multipart. A ROUTER always puts the sender's
        # id first and at least one part after it, so the id is read as plain bytes.
        sock, queue = self.sock, self.queue
        recv, events = sock.recv, sock.getsockopt
        for i in range(4096):
            if i and not events(_EVENTS) & _POLLIN:  # type: ignore[operator]  # the first read follows a poll
                return
            try:
                ident = recv(_NOBLOCK)
            except zmq.Again:
                return
            frame = recv(_NOBLOCK, copy=False)
            if frame.more:  # more parts than ours: skip the rest
                while frame.more:
                    frame = recv(_NOBLOCK, copy=False)
                self.dropped += 1
                log.warning("[%s] dropped a frame with the wrong number of parts", self.name)
                continue
            self.received += 1
            queue.append((ident, frame))

    def _handle(self, ident: bytes, frame: Any) -> None:
        release = self._releasers.get(ident)
        if release is None:
            release = self._releasers[ident] = functools.partial(self._release_view, ident)
        jr = self.journal
        buf = frame.buffer
        # The journal takes the message before its frame is decoded: a frame that kills the
        # decoder counts towards the poison limit like a message that kills the handler.
        early = _peek_seq(buf) if jr is not None else 0
        if early:
            if self.crashed and (ident, early) in self.undecodable and self._undecodable(ident, early, buf):
                return
            jr.begin(ident, early, decoded=False)  # type: ignore[union-attr]
        try:
            msg = self.rt.codec.decode(buf, release)
        except (CodecError, StaleFrame) as exc:
            self._drop(early, "a corrupt", ident, exc)
            return
        problem = _check_inbound(msg)
        if problem:
            self._drop(early, "a foreign", ident, problem)
            return
        kind, seq = msg[0], msg[1]
        if kind == RELEASE:
            for n in seq:  # [RELEASE, names]
                self.rt.pool.released(n, ident)
            return
        body = msg[2]
        last = self.last_seq.get(ident, 0)
        if seq <= last:
            self.to_ack[ident] = last  # a duplicate after a resend
            if early:
                jr.end()  # type: ignore[union-attr]
            return
        self.last_seq[ident] = seq
        if self.crashed and self.crashed.get((ident, seq), 0) >= self.poison_limit:
            if early:
                jr.end()  # type: ignore[union-attr]
            self._dead_letter(ident, seq, kind, quote(body))
            return
        if jr is not None:
            if early:
                jr.decoded()
            else:
                jr.begin(ident, seq)
        self.busy_since = time.monotonic()
        try:
            result = self.handler(kind, body)
            ok = True
        except UnknownMessage as exc:
            if kind == TELL:  # nothing to tell the sender, and a restart would not help: dead-letter it
                self.busy_since = 0.0
                if jr is not None:
                    jr.end()
                self.handled += 1
                self._dead_letter(ident, seq, kind, quote(body), str(exc))
                return
            ok = False
            result = [type(exc).__name__, _bounded(str(exc)), ""]
        except Exception as exc:
            if kind == TELL:
                # The actor crashes; the journal keeps this message's id, so the
                # next incarnation counts it towards the poison limit.
                raise
            ok = False
            result = [type(exc).__name__, _bounded(str(exc)), _bounded(traceback.format_exc())]
        self.busy_since = 0.0
        if jr is not None:
            jr.end()
        self.handled += 1
        if kind == TELL:
            self.to_ack[ident] = seq
        else:
            self.to_ack.pop(ident, None)
            if ok and isinstance(result, Deferred) and self.loop is not None:
                call_soon = self.loop.call_soon_threadsafe
                result._bind(lambda ok_, value: call_soon(lambda: self._reply(ident, seq, ok_, value)))
                return
            self._reply(ident, seq, ok, result)

    def _drop(self, early: int, what: str, ident: bytes, why: object) -> None:
        """Drop a frame that is not a message of ours (logged, counted)."""
        if early:
            self.journal.end()  # type: ignore[union-attr]
        self.dropped += 1
        log.warning("[%s] dropped %s frame from %r: %s", self.name, what, ident, why)

    def _undecodable(self, ident: bytes, seq: int, buf: memoryview) -> bool:
        """Dead-letter, without decoding it, a frame whose decoding crashed the actor ``poison_limit`` times."""
        if seq <= self.last_seq.get(ident, 0) or self.crashed.get((ident, seq), 0) < self.poison_limit:
            return False
        self.last_seq[ident] = seq
        self._dead_letter(ident, seq, buf[1], f"<a frame of {len(buf)} bytes, not decoded: decoding it crashed the actor>")
        return True

    def _reply(self, ident: bytes, seq: int, ok: bool, result: Any) -> None:
        owner = self._owners.get(ident)
        if owner is None and ident[:1].isdigit():
            # Link idents start with the asker's pid: a frame it sent us goes back as is.
            owner = self._owners[ident] = shm_prefix(self.rt.run_id, int(ident.split(b".", 1)[0]))
        try:
            frame, segs = self.rt.codec.encode([wire.REPLY, seq, ok, result], owner_prefix=owner)
        except Exception as exc:
            frame, segs = self.rt.codec.encode(
                [wire.REPLY, seq, False, [type(exc).__name__, f"cannot send the reply: {exc}", ""]]
            )
        sock = self.sock
        sock.send(ident, _SNDMORE)
        sock.send(frame)  # a copying send (see Link._transmit)
        if segs:
            self.rt.pool.sent(segs, ident)
            self.rt.pool.acked(segs)  # replies are not re-sent: only the view holds them

    def _dead_letter(self, ident: bytes, seq: int, kind: int, text: str, reason: str = "") -> None:
        """Give up on a message (``text``: what it was, quoted); ``reason``: why, if it did not crash the actor."""
        self.dead_lettered += 1
        reason = reason or f"it crashed actor {self.name!r} {self.crashed.get((ident, seq), '?')} times"
        record = {
            "actor": self.name,
            "sender": ident.decode(errors="replace"),
            "seq": seq,
            "kind": {wire.TELL: "tell", wire.ASK: "ask", wire.CTRL: "ctrl"}.get(kind, str(kind)),
            "reason": reason,
            "message": text,
            "time": time.time(),
        }
        log.error("[%s] dead-lettered message %s from %s: %s", self.name, seq, record["sender"], reason)
        if self.dead_letter is not None:
            self.dead_letter(record)
        self.sock.send_multipart([ident, msgpack.packb([wire.DEAD, seq, reason])])
        self.crashed.pop((ident, seq), None)
        if self.journal is not None:
            self.journal.forget_crash(ident, seq)

    def _release_view(self, ident: bytes, name: str, gen: int) -> None:
        self._release(ident, name)

    def _release(self, ident: bytes, name: str) -> None:
        self.releases.setdefault(ident, []).append(name)
        self.rt.wake(self)

    def flush(self) -> None:
        """Send batched acks and view releases."""
        if self.to_ack:
            acks, self.to_ack = self.to_ack, {}
            sock = self.sock
            for ident, seq in acks.items():
                sock.send(ident, zmq.SNDMORE)
                sock.send(msgpack.packb([wire.ACK, seq]))
        if self.releases:
            rel, self.releases = self.releases, {}
            for ident, names in rel.items():
                self.sock.send_multipart([ident, msgpack.packb([wire.RELEASE, names])])

    def close(self) -> None:
        """Send what is batched, remember what was handled (see the module docstring), close."""
        self.flush()
        self.sock.close()
        if self.seen_path is not None and self.last_seq:
            tmp = f"{self.seen_path}.{os.getpid()}"
            with open(tmp, "wb") as f:
                f.write(msgpack.packb(self.last_seq))
            os.replace(tmp, self.seen_path)


#: The largest sequence number a frame may carry (msgpack's and our counters' range).
_MAX_SEQ = (1 << 63) - 1
#: How long an error text sent back to an asker may be (a handler's message can quote a huge request).
_MAX_ERROR_CHARS = 8192
_HEAD = struct.Struct(">BBB")  # a fixarray's tag, a fixint kind, the seq's first byte
_UINT = {0xCC: struct.Struct(">B"), 0xCD: struct.Struct(">H"), 0xCE: struct.Struct(">I"), 0xCF: struct.Struct(">Q")}


def _peek_seq(buf: memoryview) -> int:
    """The seq of a ``[TELL|ASK|CTRL, seq, body]`` frame as msgpack writes it, read without decoding; else 0."""
    if len(buf) < 12:  # enough for the longest seq; a shorter frame is decoded first, then journaled
        return 0
    array, kind, b = _HEAD.unpack_from(buf)
    if array != 0x93 or kind not in _KINDS:  # a fixarray of 3 items, a kind of a message
        return 0
    if b < 0x80:  # a positive fixint
        return b
    u = _UINT.get(b)
    return u.unpack_from(buf, 3)[0] if u is not None else 0


def _bounded(text: str) -> str:
    """``text``, cut to :data:`_MAX_ERROR_CHARS` (saying so)."""
    if len(text) <= _MAX_ERROR_CHARS:
        return text
    return f"{text[:_MAX_ERROR_CHARS]}... ({len(text) - _MAX_ERROR_CHARS} more characters cut)"


def _check_inbound(msg: Any) -> str | None:
    """What is wrong with a decoded inbound frame, or None if it follows the wire grammar.

    ``[TELL|ASK|CTRL, seq >= 1, body]`` or ``[RELEASE, [name, ...]]`` (see :mod:`actors.wire`).
    """
    if type(msg) is not list or len(msg) not in (2, 3):
        return f"expected a list of 2 or 3 items, got {type(msg).__name__}"
    kind = msg[0]
    if type(kind) is not int:
        return f"frame kind {kind!r} is not an int"
    if kind == RELEASE:
        names = msg[1]
        if len(msg) != 2 or type(names) is not list or not all(type(n) is str for n in names):
            return "a RELEASE frame is [RELEASE, [segment names]]"
        return None
    if kind not in _KINDS:
        return f"unknown frame kind {kind!r}"
    seq = msg[1]
    if len(msg) != 3 or type(seq) is not int or not 1 <= seq <= _MAX_SEQ:
        return f"a message frame is [kind, seq >= 1, body]; got seq {seq!r} in {len(msg)} items"
    return None


def _load_seen(path: str | None) -> dict[bytes, int]:
    """The last handled sequence number per sender, as the previous incarnation left it."""
    if path is None:
        return {}
    try:
        with open(path, "rb") as f:
            seen = msgpack.unpackb(f.read())
    except FileNotFoundError:
        return {}
    except Exception as exc:  # a torn or foreign file must not keep the actor from starting
        log.warning("ignored the unreadable sequence table %s: %s", path, exc)
        return {}
    return {k: v for k, v in seen.items() if isinstance(k, bytes) and isinstance(v, int)} if isinstance(seen, dict) else {}
