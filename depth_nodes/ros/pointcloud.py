"""sensor_msgs/PointCloud2 building (organised, PCL-compatible layouts) and generic reading.

Layouts written by :func:`build_pointcloud` (all fields FLOAT32, little-endian):

==========  =====  ==============================================  ==========
rgb         pad    offsets                                          point_step
==========  =====  ==============================================  ==========
no          yes    x 0, y 4, z 8                                    16
no          no     x 0, y 4, z 8                                    12
yes         yes    x 0, y 4, z 8, rgb 16                            32
yes         no     x 0, y 4, z 8, rgb 12                            16
==========  =====  ==============================================  ==========

Extra fields follow (after rgb, or at 16 when padded without rgb, as PCL's PointXYZI puts
its intensity), one float32 each; with padding ``point_step`` is rounded up to a multiple
of 16. ``rgb`` is ``0x00RRGGBB`` as uint32 reinterpreted as float32, as PCL does.
"""

from __future__ import annotations

import array
import sys
from collections.abc import Mapping
from typing import Any, Literal

import numpy as np
from numba import njit
from numpy.typing import NDArray
from sensor_msgs.msg import PointCloud2, PointField

from depth_nodes.errors import MessageError
from depth_nodes.ros.image import buffer_as_uint8, set_message_bytes

#: PointField datatype code -> numpy dtype (little-endian; swapped for big-endian clouds).
POINTFIELD_DTYPES: dict[int, np.dtype[Any]] = {
    PointField.INT8: np.dtype('i1'),
    PointField.UINT8: np.dtype('u1'),
    PointField.INT16: np.dtype('<i2'),
    PointField.UINT16: np.dtype('<u2'),
    PointField.INT32: np.dtype('<i4'),
    PointField.UINT32: np.dtype('<u4'),
    PointField.FLOAT32: np.dtype('<f4'),
    PointField.FLOAT64: np.dtype('<f8'),
}


def pack_rgb(rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
    """Pack (..., 3) uint8 RGB into float32 holding the bits of uint32 ``0x00RRGGBB``."""
    c = rgb.astype(np.uint32)
    packed = (c[..., 0] << 16) | (c[..., 1] << 8) | c[..., 2]
    return packed.astype('<u4').view('<f4')


def unpack_rgb(packed: NDArray[Any]) -> NDArray[np.uint8]:
    """Inverse of :func:`pack_rgb` (also accepts uint32): (...) -> (..., 3) uint8."""
    u = np.ascontiguousarray(packed).view(np.uint32)
    return np.stack([(u >> 16) & 0xFF, (u >> 8) & 0xFF, u & 0xFF], axis=-1).astype(np.uint8)


def _layout(has_rgb: bool, pad: bool, extra: list[str]) -> tuple[list[tuple[str, int]], int]:
    fields = [('x', 0), ('y', 4), ('z', 8)]
    end = 16 if pad else 12
    for name in (['rgb'] if has_rgb else []) + extra:
        fields.append((name, end))
        end += 4
    step = -(-end // 16) * 16 if pad else end
    return fields, step


def build_pointcloud(
    xyz: NDArray[np.floating[Any]],
    header: Any,
    *,
    rgb: NDArray[np.uint8] | None = None,
    pad: bool = True,
    extra_fields: Mapping[str, NDArray[np.floating[Any]]] | None = None,
) -> PointCloud2:
    """Build an organised PointCloud2 (``is_dense = False``).

    Args:
        xyz: (H, W, 3) float coordinates in metres, NaN for invalid points.
        header: std_msgs/Header to copy (``None``: an empty header).
        rgb: Optional (H, W, 3) uint8 colours.
        pad: Pad points to 16/32 bytes (SSE-friendly, PCL's layout) or pack them.
        extra_fields: Optional name -> (H, W) float arrays, written as float32 fields in
            the mapping's order.

    Returns:
        The message; see the module docstring for the layouts.

    Raises:
        MessageError: A shape or dtype that does not fit, or a field name that is empty,
            repeated, or one of x, y, z, rgb.
    """
    xyz = np.asarray(xyz)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise MessageError(f'xyz must be a (H, W, 3) array, got shape {xyz.shape}')
    height, width = xyz.shape[:2]
    if rgb is not None:
        rgb = np.asarray(rgb)
        if rgb.shape != (height, width, 3) or rgb.dtype != np.uint8:
            raise MessageError(
                f'rgb must be ({height}, {width}, 3) uint8 like xyz, got shape {rgb.shape} '
                f'dtype {rgb.dtype}'
            )
    extra = dict(extra_fields or {})
    for name, values in extra.items():
        if not name or name in ('x', 'y', 'z', 'rgb'):
            raise MessageError(f'extra field name {name!r} is empty or reserved')
        if np.shape(values) != (height, width):
            raise MessageError(
                f'extra field {name!r} must have shape ({height}, {width}), '
                f'got {np.shape(values)}'
            )
    fields, step = _layout(rgb is not None, pad, list(extra))
    msg = PointCloud2()
    if header is not None:
        msg.header = header
    msg.height, msg.width = height, width
    msg.fields = [PointField(name=n, offset=o, datatype=PointField.FLOAT32, count=1)
                  for n, o in fields]
    msg.is_bigendian = False
    msg.point_step = step
    msg.row_step = step * width
    msg.is_dense = False
    set_message_bytes(msg, pack_points(xyz, rgb, extra, fields, step))
    return msg


def pack_points(xyz: NDArray[Any], rgb: NDArray[np.uint8] | None,
                extra: Mapping[str, NDArray[Any]], fields: list[tuple[str, int]],
                step: int) -> array.array[int]:
    """The points' bytes in the layout ``fields`` / ``step`` (every field float32, padding
    zero), as the message's own ``array('B')``: numba writes them in place, so the 9.8 MB of
    a padded 640x480 colour cloud are neither built field by field in numpy nor copied
    again into the message (with the message: 4.9 ms that way, 1.5 ms this one). The bytes
    are little-endian on any host (``is_bigendian`` false)."""
    height, width = xyz.shape[:2]
    data: array.array[int] = array.array('B', [0]) * (height * width * step)
    if not data:
        return data
    raw = np.frombuffer(data, np.uint8)
    floats = raw.view(np.float32).reshape(height, width, step // 4)
    offsets = dict(fields)
    _pack_kernel(np.ascontiguousarray(xyz), np.empty((0, 0, 3), np.uint8) if rgb is None
                 else np.ascontiguousarray(rgb), offsets.get('rgb', 0) // 4, floats,
                 raw.view(np.uint32).reshape(floats.shape))
    for name, values in extra.items():
        floats[..., offsets[name] // 4] = values
    if sys.byteorder != 'little':  # every slot is a 4-byte word: swap them all
        floats.byteswap(inplace=True)
    return data


@njit(cache=True, nogil=True)
def _pack_kernel(xyz: NDArray[Any], rgb: NDArray[np.uint8], rgb_slot: int,
                 floats: NDArray[np.float32], words: NDArray[np.uint32]) -> None:
    """x, y, z into slots 0 - 2 of each point, ``0x00RRGGBB`` into ``rgb_slot`` (when
    ``rgb`` is not empty); the other slots are zeroed (``floats`` and ``words`` are two
    views of one buffer)."""
    height, width, slots = floats.shape
    colour = rgb.shape[0] > 0
    for y in range(height):
        for x in range(width):
            for k in range(3, slots):
                words[y, x, k] = 0
            floats[y, x, 0] = xyz[y, x, 0]
            floats[y, x, 1] = xyz[y, x, 1]
            floats[y, x, 2] = xyz[y, x, 2]
            if colour:
                words[y, x, rgb_slot] = ((np.uint32(rgb[y, x, 0]) << 16)
                                         | (np.uint32(rgb[y, x, 1]) << 8)
                                         | np.uint32(rgb[y, x, 2]))


def read_pointcloud(msg: Any) -> dict[str, NDArray[Any]]:
    """Read every field of a PointCloud2 (rclpy or rosbags) into (H, W) arrays.

    Fields are parsed generically from ``fields`` (PointField datatypes 1..8, ``count > 1``
    giving (H, W, count)), honouring ``point_step``, ``row_step`` and ``is_bigendian``. A
    FLOAT32 or UINT32 field named ``rgb`` is decoded to (H, W, 3) uint8.

    Args:
        msg: The message.

    Returns:
        Field name -> native-endian array (copies, independent of the message).

    Raises:
        MessageError: Unknown datatype, a field outside the point, repeated names,
            ``row_step`` smaller than ``point_step * width`` or data shorter than
            ``row_step * height``.
    """
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    order: Literal['>', '<'] = '>' if msg.is_bigendian else '<'
    if point_step <= 0:
        raise MessageError(f'PointCloud2 point_step must be positive, got {point_step}')
    names, formats, offsets = [], [], []
    for f in msg.fields:
        base = POINTFIELD_DTYPES.get(int(f.datatype))
        if base is None:
            raise MessageError(f'PointCloud2 field {f.name!r} has unknown datatype {f.datatype}')
        count = max(int(f.count), 1)
        size = base.itemsize * count
        if int(f.offset) < 0 or int(f.offset) + size > point_step:
            raise MessageError(
                f'PointCloud2 field {f.name!r} (offset {f.offset}, {size} bytes) does not fit '
                f'in point_step {point_step}'
            )
        if f.name in names:
            raise MessageError(f'PointCloud2 field {f.name!r} appears twice')
        names.append(str(f.name))
        formats.append((base.newbyteorder(order), (count,)) if count > 1 else
                       base.newbyteorder(order))
        offsets.append(int(f.offset))
    if height <= 0 or width <= 0:
        points = np.zeros((max(height, 0), max(width, 0)),
                          dtype={'names': names, 'formats': formats, 'offsets': offsets,
                                 'itemsize': point_step})
    else:
        if row_step < point_step * width:
            raise MessageError(
                f'PointCloud2 row_step {row_step} is smaller than point_step {point_step} x '
                f'width {width} = {point_step * width}'
            )
        buf = buffer_as_uint8(msg.data)
        if buf.size < row_step * height:
            raise MessageError(
                f'PointCloud2 data has {buf.size} bytes, but row_step {row_step} x height '
                f'{height} needs {row_step * height}'
            )
        rows = buf[: row_step * height].reshape(height, row_step)[:, : point_step * width]
        dtype = np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                          'itemsize': point_step})
        points = rows.view(dtype)
    out: dict[str, NDArray[Any]] = {}
    for name in names:
        values = points[name]
        out[name] = np.array(values, dtype=values.dtype.newbyteorder('='))
    rgb = out.get('rgb')
    if rgb is not None and rgb.ndim == 2 and rgb.dtype in (np.float32, np.uint32):
        out['rgb'] = unpack_rgb(rgb)
    return out
