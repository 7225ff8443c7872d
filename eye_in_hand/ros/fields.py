"""Reading fields of ROS messages (rclpy or rosbags) with errors that name the field.

Duck-typed: only attributes are read, so messages from rclpy (``data`` an ``array.array``), from
``rosbags`` (``data`` a numpy ``uint8`` array) and anything shaped like them are accepted. Every
failure raises :class:`eye_in_hand.errors.ConversionError` naming the field (``data``,
``header.stamp.nanosec``, ``pose.orientation.w``, ...).
"""
from __future__ import annotations

import array
import math
from typing import Any

import numpy as np

from eye_in_hand.errors import ConversionError

__all__ = ["get_field", "field_path", "read_int", "read_float", "finite", "read_str",
           "byte_view", "to_byte_array"]


def get_field(msg: Any, attr: str, path: str) -> Any:
    """``msg.<attr>``; a missing field raises naming ``path.attr``."""
    try:
        return getattr(msg, attr)
    except AttributeError as exc:
        where = f"{path}.{attr}" if path else attr
        raise ConversionError(
            f"{where}: missing field (got a {type(msg).__name__})") from exc


def field_path(path: str, attr: str) -> str:
    """``path.attr`` (``attr`` alone at the top level)."""
    return f"{path}.{attr}" if path else attr


def read_int(msg: Any, attr: str, path: str = "") -> int:
    """``msg.<attr>`` as an int (bools and non-integral values refused)."""
    value = get_field(msg, attr, path)
    try:
        if isinstance(value, (bool, np.bool_)) or int(value) != value:
            raise TypeError
        return int(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ConversionError(
            f"{field_path(path, attr)}: expected an integer, got {value!r}") from exc


def read_float(msg: Any, attr: str, path: str = "") -> float:
    """``msg.<attr>`` as a finite float."""
    value = get_field(msg, attr, path)
    try:
        out = float(value)
    except (TypeError, ValueError) as exc:
        raise ConversionError(f"{field_path(path, attr)}: expected a number, got {value!r}"
                              ) from exc
    if not math.isfinite(out):                 # (the check inline: every robot pose reads 7)
        finite(out, field_path(path, attr))
    return out


def finite(value: float, field: str) -> float:
    """``value`` (a float), which must be finite; else the error names ``field``."""
    if not math.isfinite(value):
        raise ConversionError(f"{field}: is {value} (must be finite)")
    return value


def read_str(msg: Any, attr: str, path: str = "") -> str:
    """``msg.<attr>``, which must be a str."""
    value = get_field(msg, attr, path)
    if not isinstance(value, str):
        raise ConversionError(f"{field_path(path, attr)}: expected a string, got {value!r}")
    return value


def byte_view(data: Any, field: str) -> np.ndarray:
    """A 1-D uint8 view of a message's ``uint8[]`` field, without copying when possible.

    Handles ``array.array('B')`` (rclpy), numpy ``uint8`` arrays (rosbags), ``bytes``,
    ``bytearray`` and ``memoryview``; anything else (e.g. a list of ints) is copied.
    """
    if isinstance(data, np.ndarray):
        if data.dtype != np.uint8:
            raise ConversionError(f"{field}: expected uint8 data, got dtype {data.dtype}")
        return data.reshape(-1)  # a view for contiguous data (always, for rosbags messages)
    if isinstance(data, (array.array, bytes, bytearray, memoryview)):
        if isinstance(data, array.array) and data.itemsize != 1:
            raise ConversionError(f"{field}: expected a byte array, got typecode "
                                  f"{data.typecode!r}")
        try:
            return np.frombuffer(data, dtype=np.uint8)
        except (TypeError, ValueError) as exc:
            raise ConversionError(f"{field}: cannot be read as bytes") from exc
    try:
        arr = np.asarray(data)
    except (TypeError, ValueError) as exc:
        raise ConversionError(f"{field}: cannot be read as bytes ({type(data).__name__})") from exc
    if arr.ndim != 1 or (arr.size and (arr.dtype.kind not in "iu" or arr.min() < 0
                                       or arr.max() > 255)):
        raise ConversionError(f"{field}: expected a sequence of bytes (0..255)")
    return arr.astype(np.uint8)


def to_byte_array(arr: np.ndarray) -> array.array:
    """Copy a C-contiguous array's bytes into the ``array.array('B')`` rclpy stores (one copy)."""
    out = array.array("B")
    out.frombytes(np.ascontiguousarray(arr).data.cast("B"))
    return out

