"""Errors, the message factory and small field helpers shared by every converter.

Converters read messages through attribute access only, so they serve rclpy message objects,
rosbags-decoded messages and ``mcap_ros2`` decoded messages alike (all use the ROS 2 field names).
To *build* messages they take a :class:`MessageFactory`:

* :class:`RclpyFactory` makes rclpy message objects (the node publishes them);
* :class:`TypestoreFactory` makes rosbags typestore messages (bag writing serialises them with
  ``typestore.serialize_cdr``).

Both take the same arguments: ``factory.new("sensor_msgs/msg/Image", header=..., ...)`` with
nested messages built by ``factory.new`` too, primitive *sequences* (``uint8[]``, ``float32[]``)
as numpy arrays that ``factory.sequence`` turns into the container each library wants
(``array.array`` for rclpy, ``numpy.ndarray`` for rosbags), fixed-size arrays (``float64[9]``) as
numpy arrays, and fields left out take their ROS default values.
"""

from __future__ import annotations

import array
import importlib
import math
from functools import cache
from typing import Any, Protocol, cast

import numpy as np

from roadbev_core.errors import RoadbevError

__all__ = [
    "MessageError",
    "MessageFactory",
    "RclpyFactory",
    "TypestoreFactory",
    "field",
    "make_header",
    "stamp_from_header",
    "stamp_to_ns",
]


class MessageError(RoadbevError, ValueError):
    """A ROS message that cannot be converted; the text says which field is wrong and why."""


def field(msg: Any, name: str) -> Any:
    """``msg.<name>``, or a :class:`MessageError` naming the field when the message lacks it."""
    try:
        return getattr(msg, name)
    except AttributeError:
        raise MessageError(f"{type(msg).__name__} has no field {name!r}") from None


def as_int(value: Any, what: str, *, minimum: int = 0) -> int:
    """A message integer field as ``int`` (rejects bools, floats and out-of-range values)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise MessageError(f"{what} must be an integer, got {value!r}")
    if int(value) < minimum:
        raise MessageError(f"{what} must be >= {minimum}, got {int(value)}")
    return int(value)


def as_float(value: Any, what: str) -> float:
    """A message float field as a finite ``float``."""
    try:
        result = float(value)
    except (TypeError, ValueError):
        raise MessageError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(result):
        raise MessageError(f"{what} must be finite, got {result}")
    return result


def as_str(value: Any, what: str) -> str:
    if not isinstance(value, str):
        raise MessageError(f"{what} must be a string, got {type(value).__name__}")
    return value


def buffer_view(data: Any, dtype: np.dtype | type, what: str) -> np.ndarray:
    """A flat numpy view (no copy where the container allows it) of a primitive-array field.

    Accepts ``array.array`` (rclpy), ``numpy.ndarray`` (rosbags), ``bytes``/``memoryview``
    (mcap_ros2) and, as a slow fallback, plain sequences of numbers.
    """
    dtype = np.dtype(dtype)
    try:
        if isinstance(data, np.ndarray):
            if data.dtype == dtype:
                return data.reshape(-1)
            if data.dtype == np.uint8 and dtype.itemsize > 1:
                return _reinterpret(data.reshape(-1), dtype, what)
            return np.asarray(data, dtype=dtype).reshape(-1)
        if isinstance(data, (bytes, bytearray, memoryview)):
            return _reinterpret(np.frombuffer(data, np.uint8), dtype, what)
        if isinstance(data, array.array):
            raw = np.frombuffer(data, np.dtype(data.typecode)) if len(data) else np.zeros(0, dtype)
            return raw if raw.dtype == dtype else raw.astype(dtype)
        return np.asarray(list(data), dtype=dtype).reshape(-1)
    except (TypeError, ValueError, OverflowError) as exc:
        raise MessageError(f"{what} is not an array of {dtype.name}: {exc}") from None


def _reinterpret(raw: np.ndarray, dtype: np.dtype, what: str) -> np.ndarray:
    if dtype == np.uint8:
        return raw
    if raw.size % dtype.itemsize:
        raise MessageError(f"{what}: {raw.size} bytes is not a whole number of {dtype.name}")
    return raw.view(dtype)


def stamp_to_ns(stamp: Any) -> int:
    """``builtin_interfaces/Time`` -> integer nanoseconds."""
    sec = as_int(field(stamp, "sec"), "stamp.sec", minimum=-(2**31))
    nanosec = as_int(field(stamp, "nanosec"), "stamp.nanosec")
    if nanosec >= 1_000_000_000:
        raise MessageError(f"stamp.nanosec must be < 1e9, got {nanosec}")
    return sec * 1_000_000_000 + nanosec


def stamp_from_header(msg: Any) -> int:
    """``msg.header.stamp`` in integer nanoseconds."""
    return stamp_to_ns(field(field(msg, "header"), "stamp"))


class MessageFactory(Protocol):
    """Builds messages of one library (see the module docstring)."""

    def new(self, msgtype: str, **fields: Any) -> Any:
        """A message of ``msgtype`` ("pkg/msg/Name") with the given fields, defaults elsewhere."""
        ...

    def sequence(self, values: np.ndarray) -> Any:
        """The container this library uses for a primitive sequence field holding ``values``."""
        ...


_TYPECODES = {
    np.dtype(np.uint8): "B",
    np.dtype(np.int8): "b",
    np.dtype(np.uint16): "H",
    np.dtype(np.int16): "h",
    np.dtype(np.uint32): "I",
    np.dtype(np.int32): "i",
    np.dtype(np.uint64): "Q",
    np.dtype(np.int64): "q",
    np.dtype(np.float32): "f",
    np.dtype(np.float64): "d",
}


class RclpyFactory:
    """Builds rclpy message objects (imports the message packages lazily)."""

    def new(self, msgtype: str, **fields: Any) -> Any:
        return _rclpy_class(msgtype)(**fields)

    def sequence(self, values: np.ndarray) -> Any:
        values = np.ascontiguousarray(values)
        out = array.array(_TYPECODES[values.dtype])
        out.frombytes(values.data.cast("B"))
        return out


@cache
def _rclpy_class(msgtype: str) -> type:
    package, kind, name = _split(msgtype)
    return cast("type", getattr(importlib.import_module(f"{package}.{kind}"), name))


def _split(msgtype: str) -> tuple[str, str, str]:
    parts = msgtype.split("/")
    if len(parts) != 3:
        raise MessageError(f"message type must be 'package/msg/Name', got {msgtype!r}")
    return parts[0], parts[1], parts[2]


class TypestoreFactory:
    """Builds rosbags typestore messages, filling the fields left out with ROS defaults.

    Args:
        typestore: a rosbags ``Typestore`` (``msg_bridge.bag.typestore()`` has the project's
            custom types registered).
    """

    def __init__(self, typestore: Any) -> None:
        self.typestore = typestore

    def new(self, msgtype: str, **fields: Any) -> Any:
        try:
            _consts, fielddefs = self.typestore.fielddefs[msgtype]
        except KeyError:
            raise MessageError(f"type {msgtype!r} is not registered in the typestore") from None
        values = {}
        for name, desc in fielddefs:
            values[name] = fields.pop(name) if name in fields else self._default(desc)
        if fields:
            raise MessageError(f"{msgtype} has no field(s) {', '.join(sorted(fields))}")
        return self.typestore.types[msgtype](**values)

    def sequence(self, values: np.ndarray) -> Any:
        return np.ascontiguousarray(values)

    def _default(self, desc: tuple[Any, Any]) -> Any:
        nodetype, detail = desc
        kind = int(nodetype)
        if kind == 1:  # BASE: (type name, string bound)
            return _base_default(detail[0])
        if kind == 2:  # NAME: nested message
            return self.new(detail)
        element, count = detail
        if int(element[0]) == 1 and element[1][0] != "string":
            dtype = np.dtype(_NUMPY_TYPES[element[1][0]])
            return np.zeros(count if kind == 3 else 0, dtype=dtype)
        return [self._default(element) for _ in range(count if kind == 3 else 0)]


_NUMPY_TYPES = {
    "bool": np.bool_,
    "byte": np.uint8,
    "char": np.uint8,
    "int8": np.int8,
    "uint8": np.uint8,
    "int16": np.int16,
    "uint16": np.uint16,
    "int32": np.int32,
    "uint32": np.uint32,
    "int64": np.int64,
    "uint64": np.uint64,
    "float32": np.float32,
    "float64": np.float64,
}


def _base_default(typename: str) -> Any:
    if typename in ("string", "wstring"):
        return ""
    if typename == "bool":
        return False
    if typename.startswith("float"):
        return 0.0
    return 0


def make_header(factory: MessageFactory, stamp_ns: int, frame_id: str) -> Any:
    """A ``std_msgs/Header`` with the stamp split into seconds and nanoseconds."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    stamp = factory.new("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)
    return factory.new("std_msgs/msg/Header", stamp=stamp, frame_id=frame_id)
