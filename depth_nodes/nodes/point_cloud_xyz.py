"""point_cloud_xyz node: a depth image -> organised PointCloud2 (depth_image_proc's
PointCloudXyzNode, same topics and parameters).

Subscribes ``image_rect`` (16UC1 mm or 32FC1 m, REP 118; raw or, with
``depth_image_transport: compressedDepth``, ``image_rect/compressedDepth``) and
``camera_info``, matched by exact stamp as image_transport's camera subscriber does.
Publishes ``points``: organised H x W, x, y, z float32 at 0, 4, 8 and 16-byte points (PCL's
padded PointXYZ layout, as upstream), in the depth image's frame and stamp; pixels with no
depth are NaN points, or with ``invalid_depth`` > 0 points at that depth along their ray.

The intrinsics are the CameraInfo's rectified ``P`` (binning and ROI applied); a depth
image of another size than the CameraInfo gets them scaled to its size.

Outputs are computed only while subscribed (lazy), or always offline.

Frames without output are counted and logged: ``unsupported_encoding``, the decoding
reasons (``malformed_image``, also a depth image with no pixel, ``decode_failed``...),
``uncalibrated``, ``bad_calibration``, ``sync_*``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from depth_nodes.core.depth_image import depth_to_points
from depth_nodes.nodes.depth_common import (
    INVALID_DEPTH,
    QUEUE_SIZE,
    DepthImageNode,
    depth_transport,
)
from depth_nodes.ros.params import NodeParameters
from depth_nodes.ros.pointcloud import build_pointcloud

PARAMETERS = [depth_transport('depth_image_transport'), QUEUE_SIZE, INVALID_DEPTH]


def fill_unknown(depth: np.ndarray, invalid_depth: float) -> np.ndarray:
    """``depth`` with its unknown (NaN) pixels set to ``invalid_depth`` (0: left NaN)."""
    if invalid_depth > 0:
        return np.where(np.isnan(depth), np.float32(invalid_depth), depth)
    return depth


class PointCloudXyzNode(DepthImageNode):
    """Depth image + camera_info -> ``points``."""

    def __init__(self, node_name: str = 'point_cloud_xyz', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS)
        values = self.params.values
        self.pub_points = self.add_output(PointCloud2, 'points')
        self.add_synced_inputs(
            [(Image, 'image_rect', values['depth_image_transport']),
             (CameraInfo, 'camera_info')], self.on_frame, queue_size=values['queue_size'])

    def on_frame(self, depth_msg: Any, info: CameraInfo) -> None:
        """Turn one depth image into ``points`` (while it is wanted)."""
        if self.skip_unwanted(self.pub_points.wanted):
            return
        read = self.read_depth(depth_msg, 'image_rect')
        if read is None:
            return
        depth = read[0]
        camera = self.camera(info, 'camera_info', depth.shape)
        if camera is None:
            return
        depth = fill_unknown(depth, self.params.values['invalid_depth'])
        self.pub_points.publish(build_pointcloud(depth_to_points(depth, camera),
                                                 depth_msg.header))
