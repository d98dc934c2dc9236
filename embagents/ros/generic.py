"""Any installed ROS message <-> :class:`~embagents.msgs.RosMessage`, by introspection.

As ``ros2 topic echo`` does, the fields come from the generated class
(``get_fields_and_field_types()`` and ``SLOT_TYPES``): nested messages become
RosMessages, numeric arrays numpy arrays (a view on rclpy's ``array.array``
where it is one), strings str, ``builtin_interfaces/Time`` / ``Duration``
float seconds. A plan per ROS class is built once and cached. Imports ROS
message packages (never rclpy): used by the bridge only.

Example::

    >>> from sensor_msgs.msg import Temperature
    >>> m = generic_from_ros(Temperature(temperature=21.5), "sensor_msgs/msg/Temperature")
    >>> m.temperature, m.header.stamp
    (21.5, 0.0)
    >>> generic_to_ros(m, Temperature).temperature
    21.5
"""

from __future__ import annotations

import array
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from rosidl_parser.definition import AbstractNestedType, AbstractSequence, BasicType, NamespacedType

from embagents.msgs import RosMessage
from embagents.ros.spec import ros_interface_class

__all__ = ["generic_from_ros", "generic_to_ros", "ros_type_name"]

# ROS primitive -> (numpy dtype, array.array typecode).
_NUMERIC = {
    "float": ("<f4", "f"), "double": ("<f8", "d"),
    "int8": ("i1", "b"), "uint8": ("u1", "B"), "int16": ("<i2", "h"), "uint16": ("<u2", "H"),
    "int32": ("<i4", "i"), "uint32": ("<u4", "I"), "int64": ("<i8", "q"), "uint64": ("<u8", "Q"),
}
_TIME_TYPES = ("builtin_interfaces/msg/Time", "builtin_interfaces/msg/Duration")

Reader = Callable[[Any], Any]
Writer = Callable[[Any, str], Any]


def ros_type_name(cls: type) -> str:
    """``sensor_msgs.msg.Imu`` -> ``"sensor_msgs/msg/Imu"``."""
    pkg, kind = cls.__module__.split(".")[:2]
    return f"{pkg}/{kind}/{cls.__name__}"


def _nested_name(t: NamespacedType) -> str:
    return "/".join([*t.namespaces, t.name])


def _nested_class(t: NamespacedType) -> type:
    return ros_interface_class(_nested_name(t))


def _fields(cls: type) -> list[tuple[str, Any]]:
    names = list(cls.get_fields_and_field_types())  # type: ignore[attr-defined]
    types = list(cls.SLOT_TYPES)  # type: ignore[attr-defined]
    return list(zip(names, types, strict=True))


# --- ROS -> RosMessage ---------------------------------------------------------

_READ_PLANS: dict[type, list[tuple[str, Reader]]] = {}


def _time_from(v: Any) -> float:
    return v.sec + v.nanosec * 1e-9


def _element_reader(t: Any) -> Reader:
    if isinstance(t, NamespacedType):
        return _time_from if _nested_name(t) in _TIME_TYPES else _message_from
    return lambda v: v  # numbers, bool, str, bytes (octet)


def _reader(t: Any) -> Reader:
    if not isinstance(t, AbstractNestedType):
        return _element_reader(t)
    vt = t.value_type
    if isinstance(vt, BasicType):
        if vt.typename in _NUMERIC:
            dtype = np.dtype(_NUMERIC[vt.typename][0])
            # array.array (sequences): a view, no copy; numpy (fixed arrays): as it is.
            return lambda v: v if isinstance(v, np.ndarray) else np.frombuffer(v, dtype)
        if vt.typename == "boolean":
            return lambda v: np.asarray(v, bool)
        if vt.typename in ("octet", "char"):
            return lambda v: np.frombuffer(b"".join(v), np.uint8) if v and isinstance(v[0], bytes) else np.asarray(v, np.uint8)
    element = _element_reader(vt)
    if element is _time_from:
        return lambda v: np.array([_time_from(x) for x in v], np.float64)
    return lambda v: [element(x) for x in v]


def _read_plan(cls: type) -> list[tuple[str, Reader]]:
    plan = _READ_PLANS.get(cls)
    if plan is None:
        plan = _READ_PLANS[cls] = [(name, _reader(t)) for name, t in _fields(cls)]
    return plan


def _message_from(ros_msg: Any) -> RosMessage:
    cls = type(ros_msg)
    return RosMessage(ros_type_name(cls), {name: read(getattr(ros_msg, name)) for name, read in _read_plan(cls)})


def generic_from_ros(ros_msg: Any, ros_type: str | None = None) -> RosMessage:
    """A ROS message of any installed type -> a RosMessage with the same field names."""
    out = _message_from(ros_msg)
    if ros_type is not None:
        out.ros_type = ros_type
    return out


# --- RosMessage -> ROS ---------------------------------------------------------

_WRITE_PLANS: dict[type, dict[str, Writer]] = {}


def _time_to(cls: type) -> Writer:
    def write(v: Any, where: str) -> Any:
        if isinstance(v, RosMessage):
            v = v.sec + v.nanosec * 1e-9
        seconds = float(v)
        if not math.isfinite(seconds):
            raise ValueError(f"{where} must be finite seconds, got {v!r}")
        sec = math.floor(seconds)
        nanosec = min(round((seconds - sec) * 1e9), 999_999_999)
        return cls(sec=int(sec), nanosec=int(nanosec))

    return write


def _element_writer(t: Any) -> Writer:
    if isinstance(t, NamespacedType):
        cls = _nested_class(t)
        if _nested_name(t) in _TIME_TYPES:
            return _time_to(cls)
        return lambda v, where: _message_to(v, cls, where)
    if isinstance(t, BasicType) and t.typename in _NUMERIC:
        kind = _NUMERIC[t.typename][0]
        return (lambda v, where: float(v)) if "f" in kind else (lambda v, where: int(v))
    if isinstance(t, BasicType) and t.typename == "boolean":
        return lambda v, where: bool(v)
    return lambda v, where: v


def _writer(t: Any) -> Writer:
    if not isinstance(t, AbstractNestedType):
        return _element_writer(t)
    vt = t.value_type
    if isinstance(vt, BasicType) and vt.typename in _NUMERIC:
        dtype, code = _NUMERIC[vt.typename]
        if isinstance(t, AbstractSequence):
            def seq(v: Any, where: str) -> array.array:
                a = array.array(code)
                a.frombytes(np.ascontiguousarray(v, dtype=dtype).tobytes())
                return a
            return seq
        return lambda v, where: np.asarray(v, dtype=np.dtype(dtype).newbyteorder("="))
    if isinstance(vt, BasicType) and vt.typename == "boolean":
        return lambda v, where: [bool(x) for x in v]
    if isinstance(vt, BasicType) and vt.typename == "octet":
        return lambda v, where: [bytes([int(x)]) for x in (v if not isinstance(v, bytes) else v)]
    element = _element_writer(vt)
    return lambda v, where: [element(x, f"{where}[{i}]") for i, x in enumerate(v)]


def _write_plan(cls: type) -> dict[str, Writer]:
    plan = _WRITE_PLANS.get(cls)
    if plan is None:
        plan = _WRITE_PLANS[cls] = {name: _writer(t) for name, t in _fields(cls)}
    return plan


def _message_to(msg: Any, cls: type, where: str) -> Any:
    if isinstance(msg, RosMessage):
        values = msg.fields
    elif isinstance(msg, dict):
        values = msg
    else:
        raise ValueError(f"{where}: expected a RosMessage or dict for {ros_type_name(cls)}, got {type(msg).__name__}")
    plan = _write_plan(cls)
    out = cls()
    for name, value in values.items():
        write = plan.get(name)
        path = f"{where}.{name}" if where else name
        if write is None:
            raise ValueError(f"{ros_type_name(cls)} has no field {path!r}; its fields: {', '.join(plan)}")
        try:
            setattr(out, name, write(value, path))
        except ValueError as e:
            if "/" in str(e).split(" ", 1)[0] or "must be" in str(e):  # a nested field's error: already named
                raise
            raise ValueError(f"{ros_type_name(cls)} field {path!r}: {e}") from None
        except (AssertionError, TypeError) as e:
            detail = str(e) or f"{type(value).__name__} {value!r:.60} does not fit its type"
            raise ValueError(f"{ros_type_name(cls)} field {path!r}: {detail}") from None
    return out


def generic_to_ros(msg: RosMessage | dict[str, Any], cls: type) -> Any:
    """A RosMessage (or a dict of fields) -> a ROS message of class ``cls``; fields not given keep ROS defaults.

    Raises ValueError naming a field the type lacks, or one whose value does not fit.
    """
    return _message_to(msg, cls, "")
