"""The sending side of a mailbox: one DEALER per (IO thread, target actor).

The link keeps every message until the actor acknowledges it and re-sends
the unacknowledged ones, in order, when it connects to the actor's next
incarnation (at-least-once). An ``ask`` sent to an incarnation that then
dies fails with :class:`~actors.errors.ActorCrashed` at once; it is not
re-sent, because its caller has been told it failed.
"""

from __future__ import annotations

import itertools
import logging
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import zmq

from actors import wire
from actors.errors import ActorCrashed, CorruptFrame, RemoteError
from actors.wire import ACK, REPLY

if TYPE_CHECKING:
    from actors.runtime import Runtime

__all__ = ["Link", "Pending", "monitor_socket"]

log = logging.getLogger("actors.link")
# Plain ints: zmq's constants are IntFlags, whose arithmetic runs in enum code.
_POLLIN, _EVENTS, _NOBLOCK = int(zmq.POLLIN), int(zmq.EVENTS), int(zmq.NOBLOCK)
#: How often a blocked ask checks whether its actor is still there (seconds).
WAIT_SLICE = 0.02
_ids = itertools.count()
_monitor_ids = itertools.count()


def monitor_socket(sock: zmq.Socket, events: int) -> zmq.Socket:
    """A PAIR socket that receives ``sock``'s socket events, on an endpoint no other socket uses.

    pyzmq's default endpoint is named after the socket's fd; a socket closed
    by the garbage collector keeps its monitor bound until libzmq's reaper
    gets to it, so a new socket that reuses the fd failed with "Address
    already in use".

    >>> import zmq
    >>> ctx = zmq.Context()
    >>> a, b = ctx.socket(zmq.DEALER), ctx.socket(zmq.DEALER)
    >>> ma, mb = monitor_socket(a, zmq.EVENT_CONNECTED), monitor_socket(b, zmq.EVENT_CONNECTED)
    >>> for s in (ma, mb, a, b): s.close(0)
    >>> ctx.term()
    """
    return sock.get_monitor_socket(events, addr=f"inproc://monitor.{os.getpid()}.{next(_monitor_ids)}")


class Pending:
    """Where an ask's outcome goes: a callable taking (ok, value_or_exception)."""

    __slots__ = ("done", "ok", "value", "callback")

    def __init__(self, callback: Callable[[bool, Any], None] | None = None) -> None:
        self.done = False
        self.ok = False
        self.value: Any = None
        self.callback = callback

    def resolve(self, ok: bool, value: Any) -> None:
        if self.done:
            return
        self.done, self.ok, self.value = True, ok, value
        if self.callback is not None:
            self.callback(ok, value)


class _Out:
    __slots__ = ("kind", "frame", "segments", "epoch", "pending")

    def __init__(self, kind: int, frame: bytes, segments: list[str], pending: Pending | None) -> None:
        self.kind = kind
        self.frame = frame
        self.segments = segments
        self.epoch = -1  # connection epoch it was last sent on; -1 = never sent
        self.pending = pending


class Link:
    """Messages from this IO thread to the actor ``name`` at ``endpoint``."""

    def __init__(self, rt: Runtime, name: str, endpoint: str) -> None:
        self.rt = rt
        self.name = name
        self.endpoint = endpoint
        # pid first (the actor finds the sender's shared-memory prefix from it); the random part
        # keeps an id unique even when a later process gets a dead sender's pid, since mailboxes
        # remember each sender's last sequence number across restarts.
        self.ident = f"{os.getpid()}.{threading.get_ident() % 100000}.{next(_ids)}.{os.urandom(4).hex()}".encode()
        s = rt.ctx.socket(zmq.DEALER)
        s.setsockopt(zmq.ROUTING_ID, self.ident)
        s.setsockopt(zmq.IMMEDIATE, 1)  # never queue into zmq for an absent peer: we keep it
        s.setsockopt(zmq.LINGER, 0)
        s.setsockopt(zmq.SNDHWM, 0)
        s.setsockopt(zmq.RCVHWM, 0)
        s.setsockopt(zmq.RECONNECT_IVL, 5)
        s.setsockopt(zmq.RECONNECT_IVL_MAX, 50)
        s.setsockopt(zmq.RCVTIMEO, int(WAIT_SLICE * 1000))  # only blocking waits (see wait())
        self.monitor = monitor_socket(s, zmq.EVENT_HANDSHAKE_SUCCEEDED | zmq.EVENT_DISCONNECTED)
        s.connect(endpoint)
        self.sock = s
        self.connected = False
        self.epoch = 0
        self.seq = 0
        self.unacked: OrderedDict[int, _Out] = OrderedDict()
        # Asks the actor has handled (a later ACK or REPLY covered them) whose answer comes later:
        # it returned a Deferred (see actors.mailbox.Deferred).
        self.awaiting: dict[int, _Out] = {}
        self.releases: list[str] = []
        self.closed = False
        self.sent_count = 0

    # -- sending ------------------------------------------------------------
    def send(self, kind: int, body: Any, pending: Pending | None = None) -> int:
        if self.releases:  # views dropped since the last frame (maybe inside a handler's loop)
            self.flush_releases()
        seq = self.seq = self.seq + 1
        frame, segs = self.rt.codec.encode([kind, seq, body])
        # ZeroMQ reconnects to a restarted actor on its own, while `connected` changes only when
        # the monitor's events are handled. A sender busy in a handler would send straight to the
        # new incarnation, ahead of the backlog the old one never saw (and whose ACK of the new
        # message would then cover that backlog): handle pending monitor events first, so the
        # backlog is re-sent before this message.
        if self.monitor.getsockopt(_EVENTS) & _POLLIN:  # type: ignore[operator]
            self.on_monitor()
        out = _Out(kind, frame, segs, pending)
        self.unacked[seq] = out
        if self.connected:
            self._transmit(out)
        return seq

    def _transmit(self, out: _Out) -> bool:
        try:
            # A copying send: arrays of 64 KB and more travel in shared memory, and pyzmq
            # copies smaller frames anyway, only through a slower path when asked not to.
            self.sock.send(out.frame, _NOBLOCK)
        except zmq.Again:
            self.connected = False
            return False
        out.epoch = self.epoch
        if out.segments:
            self.rt.pool.sent(out.segments, self)
        self.sent_count += 1
        return True

    def flush_releases(self) -> None:
        if self.releases and self.connected:
            names, self.releases = self.releases, []
            try:
                self.sock.send(self.rt.codec.encode([wire.RELEASE, names], shm=False)[0], zmq.NOBLOCK)
            except zmq.Again:
                pass

    # -- receiving ----------------------------------------------------------
    def on_monitor(self) -> None:
        while True:
            try:
                frames = self.monitor.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            event = int.from_bytes(frames[0][:2], "little")
            if event == zmq.EVENT_HANDSHAKE_SUCCEEDED:
                self._on_connected()
            elif event == zmq.EVENT_DISCONNECTED:
                self._on_disconnected()

    def _on_connected(self) -> None:
        self.connected = True
        self.epoch += 1
        for out in list(self.unacked.values()):
            if not self._transmit(out):
                break

    def _on_disconnected(self) -> None:
        self.connected = False
        self.rt.pool.link_lost(self)
        self.releases.clear()  # those segments belonged to the dead incarnation's replies
        for seq, out in list(self.unacked.items()):
            if out.kind != wire.TELL and out.epoch >= 0:
                del self.unacked[seq]
                self.rt.pool.acked(out.segments)
                if out.pending is not None:
                    out.pending.resolve(False, ActorCrashed(self.name, "its process exited"))
        awaiting, self.awaiting = self.awaiting, {}
        for out in awaiting.values():
            out.pending.resolve(False, ActorCrashed(self.name, "its process exited"))  # type: ignore[union-attr]

    def on_readable(self) -> None:
        sock = self.sock
        while sock.getsockopt(_EVENTS) & _POLLIN:  # type: ignore[operator]  # cheaper than zmq.Again
            self.handle(sock.recv(_NOBLOCK, copy=False))

    def wait(self, pending: Pending, timeout: float | None) -> bool:
        """Block this thread until ``pending`` is settled or ``timeout`` passes.

        The fast path is a blocking ``recv`` on our socket, as raw pyzmq would
        do (no poll); every ``WAIT_SLICE`` seconds it reads the monitor, so a
        dead actor fails the ask within a slice. Not connected yet: the
        loop's poll path, which reacts to the connection at once.
        """
        deadline = None if timeout is None else time.monotonic() + timeout
        sock = self.sock
        beat = self.rt.beat
        while not pending.done:
            if not self.connected:
                left = None if deadline is None else max(0.0, deadline - time.monotonic())
                self.loop.run(until=lambda: pending.done or self.connected, timeout=left,  # type: ignore[attr-defined]
                              only=[sock, self.monitor])
            else:
                try:
                    self.handle(sock.recv(copy=False))  # blocks at most RCVTIMEO (a slice)
                except zmq.Again:
                    self.on_monitor()
                    beat()
            if deadline is not None and not pending.done and time.monotonic() >= deadline:
                return False
        return True

    def handle(self, frame: Any) -> None:
        """One frame from the actor: an ACK, a REPLY, a view RELEASE or a DEAD letter."""
        try:
            msg = self.rt.codec.decode(frame.buffer, self._release)
            kind = msg[0]
            if kind == REPLY:  # the ask path first: it is the one someone waits on
                _, seq, ok, value = msg
                out = self.unacked.pop(seq, None)
                if out is None and self.awaiting:
                    out = self.awaiting.pop(seq, None)
                if self.unacked:
                    self._ack(seq)
                if out is not None:
                    if out.segments:
                        self.rt.pool.acked(out.segments)
                    if out.pending is not None:
                        out.pending.resolve(ok, value if ok else RemoteError(self.name, *value))
            elif kind == ACK:
                self._ack(msg[1])
            elif kind == wire.RELEASE:
                for n in msg[1]:
                    self.rt.pool.released(n, self)
            elif kind == wire.DEAD:
                _, seq, reason = msg
                out = self.unacked.pop(seq, None)
                if out is not None:
                    self.rt.pool.acked(out.segments)
                    if out.pending is not None:
                        out.pending.resolve(False, ActorCrashed(self.name, f"message dead-lettered: {reason}"))
            else:
                raise CorruptFrame(f"unexpected frame kind {kind!r}")
        except Exception as exc:  # a bad frame must not take the sender down
            log.warning("dropped a bad frame from actor %r: %s", self.name, exc)

    def _release(self, name: str, gen: int) -> None:
        # Runs in whatever thread drops the view; list.append is atomic.
        self.releases.append(name)
        self.rt.wake(self)

    def _ack(self, upto: int) -> None:
        # The actor processes in order and replies before it acks, so every
        # message up to ``upto`` is done.
        while self.unacked:
            seq = next(iter(self.unacked))
            if seq > upto:
                return
            out = self.unacked.popitem(last=False)[1]
            self.rt.pool.acked(out.segments)
            if out.pending is not None:  # an ask without its reply yet: a Deferred answer, still to come
                out.segments = []
                self.awaiting[seq] = out

    @property
    def backlog(self) -> int:
        return len(self.unacked)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for out in self.unacked.values():
            self.rt.pool.acked(out.segments)
            if out.pending is not None:
                out.pending.resolve(False, ActorCrashed(self.name, "the link was closed"))
        for out in self.awaiting.values():
            out.pending.resolve(False, ActorCrashed(self.name, "the link was closed"))  # type: ignore[union-attr]
        self.unacked.clear()
        self.awaiting.clear()
        self.sock.disable_monitor()
        self.monitor.close(0)
        self.sock.close(0)
