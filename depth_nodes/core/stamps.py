"""Time stamps as one integer of nanoseconds (no ROS).

A ROS stamp (``builtin_interfaces/Time``: ``sec`` and ``nanosec``) and every object that
carries one (a ``std_msgs/Header``, a message with a ``header``), from rclpy or from a bag
read with rosbags, becomes nanoseconds through :func:`stamp_ns`; nothing else in the package
writes the formula out.
"""

from __future__ import annotations

from typing import Any

__all__ = ['NS_PER_S', 'STAMP_RESET_S', 'stamp_ns', 'stamp_parts']

#: Nanoseconds in a second.
NS_PER_S = 1_000_000_000
#: Stamps that jump back by this many seconds or more start a stream over (a looping bag,
#: a restarted driver); a smaller step back is a message out of order.
STAMP_RESET_S = 1.0


def stamp_ns(obj: Any) -> int:
    """Nanoseconds of a stamp, a header or a message with a header."""
    stamp = getattr(obj, 'header', obj)
    stamp = getattr(stamp, 'stamp', stamp)
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def stamp_parts(ns: int) -> tuple[int, int]:
    """``(sec, nanosec)`` of a stamp in nanoseconds (nanosec in [0, 1e9))."""
    sec, nanosec = divmod(int(ns), NS_PER_S)
    return sec, nanosec
