"""The Zenoh bridge actor: the one process of a run that imports zenoh.

It serves the System's :class:`~embagents.zenoh.ZenohBridge`: each exported
internal topic is subscribed here and put on Zenoh under the namespace;
each import's key expression is subscribed on Zenoh and published on its
internal topic. Messages cross as the actors' msgpack frames, relayed as
they came: an export's frame goes into the payload undecoded, an import's
payload body goes onto ipc undecoded (the receiving component's bounded
decoder refuses a malformed one, counted as ``bad``). Only a frame that may
hold an extension of type 3 is decoded: on the way out its shared-memory
arrays are copied once into the payload after the frame (shared memory
never leaves a host; see :class:`_Blobs`), on the way in such arrays
(or a forged handle, ``refused``) are checked against the payload; so are
compressed ones. Imports are published from the Zenoh thread that calls
back with them (no hand-over to the actor's loop thread).

Keep-all topics use zenoh-ext's advanced publisher (the last ``window``
samples cached, heartbeats for miss detection) and advanced subscriber
(recovery of missed samples by sequence number, in order, once): a link cut
shorter than the window loses nothing; a loss beyond it is counted
(``lost`` in ``embagents status``) and logged. A restarted bridge gets the
publishers' caches again: what its killed incarnation had forwarded (the last
sequence number of each source, in a file of the run: :class:`_Delivered`)
is dropped and counted as ``replayed``, but for the last :data:`RESEND`, which
may have died in ZeroMQ's queue: those are sent again, and the component's
subscription drops those it had (a source's samples go on ipc under a
publisher id of that source's, with its sequence numbers). History the
advanced subscriber skips (a live sample came first) is fetched here
(``_recover``). So a component gets each message once, in order.
Keep-latest topics are plain publishers that drop under congestion and just resume.

Links: explicit endpoints, multicast scouting off. Each endpoint's state
(up, down since when, never up with the last error) and the traffic each
way are in ``embagents status``; an endpoint without a link for
``link_down_s`` reports SYSTEM_FAILURE on the bridge's health (topic
``_health``) so fallbacks and events can act, and HEALTHY once it is back.
"""

from __future__ import annotations

import hashlib
import json
import logging
import mmap
import os
import re
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from actors import Actor
from actors.codec import Codec
from actors.errors import CodecError, CorruptFrame, StaleFrame, UnknownMessage
from actors.topics import Publisher
from embagents.msgs import CompressedImage, Health, HealthStatus, Image
from embagents.requests import HealthQuery
from embagents.system import loaded_system
from embagents.zenoh.spec import BRIDGE_NAME, ZenohBridge, zenoh_key

__all__ = ["BRIDGE_NAME", "CHECK_EVERY_S", "ZenohBridgeActor", "zenoh_config"]

log = logging.getLogger("embagents.zenoh.bridge")
#: How often link states and health are looked at.
CHECK_EVERY_S = 0.25
#: A connect endpoint without a link has its TCP port tried this often, to say why (refused, unreachable...).
PROBE_EVERY_S = 2.0
PROBE_ANSWERED_EVERY_S = 30.0
HEALTH_TOPIC = "_health"
#: A restarted bridge sends each source's last this many forwarded messages again: the killed one may
#: not have got them out (still in ZeroMQ's queue). No more can be: a publisher has at most this many
#: messages not yet handled by a keep-all subscriber. The component drops those it had by their number.
RESEND = Publisher.window
#: The longest a restarted bridge waits for a publisher's cache to answer (see ZenohBridgeActor._recover).
RECOVER_TIMEOUT_S = 5.0
#: Superseded Zenoh sources of one key (a peer bridge's earlier incarnations) whose ipc publishers stay
#: open: a late sample of one still goes out under its own numbers. Older ones are closed, so a peer
#: restarted again and again for days leaves no sockets behind here.
KEEP_SOURCES = 4
#: The first bytes of our Zenoh payloads: the frame format's version.
MAGIC = b"EZ2\0"
LZ4 = b"EZL\0"  # then an lz4 frame of a whole MAGIC payload
JPEG = b"EZJ\0"  # then a MAGIC payload's rest: its message is a CompressedImage that goes on as an Image
#: The most an lz4 payload may grow to (a decompression bomb is a corrupt frame).
MAX_PAYLOAD = 256 * 1024 * 1024
#: Magic, msgpack body length, and a keep-all sample's number among all its export's samples across
#: bridge restarts (0: none). In the header, not an attachment: that costs a put ~20 us with cold caches.
_HEAD = struct.Struct("<4sIQ")
_NUMBER = struct.Struct("<Q")
#: Where a msgpack frame may hold an extension of type 3 (EXT_SHM: a shared-memory handle, or our
#: payload's array handle): the header of each ext size, then the type. Nested messages are inside
#: their parent's bytes as they are, so a frame without a match holds none at any depth. A match in
#: plain data (a false alarm) only costs a decode.
_MAY_HOLD_HANDLES = re.compile(rb"[\xd4-\xd8]\x03|\xc7.\x03|\xc8..\x03|\xc9....\x03", re.S)


class _Blobs:
    """Large arrays out of band (the codec's sink and source, as shared memory is on a host).

    A payload is ``MAGIC, len(body), number, body (msgpack), blob bytes``: each array of 64 KB or more is
    copied once, straight from its shared-memory ring into the payload, instead of through three
    msgpack buffers; its handle in the body is ``[offset, nbytes, dtype, shape]``. A receiver
    views it in the payload it got, after checking the handle against the payload's size.
    """

    def __init__(self) -> None:
        self.arrays: list[np.ndarray] = []
        self.size = 0
        self._local = threading.local()  # the payload being decoded, per zenoh thread

    # -- encoding (the actor's thread) --
    def put(self, arr: np.ndarray) -> list[Any]:
        arr = np.ascontiguousarray(arr)
        handle = [self.size, arr.nbytes, arr.dtype.str, list(arr.shape)]
        self.arrays.append(arr)
        self.size += arr.nbytes
        return handle

    def frame(self, body: bytes, number: int = 0) -> bytearray:
        out = bytearray(_HEAD.size + len(body) + self.size)  # zenoh takes a bytearray without a copy
        _HEAD.pack_into(out, 0, MAGIC, len(body), number)
        start = _HEAD.size + len(body)
        out[_HEAD.size:start] = body
        for arr in self.arrays:
            out[start:start + arr.nbytes] = arr.data.cast("B")
            start += arr.nbytes
        self.arrays, self.size = [], 0
        return out

    # -- decoding (zenoh's threads) --
    def split(self, data: bytes) -> memoryview:
        if len(data) < _HEAD.size:
            raise CorruptFrame(f"a {len(data)}-byte payload is no embagents frame")
        magic, n, _ = _HEAD.unpack_from(data)
        if magic[:2] == MAGIC[:2] and magic not in (MAGIC, JPEG, LZ4) and magic[3:] == b"\0":
            # An older (or newer) bridge's frame format: say so, not just "corrupt".
            raise CorruptFrame(f"frame format {magic[:3].decode(errors='replace')} from a bridge of another "
                               f"embagents version (this one speaks {MAGIC[:3].decode()}): run the same "
                               "embagents version on both hosts")
        if magic not in (MAGIC, JPEG) or _HEAD.size + n > len(data):
            raise CorruptFrame(f"not an embagents frame (magic {magic!r}, body {n} of {len(data)} bytes)")
        self._local.data, self._local.blobs = data, _HEAD.size + n
        return memoryview(data)[_HEAD.size:_HEAD.size + n]

    def view(self, handle: list[Any], on_release: Any) -> np.ndarray:
        data, base = self._local.data, self._local.blobs
        try:
            off, nbytes, dtype, shape = handle
            dt = np.dtype(dtype)
            count = int(np.prod(shape, dtype=np.int64)) if shape else 1
            ok = (not dt.hasobject and isinstance(off, int) and 0 <= off and count >= 0
                  and count * dt.itemsize == nbytes and base + off + nbytes <= len(data))
        except Exception as exc:  # noqa: BLE001 - any malformed handle is a corrupt frame
            raise CorruptFrame(f"bad array handle {handle!r:.100}: {exc}") from None
        if not ok:
            raise CorruptFrame(f"bad array handle {handle!r:.100} in a {len(data)}-byte payload")
        return np.frombuffer(data, dtype=dt, count=count, offset=base + off).reshape(shape)


class _Delivered:
    """The last sequence number forwarded from each keep-all Zenoh source, in a file of the run.

    A restarted bridge's advanced subscriber gets the publishers' whole replay cache again
    (history): what its previous incarnation already forwarded is dropped here (counted as
    ``replayed``), so the component gets each message once. One slot per source (a publisher
    incarnation: session id and entity id), written after each forward: a memory write into a
    shared mapping, which survives this process being killed. The least recently used slot is
    reused past ``slots`` sources. Lookups read dicts, not the mapping (the receive path is hot).
    """

    SLOT = struct.Struct("<32sIQQ")  # zid, eid, last sequence number, last use (0: free)

    def __init__(self, path: str, slots: int = 1024) -> None:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        size = slots * self.SLOT.size
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            if os.fstat(fd).st_size != size:
                os.ftruncate(fd, 0)
                os.ftruncate(fd, size)
            self.map = mmap.mmap(fd, size)
        finally:
            os.close(fd)
        self.slot: dict[tuple[bytes, int], int] = {}
        self.last: dict[tuple[bytes, int], int] = {}
        self.used = [0] * slots
        for i in range(slots):
            zid, eid, sn, used = self.SLOT.unpack_from(self.map, i * self.SLOT.size)
            if used:
                key = (zid.rstrip(b"\0"), eid)
                self.slot[key], self.last[key], self.used[i] = i, sn, used
        self.tick = max(self.used)
        self.restarted = bool(self.slot)  # an earlier incarnation forwarded something

    def seen(self, source: tuple[bytes, int], sn: int) -> bool:
        return sn <= self.last.get(source, -1)

    def forwarded(self, source: tuple[bytes, int], sn: int) -> None:
        if self.seen(source, sn):  # sent again (see RESEND)
            return
        self.tick += 1
        i = self.slot.get(source)
        if i is None:
            i = min(range(len(self.used)), key=self.used.__getitem__)  # a free one (0) or the least recently used
            for key, j in list(self.slot.items()):
                if j == i:
                    del self.slot[key], self.last[key]
            self.slot[source] = i
        self.last[source], self.used[i] = sn, self.tick
        self.SLOT.pack_into(self.map, i * self.SLOT.size, source[0], source[1], sn, self.tick)

    def close(self) -> None:
        self.map.close()


class _Numbers:
    """Numbers of the run that outlive this process (a killed bridge's successor goes on from them): an mmap."""

    def __init__(self, path: str, n: int) -> None:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            if os.fstat(fd).st_size != 8 * max(n, 1):
                os.ftruncate(fd, 0)
                os.ftruncate(fd, 8 * max(n, 1))
            self.map = mmap.mmap(fd, 8 * max(n, 1))
        finally:
            os.close(fd)

    def get(self, i: int) -> int:
        return int(_NUMBER.unpack_from(self.map, 8 * i)[0])

    def set(self, i: int, value: int) -> None:
        _NUMBER.pack_into(self.map, 8 * i, value)

    def close(self) -> None:
        self.map.close()


class _Source:
    """A keep-all import's Zenoh source (an advanced publisher's incarnation), as its samples need it."""

    __slots__ = ("id", "lookup", "key", "pub", "resumed", "number")

    def __init__(self, zid: Any, eid: int, key: str) -> None:
        self.lookup = (zid, eid)  # its key among its import's sources
        self.id: tuple[bytes, int] = (str(zid).encode(), int(eid))  # as _source gives it
        self.key = key  # an advanced publisher puts on one key
        self.pub: Publisher | None = None  # its ipc publisher (see ZenohBridgeActor._source_publisher)
        self.resumed = False  # a restarted bridge forwarded a sample of it (see ZenohBridgeActor._recover)
        self.number = 0  # the export's number of its last sample


def _source(sample: Any) -> tuple[tuple[bytes, int], int] | None:
    """A sample's (source id, sequence number), set by the advanced publisher; None on a plain put."""
    info = sample.source_info
    if info is None:
        return None
    gid = info.source_id
    return (str(gid.zid).encode(), int(gid.eid)), int(info.source_sn)


def zenoh_config(spec: ZenohBridge) -> Any:
    """The zenoh.Config of a bridge: peer mode, explicit endpoints, no multicast, no shared memory."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps(spec.listen))
    conf.insert_json5("connect/endpoints", json.dumps(spec.connect))
    # Retry a lost or not yet reachable peer every 0.1-0.5 s, for ever: a link comes back on its own.
    conf.insert_json5("connect/timeout_ms", "-1")  # 0 would mean: one try, no retry
    conf.insert_json5("connect/exit_on_failure", "false")
    conf.insert_json5("connect/retry", '{"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/delay", "0")  # open at once: links come up (and are watched) in the background
    conf.insert_json5("transport/shared_memory/enabled", "false")
    # A silent peer is gone after the lease (Zenoh's default, 10 s, hides a pulled cable that long).
    conf.insert_json5("transport/link/tx/lease", str(int(spec.lease_s * 1000)))
    if spec.tls is not None:
        tls = {
            "root_ca_certificate": spec.tls.ca,
            "listen_certificate": spec.tls.cert, "listen_private_key": spec.tls.key,
            "connect_certificate": spec.tls.cert, "connect_private_key": spec.tls.key,
            "enable_mtls": True,
            # Certificates name hosts (embagents keys --tls --host); peers are reached by address.
            "verify_name_on_connect": False,
        }
        conf.insert_json5("transport/link/tls", json.dumps(tls))
    if spec.peers is not None:
        conf.insert_json5("access_control", json.dumps(access_rules({k: list(v) for k, v in spec.peers.items()})))
    return conf


#: Every kind of Zenoh message an access rule covers (the advanced pub/sub's queries and tokens too).
_ACL_MESSAGES = ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply", "liveliness_token",
                 "declare_liveliness_subscriber", "liveliness_query"]


def access_rules(peers: dict[str, list[str]]) -> dict[str, Any]:
    """Zenoh's access_control for ``ZenohBridge(peers=...)``: deny by default; per certificate name,
    its key expressions (with what the advanced pub/sub hangs under them and its ``@adv`` tokens)."""
    rules, subjects, policies = [], [], []
    for i, (name, keys) in enumerate(sorted(peers.items())):
        exprs = sorted({x for k in map(zenoh_key, keys) for x in (k, k if k.endswith("**") else k + "/**")}
                       | {"@adv/**"})
        rules.append({"id": f"r{i}", "messages": _ACL_MESSAGES, "flows": ["ingress", "egress"],
                      "permission": "allow", "key_exprs": exprs})
        subjects.append({"id": f"s{i}", "cert_common_names": [name]})
        policies.append({"rules": [f"r{i}"], "subjects": [f"s{i}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def _split(endpoint: str) -> tuple[str, str, int]:
    """'tcp/127.0.0.1:7447' -> ('tcp', '127.0.0.1', 7447)."""
    proto, _, rest = endpoint.partition("/")
    rest = rest.split("#", 1)[0].split("?", 1)[0]
    host, _, port = rest.rpartition(":")
    return proto, host.strip("[]"), int(port) if port.isdigit() else -1


def _to_jpeg(msg: Any, quality: int) -> Any:
    """An Image as a CompressedImage (JPEG), for ``Export(compress="jpeg")``; anything else as it is."""
    import cv2


    if not isinstance(msg, Image) or msg.data.dtype != np.uint8 or msg.encoding not in ("rgb8", "bgr8", "mono8"):
        raise ValueError(f"compress='jpeg' takes an Image of rgb8, bgr8 or mono8 uint8 pixels, got {msg!r:.120}; "
                         "use compress='lz4' for other messages")
    pixels = msg.data[..., ::-1] if msg.encoding == "rgb8" else msg.data  # OpenCV writes BGR
    ok, jpeg = cv2.imencode(".jpg", np.ascontiguousarray(pixels), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"OpenCV could not encode a {msg.data.shape} image as JPEG")
    return CompressedImage(data=jpeg.tobytes(), format="jpeg", stamp=msg.stamp, frame_id=f"{msg.encoding}|{msg.frame_id}")


def _from_jpeg(msg: Any) -> Any:
    import cv2


    if not isinstance(msg, CompressedImage):
        raise CorruptFrame(f"a JPEG payload that holds no CompressedImage: {msg!r:.100}")
    encoding, _, frame_id = msg.frame_id.partition("|")
    mono = encoding == "mono8"
    pixels = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_GRAYSCALE if mono else cv2.IMREAD_COLOR)
    if pixels is None:
        raise CorruptFrame("a JPEG payload OpenCV cannot decode")
    if encoding == "rgb8":
        pixels = np.ascontiguousarray(pixels[..., ::-1])
    return Image(data=pixels, encoding=encoding if encoding in ("rgb8", "bgr8", "mono8") else "bgr8",
                 stamp=msg.stamp, frame_id=frame_id)


def _unlz4(data: bytes) -> bytes:
    import lz4.frame

    try:
        dec = lz4.frame.LZ4FrameDecompressor()
        out = dec.decompress(data, max_length=MAX_PAYLOAD)
    except RuntimeError as exc:
        raise CorruptFrame(f"not an lz4 frame: {exc}") from None
    if not dec.eof:
        raise CorruptFrame(f"an lz4 payload larger than {MAX_PAYLOAD} bytes or cut short")
    return bytes(out)


class _Endpoint:
    """What the bridge knows of one configured endpoint."""

    def __init__(self, endpoint: str, role: str, now: float) -> None:
        self.endpoint, self.role = endpoint, role
        self.proto, self.host, self.port = _split(endpoint)
        self.links: set[tuple[str, str]] = set()
        self.ever_up = False
        self.since = now  # of the current state
        self.last_error = ""
        self.reported = False  # the failure of this down period is logged and on health
        self.probing = False
        self.next_probe = now + PROBE_EVERY_S / 4

    def matches(self, src: str, dst: str) -> bool:
        if self.role == "connect":
            _, host, port = _split(dst)
            return port == self.port and (host == self.host or not self.host[:1].isdigit())
        return _split(src)[2] == self.port

    @property
    def state(self) -> str:
        return "up" if self.links else ("down" if self.ever_up else "never up")


class ZenohBridgeActor(Actor):
    """Bridges the System at ``system_path`` (or ``bridge``: :meth:`ZenohBridge.to_dict`, for the bench)."""

    def __init__(self, system_path: str | None = None, bridge: dict[str, Any] | None = None) -> None:
        self.system_path = system_path
        self.raw_bridge = bridge

    def _spec(self) -> ZenohBridge:
        if self.system_path is not None:

            spec = loaded_system(self.system_path).zenoh
            if spec is None:
                raise RuntimeError(f"{self.system_path} declares no ZenohBridge (System(..., zenoh=ZenohBridge(...)))")
            return spec
        assert self.raw_bridge is not None
        return ZenohBridge.from_dict(self.raw_bridge)

    # -- start -------------------------------------------------------------------------
    def on_start(self) -> None:
        import zenoh
        import zenoh.ext

        zext: Any = zenoh.ext  # its stubs require every optional config field by name

        self.spec = spec = self._spec()
        self.blobs = _Blobs()
        self.codec = Codec(source=self.blobs)
        self.counts = {"msgs_out": 0, "bytes_out": 0, "msgs_in": 0, "bytes_in": 0, "lost": 0, "refused": 0,
                       "replayed": 0}
        self._prev: tuple[float, dict[str, int]] | None = None
        self._lock = threading.Lock()  # counters touched by zenoh's threads
        now = time.monotonic()
        self.endpoints = [_Endpoint(e, "listen", now) for e in spec.listen] + \
                         [_Endpoint(e, "connect", now) for e in spec.connect]
        self.health = (HealthStatus.HEALTHY, "starting")
        ctx = self.context
        # Zenoh's own warnings (a peer refused in the TLS handshake, garbage on the port) go to this
        # actor's stderr, which the run logs; RUST_LOG overrides the level.
        os.environ.setdefault("NO_COLOR", "1")  # plain lines in the run's log
        # (name checks are off on purpose: peers are reached by address and proved by the CA, see zenoh_config)
        zenoh.init_log_from_env_or("warn,zenoh_link_tls::utils=error,zenoh::net::runtime::orchestrator=error")
        self.session = zenoh.open(zenoh_config(spec))

        def on_link(event: Any) -> None:  # zenoh's thread
            kind, link = event.kind, event.link
            up = kind == zenoh.SampleKind.PUT
            src, dst = str(link.src), str(link.dst)
            ctx.call_soon_threadsafe(lambda: self._link(up, src, dst))

        self.link_listener = self.session.info.declare_link_events_listener(on_link, history=True)
        self.publishers: dict[str, Any] = {}
        self.exported: dict[str, Any] = {}  # topic -> its (raw) subscription
        self.compress = {e.topic: (e.compress, e.jpeg_quality) for e in spec.exports if e.compress}
        # Keep-all samples are numbered across this bridge's incarnations (in the header): a receiver
        # counts what a killed incarnation took but never got out (the advanced subscriber's sequence
        # numbers start again with each incarnation, so they cannot tell).
        self.sent = _Numbers(os.path.join(ctx.run_dir, "zenoh", f"{ctx.name}.sent"), len(spec.exports))
        self.numbers = [self.sent.get(i) for i in range(len(spec.exports))]
        pub: Any
        for n, e in enumerate(spec.exports):
            key = spec.key_of(e)
            if e.keep == "all":
                pub = zext.declare_advanced_publisher(
                    self.session, key, congestion_control=zenoh.CongestionControl.BLOCK, express=True,
                    reliability=zenoh.Reliability.RELIABLE, cache=zext.CacheConfig(max_samples=e.window),
                    sample_miss_detection=zext.MissDetectionConfig(heartbeat=0.1), publisher_detection=True)
            else:
                pub = self.session.declare_publisher(key, congestion_control=zenoh.CongestionControl.DROP, express=True)
            self.publishers[e.topic] = pub
            # Raw: a frame goes on as it came (see _exporter); only one holding shared memory is decoded.
            self.exported[e.topic] = ctx.subscribe(
                e.topic, self._exporter(pub, e.topic, n if e.keep == "all" else -1),
                queue_size=max(10, min(e.window, 1000)), keep=e.keep, raw=True)
        # What this bridge's earlier incarnations forwarded (keep-all imports), by source and sequence number.
        self.delivered = _Delivered(os.path.join(ctx.run_dir, "zenoh", f"{ctx.name}.delivered"))
        self.chains: dict[str, _Source] = {}  # key -> the source of its last numbered sample
        self.subscribers: list[Any] = []
        self.miss_listeners: list[Any] = []
        # Imports are published from the zenoh thread that calls back with them, with publishers of
        # their own (a hand-over to the loop thread costs a wake-up); the lock makes one thread at a
        # time use them (ZeroMQ sockets are not thread-safe) and guards the keep-all bookkeeping.
        self._in_lock = threading.Lock()
        self.stopped = False
        self.in_publishers: dict[str, Any] = {}
        # Keep-all samples of an advanced publisher go on ipc from a publisher of their source's: its id is
        # the source's, its sequence numbers the source's, the same in this bridge's next incarnation (see RESEND).
        self.source_publishers: dict[tuple[str, tuple[bytes, int]], Publisher] = {}
        # Sources a newer one took over from, by key (see KEEP_SOURCES), and each import's sources (under _in_lock).
        self.superseded: dict[str, deque[_Source]] = {}
        self.import_sources: list[dict[tuple[Any, int], _Source]] = []
        sub: Any
        for i in spec.imports:
            assert i.topic is not None  # Import fills it in from the key
            if i.topic not in self.in_publishers:
                self.in_publishers[i.topic] = ctx.thread_publisher(i.topic)
            # Keep-latest: called on the network thread that read the sample (indirect=False), not handed
            # to a Python thread of zenoh's first (a wake-up); one link's samples come from one thread.
            # Keep-all: zenoh's Python thread calls us in the order the advanced subscriber delivers, its
            # history and recovery replies included; from network threads they raced for the GIL and a
            # restarted bridge delivered out of order (seen: 110 before 101). A publish that waits for a slow
            # keep-all component (at most its stall_timeout, 1 s) holds that thread meanwhile: backpressure.
            cb = zenoh.handlers.Callback(self._in_callback(i.topic, once=i.keep == "all"), indirect=i.keep == "all")
            if i.keep == "all":
                sub = zext.declare_advanced_subscriber(
                    self.session, zenoh_key(i.key), cb, allowed_origin=zenoh.Locality.REMOTE,
                    history=zext.HistoryConfig(detect_late_publishers=True), recovery=zext.RecoveryConfig(heartbeat=True),
                    subscriber_detection=True)
                self.miss_listeners.append(sub.sample_miss_listener(
                    lambda miss, key=i.key: self._missed(key, str(miss.source), int(miss.nb))))
            else:
                sub = self.session.declare_subscriber(zenoh_key(i.key), cb, allowed_origin=zenoh.Locality.REMOTE)
            self.subscribers.append(sub)
        log.info("zenoh bridge %r: exports %s, imports %s, listen %s, connect %s", spec.namespace,
                 [spec.key_of(e) for e in spec.exports], [i.key for i in spec.imports], spec.listen, spec.connect)
        self._timer = ctx.call_later(CHECK_EVERY_S, self._check)

    # -- traffic ------------------------------------------------------------------------
    def _exporter(self, pub: Any, topic: str, number: int) -> Callable[[memoryview], None]:
        """The callback that puts ``topic``'s frames on Zenoh (the actor's thread); ``number``: the
        export's index among the numbered (keep-all) ones, else -1. A closure over what it uses:
        each lookup and call costs with the cold caches of a 100 Hz stream."""
        how, quality = self.compress.get(topic, (None, 0))
        head, pack_into, search, put = _HEAD.size, _HEAD.pack_into, _MAY_HOLD_HANDLES.search, pub.put
        numbers, counts, sent = self.numbers, self.counts, self.sent

        def out(frame: memoryview) -> None:
            n = numbers[number] + 1 if number >= 0 else 0
            try:
                if how is None and search(frame) is None:
                    # The ipc frame is the payload's body as it is: no decode, no encode.
                    data = bytearray(head + len(frame))  # zenoh takes a bytearray without a copy
                    pack_into(data, 0, MAGIC, len(frame), n)
                    data[head:] = frame
                else:
                    data = self._encode(self.exported[topic].decode(frame), how, quality, n)
            except StaleFrame as exc:  # its shared memory was reused meanwhile: dropped, as a subscription drops it
                self.exported[topic].dropped += 1
                log.debug("topic %s: %s", topic, exc)
                return
            except Exception as exc:  # noqa: BLE001 - an unencodable message is dropped, counted, named
                self.blobs.arrays, self.blobs.size = [], 0
                with self._lock:
                    self.counts["refused"] += 1
                log.error("not sent on %s: %s", topic, exc)
                return
            put(data)
            if n:
                numbers[number] = n
                sent.set(number, n)  # after the put: a kill before it numbers the message again, never skips
            # Only this thread writes these two (status reads them): no lock.
            counts["msgs_out"] += 1
            counts["bytes_out"] += len(data)

        return out

    def _encode(self, msg: Any, how: str | None, quality: int, number: int) -> bytearray:
        """A decoded message's payload: its arrays copied out of shared memory, compressed if asked."""
        if how == "jpeg":
            msg = _to_jpeg(msg, quality)
        body, _ = self.codec.encode(msg, sink=self.blobs)
        data = self.blobs.frame(body, number)
        if how == "jpeg":
            data[:4] = JPEG
        elif how == "lz4":
            import lz4.frame

            data = bytearray(LZ4 + lz4.frame.compress(data))
        return data

    def _in_callback(self, topic: str, once: bool = False) -> Any:
        codec, blobs, counts, lock = self.codec, self.blobs, self.counts, self._lock
        delivered, in_lock, pub, chains = self.delivered, self._in_lock, self.in_publishers[topic], self.chains
        relay_max = pub.rt.codec.max_frame_bytes
        restarted = delivered.restarted  # only a restarted bridge gets replays of what it forwarded
        head, unpack_from, search = _HEAD.size, _HEAD.unpack_from, _MAY_HOLD_HANDLES.search
        # Keep-all: each source's id, key and ipc publisher, by its ZenohId object and entity id (worked out
        # once: each call into zenoh or lookup costs with the cold caches of a 100 Hz stream). Not by its
        # EntityGlobalId: that hashes by identity, and each sample brings a new one.
        sources: dict[tuple[Any, int], _Source] = {}
        self.import_sources.append(sources)

        def on_sample(sample: Any) -> None:  # zenoh's thread (see on_start)
            source: _Source | None = None
            info = sample.source_info if once else None  # None: a plain put (no advanced publisher)
            if info is not None:
                gid, sn = info.source_id, info.source_sn
                zid, eid = gid.zid, gid.eid
                source = sources.get((zid, eid))
                if source is None:
                    source = sources[(zid, eid)] = _Source(zid, eid, str(sample.key_expr))
                if restarted and (last := delivered.last.get(source.id)) is not None:
                    if sn <= last - RESEND:  # surely got out by the killed incarnation
                        with lock:
                            counts["replayed"] += 1
                        return
                    if not source.resumed:
                        source.resumed = True
                        # The first sample after a restart further on than the resent ones: the advanced
                        # subscriber skipped history (see _recover), fetched here and forwarded first.
                        first = max(last - RESEND + 1, 0)
                        if sn > first:
                            for old in self._recover(source.key, source.id, first, sn - 1, last):
                                on_sample(old)
                    if sn <= last:  # sent again: the component drops it if it had it
                        with lock:
                            counts["replayed"] += 1
            data = sample.payload.to_bytes()
            size = len(data)
            # A frame with no arrays after it and no handles in it goes on as it came: receivers
            # decode it (and drop, counted as bad, one that is not well formed). Any other is decoded
            # here: its arrays (views into the payload) go into this host's shared memory.
            body: memoryview | None = None
            if head < size <= relay_max:
                magic, length, number = unpack_from(data)
                if magic == MAGIC and length == size - head and search(data, head) is None:
                    body = memoryview(data)[head:]
            if body is None:
                try:
                    if data[:4] == LZ4:
                        data = _unlz4(data[4:])
                    msg = codec.decode(blobs.split(data))
                    number = unpack_from(data)[2]  # split checked the header is there
                    if data[:4] == JPEG:
                        msg = _from_jpeg(msg)
                except CodecError as exc:  # a peer's garbage: dropped and counted, never a crash
                    with lock:
                        counts["refused"] += 1
                    log.warning("dropped a frame on %s from %s: %s", sample.key_expr, topic, exc)
                    return
            with in_lock:
                if self.stopped:  # on_stop undeclared us while this sample was on its way: the publishers go
                    return
                counts["msgs_in"] += 1  # written under _in_lock only (status reads them)
                counts["bytes_in"] += size
                out, seq = pub, None
                prev = None  # the source of the last numbered sample on this key, when another one (looked up once)
                if source is not None and number and (chained := chains.get(source.key)) is not None \
                        and chained.id != source.id:
                    prev = chained
                if prev is not None and source is not None and number <= prev.number:
                    # The peer's bridge was killed after its put and before it noted the number: its next
                    # incarnation sends what it had taken from its component again, numbered the same.
                    delivered.forwarded(source.id, sn)
                    with lock:
                        counts["replayed"] += 1
                    return
                if source is not None:
                    out = source.pub or self._source_publisher(topic, source)
                    seq = sn + 1  # ipc numbers start at 1
                try:
                    if body is not None:
                        out.publish_frame(body, seq)
                    else:
                        out.publish(msg, seq)
                except Exception as exc:  # noqa: BLE001 - never into zenoh's thread: dropped, counted, named
                    with lock:
                        counts["refused"] += 1
                    log.error("not published on %s: %s", topic, exc)
                    return
                if source is None:
                    return
                # The bookkeeping once the message is on its way: noted as forwarded (for a successor);
                # a jump in the export's numbers counted (see _chain_broken).
                delivered.forwarded(source.id, sn)
                if number:
                    if prev is not None:
                        if number > prev.number + 1:
                            self._chain_broken(source.key, number - prev.number - 1)
                        self._supersede(prev)
                    source.number = number
                    chains[source.key] = source

        return on_sample

    def _supersede(self, old: _Source) -> None:
        """A newer source took over ``old``'s key (its peer bridge restarted): past KEEP_SOURCES such, the
        oldest one's ipc publishers are closed (under _in_lock)."""
        gone = self.superseded.setdefault(old.key, deque())
        if any(s.id == old.id for s in gone):
            return
        gone.append(old)
        while len(gone) > KEEP_SOURCES:
            oldest = gone.popleft()
            for sources in self.import_sources:  # two imports of one topic may both know it
                if (known := sources.get(oldest.lookup)) is not None and known.id == oldest.id:
                    del sources[oldest.lookup]
                    known.pub = None
            for pair in [p for p in self.source_publishers if p[1] == oldest.id]:
                self.context.close_thread_publisher(self.source_publishers.pop(pair))
            log.debug("closed the ipc publisher(s) of %s's source %s (%d newer)", oldest.key, oldest.id, KEEP_SOURCES)

    def _source_publisher(self, topic: str, source: _Source) -> Publisher:
        """The ipc publisher of ``topic`` for one Zenoh source: its id is the source's (under _in_lock)."""
        pub = self.source_publishers.get((topic, source.id))  # two imports of one topic share it
        if pub is None:
            digest = hashlib.blake2b(repr((topic, source.id)).encode(), digest_size=6).digest()
            pub = self.context.thread_publisher(topic, pub_id=int.from_bytes(digest, "little") or 1)
            self.source_publishers[(topic, source.id)] = pub
        source.pub = pub
        return pub

    def _recover(self, key: str, source: tuple[bytes, int], first: int, last: int, had: int) -> list[Any]:
        """Samples ``first``..``last`` of ``source`` from its publisher's cache, in order (zenoh's thread).

        A restarted bridge's advanced subscriber delivers a source's first live sample at once when it
        comes before the replies to its history query for that source (a publisher it learnt of from
        its token, after the link came up), and then drops the replies as old: what the source published
        while the bridge was down would be skipped, silently. Those the cache no longer holds beyond
        ``had`` (the last the killed incarnation forwarded) are counted lost.
        """
        import zenoh

        zid, eid = source
        selector = f"{key}/@adv/*/{zid.decode()}/{eid}/**?_sn={first}..{last}"  # the advanced cache's queryable
        found: dict[int, Any] = {}
        try:
            for reply in self.session.get(selector, target=zenoh.QueryTarget.ALL, timeout=RECOVER_TIMEOUT_S,
                                          consolidation=zenoh.ConsolidationMode.NONE,
                                          accept_replies=zenoh.ReplyKeyExpr.ANY):
                sample = reply.ok
                got = _source(sample) if sample is not None else None
                if got is not None and got[0] == source and first <= got[1] <= last:
                    found[got[1]] = sample
        except Exception as exc:  # noqa: BLE001 - a failed query is a loss, counted below
            log.warning("could not query %s: %s", selector, exc)
        missing = sum(1 for sn in range(max(first, had + 1), last + 1) if sn not in found)
        log.info("%d message(s) on %s after a restart from the publisher's cache (%d..%d)", len(found), key, first, last)
        if missing:
            with self._lock:
                self.counts["lost"] += missing
            log.error("%d message(s) on %s lost: gone from the publisher's cache (Export(window=...)) while this "
                      "bridge restarted", missing, key)
        return [found[sn] for sn in sorted(found)]

    def _chain_broken(self, key: str, n: int) -> None:
        """A new incarnation of the exporting bridge goes on from its predecessor's last number: a jump
        is what the killed one had taken from its component but never got out (under _in_lock)."""
        with self._lock:
            self.counts["lost"] += n
        log.error("%d message(s) on %s lost: the exporting bridge was killed with them taken from its "
                  "component but not sent", n, key)

    def _missed(self, key: str, source: str, n: int) -> None:  # zenoh's thread
        with self._lock:
            self.counts["lost"] += n
        log.error("%d message(s) on %s from %s lost: the link was down longer than the publisher's replay window "
                  "(Export(window=...))", n, key, source)

    # -- links and health ---------------------------------------------------------------
    def _link(self, up: bool, src: str, dst: str) -> None:
        now = time.monotonic()
        for ep in self.endpoints:
            if not ep.matches(src, dst):
                continue
            was = ep.state
            (ep.links.add if up else ep.links.discard)((src, dst))
            if ep.state != was:
                ep.since = now
                if up:
                    ep.ever_up, ep.last_error = True, ""
                    log.info("link %s (%s) up: %s -> %s", ep.endpoint, ep.role, src, dst)
                else:
                    log.warning("link %s (%s) down: %s -> %s", ep.endpoint, ep.role, src, dst)
                    ep.reported = False
        self.context.changed()

    def _probe(self, ep: _Endpoint) -> None:
        """Why a connect endpoint has no link: try its TCP port (in a thread: it may take a second)."""
        ep.probing = True

        def run() -> None:
            try:
                with socket.create_connection((ep.host, ep.port), timeout=1.0):
                    err = ("its port answers TCP but no Zenoh link came up: a wrong or missing certificate, "
                           "or not a Zenoh peer there (see both sides' logs)")
            except OSError as exc:
                err = f"{exc.strerror or exc} connecting to {ep.host}:{ep.port}"
            self.context.call_soon_threadsafe(lambda: self._probed(ep, err))

        threading.Thread(target=run, name="zenoh-probe", daemon=True).start()

    def _probed(self, ep: _Endpoint, err: str) -> None:
        ep.probing = False
        if err.startswith("its port answers"):  # each probe is a failed handshake in the peer's log: seldom now
            ep.next_probe = time.monotonic() + PROBE_ANSWERED_EVERY_S
        if not ep.links:
            ep.last_error = err

    def _check(self) -> None:
        now = time.monotonic()
        failing = []
        for ep in self.endpoints:
            if ep.links:
                continue
            if ep.role == "connect" and not ep.probing and now >= ep.next_probe:
                ep.next_probe = now + PROBE_EVERY_S
                self._probe(ep)
            if now - ep.since >= self.spec.link_down_s:
                what = ("never came up" if not ep.ever_up else "down") + f" for {now - ep.since:.0f} s"
                why = ep.last_error or ("no peer connected" if ep.role == "listen" else "no answer")
                failing.append(f"{ep.endpoint} {what}: {why}")
                if not ep.reported:
                    ep.reported = True
                    fix = ("start the other side, check the address and the firewall"
                           if ep.role == "connect" else "the other side's connect= must name this address")
                    log.error("zenoh link %s (%s) %s: %s; %s", ep.endpoint, ep.role, what, why, fix)
        if failing:
            self._set_health(HealthStatus.SYSTEM_FAILURE, "; ".join(failing))
        elif all(ep.links for ep in self.endpoints):
            self._set_health(HealthStatus.HEALTHY, "links up")
        self._timer = self.context.call_later(CHECK_EVERY_S, self._check)

    def _set_health(self, status: HealthStatus, text: str) -> None:
        # Published when the status changes (fallbacks act on each report); the text (with its
        # seconds) is kept up to date for `embagents status` and HealthQuery.
        changed = status != self.health[0]
        self.health = (status, text)
        if changed:
            self.context.publish(HEALTH_TOPIC, Health(component=self.context.name, status=status, text=text,
                                                      stamp=time.time()))

    # -- status ----------------------------------------------------------------------------
    def links(self) -> list[dict[str, Any]]:
        """Each endpoint: role, state, since (s), links, last error."""
        now = time.monotonic()
        return [{"endpoint": ep.endpoint, "role": ep.role, "state": ep.state, "for_s": round(now - ep.since, 1),
                 "links": len(ep.links), "last_error": ep.last_error} for ep in self.endpoints]

    def status_detail(self) -> dict[str, Any]:
        now = time.monotonic()
        with self._lock:
            counts = dict(self.counts)
        rates = dict.fromkeys(("msgs_out", "bytes_out", "msgs_in", "bytes_in"), 0.0)
        if self._prev is not None and now > self._prev[0]:
            dt = now - self._prev[0]
            rates = {k: round((counts[k] - self._prev[1][k]) / dt, 1) for k in rates}
        self._prev = (now, counts)
        links = self.links()
        lines = []
        for ln in links:
            state = ln["state"] + ("" if ln["state"] == "up" else f" for {ln['for_s']:.0f}s")
            err = f"  last error: {ln['last_error']}" if ln["last_error"] and ln["state"] != "up" else ""
            lines.append(f"zenoh {ln['role']} {ln['endpoint']}: {state}, {ln['links']} link(s){err}")
        lines.append(f"zenoh {self.spec.namespace}: out {rates['msgs_out']:g} msg/s {rates['bytes_out']:g} B/s, "
                     f"in {rates['msgs_in']:g} msg/s {rates['bytes_in']:g} B/s, lost {counts['lost']}, "
                     f"refused {counts['refused']}, replayed {counts['replayed']}; health {self.health[0].name}")
        return {"links": links, "counts": counts, "rates": rates, "health": self.health[0].name,
                "source_publishers": len(getattr(self, "source_publishers", ())),
                "health_text": self.health[1], "lines": lines}

    def on_receive(self, message: Any) -> Any:
        if message == "stats":
            return self.status_detail()
        if isinstance(message, HealthQuery):
            return {"status": int(self.health[0]), "text": self.health[1]}
        raise UnknownMessage("the Zenoh bridge", message, "it answers 'stats' and HealthQuery()")

    def on_stop(self) -> None:
        for sub in self.subscribers:
            sub.undeclare()
        with self._in_lock:  # a sample being published finishes; later ones find the publishers gone
            self.stopped = True
        for pub in self.publishers.values():
            pub.undeclare()
        self.link_listener.undeclare()
        self.session.close()
        self.delivered.close()
        self.sent.close()
