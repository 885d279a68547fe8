"""Building ROS messages for two runtimes: rclpy (the live node) and rosbags (replay, bag writing, tests).

Writers in `msg_adapters` never import a message class themselves; they ask a `MessageFactory`:

    factory.make("sensor_msgs/msg/PointCloud2", header=factory.header(stamp, "camera"), ...)

`RclpyFactory` returns rclpy message objects (publishable), `RosbagsFactory` returns rosbags dataclasses
(serializable with `typestore.serialize_cdr`, writable to a bag without a ROS runtime). Both accept the
same field values: numpy arrays, bytes, lists or scalars are converted to what the runtime stores
(`array.array` / numpy arrays / Python scalars). Fields left out get the message's default value.

Stamps: every function that takes a stamp accepts integer nanoseconds, a stamp message (anything with
`sec` and `nanosec`, e.g. the input image's `header.stamp`) or float seconds. The package passes integer
nanoseconds (or the input's stamp message) end to end: float64 seconds cannot hold today's epoch stamps
to the nanosecond (about 0.2 us resolution), and downstream exact-time synchronizers compare nanoseconds.
"""

from __future__ import annotations

import array
import dataclasses
import importlib
import importlib.util
import itertools
import math
import re
from abc import ABC, abstractmethod
from functools import lru_cache
from typing import Any

import numpy as np

from msg_adapters.definitions import register_hri_types

# Element types of numeric message fields (ROS IDL names as rclpy and rosbags spell them).
_NUMPY_OF = {
    "float": np.float32, "float32": np.float32, "double": np.float64, "float64": np.float64,
    "int8": np.int8, "uint8": np.uint8, "int16": np.int16, "uint16": np.uint16,
    "int32": np.int32, "uint32": np.uint32, "int64": np.int64, "uint64": np.uint64,
    "octet": np.uint8, "byte": np.uint8, "char": np.uint8, "boolean": np.bool_, "bool": np.bool_,
}
_ARRAY_TYPECODE = {
    "float": "f", "double": "d", "int8": "b", "uint8": "B", "int16": "h", "uint16": "H",
    "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q",
}
_FLOAT_TYPES = {"float", "double", "float32", "float64"}
_INT_TYPES = {"int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "char"}
_STRING_TYPES = {"string", "wstring"}
# Non-zero field defaults from the .msg files, which rosbags' typestore does not keep (rclpy does).
_MSG_DEFAULTS: dict[str, dict[str, Any]] = {
    "geometry_msgs/msg/Quaternion": {"w": 1.0},
    "sensor_msgs/msg/NavSatStatus": {"status": -2},
}
_MSG_NAME = re.compile(r"^([A-Za-z0-9_]+)/(?:msg/)?([A-Za-z0-9_]+)$")


def normalize_typename(typename: str) -> str:
    """'sensor_msgs/PointCloud2' or 'sensor_msgs/msg/PointCloud2' -> 'sensor_msgs/msg/PointCloud2'."""
    m = _MSG_NAME.match(typename)
    if not m:
        raise TypeError(f"not a message type name: {typename!r} (expected 'package/msg/Type')")
    return f"{m.group(1)}/msg/{m.group(2)}"


# ---------------------------------------------------------------------------------------------- stamps
def stamp_to_ns(stamp: Any) -> int:
    """Integer nanoseconds, a stamp message (`sec`, `nanosec`) or float seconds -> integer nanoseconds."""
    if hasattr(stamp, "sec") and hasattr(stamp, "nanosec"):
        return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    if isinstance(stamp, (bool, np.bool_)) or not isinstance(stamp, (int, float, np.integer, np.floating)):
        raise TypeError(f"stamp must be integer ns, a stamp message or float seconds, got {type(stamp).__name__}")
    if isinstance(stamp, (int, np.integer)):
        return int(stamp)
    if not math.isfinite(stamp):
        raise ValueError(f"stamp must be finite, got {stamp}")
    seconds = float(stamp)
    whole = math.floor(seconds)  # split first: the fraction is exact, seconds * 1e9 would round to 256 ns
    return whole * 1_000_000_000 + round((seconds - whole) * 1e9)


def stamp_to_sec(stamp: Any) -> float:
    """A stamp message (`sec`, `nanosec`: builtin_interfaces/Time of either runtime) or float -> seconds."""
    if hasattr(stamp, "sec") and hasattr(stamp, "nanosec"):
        return int(stamp.sec) + int(stamp.nanosec) * 1e-9
    return stamp_to_ns(stamp) * 1e-9


def split_stamp(stamp: Any) -> tuple[int, int]:
    """A stamp (see `stamp_to_ns`) -> (sec, nanosec) with 0 <= nanosec < 1e9 (sec may be negative)."""
    sec, nanosec = divmod(stamp_to_ns(stamp), 1_000_000_000)
    if not -(2**31) <= sec < 2**31:
        raise ValueError(f"stamp {sec} s does not fit builtin_interfaces/Time (int32 seconds)")
    return sec, nanosec


# --------------------------------------------------------------------------------------------- factory
class MessageFactory(ABC):
    """Makes messages of one runtime; see the module docstring."""

    name: str = "abstract"

    @abstractmethod
    def message_class(self, typename: str) -> type:
        """The class of `typename` ('package/msg/Type') in this runtime."""

    @abstractmethod
    def make(self, typename: str, **fields: Any) -> Any:
        """A `typename` message with `fields` set (converted to the runtime's storage) and defaults elsewhere.

        Raises TypeError for an unknown type or field name, ValueError for a value of the wrong size.
        """

    def time(self, stamp: Any) -> Any:
        """builtin_interfaces/Time from a stamp (integer ns, a stamp message or float seconds), exactly."""
        sec, nanosec = split_stamp(stamp)
        return self.make("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)

    def duration(self, seconds: float) -> Any:
        sec, nanosec = divmod(round(float(seconds) * 1e9), 1_000_000_000)
        return self.make("builtin_interfaces/msg/Duration", sec=sec, nanosec=nanosec)

    def header(self, stamp: Any, frame_id: str) -> Any:
        """std_msgs/Header with the given stamp (float seconds or stamp message) and frame."""
        return self.make("std_msgs/msg/Header", stamp=self.time(stamp), frame_id=str(frame_id))

    def points(self, xyz: np.ndarray) -> list[Any]:
        """(N, 3) array -> list of N geometry_msgs/Point (the slow part of big Marker messages). The fields
        are passed by position, x, y, z as the message defines them (half the time of keywords)."""
        cls = self.message_class("geometry_msgs/msg/Point")
        return list(itertools.starmap(cls, np.asarray(xyz, dtype=np.float64).reshape(-1, 3).tolist()))

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class RclpyFactory(MessageFactory):
    """rclpy message objects (needs the ROS 2 Python message packages, not a running ROS graph)."""

    name = "rclpy"

    def __init__(self) -> None:
        self._classes: dict[str, type] = {}
        self._converters: dict[type, dict[str, Any]] = {}
        self._fast_points: bool | None = None

    def message_class(self, typename: str) -> type:
        cls = self._classes.get(typename)
        if cls is None:
            full = normalize_typename(typename)
            package, _, type_name = full.split("/")
            try:
                cls = getattr(importlib.import_module(f"{package}.msg"), type_name)
            except (ImportError, AttributeError) as e:
                raise TypeError(f"unknown message type {full!r} for rclpy: {e}") from e
            self._classes[typename] = cls
        return cls

    def _field_converters(self, cls: type) -> dict[str, Any]:
        conv = self._converters.get(cls)
        if conv is None:
            conv = {name: _rclpy_converter(name, t) for name, t in cls._fields_and_field_types.items()}
            self._converters[cls] = conv
        return conv

    def make(self, typename: str, **fields: Any) -> Any:
        cls = self.message_class(typename)
        conv = self._field_converters(cls)
        unknown = sorted(set(fields) - set(conv))
        if unknown:
            raise TypeError(f"{typename} has no field(s) {', '.join(unknown)}; fields: {', '.join(conv)}")
        return cls(**{name: conv[name](value) for name, value in fields.items()})

    def points(self, xyz: np.ndarray) -> list[Any]:
        # rclpy's generated __init__ costs ~1.5 us per Point; filling the slots directly is ~5x faster.
        # Used only after checking, once, that it builds a Point equal to the constructor's.
        cls = self.message_class("geometry_msgs/msg/Point")
        rows = np.asarray(xyz, dtype=np.float64).reshape(-1, 3).tolist()
        if self._fast_points is None:
            self._fast_points = _fast_point_works(cls)
        if not self._fast_points:
            return super().points(xyz)
        new = cls.__new__
        out = []
        for x, y, z in rows:
            p = new(cls)
            p._x, p._y, p._z, p._check_fields = x, y, z, False
            out.append(p)
        return out


def _fast_point_works(cls: type) -> bool:
    if set(getattr(cls, "__slots__", ())) != {"_x", "_y", "_z", "_check_fields"}:
        return False
    try:
        p = cls.__new__(cls)
        p._x, p._y, p._z, p._check_fields = 1.0, -2.0, 3.5, False
        return p == cls(x=1.0, y=-2.0, z=3.5) and (p.x, p.y, p.z) == (1.0, -2.0, 3.5)
    except Exception:  # noqa: BLE001 - any surprise means: use the constructor
        return False


def _rclpy_converter(name: str, idl_type: str) -> Any:
    """Value converter for one rclpy field, from its IDL type string ('sequence<uint8>', 'double[9]')."""
    seq = re.match(r"^sequence<([^,>]+)(?:, *\d+)?>$", idl_type)
    fixed = re.match(r"^([a-z0-9_]+)\[(\d+)\]$", idl_type)
    if seq and seq.group(1) in _ARRAY_TYPECODE:
        typecode, dtype = _ARRAY_TYPECODE[seq.group(1)], _NUMPY_OF[seq.group(1)]

        def to_array(value: Any) -> array.array:
            if isinstance(value, array.array) and value.typecode == typecode:
                return value
            if typecode == "B" and isinstance(value, (bytes, bytearray, memoryview)):
                return array.array("B", value)
            out = array.array(typecode)
            out.frombytes(np.ascontiguousarray(np.asarray(value, dtype=dtype).ravel()).tobytes())
            return out

        return to_array
    if fixed and fixed.group(1) in _NUMPY_OF:
        dtype, size = _NUMPY_OF[fixed.group(1)], int(fixed.group(2))

        def to_fixed(value: Any) -> np.ndarray:
            out = np.asarray(value, dtype=dtype).ravel()
            if out.size != size:
                raise ValueError(f"field {name!r} needs {size} values, got {out.size}")
            return out

        return to_fixed
    if seq or fixed:
        return list
    base = re.sub(r"<=\d+$", "", idl_type)
    if base in _FLOAT_TYPES:
        return float
    if base in _INT_TYPES:
        return int
    if base == "boolean":
        return bool
    if base == "octet":
        return lambda v: v if isinstance(v, bytes) else bytes([int(v)])
    if base in _STRING_TYPES:
        return str
    return lambda v: v  # a nested message


class RosbagsFactory(MessageFactory):
    """rosbags message dataclasses, from a typestore (default: ROS 2 Jazzy). The package's own copies of the
    hri_msgs definitions (msg_adapters/msg) are registered in it, so that bags get them without hri_msgs."""

    name = "rosbags"

    def __init__(self, typestore: Any = None) -> None:
        self.typestore = register_hri_types(typestore if typestore is not None else _jazzy_typestore())

    def message_class(self, typename: str) -> type:
        full = normalize_typename(typename)
        try:
            return self.typestore.types[full]
        except KeyError:
            raise TypeError(f"unknown message type {full!r} in the rosbags typestore") from None

    def make(self, typename: str, **fields: Any) -> Any:
        full = normalize_typename(typename)
        cls = self.message_class(full)
        defs = self.typestore.fielddefs[full][1]
        names = [name for name, _ in defs]
        unknown = sorted(set(fields) - set(names))
        if unknown:
            raise TypeError(f"{full} has no field(s) {', '.join(unknown)}; fields: {', '.join(names)}")
        defaults = _MSG_DEFAULTS.get(full, {})
        values = {}
        for name, desc in defs:
            if name in fields:
                values[name] = self._convert(name, desc, fields[name])
            elif name in defaults:
                values[name] = defaults[name]
            else:
                values[name] = self._default(desc)
        return cls(**values)

    def _convert(self, name: str, desc: tuple, value: Any) -> Any:
        kind, info = desc
        kind = int(kind)
        if kind == 1:  # base type
            return _rosbags_scalar(info[0], value)
        if kind in (3, 4):  # array, sequence
            (sub_kind, sub_info), size = info
            if int(sub_kind) == 1 and sub_info[0] in _NUMPY_OF:
                out = _to_numpy(value, _NUMPY_OF[sub_info[0]])
                if kind == 3 and out.size != size:
                    raise ValueError(f"field {name!r} needs {size} values, got {out.size}")
                return out
            return list(value)
        return value  # nested message

    def _default(self, desc: tuple) -> Any:
        kind, info = desc
        kind = int(kind)
        if kind == 1:
            return _rosbags_scalar(info[0], None)
        if kind == 2:
            return self.make(info)
        (sub_kind, sub_info), size = info
        numeric = int(sub_kind) == 1 and sub_info[0] in _NUMPY_OF
        if kind == 3:
            if numeric:
                return np.zeros(size, dtype=_NUMPY_OF[sub_info[0]])
            return [self._default((sub_kind, sub_info)) for _ in range(size)]
        return np.zeros(0, dtype=_NUMPY_OF[sub_info[0]]) if numeric else []


def _to_numpy(value: Any, dtype: Any) -> np.ndarray:
    if dtype == np.uint8 and isinstance(value, (bytes, bytearray, memoryview)):
        return np.frombuffer(value, dtype=np.uint8).copy()
    if isinstance(value, array.array):
        value = np.frombuffer(value, dtype=value.typecode)
    return np.ascontiguousarray(np.asarray(value, dtype=dtype).ravel())


def _rosbags_scalar(type_name: str, value: Any) -> Any:
    if type_name in _FLOAT_TYPES:
        return 0.0 if value is None else float(value)
    if type_name in _INT_TYPES or type_name in ("byte", "octet"):
        if value is None:
            return 0
        if isinstance(value, (bytes, bytearray)):
            if len(value) != 1:
                raise ValueError(f"a byte field needs 1 byte, got {len(value)}")
            return value[0]
        return int(value)
    if type_name == "bool":
        return False if value is None else bool(value)
    return "" if value is None else str(value)


@lru_cache(maxsize=1)
def _jazzy_typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def to_plain(msg: Any) -> Any:
    """A message of either runtime as nested Python values (dicts, lists, numbers, strings).

    Numeric arrays become lists and single bytes (rclpy's `byte` fields) ints, so rclpy and rosbags
    messages with the same content compare equal. For logging, JSON dumps and tests.
    """
    if hasattr(msg, "__dataclass_fields__") and hasattr(msg, "__msgtype__"):
        # rosbags also lists constants and __msgtype__ as fields; ROS 2 field names start lower-case.
        names = [f.name for f in dataclasses.fields(msg) if f.name[:1].islower()]
        return {name: to_plain(getattr(msg, name)) for name in names}
    if hasattr(msg, "get_fields_and_field_types"):
        return {name: to_plain(getattr(msg, name)) for name in msg.get_fields_and_field_types()}
    if isinstance(msg, (np.ndarray, array.array)):
        return msg.tolist()
    if isinstance(msg, (list, tuple)):
        return [to_plain(m) for m in msg]
    if isinstance(msg, bytes) and len(msg) == 1:
        return msg[0]
    if isinstance(msg, np.generic):
        return msg.item()
    return msg


def rclpy_available() -> bool:
    """Whether rclpy and the standard message packages can be imported (checked without importing)."""
    try:
        modules = ("rclpy", "sensor_msgs", "visualization_msgs")
        return all(importlib.util.find_spec(m) is not None for m in modules)
    except (ImportError, ValueError):  # a module blocked or half-imported
        return False


@lru_cache(maxsize=1)
def default_factory() -> MessageFactory:
    """RclpyFactory where rclpy is installed, else RosbagsFactory (the replay path runs without rclpy)."""
    return RclpyFactory() if rclpy_available() else RosbagsFactory()


def resolve_factory(factory: MessageFactory | None) -> MessageFactory:
    return default_factory() if factory is None else factory
