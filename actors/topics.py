"""Topics: publish/subscribe between processes, point to point, no broker.

Each subscription binds its own SUB socket and writes its endpoint into
``<run>/topics/<topic>/``; publishers connect their PUB socket to every
endpoint listed there. A publisher notices new subscribers by the folder's
mtime (one ``stat`` per publish), so nothing polls. Arrays of 64 KB and more
go through the publisher's shared-memory ring (see :mod:`actors.shm`).

A subscription has a queue size and a policy: ``keep="latest"`` drops the
oldest queued messages when full (sensor data), ``keep="all"`` stops reading
until there is room (ZeroMQ's high-water mark then drops at the publisher).

Example::

    >>> pub = Publisher(rt, "chatter")                       # doctest: +SKIP
    >>> sub = Subscription(rt, loop, "chatter", print, queue_size=10)
    >>> pub.publish({"text": "hi"})
"""

from __future__ import annotations

import itertools
import logging
import os
import time
import weakref
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import zmq

from actors import wire
from actors.errors import CodecError, StaleFrame

if TYPE_CHECKING:
    from actors.loop import Loop
    from actors.runtime import Runtime

__all__ = ["Publisher", "Subscription", "topic_dir"]

log = logging.getLogger("actors.topics")
_ids = itertools.count()
# This process's subscriptions by id (their mark's name): see Publisher._await_subscriptions.
_local: weakref.WeakValueDictionary[str, Subscription] = weakref.WeakValueDictionary()


def topic_dir(run_dir: str, topic: str) -> str:
    return os.path.join(run_dir, "topics", topic)


class Publisher:
    """Publishes on ``topic``; optionally checks the message type."""

    def __init__(self, rt: Runtime, topic: str, msg_type: type | None = None, *, ring: int = 8) -> None:
        self.rt = rt
        self.topic = wire.check_name(topic.replace("/", "."))
        self.msg_type = msg_type
        self.ring = ring
        self.dir = topic_dir(rt.run_dir, self.topic)
        os.makedirs(self.dir, mode=0o700, exist_ok=True)
        # XPUB (verbose) shows each subscriber's subscription: a new subscriber's
        # first message is only sent once its pipe is live (no slow joiner).
        s = rt.ctx.socket(zmq.XPUB)
        s.setsockopt(zmq.XPUB_VERBOSE, 1)
        s.setsockopt(zmq.LINGER, 0)
        s.setsockopt(zmq.SNDHWM, 1000)
        s.setsockopt(zmq.RECONNECT_IVL, 20)
        self.sock = s
        self._mtime = -1
        self._peers: set[str] = set()
        self.unconfirmed = 0  # new subscriptions whose SUBSCRIBE did not come within the wait (dead ones)
        self.sent = 0

    def _refresh(self) -> None:
        try:
            mtime = os.stat(self.dir).st_mtime_ns
        except FileNotFoundError:
            return
        if mtime == self._mtime:
            return
        self._mtime = mtime
        now = {f for f in os.listdir(self.dir) if not f.startswith(".")}
        new = now - self._peers
        for f in new:
            self.sock.connect(f"ipc://{self.rt.run_dir}/s.{f}")
        self.unconfirmed = self._await_subscriptions(new)
        for f in self._peers - now:
            try:
                self.sock.disconnect(f"ipc://{self.rt.run_dir}/s.{f}")
            except zmq.ZMQError:
                pass
        self._peers = now

    def _await_subscriptions(self, new: set[str], timeout: float = 0.5) -> int:
        """Wait until the ``new`` subscriptions' SUBSCRIBE arrived; return how many did not."""
        # A ZeroMQ socket runs its pending commands (attach the new pipe, send
        # SUBSCRIBE) only inside its owner's calls. A subscription of this
        # process would not answer until the wait is over (measured: the full
        # 0.5 s), so nudge those sockets while waiting.
        own = [sub.sock for f in new if (sub := _local.get(f)) is not None]
        sock, n, deadline = self.sock, len(new), time.monotonic() + timeout
        while n > 0:
            for s in own:
                s.getsockopt(zmq.EVENTS)
            left = deadline - time.monotonic()
            if left <= 0:
                break
            if sock.poll(max(1, int(1000 * (min(left, 0.002) if own else left)))) and sock.recv()[:1] == b"\x01":
                n -= 1
        return n

    @property
    def subscribers(self) -> int:
        self._refresh()
        return len(self._peers)

    def publish(self, msg: Any) -> None:
        if self.msg_type is not None and not isinstance(msg, self.msg_type):
            raise TypeError(
                f"topic {self.topic!r} carries {self.msg_type.__name__}, "
                f"got {type(msg).__name__}: publish a {self.msg_type.__name__} or declare another topic"
            )
        self._refresh()
        if not self._peers:
            return
        enc = self.rt.codec
        pool = self.rt.pool
        topic, ring = self.topic, self.ring
        old_sink = enc.sink

        class _Ring:
            def put(self, arr: Any) -> list[Any]:
                return pool.put_ring(topic, arr, ring=ring)

        enc.sink = _Ring()
        try:
            frame, _ = enc.encode(msg)
        finally:
            enc.sink = old_sink
        self.sock.send(frame, zmq.NOBLOCK, copy=len(frame) > 4096)
        self.sent += 1

    def close(self) -> None:
        self.sock.close(0)


class Subscription:
    """Receives ``topic`` in ``loop``'s thread and calls ``callback(msg)``."""

    def __init__(
        self,
        rt: Runtime,
        loop: Loop,
        topic: str,
        callback: Callable[[Any], None],
        *,
        queue_size: int = 10,
        keep: str = "latest",
        msg_type: type | None = None,
    ) -> None:
        if keep not in ("latest", "all"):
            raise ValueError(f"keep must be 'latest' or 'all', not {keep!r}")
        if queue_size < 1:
            raise ValueError(f"queue_size must be at least 1, not {queue_size}")
        self.rt = rt
        self.loop = loop
        self.topic = wire.check_name(topic.replace("/", "."))
        self.callback = callback
        self.keep = keep
        self.queue_size = queue_size
        self.msg_type = msg_type
        self.id = f"{os.getpid()}-{next(_ids)}"
        s = rt.ctx.socket(zmq.SUB)
        s.setsockopt(zmq.LINGER, 0)
        s.setsockopt(zmq.RCVHWM, max(queue_size, 16))
        s.setsockopt(zmq.MAXMSGSIZE, rt.codec.max_frame_bytes + 1024)
        s.setsockopt(zmq.SUBSCRIBE, b"")
        s.bind(f"ipc://{rt.run_dir}/s.{self.id}")
        self.sock = s
        self.queue: deque[Any] = deque(maxlen=queue_size if keep == "latest" else None)
        self.received = 0
        self.dropped = 0
        self.bad = 0
        d = topic_dir(rt.run_dir, self.topic)
        os.makedirs(d, mode=0o700, exist_ok=True)
        self._mark = os.path.join(d, self.id)
        with open(self._mark, "w") as f:
            f.write(str(os.getpid()))
        _local[self.id] = self
        loop.add(s, self.on_readable)

    def on_readable(self) -> None:
        sock, q, decode = self.sock, self.queue, self.rt.codec.decode
        while self.keep == "latest" or len(q) < self.queue_size:
            try:
                frame = sock.recv(zmq.NOBLOCK, copy=False)
            except zmq.Again:
                break
            self.received += 1
            try:
                msg = decode(frame.buffer)
            except StaleFrame as exc:
                self.dropped += 1
                log.debug("topic %s: %s", self.topic, exc)
                continue
            except CodecError as exc:
                self.bad += 1
                log.warning("topic %s: dropped a corrupt frame: %s", self.topic, exc)
                continue
            if self.msg_type is not None and not isinstance(msg, self.msg_type):
                self.bad += 1
                log.warning(
                    "topic %s: dropped a %s (this subscription takes %s)",
                    self.topic, type(msg).__name__, self.msg_type.__name__,
                )
                continue
            if q.maxlen is not None and len(q) == q.maxlen:
                self.dropped += 1
            q.append(msg)
        while q:
            self.callback(q.popleft())
        # keep="all" may have left messages in the socket: come back for them.
        if self.keep == "all" and sock.getsockopt(zmq.EVENTS) & zmq.POLLIN:
            self.loop.call_later(0, self.on_readable)

    def close(self) -> None:
        try:
            os.unlink(self._mark)
        except FileNotFoundError:
            pass
        self.loop.remove(self.sock)
        self.sock.close(0)


