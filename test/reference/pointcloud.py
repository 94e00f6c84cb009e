"""Plain numpy reference of the point cloud packing (``depth_nodes/ros/pointcloud.py``), for
``test_pointcloud_msg.py``."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.ros.pointcloud import pack_rgb


def pack_points_reference(xyz: NDArray[Any], rgb: NDArray[np.uint8] | None,
                          extra: Mapping[str, NDArray[Any]], fields: list[tuple[str, int]],
                          step: int) -> bytes:
    """:func:`~depth_nodes.ros.pointcloud.pack_points` with a numpy structured array
    (little-endian on any host)."""
    height, width = xyz.shape[:2]
    dtype = np.dtype({'names': [n for n, _ in fields], 'formats': ['<f4'] * len(fields),
                      'offsets': [o for _, o in fields], 'itemsize': step})
    points = np.zeros((height, width), dtype=dtype)
    for i, axis in enumerate('xyz'):
        points[axis] = xyz[..., i]
    if rgb is not None:
        points['rgb'] = pack_rgb(rgb)
    for name, values in extra.items():
        points[name] = values
    return points.tobytes()
