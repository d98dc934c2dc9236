"""msgpack encoding with extension types for numpy arrays and message classes.

No pickle: a frame can only ever decode to msgpack-native values, numpy
arrays of plain dtypes, and attrs classes registered with :func:`message`.
A socket is therefore never a way to run code.

Example::

    >>> import attrs
    >>> @message("demo/Point")
    ... @attrs.define
    ... class Point:
    ...     x: float
    ...     y: float
    >>> codec = Codec()
    >>> codec.decode(codec.encode(Point(1.0, 2.0))[0])
    Point(x=1.0, y=2.0)

A class of fixed layout may also have a *flat* form (``register(...,
flat=(pack, unpack))``): its frame is ``pack(obj)``'s bytes, and a
:class:`Flat` sends bytes already in that form without building the object
(the ROS bridge turns an ``Imu``'s CDR bytes into its flat form directly).
A nested msgpack map of fields costs ~60 us to encode and ~75 us to decode
with cold caches (a 200 Hz sensor's messages find them cold); a flat ``Imu``
~10 us each.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Callable
from typing import Any, Protocol, TypeVar

import attrs
import msgpack
import numpy as np

from actors.errors import (
    CodecError,
    CorruptFrame,
    MessageTooLarge,
    StaleFrame,
    UnregisteredType,
    quote,
)

__all__ = [
    "Codec",
    "Flat",
    "MAX_EXT_DEPTH",
    "SHM_THRESHOLD",
    "ShmSink",
    "ShmSource",
    "message",
    "message_class",
    "message_name",
    "register",
]

EXT_NDARRAY = 1
EXT_MESSAGE = 2
EXT_SHM = 3
EXT_FLAT = 4

#: Arrays at or above this many bytes travel through shared memory.
SHM_THRESHOLD = 64 * 1024
#: A nested payload larger than this is packed by a Packer that is not kept (its buffer goes with it).
_KEEP_PACKER_BYTES = 1 << 20
#: Default cap on one encoded frame (shared-memory payloads not counted).
MAX_FRAME_BYTES = 64 * 1024 * 1024
#: How deep extensions (a message inside a message, an array inside a message) may nest. Each
#: level is one more msgpack unpacker on the C stack (tens of KB each): 200 levels crashed a
#: receiver with SIGSEGV, so a deeper frame is corrupt, and the encoder refuses to write one.
MAX_EXT_DEPTH = 32

_by_class: dict[type, tuple[str, tuple[str, ...]]] = {}
_by_name: dict[str, type] = {}
#: Flat forms: class -> (the payload's prefix: its wire name, pack); the prefix -> unpack.
_flat_by_class: dict[type, tuple[bytes, Callable[[Any], bytes]]] = {}
_unflat: dict[bytes, Callable[[memoryview], Any]] = {}

# msgpack's ext 8/16/32 headers: the marker, the payload's length, the extension type.
_EXT8, _EXT16, _EXT32 = struct.Struct(">BBb"), struct.Struct(">BHb"), struct.Struct(">BIb")

T = TypeVar("T", bound=type)
#: A class's flat form: ``pack(obj) -> bytes`` and ``unpack(memoryview) -> obj``.
FlatForm = tuple[Callable[[Any], bytes], Callable[[memoryview], Any]]


def register(cls: T, name: str | None = None, flat: FlatForm | None = None) -> T:
    """Register an attrs class so instances can cross process boundaries.

    ``name`` is the stable wire name (default ``module.QualName``); both ends
    must register the class under the same name. ``flat``: ``(pack,
    unpack)`` of a fixed-layout class, sent as ``pack(obj)``'s bytes instead
    of a map of its fields (see the module doc). ``unpack`` reads any bytes a
    peer may send: it must raise (any exception: the frame is corrupt) on
    bytes that are not an object's flat form, and must not build anything but
    the class's instances.
    """
    is_attrs = attrs.has(cls)  # kept apart: attrs.has would narrow cls and lose T
    if not is_attrs:
        raise TypeError(f"{cls.__qualname__} must be an attrs class (decorate it with @attrs.define)")
    wire = name or f"{cls.__module__}.{cls.__qualname__}"
    other = _by_name.get(wire)
    if other is not None and other is not cls and other.__qualname__ != cls.__qualname__:
        raise ValueError(f"message name {wire!r} is already registered for {other!r}")
    fields = tuple(f.name for f in attrs.fields(cls) if f.init)
    _by_class[cls] = (wire, fields)
    _by_name[wire] = cls
    if flat is not None:
        key = wire.encode()
        if len(key) > 255:
            raise ValueError(f"message name {wire[:60]!r}... is too long for a flat form (255 bytes at most)")
        pack, unpack = flat
        _flat_by_class[cls] = (bytes([len(key)]) + key, pack)
        _unflat[key] = unpack
    return cls


def message(name: str | None = None, flat: FlatForm | None = None) -> Callable[[T], T]:
    """Class decorator form of :func:`register`."""

    def deco(cls: T) -> T:
        return register(cls, name, flat)

    return deco


class Flat:
    """A message of a class with a flat form, as those bytes: encoded as they are; receivers get the object.

    Built where the bytes come from elsewhere (a ROS message's CDR), to skip
    building an object only to encode it again.

    >>> import attrs, struct
    >>> @message("demo/Pair", flat=(lambda p: struct.pack("<2d", p.a, p.b), lambda b: Pair(*struct.unpack("<2d", b))))
    ... @attrs.define
    ... class Pair:
    ...     a: float
    ...     b: float
    >>> Codec().decode(Codec().encode(Flat(Pair, struct.pack("<2d", 1.0, 2.0)))[0])
    Pair(a=1.0, b=2.0)
    """

    __slots__ = ("cls", "data", "prefix")

    def __init__(self, cls: type, data: bytes) -> None:
        entry = _flat_by_class.get(cls)
        if entry is None:
            raise TypeError(f"{cls.__qualname__} has no flat form: register it with flat=(pack, unpack)")
        self.cls, self.data, self.prefix = cls, data, entry[0]

    def message(self) -> Any:
        """The object these bytes stand for."""
        return _unflat[self.prefix[1:]](memoryview(self.data))

    def frame(self) -> bytes:
        """Its encoded frame, built without a Packer (a publisher's hot path): :meth:`Codec.decode` reads the message.

        The same bytes as :meth:`Codec.encode` writes, but for payloads of 1, 2, 4, 8 or 16 bytes
        (msgpack gives those a fixext header).
        """
        n = len(self.prefix) + len(self.data)
        if n < 1 << 8:
            head = _EXT8.pack(0xC7, n, EXT_FLAT)
        elif n < 1 << 16:
            head = _EXT16.pack(0xC8, n, EXT_FLAT)
        else:
            head = _EXT32.pack(0xC9, n, EXT_FLAT)
        return head + self.prefix + self.data

    def __repr__(self) -> str:
        return f"Flat({self.cls.__qualname__}, {len(self.data)} bytes)"


def message_name(cls: type) -> str:
    """The wire name of a registered message class."""
    try:
        return _by_class[cls][0]
    except KeyError:
        raise UnregisteredType(_unregistered_text(cls)) from None


def message_class(name: str) -> type:
    """The class registered under wire name ``name``."""
    try:
        return _by_name[name]
    except KeyError:
        raise UnregisteredType(
            f"unknown message type {quote(name, 100)}: no class is registered under that name in this "
            "process; import the module that defines it (and decorate it with @actors.message)"
        ) from None


def _unregistered_text(cls: type) -> str:
    return (
        f"cannot send an object of type {cls.__module__}.{cls.__qualname__}: it is not a "
        "registered message type; decorate its attrs class with @actors.message(...) "
        "or send msgpack-native data (dict, list, str, bytes, numbers, numpy arrays)"
    )


class ShmSink(Protocol):
    """Where the encoder puts large arrays (see :mod:`actors.shm`)."""

    def put(self, arr: np.ndarray) -> list[Any]: ...


class ShmSource(Protocol):
    """Where the decoder maps shared-memory handles from."""

    def view(self, handle: list[Any], on_release: Callable[[str, int], None] | None) -> np.ndarray: ...


class _Enc:
    """Per-thread encoding state: reusable Packers, the frame's and one per nesting depth.

    A message's fields and an array's header are packed inside the frame (an
    extension's payload). ``msgpack.packb`` would build a Packer, with its
    256 KB buffer, for each: in a process with a small heap that buffer went
    back to the system after every frame (three ``brk`` calls, measured: an
    answer holding an array took 13.8 us to encode; 3.3 us now).
    """

    __slots__ = ("sink", "threshold", "segments", "packer", "nested", "depth", "source", "owner_prefix", "forward")

    def __init__(self, threshold: int, source: Any = None) -> None:
        self.source = source
        self.owner_prefix: str | None = None  # segments of this prefix go back as they are
        self.forward = False  # received topic frames go on as their handles
        self.sink: ShmSink | None = None
        self.threshold = threshold
        self.segments: list[str] = []
        self.packer = msgpack.Packer(default=self.default)
        self.nested: list[msgpack.Packer] = []  # nested[d]: packs payloads d + 1 levels deep
        self.depth = 0

    def pack_nested(self, obj: Any) -> bytes:
        """``obj`` packed as an extension's payload (a message inside a message is one level deeper)."""
        depth = self.depth
        if depth >= MAX_EXT_DEPTH:
            raise CodecError(
                f"messages and arrays nest more than {MAX_EXT_DEPTH} deep (a message inside a message ...); "
                "no receiver decodes that: flatten the message"
            )
        if depth == len(self.nested):
            self.nested.append(msgpack.Packer(default=self.default))
        self.depth = depth + 1
        try:
            data = self.nested[depth].pack(obj)  # a Packer empties itself after a failed pack
        finally:
            self.depth = depth
        if len(data) > _KEEP_PACKER_BYTES:  # a Packer keeps its largest buffer: not a big one per depth
            self.nested[depth] = msgpack.Packer(default=self.default)
        return data

    def default(self, obj: Any) -> Any:
        cls = type(obj)
        if cls is Flat:
            return msgpack.ExtType(EXT_FLAT, obj.prefix + obj.data)
        entry = _by_class.get(cls)
        if entry is not None:
            flat = _flat_by_class.get(cls)
            if flat is not None:
                return msgpack.ExtType(EXT_FLAT, flat[0] + flat[1](obj))
            wire, fields = entry
            body = [wire, {f: getattr(obj, f) for f in fields}]
            return msgpack.ExtType(EXT_MESSAGE, self.pack_nested(body))
        if isinstance(obj, np.ndarray):
            if obj.dtype.hasobject:
                raise UnregisteredType("numpy arrays of dtype object cannot be sent; use a plain dtype")
            if self.sink is not None and obj.nbytes >= self.threshold:
                prefix = self.owner_prefix
                if prefix is not None and self.source is not None:
                    origin = self.source.origin(obj)
                    if origin is not None and origin[0].startswith(prefix):
                        # The frame goes back to the process that owns its segment: no copy.
                        return msgpack.ExtType(EXT_SHM, self.pack_nested(origin))
                if self.forward and self.source is not None:
                    origin = self.source.origin(obj, forwardable=True)
                    if origin is not None:
                        # A topic frame goes on to a third process as it is: written once, by its publisher.
                        return msgpack.ExtType(EXT_SHM, self.pack_nested(origin))
                handle = self.sink.put(obj)
                self.segments.append(handle[0])
                return msgpack.ExtType(EXT_SHM, self.pack_nested(handle))
            arr = np.ascontiguousarray(obj)
            return msgpack.ExtType(EXT_NDARRAY, self.pack_nested([arr.dtype.str, list(arr.shape), arr.tobytes()]))
        if isinstance(obj, np.generic):
            return obj.item()
        if isinstance(obj, (set, frozenset, tuple)):
            return list(obj)
        raise UnregisteredType(_unregistered_text(cls))


class _Dec:
    """Per-thread decoding state: one ext hook, told where releases go before each frame.

    ``depth`` counts the extension payloads being unpacked inside each other: past
    :data:`MAX_EXT_DEPTH` the frame is corrupt (see there), before another unpacker starts.
    """

    __slots__ = ("source", "on_release", "mapped", "depth")

    def __init__(self, source: ShmSource | None) -> None:
        self.source = source
        self.on_release: Callable[[str, int], None] | None = None
        self.mapped: list[list[Any]] | None = None  # the handles of this frame's shared-memory arrays
        self.depth = 0

    def ext_hook(self, code: int, payload: bytes) -> Any:
        if code == EXT_NDARRAY:
            dtype, shape, raw = msgpack.unpackb(payload)
            return np.frombuffer(raw, dtype=np.dtype(dtype)).reshape(shape)
        if code == EXT_MESSAGE:
            depth = self.depth
            if depth >= MAX_EXT_DEPTH:
                raise CorruptFrame(f"messages nested more than {MAX_EXT_DEPTH} deep (a frame built to exhaust the stack?)")
            self.depth = depth + 1
            try:
                wire, fields = msgpack.unpackb(payload, ext_hook=self.ext_hook, strict_map_key=False)
            finally:
                self.depth = depth
            return message_class(wire)(**fields)
        if code == EXT_FLAT:
            view = memoryview(payload)
            key = bytes(view[1 : 1 + payload[0]]) if payload else b""
            unpack = _unflat.get(key)
            if unpack is None:
                message_class(key.decode(errors="replace"))  # unknown: the error that says what to import
                raise CorruptFrame(f"{quote(key.decode(errors='replace'), 100)} has no flat form in this process")
            return unpack(view[1 + len(key) :])
        if code == EXT_SHM:
            if self.source is None:
                raise CorruptFrame("shared-memory handle on a channel that does not accept them")
            handle = msgpack.unpackb(payload)
            arr = self.source.view(handle, self.on_release)
            if self.mapped is not None:
                self.mapped.append(handle)
            return arr
        raise CorruptFrame(f"unknown msgpack extension type {code}")


class Codec:
    """Encode and decode frames; optionally route large arrays through shared memory.

    ``sink`` receives arrays of ``threshold`` bytes or more when encoding;
    ``source`` maps their handles when decoding. Without them, arrays travel
    inline in the frame.
    """

    def __init__(
        self,
        sink: ShmSink | None = None,
        source: ShmSource | None = None,
        *,
        threshold: int = SHM_THRESHOLD,
        max_frame_bytes: int = MAX_FRAME_BYTES,
    ) -> None:
        self.sink = sink
        self.source = source
        self.threshold = threshold
        self.max_frame_bytes = max_frame_bytes
        self._local = threading.local()  # packers and hooks are per thread

    def _state(self) -> tuple[_Enc, _Dec]:
        st = getattr(self._local, "st", None)
        if st is None:
            st = self._local.st = (_Enc(self.threshold, self.source), _Dec(self.source))
        return st

    def encode(
        self,
        obj: Any,
        *,
        shm: bool = True,
        owner_prefix: str | None = None,
        sink: ShmSink | None = None,
        forward: bool = False,
    ) -> tuple[bytes, list[str]]:
        """Return the frame and the names of the shared-memory segments it refers to.

        ``owner_prefix``: the receiver's segment prefix; a received frame of the
        receiver's own is sent back as its handle instead of being copied.
        ``sink``: where this frame's large arrays go instead of the codec's own
        sink (a topic's ring); it applies to this call only, so encodes on other
        threads never see it.
        ``forward``: a received topic frame (another process's ring segment)
        goes as its handle, not copied; the receiver checks that it is still
        whole after using it (:meth:`actors.shm.ShmReader.unchanged`).
        """
        enc = self._state()[0]
        enc.owner_prefix = owner_prefix
        enc.forward = forward
        enc.sink = (sink or self.sink) if shm else None
        segments: list[Any] = []
        enc.segments = segments
        enc.depth = 0
        try:
            data = enc.packer.pack(obj)
        except BaseException:
            enc.packer.reset()  # a half-packed object must not leak into the next frame
            raise
        if len(data) > self.max_frame_bytes:
            raise MessageTooLarge(len(data), self.max_frame_bytes)
        return data, segments

    def decode(
        self,
        data: bytes | memoryview,
        on_release: Callable[[str, int], None] | None = None,
        *,
        mapped: list[list[Any]] | None = None,
    ) -> Any:
        """Decode one frame; raise :class:`CorruptFrame` for anything that is not ours.

        ``mapped``: gets the handle of each shared-memory array of the frame
        (to check later that forwarded frames stayed whole).
        """
        if data and data[0] in _FLAT_MARKERS:  # maybe one flat message (a sensor stream's): no unpacker
            try:
                msg = _flat_frame(data)
            except Exception as exc:  # noqa: BLE001 - whatever unpack raises: the frame is not a flat message
                raise CorruptFrame(f"undecodable flat message ({type(exc).__name__}: {str(exc)[:200]})") from exc
            if msg is not _NOT_FLAT:
                return msg
        dec = self._state()[1]
        dec.on_release = on_release
        dec.mapped = mapped
        dec.depth = 0
        try:
            return msgpack.unpackb(data, ext_hook=dec.ext_hook, strict_map_key=False)
        except (CorruptFrame, UnregisteredType, StaleFrame):
            raise
        except Exception as exc:  # msgpack raises many types for garbage input
            raise CorruptFrame(f"undecodable frame ({type(exc).__name__}: {str(exc)[:200]})") from exc
        finally:
            dec.mapped = None

    def peek(self, data: bytes | memoryview) -> Any:
        """Decode one frame without mapping shared memory (its arrays are None): to name a frame
        whose arrays cannot be read (a :class:`StaleFrame`) in the error answered for it."""
        dec = _Dec(_NoShm())
        try:
            return msgpack.unpackb(data, ext_hook=dec.ext_hook, strict_map_key=False)
        except (CorruptFrame, UnregisteredType):
            raise
        except Exception as exc:
            raise CorruptFrame(f"undecodable frame ({type(exc).__name__}: {str(exc)[:200]})") from exc


_FLAT_MARKERS = (0xC7, 0xC8)  # msgpack's ext 8 and ext 16 (a flat message of up to 64 KB)
_NOT_FLAT = object()


def _flat_frame(data: bytes | memoryview) -> Any:
    """The message of a frame that is one flat message, read without an unpacker; else ``_NOT_FLAT``."""
    if data[0] == 0xC7:
        n, code, start = data[1], data[2], 3
    else:
        n, code, start = (data[1] << 8) | data[2], data[3], 4
    if code != EXT_FLAT or len(data) != start + n:
        return _NOT_FLAT
    end = start + 1 + data[start]
    unpack = _unflat.get(bytes(data[start + 1 : end]))
    if unpack is None:
        return _NOT_FLAT  # the unpacker's path says what is wrong
    return unpack(memoryview(data)[end:])


class _NoShm:
    """A source that maps nothing: :meth:`Codec.peek`'s."""

    def view(self, handle: list[Any], on_release: Callable[[str, int], None] | None) -> Any:
        return None
