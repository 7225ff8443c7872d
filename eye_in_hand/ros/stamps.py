"""Time stamps and headers: int nanoseconds <-> ``builtin_interfaces/Time``, ``std_msgs/Header``.

Readers are duck-typed (rclpy or rosbags messages); builders return rclpy message objects.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from eye_in_hand.errors import ConversionError
from eye_in_hand.ros.fields import get_field, read_int

__all__ = ["stamp_to_ns", "sec_nanosec_to_ns", "ns_to_stamp", "header_stamp_ns", "make_header",
           "header_or_new"]

_NS_PER_S = 1_000_000_000
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1


def stamp_to_ns(stamp: Any, *, field: str = "stamp") -> int:
    """Nanoseconds (int) of a ``builtin_interfaces/Time``-like object (``sec``, ``nanosec``).

    Raises:
        ConversionError: missing fields, or ``nanosec`` outside [0, 1e9).
    """
    return sec_nanosec_to_ns(read_int(stamp, "sec", field), read_int(stamp, "nanosec", field),
                             field)


def sec_nanosec_to_ns(sec: int, nanosec: int, field: str = "stamp") -> int:
    """Nanoseconds of a stamp's two integer fields (as :func:`stamp_to_ns` reads them).

    Raises:
        ConversionError: ``nanosec`` outside [0, 1e9).
    """
    if not 0 <= nanosec < _NS_PER_S:
        raise ConversionError(f"{field}.nanosec: {nanosec} is outside [0, 1e9)")
    return sec * _NS_PER_S + nanosec


def ns_to_stamp(stamp_ns: int) -> Any:
    """A ``builtin_interfaces.msg.Time`` from int nanoseconds (negative stamps are floored).

    Raises:
        ConversionError: not an integer, or seconds outside the int32 range of the message.
    """
    # local: message packages are the optional [ros] extra; decoding and offline code import
    # this module without them
    from builtin_interfaces.msg import Time

    if isinstance(stamp_ns, (bool, np.bool_)) or not isinstance(stamp_ns, (int, np.integer)):
        raise ConversionError(
            f"stamp_ns: expected int nanoseconds, got {type(stamp_ns).__name__} {stamp_ns!r}")
    sec, nanosec = divmod(int(stamp_ns), _NS_PER_S)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        raise ConversionError(f"stamp_ns: {stamp_ns} does not fit builtin_interfaces/Time")
    return Time(sec=sec, nanosec=nanosec)


def header_stamp_ns(msg: Any) -> int:
    """Nanoseconds of ``msg.header.stamp`` (any stamped message, rclpy or rosbags)."""
    return stamp_to_ns(get_field(get_field(msg, "header", ""), "stamp", "header"),
                       field="header.stamp")


def make_header(stamp_ns: int = 0, frame_id: str = "") -> Any:
    """A ``std_msgs.msg.Header`` with the given stamp (int ns) and frame id."""
    # local: message packages are the optional [ros] extra; decoding and offline code import
    # this module without them
    from std_msgs.msg import Header

    if not isinstance(frame_id, str):
        raise ConversionError(f"frame_id: expected a string, got {frame_id!r}")
    return Header(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)


def header_or_new(header: Any, stamp_ns: int, frame_id: str) -> Any:
    """``header`` when given, else a new one from ``stamp_ns`` and ``frame_id``."""
    return make_header(stamp_ns, frame_id) if header is None else header

