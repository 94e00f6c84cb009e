"""point_cloud_xyzrgb node: a depth image registered to a colour camera, plus that
camera's image -> coloured organised PointCloud2 (depth_image_proc's PointCloudXyzrgbNode,
same topics and parameters).

Subscribes ``depth_registered/image_rect`` (16UC1 mm or 32FC1 m; ``depth_image_transport``
raw or compressedDepth), ``rgb/image_rect_color`` (mono8/16, rgb8/16, bgr8/16, rgba, bgra,
Bayer or YUV; ``image_transport`` raw or compressed) and ``rgb/camera_info``; matched by
the ApproximateTime policy, or by exact stamps with ``exact_sync``. Publishes ``points``:
organised at the depth image's size, x, y, z at 0, 4, 8 and rgb (PCL's packed float) at
16, 32-byte points, in the depth image's frame and stamp.

The depth and colour images may differ in size (upstream drops such a frame, or crashed:
ros-perception/image_pipeline#1147): the cloud has one point per depth pixel, with the
CameraInfo's intrinsics scaled to the depth image and the colour of the colour pixel
whose area holds the depth pixel's centre.

Outputs are computed only while subscribed (lazy), or always offline.

Frames without output are counted and logged: ``unsupported_encoding``, the decoding
reasons, ``malformed_image`` (also a depth or colour image with no pixel),
``uncalibrated``, ``bad_calibration``, ``sync_*``.
"""

from __future__ import annotations

from typing import Any

from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from depth_nodes.core.depth_image import colour_at_depth_pixels, depth_to_points
from depth_nodes.errors import MessageError
from depth_nodes.nodes.depth_common import (
    INVALID_DEPTH,
    QUEUE_SIZE,
    DepthImageNode,
    depth_transport,
)
from depth_nodes.nodes.point_cloud import COLOR_ENCODINGS
from depth_nodes.nodes.point_cloud_xyz import fill_unknown
from depth_nodes.ros.image import to_rgb8
from depth_nodes.ros.params import IMAGE_TRANSPORT, NodeParameters, ParamSpec
from depth_nodes.ros.pointcloud import build_pointcloud
from depth_nodes.ros.transport import image_pixels

PARAMETERS = [
    IMAGE_TRANSPORT,
    depth_transport('depth_image_transport'),
    QUEUE_SIZE,
    ParamSpec('exact_sync', False, 'Match the three inputs by exact stamps instead of the '
              'ApproximateTime policy', read_only=True),
    INVALID_DEPTH,
]


class PointCloudXyzrgbNode(DepthImageNode):
    """Registered depth + colour image + camera_info -> coloured ``points``."""

    def __init__(self, node_name: str = 'point_cloud_xyzrgb', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS)
        values = self.params.values
        self.pub_points = self.add_output(PointCloud2, 'points')
        self.add_synced_inputs(
            [(Image, 'depth_registered/image_rect', values['depth_image_transport']),
             (Image, 'rgb/image_rect_color', values['image_transport']),
             (CameraInfo, 'rgb/camera_info')],
            self.on_frame, queue_size=values['queue_size'],
            approximate=not values['exact_sync'])

    def on_frame(self, depth_msg: Any, colour_msg: Any, info: CameraInfo) -> None:
        """Turn one matched set into ``points`` (while it is wanted)."""
        if self.skip_unwanted(self.pub_points.wanted):
            return
        read = self.read_depth(depth_msg, 'depth_registered/image_rect')
        if read is None:
            return
        depth = read[0]
        try:
            pixels, encoding = image_pixels(colour_msg)
        except MessageError as exc:
            self.decoding_failed(exc, 'rgb/image_rect_color')
            return
        if encoding not in COLOR_ENCODINGS:
            self.drop('unsupported_encoding', f'rgb/image_rect_color encoding {encoding!r} '
                      f'is not one of {", ".join(COLOR_ENCODINGS)}')
            return
        if not self.has_pixels(pixels, 'rgb/image_rect_color'):
            return
        camera = self.camera(info, 'rgb/camera_info', depth.shape)
        if camera is None:
            return
        rgb = colour_at_depth_pixels(to_rgb8(pixels, encoding), depth.shape)
        depth = fill_unknown(depth, self.params.values['invalid_depth'])
        self.pub_points.publish(build_pointcloud(depth_to_points(depth, camera),
                                                 depth_msg.header, rgb=rgb))
