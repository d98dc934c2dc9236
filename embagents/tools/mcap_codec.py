"""Our messages in MCAP: a schema per message type, encode and decode.

Images, compressed images and audio use Foxglove's own protobuf schemas
(``foxglove.RawImage``, ``foxglove.CompressedImage``, ``foxglove.RawAudio``,
from ``foxglove-sdk``), so Foxglove shows them as they are. Every other
type is JSON with a JSON Schema made from its attrs fields (schema name:
its wire name with a dot, ``embagents.Detections``, a user's ``demo.Point``); small arrays are JSON lists, large ones an object
``{"dtype", "shape", "base64"}``. Supervisor events (dicts) are JSON objects.
:func:`decode` turns a recorded message back into the message class.

Example::

    >>> from embagents.msgs import String
    >>> kind = kind_of(String)
    >>> kind.schema_name, kind.message_encoding
    ('embagents.String', 'json')
    >>> decode(kind.schema_name, kind.encode(String(data="hi")))
    String(data='hi')
"""

from __future__ import annotations

import base64
import enum
import json
import typing
from collections.abc import Callable
from functools import cache
from typing import Any, NamedTuple

import attrs
import numpy as np

from actors.codec import message_class, message_name
from actors.errors import UnregisteredType
from embagents.msgs import Audio, CompressedImage, Image, RosMessage
from embagents.tools.plain import field_types

__all__ = ["EVENTS_SCHEMA", "Kind", "decode", "kind_of"]

#: The schema name of supervisor events (plain dicts).
EVENTS_SCHEMA = "embagents.SupervisorEvent"
#: Arrays with more elements than this are stored as base64 bytes, not JSON lists.
_LIST_MAX = 4096

_DTYPES = {"mono16": "uint16", "16UC1": "uint16", "32FC1": "float32"}


class Kind(NamedTuple):
    """How one message type is stored: its schema and its encoder."""

    schema_name: str
    schema_encoding: str  # "protobuf" or "jsonschema"
    schema_data: bytes
    message_encoding: str  # "protobuf" or "json"
    encode: Callable[[Any], bytes]


def _stamp(seconds: float) -> Any:
    from foxglove.messages import Timestamp

    sec = int(seconds)
    return Timestamp(sec=max(sec, 0), nsec=max(int((seconds - sec) * 1e9), 0))


def _raw_image(msg: Any) -> bytes:
    from foxglove.messages import RawImage

    a = np.ascontiguousarray(msg.data)
    h, w = a.shape[:2]
    return RawImage(timestamp=_stamp(msg.stamp), frame_id=msg.frame_id, width=w, height=h,
                    encoding=msg.encoding, step=w * (a.shape[2] if a.ndim == 3 else 1) * a.itemsize,
                    data=a.tobytes()).encode()


def _compressed_image(msg: Any) -> bytes:
    from foxglove.messages import CompressedImage

    return CompressedImage(timestamp=_stamp(msg.stamp), frame_id=msg.frame_id, data=bytes(msg.data),
                           format=msg.format).encode()


def _raw_audio(msg: Any) -> bytes:
    from foxglove.messages import RawAudio

    a = np.ascontiguousarray(msg.data)
    fmt = "pcm-f32" if a.dtype == np.float32 else "pcm-s16"
    a = a if fmt == "pcm-f32" else a.astype("<i2", copy=False)
    return RawAudio(timestamp=_stamp(msg.stamp), data=a.tobytes(), format=fmt, sample_rate=msg.sample_rate,
                    number_of_channels=msg.channels).encode()


def _json_schema(tp: Any) -> dict[str, Any]:
    origin = typing.get_origin(tp)
    simple = {str: "string", bool: "boolean", int: "integer", float: "number", bytes: "string"}
    if tp in simple:
        return {"type": simple[tp]}
    if tp is np.ndarray:
        packed = {"type": "object", "properties": {"dtype": {"type": "string"}, "shape": {"type": "array"},
                                                   "base64": {"type": "string", "contentEncoding": "base64"}}}
        return {"oneOf": [{"type": "array"}, packed]}
    if origin in (list, tuple):
        args = [a for a in typing.get_args(tp) if a is not Ellipsis]
        return {"type": "array", "items": _json_schema(args[0]) if args else {}}
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return {"type": "string", "enum": list(tp.__members__)}
    return {}


def _plain_value(v: Any) -> Any:
    if attrs.has(type(v)):  # a message inside a message (Pose in PoseStamped, a RosMessage's nested ones)
        return {f.name: _plain_value(getattr(v, f.name)) for f in attrs.fields(type(v))}
    if isinstance(v, dict):
        return {str(k): _plain_value(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain_value(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        if v.size <= _LIST_MAX:
            return v.tolist()
        a = np.ascontiguousarray(v)
        return {"dtype": str(a.dtype), "shape": list(a.shape), "base64": base64.b64encode(a.tobytes()).decode()}
    if isinstance(v, enum.Enum):
        return v.name
    if isinstance(v, (bytes, bytearray)):
        return base64.b64encode(v).decode()
    return v


def _generic_fields(value: Any) -> Any:
    """A RosMessage's recorded fields back: nested messages as RosMessages, packed arrays as arrays."""

    if isinstance(value, dict):
        if set(value) == {"dtype", "shape", "base64"}:
            return np.frombuffer(base64.b64decode(value["base64"]), dtype=value["dtype"]).reshape(value["shape"]).copy()
        if set(value) == {"ros_type", "fields"}:
            return RosMessage(value["ros_type"], _generic_fields(value["fields"]))
        return {k: _generic_fields(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_generic_fields(v) for v in value]
    return value


def _json_encoder(cls: type) -> Callable[[Any], bytes]:
    names = [f.name for f in attrs.fields(cls)]

    def encode(msg: Any) -> bytes:
        return json.dumps({n: _plain_value(getattr(msg, n)) for n in names}).encode()

    return encode


def _event_json(msg: Any) -> bytes:
    return json.dumps(msg, default=str).encode()


@cache
def kind_of(cls: type | None) -> Kind:
    """How messages of ``cls`` are stored (``None``: supervisor events, plain dicts)."""

    if cls is None or cls is dict:
        schema = {"title": EVENTS_SCHEMA, "type": "object"}
        return Kind(EVENTS_SCHEMA, "jsonschema", json.dumps(schema).encode(), "json", _event_json)
    foxglove = {Image: ("RawImage", _raw_image), CompressedImage: ("CompressedImage", _compressed_image),
                Audio: ("RawAudio", _raw_audio)}
    if cls in foxglove:
        import foxglove.messages as fm

        name, encode = foxglove[cls]
        schema = getattr(fm, name).get_schema()
        return Kind(schema.name, schema.encoding, bytes(schema.data), "protobuf", encode)

    name = message_name(cls).replace("/", ".")  # "embagents/String" -> "embagents.String"; a user's "demo.Point"
    props = {n: _json_schema(t) for n, t in field_types(cls).items()}
    json_schema = {"title": name, "type": "object", "properties": props}
    return Kind(name, "jsonschema", json.dumps(json_schema).encode(), "json", _json_encoder(cls))


def _array_field(cls: type, name: str, value: Any) -> np.ndarray:
    if isinstance(value, dict):
        return np.frombuffer(base64.b64decode(value["base64"]), dtype=value["dtype"]).reshape(value["shape"]).copy()
    default = attrs.fields_dict(cls)[name].default
    dtype = default.factory().dtype if isinstance(default, attrs.Factory) else None  # type: ignore[arg-type,union-attr]  # attrs' stubs declare Factory a function; it is a class
    return np.asarray(value, dtype=dtype)


def _from_json(cls: type, data: bytes) -> Any:
    values = json.loads(data)
    if cls is RosMessage:
        return RosMessage(values.get("ros_type", ""), _generic_fields(values.get("fields", {})))
    types = field_types(cls)
    for name, tp in types.items():
        if name in values and tp is np.ndarray:
            values[name] = _array_field(cls, name, values[name])
        elif name in values and tp is bytes:
            values[name] = base64.b64decode(values[name])
    return cls(**{k: v for k, v in values.items() if k in types})


@cache
def _proto_class(schema_name: str) -> Any:
    """The protobuf class of a Foxglove schema (built from the schema foxglove-sdk ships)."""
    import foxglove.messages as fm
    from google.protobuf.descriptor_pb2 import FileDescriptorSet
    from google.protobuf.descriptor_pool import DescriptorPool
    from google.protobuf.message_factory import GetMessageClass

    schema = getattr(fm, schema_name.split(".")[-1]).get_schema()
    pool = DescriptorPool()
    for fd in FileDescriptorSet.FromString(bytes(schema.data)).file:
        pool.Add(fd)
    return GetMessageClass(pool.FindMessageTypeByName(schema_name))


def _seconds(ts: Any) -> float:
    return float(ts.seconds) + ts.nanos / 1e9


def _from_proto(schema_name: str, data: bytes) -> Any:
    p = _proto_class(schema_name).FromString(data)
    if schema_name == "foxglove.RawImage":
        dtype = np.dtype(_DTYPES.get(p.encoding, "uint8"))
        channels = p.step // max(p.width * dtype.itemsize, 1)
        shape = (p.height, p.width, channels) if channels > 1 else (p.height, p.width)
        arr = np.frombuffer(p.data, dtype=dtype).reshape(shape)
        return Image(data=arr, encoding=p.encoding, stamp=_seconds(p.timestamp), frame_id=p.frame_id)
    if schema_name == "foxglove.CompressedImage":
        return CompressedImage(data=p.data, format=p.format, stamp=_seconds(p.timestamp), frame_id=p.frame_id)
    if schema_name == "foxglove.RawAudio":
        arr = np.frombuffer(p.data, dtype=np.float32 if p.format == "pcm-f32" else np.int16)
        return Audio(data=arr, sample_rate=p.sample_rate, channels=p.number_of_channels, stamp=_seconds(p.timestamp))
    raise ValueError(f"no embagents message for the Foxglove schema {schema_name!r}")


def decode(schema_name: str, data: bytes) -> Any:
    """A recorded message as the message it was (a dict for supervisor events).

    Raises ValueError for a schema this version does not know.
    """

    if schema_name == EVENTS_SCHEMA:
        return json.loads(data)
    if schema_name.startswith("foxglove."):
        return _from_proto(schema_name, data)
    try:
        cls = message_class(schema_name.replace(".", "/", 1))
    except UnregisteredType:
        raise ValueError(f"unknown schema {schema_name!r} (known: foxglove.RawImage, foxglove.CompressedImage, "
                         f"foxglove.RawAudio, {EVENTS_SCHEMA}, and the registered message types, e.g. "
                         "embagents.String; a type of your own is known once its module is imported)") from None
    return _from_json(cls, data)
