"""Topics: publish/subscribe between processes, point to point, no broker.

Each subscription binds its own socket and writes its endpoint into
``<run>/topics/<topic>/``; publishers connect to every endpoint listed
there. Whoever adds or removes an endpoint there writes a new random word
into the topic's change file (``<run>/topics/.<topic>.changed``), which
publishers map: a publish reads
it from memory and lists the folder only when it changed, so nothing polls
(a ``stat`` of the folder per publish cost ~20-30 us with cold caches, a
200 Hz stream's). Arrays of 64 KB and more go through the publisher's
shared-memory ring (see :mod:`actors.shm`).

Every frame is a 16-byte header (publisher id, sequence number) and the
message: a subscription counts the gaps in each publisher's sequence as
drops, wherever they happened.

A subscription has a queue size and a policy:

- ``keep="latest"`` (sensor data): a SUB socket behind the publisher's one
  XPUB. The oldest queued messages are dropped when the queue is full, and
  ZeroMQ drops at the publisher when the subscriber falls a high-water mark
  behind; both count as ``dropped``.
- ``keep="all"``: a PULL socket with a PUSH of its own in each publisher.
  The subscription reads a message only once its callback returned from the
  one before, and a publisher whose PUSH to it is full waits (it is slowed, as a reliable KEEP_ALL ROS 2
  reader slows its writer): nothing is lost while both sides live. The wait
  is bounded (``stall_timeout``, default 1 s): past it the subscriber is
  reported as stalled, and messages for it are dropped at once, counted,
  until it reads again. A subscription in the publisher's own thread cannot
  read while the publisher waits, so it is not waited for.

A keep-all subscription may have a durable ``key`` (an actor's subscriptions
get ``<actor name>#<n>``, the n-th keep-all subscription of the actor to the
topic): its identity across incarnations of its process. A publisher keeps
what it sent to a keyed subscription until the subscription acknowledges it
(its callback returned: the sequence number goes into its credit file, see
:mod:`actors.credits`), at most ``window`` messages. When the subscription's
process dies, the publisher keeps those messages, and up to ``window`` in
all of what it publishes after, for ``successor_timeout`` (30 s); when a
subscription with the same key appears (the actor restarted, or its standby
took over), they are re-sent to it first, in order (on the publisher's next
publish: a publisher notices subscriptions only then). Delivery is
at-least-once, like a mailbox's: a message the dead incarnation had taken
but whose callback had not returned is delivered again (re-sent frames are
flagged and counted: the subscription's ``redelivered``, the publisher's
``resent``); a subscription drops a sequence number it has already seen, so
one incarnation gets each message once. What is past the bound, or held
longer than ``successor_timeout`` (a subscriber stopped for good), is
dropped and logged. Arrays that went through shared memory may have been
overwritten meanwhile: a re-sent one that was is counted as dropped.

Example::

    >>> import tempfile
    >>> from actors.loop import Loop
    >>> from actors.runtime import Runtime
    >>> rt, loop, got = Runtime(tempfile.mkdtemp(), "doc"), Loop(), []
    >>> sub = Subscription(rt, loop, "chatter", got.append, queue_size=10, keep="all")
    >>> pub = Publisher(rt, "chatter")
    >>> pub.publish({"text": "hi"})
    >>> loop.run(until=lambda: bool(got), timeout=5)
    True
    >>> got
    [{'text': 'hi'}]
    >>> pub.close(); sub.close(); rt.close()
"""

from __future__ import annotations

import itertools
import logging
import mmap
import os
import struct
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, cast

import zmq
import zmq.backend

from actors import wire
from actors.codec import Flat
from actors.credits import CreditBoard, CreditView
from actors.errors import CodecError, StaleFrame

if TYPE_CHECKING:
    from actors.loop import Loop
    from actors.runtime import Runtime

__all__ = ["Publisher", "Subscription", "mark_changed", "subscriber_pids", "topic_dir"]

log = logging.getLogger("actors.topics")
#: A ``keep="all"`` subscription's id ends with this: publishers PUSH to it instead of publishing.
KEEP_ALL_SUFFIX = "-all"
_NOBLOCK = int(zmq.NOBLOCK)
_EVENTS, _POLLIN = int(zmq.EVENTS), int(zmq.POLLIN)
#: pyzmq's send without the Python wrapper of ``zmq.Socket`` (for routing_id and group, which topics never
#: use; it passes the rest on as keyword arguments): a send with cold caches (a 100 Hz stream's) costs
#: ~65 us instead of ~125 (measured, ipc PUSH), on every topic hop's path.
_zsend = cast("Callable[[Any, bytes, int, bool], object]", zmq.backend.Socket.send)  # (its overloads want Literal copy)
#: Frames below this size are copied into ZeroMQ (pyzmq copies them even when told not to).
_COPY_THRESHOLD = zmq.COPY_THRESHOLD
#: A topic frame's header: the publisher's id and its sequence number.
_HEADER = struct.Struct("<QQ")
#: Set in the header's publisher id on a frame re-sent to a new incarnation (ids have 48 bits).
_AGAIN = 1 << 63
#: Bytes of frames kept for one keyed subscriber past which a send looks for its acknowledgements at once.
_KEEP_BYTES = 8 << 20
#: Publisher ids a subscription remembers sequence numbers for (restarted publishers get new ids).
_MAX_PUBLISHERS = 1024
_ids = itertools.count()
# This process's subscriptions by id (their mark's name): see Publisher._await_subscriptions.
_local: weakref.WeakValueDictionary[str, Subscription] = weakref.WeakValueDictionary()


def topic_dir(run_dir: str, topic: str) -> str:
    return os.path.join(run_dir, "topics", topic)


def _changed_path(folder: str) -> str:
    """The change file of the topic in ``folder``: beside it, so that the folder holds endpoints only."""
    parent, topic = os.path.split(folder)
    return os.path.join(parent, f".{topic}.changed")


def mark_changed(folder: str) -> None:
    """Tell the publishers of the topic in ``folder`` that its endpoints changed (after adding or removing one).

    A random word, not a count: two processes that change the folder at once
    cannot write the same value back.
    """
    fd = os.open(_changed_path(folder), os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC, 0o600)
    try:
        os.pwrite(fd, os.urandom(8), 0)
    finally:
        os.close(fd)


def _map_changed(folder: str) -> mmap.mmap:
    fd = os.open(_changed_path(folder), os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
    try:
        if os.fstat(fd).st_size < 8:
            os.ftruncate(fd, 8)  # zeros: as if never changed; a concurrent pwrite is kept (same size)
        return mmap.mmap(fd, 8, prot=mmap.PROT_READ)
    finally:
        os.close(fd)


def subscriber_pids(run_dir: str, topic: str) -> set[int]:
    """The processes with a subscription to ``topic`` now: a publisher that publishes from now on reaches them.

    Each subscription's mark in the topic's folder is named ``<pid>-<n>``
    (``-all`` for keep-all): a publisher connects to it before its next send;
    a keep-all one queues at once, a keep-latest one waits for the
    subscription to arrive (see :meth:`Publisher._await_subscriptions`).
    """
    try:
        names = os.listdir(topic_dir(run_dir, topic.replace("/", ".")))
    except FileNotFoundError:
        return set()
    return {int(pid) for pid, _, _ in (n.partition("-") for n in names) if pid.isdigit()}


class _Ring:
    """A publisher's shared-memory sink: large arrays go into the topic's ring."""

    __slots__ = ("pool", "topic", "ring")

    def __init__(self, pool: Any, topic: str, ring: int) -> None:
        self.pool, self.topic, self.ring = pool, topic, ring

    def put(self, arr: Any) -> list[Any]:
        return self.pool.put_ring(self.topic, arr, ring=self.ring)


class _Reliable:
    """A publisher's PUSH to one ``keep="all"`` subscription, and its credit view."""

    __slots__ = ("sub_id", "key", "sock", "credits", "unacked", "kept", "stalled", "dropped", "local", "gone_at")

    def __init__(self, sub_id: str, sock: zmq.Socket | None, credits: CreditView, local: bool) -> None:
        self.sub_id = sub_id
        self.key = credits.key  # durable: what it did not acknowledge goes to its next incarnation
        self.sock = sock
        self.credits = credits
        # (sequence number, frame) sent and not acknowledged when last looked at; frames only when keyed.
        self.unacked: deque[tuple[int, bytes | None]] = deque()
        self.kept = 0  # bytes of the frames in unacked
        self.stalled = False
        self.dropped = 0
        self.local = local  # its subscription lives in this thread: it cannot read while we wait
        self.gone_at = 0.0  # when its process went (keyed ones wait for a successor)


class Publisher:
    """Publishes on ``topic``; optionally checks the message type.

    ``stall_timeout``: the longest a publish waits for a ``keep="all"``
    subscriber that is ``window`` messages behind before it reports it
    stalled and drops for it (counted) until it reads again.

    ``pub_id`` (48 bits, not 0; random by default), with ``seq`` given to
    each publish: for a relay whose messages are numbered by their source (a
    Zenoh bridge) and that may be killed and restarted. Its successor
    publishes under the same id with the same numbers, so it may re-send what
    the killed one may not have got out: a subscription drops a number it
    has had from that id, and counts a jump as dropped.
    """

    #: Messages in flight to one keep-all subscriber before a publish waits for it.
    window = 256
    #: How long messages for a dead keyed subscriber are kept for its next incarnation.
    successor_timeout = 30.0

    def __init__(
        self,
        rt: Runtime,
        topic: str,
        msg_type: type | None = None,
        *,
        ring: int = 8,
        stall_timeout: float = 1.0,
        pub_id: int | None = None,
    ) -> None:
        self.rt = rt
        self.topic = wire.check_name(topic.replace("/", "."))
        self.msg_type = msg_type
        self.ring = ring
        self.stall_timeout = stall_timeout
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
        self._sink = _Ring(rt.pool, self.topic, ring)  # built once: encodes pass it explicitly
        if pub_id is not None and not 0 < pub_id < 1 << 48:
            raise ValueError(f"a publisher id has 48 bits and is not 0, got {pub_id}")
        self.id = int.from_bytes(os.urandom(6), "little") if pub_id is None else pub_id
        self._changed = _map_changed(self.dir)
        self._seen: bytes | None = None  # the folder's change word when last listed
        self._peers: set[str] = set()
        self._latest = 0  # keep="latest" peers on the XPUB
        self._reliable: dict[str, _Reliable] = {}
        self._orphans: dict[str, _Reliable] = {}  # key -> a dead keyed subscriber's messages, for its successor
        self.resent = 0  # messages re-sent to a new incarnation of a subscriber
        self.unconfirmed = 0  # new subscriptions whose SUBSCRIBE did not come within the wait (dead ones)
        self.sent = 0

    def _refresh(self) -> None:
        word = self._changed[:8]
        if word == self._seen:
            return
        self._seen = word  # read before listing: a change while we list is seen at the next publish
        try:
            now = {f for f in os.listdir(self.dir) if not f.startswith(".")}
        except FileNotFoundError:
            return
        for f in self._peers - now:  # the gone first: a successor below takes over what they held
            if f.endswith(KEEP_ALL_SUFFIX):
                rel = self._reliable.pop(f, None)
                if rel is not None:
                    self._gone(rel)
                continue
            try:
                self.sock.disconnect(f"ipc://{self.rt.run_dir}/s.{f}")
            except zmq.ZMQError:
                pass
        latest = set()
        for f in now - self._peers:
            endpoint = f"ipc://{self.rt.run_dir}/s.{f}"
            if f.endswith(KEEP_ALL_SUFFIX):
                rel = self._push(f, endpoint)
                if rel.key is not None:
                    self._succeed(rel)
                self._reliable[f] = rel
            else:
                self.sock.connect(endpoint)
                latest.add(f)
        self.unconfirmed = self._await_subscriptions(latest)
        self._peers = now
        self._latest = sum(1 for f in now if not f.endswith(KEEP_ALL_SUFFIX))

    def _gone(self, rel: _Reliable) -> None:
        """``rel``'s subscription went (its file was removed); a keyed one's messages wait for its successor."""
        if rel.sock is not None:
            rel.sock.close(0)
            rel.sock = None
        if rel.key is None:
            rel.credits.close()
            return
        self._trim(rel)
        rel.gone_at = time.monotonic()
        old = self._orphans.pop(rel.key, None)
        if old is not None:  # two gone in a row: the older one's successor never served
            old.credits.close()
        self._orphans[rel.key] = rel

    def _succeed(self, rel: _Reliable) -> None:
        """``rel`` is a new incarnation of a keyed subscription: re-send what the previous one did not acknowledge."""
        key = rel.key
        assert key is not None
        prev = self._orphans.pop(key, None)
        if prev is None:  # the previous one may still be listed (its file not cleaned up yet)
            prev = next((r for r in self._reliable.values() if r.key == key), None)
            if prev is None:
                return
            del self._reliable[prev.sub_id]
            self._gone(prev)
            self._orphans.pop(key, None)
        assert rel.sock is not None
        self._trim(prev)
        prev.credits.close()
        for seq, frame in prev.unacked:
            assert frame is not None
            again = _HEADER.pack(self.id | _AGAIN, seq) + frame[_HEADER.size:]
            rel.sock.send(again, _NOBLOCK, copy=len(again) < _COPY_THRESHOLD)
            rel.unacked.append((seq, frame))
            rel.kept += len(frame)
        self.resent += len(prev.unacked)
        rel.dropped = prev.dropped
        log.info("topic %s: keep-all subscriber %s is back as %s: re-sent the %d message(s) it had not acknowledged",
                 self.topic, key, rel.sub_id, len(prev.unacked))

    def _trim(self, rel: _Reliable) -> None:
        """Forget what ``rel`` has acknowledged."""
        acked = rel.credits.handled(self.id)
        unacked = rel.unacked
        while unacked and unacked[0][0] <= acked:
            frame = unacked.popleft()[1]
            if frame is not None:
                rel.kept -= len(frame)

    def _hold(self, frame: bytes) -> None:
        """Keep ``frame`` (just published) for each dead keyed subscriber's successor, within the bounds."""
        now = time.monotonic()
        for key, rel in list(self._orphans.items()):
            if now - rel.gone_at > self.successor_timeout:
                del self._orphans[key]
                rel.credits.close()
                log.warning("topic %s: keep-all subscriber %s did not come back within %.0f s: "
                            "dropped the %d message(s) kept for it", self.topic, key, self.successor_timeout,
                            len(rel.unacked) + rel.dropped)
                continue
            if len(rel.unacked) < self.window:
                rel.unacked.append((self.sent, frame))
                rel.kept += len(frame)
                continue
            if not rel.stalled:
                rel.stalled = True
                log.warning("topic %s: keep-all subscriber %s is gone and %d messages are kept for it: "
                            "dropping for it (counted) until it comes back", self.topic, key, self.window)
            rel.dropped += 1

    def _push(self, sub_id: str, endpoint: str) -> _Reliable:
        s = self.rt.ctx.socket(zmq.PUSH)
        s.setsockopt(zmq.SNDHWM, 0)  # the credit window bounds what is in flight (see actors.credits)
        s.setsockopt(zmq.LINGER, 200)  # a clean close still delivers what is queued
        s.setsockopt(zmq.RECONNECT_IVL, 20)
        s.connect(endpoint)  # the pipe exists at once: nothing sent before the connection is lost
        local = _local.get(sub_id)
        credits = CreditView(os.path.join(self.dir, sub_id))
        return _Reliable(sub_id, s, credits,
                         local is not None and local.loop.thread_id == threading.get_ident())

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

    @property
    def stalled(self) -> list[str]:
        """The ``keep="all"`` subscriptions this publisher is dropping for (see the class doc)."""
        # A copy first (one step under the GIL): a thread publisher's stats are read from the actor's thread.
        return [r.sub_id for r in list(self._reliable.values()) if r.stalled]

    @property
    def dropped(self) -> int:
        """Messages dropped for stalled ``keep="all"`` subscribers (and gone ones past the bound)."""
        return sum(r.dropped for r in self._reliable.values()) + sum(r.dropped for r in self._orphans.values())

    @property
    def kept(self) -> int:
        """Bytes of frames kept for keyed ``keep="all"`` subscribers until they acknowledge them."""
        return sum(r.kept for r in self._reliable.values()) + sum(r.kept for r in self._orphans.values())

    @property
    def held(self) -> int:
        """Messages kept for keyed ``keep="all"`` subscribers that are gone, for their next incarnation."""
        return sum(len(r.unacked) for r in self._orphans.values())

    def publish(self, msg: Any, seq: int | None = None) -> None:
        """Publish ``msg``; ``seq``: its sequence number (see ``pub_id``), else the next one."""
        if self.msg_type is not None and not isinstance(msg, self.msg_type):
            raise TypeError(
                f"topic {self.topic!r} carries {self.msg_type.__name__}, "
                f"got {type(msg).__name__}: publish a {self.msg_type.__name__} or declare another topic"
            )
        self._refresh()
        if seq is not None:
            self.sent = seq - 1  # _send numbers it
        if not self._peers and not self._orphans:
            return
        # A Flat is its frame already (an Imu from the ROS bridge): no Packer, no callbacks (~25 us cold).
        body = msg.frame() if type(msg) is Flat else self.rt.codec.encode(msg, sink=self._sink)[0]
        self._send(body)

    def publish_frame(self, body: bytes | memoryview, seq: int | None = None) -> None:
        """Publish a message already encoded by a codec (a relay's: :class:`Subscription` ``raw=True``).

        ``body`` must hold no shared-memory handles (a frame of another host's never does):
        receivers decode it as any frame, and drop (count as ``bad``) one that is not well formed.
        The declared message type is not checked (that takes a decode). ``seq``: as for :meth:`publish`.
        """
        self._refresh()
        if seq is not None:
            self.sent = seq - 1
        if self._peers or self._orphans:
            self._send(body)

    def _send(self, body: bytes | memoryview) -> None:
        self.sent += 1
        frame = _HEADER.pack(self.id, self.sent) + body
        # Below pyzmq's copy threshold copy=False copies all the same, through a Frame object made per
        # send, per subscriber (measured: 1.2 us a send copied, 1.6-2.5 us not); above it, no copy.
        copy = len(frame) < _COPY_THRESHOLD
        if self._latest:
            _zsend(self.sock, frame, _NOBLOCK, copy)  # XPUB drops at its HWM (counted as gaps)
        for rel in self._reliable.values():
            self._send_reliable(rel, frame, copy)
        if self._orphans:
            self._hold(frame)

    def _send_reliable(self, rel: _Reliable, frame: bytes, copy: bool) -> None:
        window, unacked = self.window, rel.unacked
        if len(unacked) >= window:
            self._trim(rel)
            if len(unacked) >= window and (rel.stalled or rel.local or not self._wait_credit(rel)):
                if not rel.stalled:
                    rel.stalled = True
                    log.warning(
                        "topic %s: keep-all subscriber %s is %d messages behind and did not read "
                        "for %.1f s: dropping for it (counted) until it reads again",
                        self.topic, rel.sub_id, len(unacked), 0 if rel.local else self.stall_timeout,
                    )
                rel.dropped += 1
                return
        _zsend(rel.sock, frame, _NOBLOCK, copy)  # SNDHWM 0: never refused
        if rel.key is None:
            unacked.append((self.sent, None))
        else:  # kept for its next incarnation until acknowledged; large ones let go as soon as they are
            unacked.append((self.sent, frame))
            rel.kept += len(frame)
            if rel.kept > _KEEP_BYTES:
                self._trim(rel)
        if rel.stalled:
            rel.stalled = False
            log.warning("topic %s: keep-all subscriber %s reads again (%d dropped for it)",
                        self.topic, rel.sub_id, rel.dropped)

    def _wait_credit(self, rel: _Reliable) -> bool:
        """Wait until ``rel`` has room in its window, at most ``stall_timeout``."""
        # The subscriber's progress is a counter in shared memory, with no wake-up of its own:
        # sleep in short, growing steps. Only a publisher held back by a slow reader waits
        # here; an idle one never does.
        deadline = time.monotonic() + self.stall_timeout
        nap = 0.00005
        while time.monotonic() < deadline:
            time.sleep(nap)
            nap = min(nap * 2, 0.002)
            self._trim(rel)
            if len(rel.unacked) < self.window:
                return True
            self.rt.beat()  # slowed by a reader is work, not a hang
        return False

    def close(self) -> None:
        for rel in self._reliable.values():
            if rel.sock is not None:
                rel.sock.close()
            rel.credits.close()
        for rel in self._orphans.values():
            rel.credits.close()
        self._reliable.clear()
        self._orphans.clear()
        self._changed.close()
        self.sock.close(0)


class Subscription:
    """Receives ``topic`` in ``loop``'s thread and calls ``callback(msg)``.

    ``received`` counts frames read, ``dropped`` messages lost on the way
    (queue overflow, a publisher's high-water mark or stall, a reused
    shared-memory frame), ``bad`` frames that were not well-formed
    topic messages of the declared type (logged and skipped) and
    ``redelivered`` messages a publisher re-sent to this incarnation (a
    previous one may have handled them). ``key`` (``keep="all"`` only) makes
    the subscription durable across incarnations (see the module doc).
    ``raw``: the callback gets each message's frame undecoded (a memoryview;
    :meth:`decode` decodes it), for a relay that sends it on as it is
    (:meth:`Publisher.publish_frame`, a Zenoh bridge).
    """

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
        key: str | None = None,
        raw: bool = False,
    ) -> None:
        if raw and msg_type is not None:
            raise ValueError("a raw subscription gets undecoded frames: it cannot check msg_type (drop one of them)")
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
        self.raw = raw
        self.id = f"{os.getpid()}-{next(_ids)}" + (KEEP_ALL_SUFFIX if keep == "all" else "")
        s = rt.ctx.socket(zmq.PULL if keep == "all" else zmq.SUB)
        s.setsockopt(zmq.LINGER, 0)
        # keep="all": no high-water mark (publishers bound what is in flight by credits).
        s.setsockopt(zmq.RCVHWM, max(queue_size, 16) if keep == "latest" else 0)
        s.setsockopt(zmq.MAXMSGSIZE, rt.codec.max_frame_bytes + 1024)
        if keep == "latest":
            s.setsockopt(zmq.SUBSCRIBE, b"")
        s.bind(f"ipc://{rt.run_dir}/s.{self.id}")
        self.sock = s
        self.queue: deque[Any] = deque(maxlen=queue_size)  # keep="latest" only (see _take_all)
        self.received = 0
        self.dropped = 0
        self.bad = 0
        self.redelivered = 0
        self._last: dict[int, int] = {}  # publisher id -> last sequence number seen
        d = topic_dir(rt.run_dir, self.topic)
        os.makedirs(d, mode=0o700, exist_ok=True)
        self._mark = os.path.join(d, self.id)
        self._credits: CreditBoard | None = None
        if keep == "all":
            self._credits = CreditBoard.create(self._mark, key or "")  # publishers read our progress here
        else:
            with open(self._mark, "w") as f:
                f.write(str(os.getpid()))
        mark_changed(d)
        _local[self.id] = self
        loop.add(s, self.on_readable)

    def stats(self) -> dict[str, Any]:
        """What ``embagents status`` shows for this subscription."""
        return {"topic": self.topic, "keep": self.keep, "queue_size": self.queue_size,
                "received": self.received, "dropped": self.dropped, "bad": self.bad,
                "redelivered": self.redelivered}

    def on_readable(self) -> None:
        if self.keep == "all":
            self._take_all()
            return
        sock, q = self.sock, self.queue
        # Frames come as bytes, not zmq.Frames (12 us a frame with cold caches instead of 35; a frame's
        # arrays are copied out of it by msgpack or mapped from shared memory anyway).
        # The poll said readable: read at once. After that, EVENTS before each read, not a read that
        # raises zmq.Again: the exception costs every message. Each EVENTS costs ~20 us with cold caches
        # (a 200 Hz stream's), so they are no more than needed.
        first = True
        while True:
            if first:
                first = False
                try:
                    frame = sock.recv(_NOBLOCK)
                except zmq.Again:  # a spurious wake (or called again with nothing left)
                    break
            elif sock.getsockopt(_EVENTS) & _POLLIN:  # type: ignore[operator]
                frame = sock.recv(_NOBLOCK)
            else:
                break
            self.received += 1
            pub_id, seq, msg = self._decode(frame)
            if msg is _SKIP or msg is _SEEN:
                continue
            if len(q) == q.maxlen:
                self.dropped += 1  # the oldest goes
            q.append(msg)
        while q:
            self.callback(q.popleft())

    def _take_all(self) -> None:
        """keep="all": each message is called back as soon as it is read, at most ``queue_size`` a turn.

        Not queued first: a queue only decides what a keep-latest subscription drops, and the
        EVENTS that says whether more came costs ~20 us with cold caches, a whole stream's latency
        (see on_readable), when asked before the callback.
        """
        sock, credits, callback, decode = self.sock, self._credits, self.callback, self._decode
        assert credits is not None
        try:
            frame = sock.recv(_NOBLOCK)
        except zmq.Again:  # a spurious wake (or called again with nothing left)
            return
        left = self.queue_size
        while True:
            self.received += 1
            pub_id, seq, msg = decode(frame)
            if msg is not _SEEN:
                if msg is not _SKIP:
                    callback(msg)
                if pub_id:
                    credits.handled(pub_id, seq)  # acknowledged (or skipped): the publisher forgets it
            left -= 1
            if not sock.getsockopt(_EVENTS) & _POLLIN:  # type: ignore[operator]
                return
            if left == 0:  # the others in the loop get their turn: come back for the rest
                self.loop.call_later(0, self.on_readable)
                return
            frame = sock.recv(_NOBLOCK)

    def _decode(self, frame: Any) -> tuple[int, int, Any]:
        """``(publisher id, sequence number, message)``.

        The message is ``_SKIP`` (counted) for a stale, corrupt or foreign
        frame, ``_SEEN`` for one this subscription had already (a re-sent one).
        """
        buf = memoryview(frame)
        if len(buf) <= _HEADER.size:
            self.bad += 1
            log.warning("topic %s: dropped a frame of %d bytes (too short for a topic frame)", self.topic, len(buf))
            return 0, 0, _SKIP
        pub_id, seq = _HEADER.unpack_from(buf)
        again = pub_id & _AGAIN
        if again:
            pub_id ^= _AGAIN
        last = self._last.get(pub_id)
        if last is None and len(self._last) >= _MAX_PUBLISHERS:
            self._last.pop(next(iter(self._last)))
        if last is not None and seq > last + 1:
            self.dropped += seq - last - 1  # lost before it reached us
        elif last is not None and seq <= last:  # re-sent (to a keep-all successor, by a restarted relay): had it
            return pub_id, seq, _SEEN
        if again:
            self.redelivered += 1
        self._last[pub_id] = seq
        if self.raw:
            return pub_id, seq, buf[_HEADER.size:]  # a view: it keeps the received frame alive
        try:
            msg = self.rt.codec.decode(buf[_HEADER.size:])
        except StaleFrame as exc:
            self.dropped += 1
            log.debug("topic %s: %s", self.topic, exc)
            return pub_id, seq, _SKIP
        except CodecError as exc:
            self.bad += 1
            log.warning("topic %s: dropped a corrupt frame: %s", self.topic, exc)
            return pub_id, seq, _SKIP
        if self.msg_type is not None and not isinstance(msg, self.msg_type):
            self.bad += 1
            log.warning(
                "topic %s: dropped a %s (this subscription takes %s)",
                self.topic, type(msg).__name__, self.msg_type.__name__,
            )
            return pub_id, seq, _SKIP
        return pub_id, seq, msg

    def decode(self, body: bytes | memoryview) -> Any:
        """A raw subscription's frame decoded (shared-memory arrays mapped), as a decoded subscription gets it."""
        return self.rt.codec.decode(body)

    def close(self) -> None:
        try:
            os.unlink(self._mark)
            mark_changed(os.path.dirname(self._mark))
        except FileNotFoundError:
            pass
        _local.pop(self.id, None)
        self.loop.remove(self.sock)
        self.sock.close(0)
        if self._credits is not None:
            self._credits.close()


_SKIP = object()
_SEEN = object()
