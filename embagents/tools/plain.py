"""Messages as plain data and back: what ``topic echo`` prints and ``topic pub`` reads.

:func:`to_plain` turns a message (an attrs class, a dict such as a supervisor
event) into JSON-able data; arrays are summarised as their shape and dtype
unless ``full_arrays``. :func:`build_message` makes a message from plain
fields and, when a value does not fit, names the field, what it holds and
what it should hold.

Example::

    >>> from embagents.msgs import Image, String
    >>> import numpy as np
    >>> to_plain(Image(data=np.zeros((2, 3, 3), np.uint8)))["data"]
    '<array shape=(2, 3, 3) dtype=uint8>'
    >>> build_message(String, {"data": "hi"})
    String(data='hi')
    >>> build_message(String, {"data": 5})
    Traceback (most recent call last):
    ValueError: String field 'data' must be a str, got 5 (int); fields of String: data (str)
"""

from __future__ import annotations

import enum
import typing
from typing import Any

import attrs
import numpy as np

from embagents.msgs import RosMessage

__all__ = ["build_message", "field_types", "format_text", "to_plain"]


def to_plain(msg: Any, *, full_arrays: bool = False) -> Any:
    """``msg`` as JSON-able data (attrs classes become dicts, arrays summaries or lists).

    A :class:`~embagents.msgs.RosMessage` shows its ROS fields, as ``ros2 topic echo`` does.
    """

    if isinstance(msg, RosMessage):
        return to_plain(msg.fields, full_arrays=full_arrays)
    if attrs.has(type(msg)):
        return {f.name: to_plain(getattr(msg, f.name), full_arrays=full_arrays) for f in attrs.fields(type(msg))}
    if isinstance(msg, np.ndarray):
        return msg.tolist() if full_arrays else f"<array shape={tuple(msg.shape)} dtype={msg.dtype}>"
    if isinstance(msg, (bytes, bytearray, memoryview)):
        return list(bytes(msg)) if full_arrays else f"<{len(msg)} bytes>"
    if isinstance(msg, enum.Enum):
        return msg.name
    if isinstance(msg, dict):
        return {str(k): to_plain(v, full_arrays=full_arrays) for k, v in msg.items()}
    if isinstance(msg, (list, tuple)):
        return [to_plain(v, full_arrays=full_arrays) for v in msg]
    if isinstance(msg, np.generic):
        return msg.item()
    return msg


def format_text(plain: Any, indent: str = "") -> str:
    """Plain data as indented ``key: value`` lines (the ``topic echo`` text form).

    >>> print(format_text({"data": "hi", "pose": {"x": 1}}))
    data: hi
    pose:
      x: 1
    """
    if not isinstance(plain, dict):
        return f"{indent}{plain}"
    lines = []
    for k, v in plain.items():
        if isinstance(v, dict) and v:
            lines.append(f"{indent}{k}:")
            lines.append(format_text(v, indent + "  "))
        else:
            lines.append(f"{indent}{k}: {v}")
    return "\n".join(lines)


def field_types(cls: type) -> dict[str, Any]:
    """A message class's fields and their (resolved) types."""
    hints = typing.get_type_hints(cls, globalns=vars(__import__(cls.__module__, fromlist=["_"])))
    return {f.name: hints.get(f.name, Any) for f in attrs.fields(cls)}


def _type_text(tp: Any) -> str:
    if tp is np.ndarray:
        return "array"
    if typing.get_origin(tp) is not None:
        return str(tp).replace("typing.", "")
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _fits(tp: Any, value: Any) -> bool:
    """Whether ``value`` (plain data from YAML/JSON) may be given for a field of type ``tp``."""
    origin = typing.get_origin(tp)
    if tp is Any:
        return True
    if tp is bool:
        return isinstance(value, bool)
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if tp is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if tp is str:
        return isinstance(value, str)
    if tp is bytes:
        return isinstance(value, (bytes, str))
    if tp is np.ndarray:
        return isinstance(value, (list, int, float)) and not isinstance(value, bool)
    if origin is list:
        (item,) = typing.get_args(tp) or (Any,)
        return isinstance(value, list) and all(_fits(item, v) for v in value)
    if origin is tuple:
        args = typing.get_args(tp)
        return (isinstance(value, (list, tuple)) and len(value) == len(args)
                and all(_fits(a, v) for a, v in zip(args, value, strict=True)))
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return isinstance(value, (str, int))
    return True


def build_message(cls: type, fields: dict[str, Any]) -> Any:
    """``cls(**fields)``; a ValueError names the field that does not fit and the fields the type has."""
    if not isinstance(fields, dict):
        raise ValueError(f"{cls.__name__} data must be a mapping of fields such as {{data: hi}}, got {fields!r}")
    types = field_types(cls)
    listing = f"fields of {cls.__name__}: " + ", ".join(f"{n} ({_type_text(t)})" for n, t in types.items())
    for name, value in fields.items():
        if name not in types:
            raise ValueError(f"{cls.__name__} has no field {name!r}; {listing}")
        if not _fits(types[name], value):
            raise ValueError(f"{cls.__name__} field {name!r} must be a {_type_text(types[name])}, "
                             f"got {value!r} ({type(value).__name__}); {listing}")
    values = {k: (v.encode() if types[k] is bytes and isinstance(v, str) else v) for k, v in fields.items()}
    try:
        return cls(**values)
    except (TypeError, ValueError) as exc:  # a converter or a check across fields refused it
        raise ValueError(f"cannot make a {cls.__name__} from {fields!r}: {exc}; {listing}") from None
