"""Messages written straight to CDR bytes, for the few that are too large to build as
Python objects in time: a mesh of 100 000 triangles is 300 000 ``geometry_msgs/Point``
objects, about 3 us each to create and 3 us each to serialise (measured with rclpy), near
two seconds a mesh; written here from numpy arrays it takes milliseconds.

A :class:`Serialized` message is published as bytes live (rclpy's ``publish`` takes them)
and written as bytes to a bag offline; a node of the same process that subscribes to its
topic gets it deserialised (:meth:`Serialized.message`). ``test/ros/test_serialized.py``
checks every writer here against rclpy's own deserialisation.

CDR as ROS 2 sends it (little endian, XCDR1): a 4-byte encapsulation header, then each
field aligned to its size from the end of that header; a string is a uint32 length
(terminator included), its bytes and a 0; a sequence a uint32 count and its elements.
"""

from __future__ import annotations

import importlib
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ['CdrReader', 'CdrWriter', 'MarkerData', 'Serialized', 'marker_array',
           'read_marker_array']

#: CDR, little endian.
ENCAPSULATION = b'\x00\x01\x00\x00'
MARKER_ARRAY = 'visualization_msgs/msg/MarkerArray'
#: visualization_msgs/Marker's types and actions used here.
TRIANGLE_LIST, ADD, DELETE, DELETEALL = 11, 0, 2, 3


@dataclass(frozen=True)
class Serialized:
    """A message as CDR bytes (encapsulation header included), with its type name
    (``package/msg/Name``) and the stamp of its header(s), ns (None: none)."""

    data: bytes
    msgtype: str
    stamp_ns: int | None = None

    def message(self) -> Any:
        """The message as an rclpy object."""
        from rclpy.serialization import deserialize_message
        package, _, name = self.msgtype.split('/')
        return deserialize_message(self.data,
                                   getattr(importlib.import_module(f'{package}.msg'), name))


class CdrWriter:
    """Appends CDR fields, aligned (see the module notes)."""

    def __init__(self) -> None:
        self.parts: list[bytes] = [ENCAPSULATION]
        self.size = 0  # bytes after the encapsulation header

    def _align(self, n: int) -> None:
        pad = -self.size % n
        if pad:
            self.parts.append(b'\0' * pad)
            self.size += pad

    def raw(self, data: bytes, align: int) -> None:
        self._align(align)
        self.parts.append(data)
        self.size += len(data)

    def pack(self, fmt: str, *values: Any, align: int) -> None:
        self.raw(struct.pack('<' + fmt, *values), align)

    def string(self, text: str) -> None:
        data = text.encode('utf-8') + b'\0'
        self.pack('I', len(data), align=4)
        self.raw(data, 1)

    def array(self, values: NDArray[Any], count: int) -> None:
        """A sequence of ``count`` elements whose fields are ``values`` (a contiguous
        little-endian array, aligned to its item size)."""
        self.pack('I', count, align=4)
        if count:
            self.raw(np.ascontiguousarray(values).tobytes(), values.dtype.itemsize)

    def header(self, stamp: tuple[int, int], frame_id: str) -> None:
        self.pack('iI', *stamp, align=4)
        self.string(frame_id)

    def bytes(self) -> bytes:
        return b''.join(self.parts)


def marker_array(stamp: tuple[int, int], frame_id: str, namespace: str,
                 markers: list[tuple[int, NDArray[np.float32] | None]],
                 color: tuple[float, float, float, float], *,
                 delete_all: bool = False) -> Serialized:
    """A visualization_msgs/MarkerArray of TRIANGLE_LIST markers in one frame and
    namespace: ``(id, vertices)`` adds (or replaces) marker ``id`` with the (3 t, 3)
    triangle vertices, ``(id, None)`` deletes it; all in ``color``, identity pose, scale 1.
    ``delete_all``: a DELETEALL marker first (a viewer forgets what it drew before).
    """
    out = CdrWriter()
    out.pack('I', len(markers) + delete_all, align=4)
    empty3 = np.empty((0, 3), np.float64)
    entries: list[tuple[int, int, NDArray[np.float32] | None]] = \
        [(0, DELETEALL, None)] if delete_all else []
    entries += [(marker_id, DELETE if vertices is None else ADD, vertices)
                for marker_id, vertices in markers]
    for marker_id, action, vertices in entries:
        out.header(stamp, frame_id)
        out.string(namespace)
        out.pack('iii', marker_id, TRIANGLE_LIST, action, align=4)
        out.pack('7d', 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, align=8)  # pose
        out.pack('3d', 1.0, 1.0, 1.0, align=8)  # scale
        out.pack('4f', *color, align=4)
        out.pack('iI', 0, 0, align=4)  # lifetime: forever
        out.pack('?', False, align=1)  # frame_locked
        points = empty3 if vertices is None else np.asarray(vertices, '<f8')
        out.array(points, len(points))
        out.pack('I', 0, align=4)  # colors
        out.string('')  # texture_resource
        out.header((0, 0), '')  # texture: sensor_msgs/CompressedImage
        out.string('')
        out.pack('I', 0, align=4)
        out.pack('I', 0, align=4)  # uv_coordinates
        out.string('')  # text
        out.string('')  # mesh_resource
        out.string('')  # mesh_file.filename
        out.pack('I', 0, align=4)  # mesh_file.data
        out.pack('?', False, align=1)  # mesh_use_embedded_materials
    return Serialized(out.bytes(), MARKER_ARRAY, stamp[0] * 10**9 + stamp[1])


@dataclass
class MarkerData:
    """The fields of one Marker that a mesh needs.

    Attributes:
        namespace: ``ns``.
        id: ``id``.
        type: ``type`` (11: TRIANGLE_LIST).
        action: ``action`` (0 add, 2 delete, 3 delete all).
        pose: ``(x, y, z, qx, qy, qz, qw)``.
        points: (N, 3) float64.
        colors: (M, 4) float32 RGBA (M is 0 or N).
    """

    namespace: str
    id: int
    type: int
    action: int
    pose: tuple[float, ...]
    points: NDArray[np.float64]
    colors: NDArray[np.float32]


class CdrReader:
    """Reads CDR fields in order (see the module notes)."""

    def __init__(self, data: bytes) -> None:
        if data[:4] != ENCAPSULATION:
            raise ValueError('not little-endian CDR')
        self.data = memoryview(data)[4:]
        self.at = 0

    def _align(self, n: int) -> None:
        self.at += -self.at % n

    def unpack(self, fmt: str, align: int) -> tuple[Any, ...]:
        self._align(align)
        values = struct.unpack_from('<' + fmt, self.data, self.at)
        self.at += struct.calcsize('<' + fmt)
        return values

    def string(self) -> str:
        (size,) = self.unpack('I', 4)
        text = bytes(self.data[self.at:self.at + max(size - 1, 0)]).decode('utf-8', 'replace')
        self.at += size
        return text

    def array(self, dtype: str, width: int) -> NDArray[Any]:
        """A sequence of ``width``-field elements of ``dtype``, as (count, width)."""
        (count,) = self.unpack('I', 4)
        item = np.dtype(dtype)
        if not count:
            return np.empty((0, width), item)
        self._align(item.itemsize)
        size = count * width * item.itemsize
        if self.at + size > len(self.data):
            raise ValueError('a sequence runs past the end of the message')
        out = np.frombuffer(self.data, item, count * width, self.at).reshape(count, width)
        self.at += size
        return out

    def header(self) -> tuple[int, int, str]:
        sec, nanosec = self.unpack('iI', 4)
        return sec, nanosec, self.string()


def read_marker_array(data: bytes) -> list[MarkerData]:
    """The markers of a serialised visualization_msgs/MarkerArray (Jazzy's layout).

    Raises:
        ValueError: The bytes do not hold one.
    """
    reader = CdrReader(data)
    try:
        (count,) = reader.unpack('I', 4)
        markers = []
        for _ in range(count):
            reader.header()
            namespace = reader.string()
            marker_id, kind, action = reader.unpack('iii', 4)
            pose = reader.unpack('7d', 8)
            reader.unpack('3d', 8)  # scale
            reader.unpack('4f', 4)  # color
            reader.unpack('iI', 4)  # lifetime
            reader.unpack('?', 1)  # frame_locked
            points = reader.array('<f8', 3)
            colors = reader.array('<f4', 4)
            reader.string()  # texture_resource
            reader.header()  # texture
            reader.string()
            reader.array('u1', 1)
            reader.array('<f4', 2)  # uv_coordinates
            reader.string()  # text
            reader.string()  # mesh_resource
            reader.string()  # mesh_file.filename
            reader.array('u1', 1)
            reader.unpack('?', 1)  # mesh_use_embedded_materials
            markers.append(MarkerData(namespace, marker_id, kind, action, pose,
                                      points.astype(np.float64), colors.astype(np.float32)))
    except struct.error:
        raise ValueError('the message ends before its last marker') from None
    return markers
