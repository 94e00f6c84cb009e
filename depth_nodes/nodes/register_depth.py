"""register_depth node: a depth image moved into another camera, usually the colour camera
beside it (depth_image_proc's RegisterNode, same topics and parameters).

Subscribes ``depth/image_rect`` (16UC1 mm or 32FC1 m; ``depth_image_transport`` raw or
compressedDepth), ``depth/camera_info`` and ``rgb/camera_info``, matched by the
ApproximateTime policy. Publishes, with the depth image's stamp and the colour camera's
frame: ``depth_registered/image_rect`` (Z in the colour camera, at the colour
CameraInfo's size, in the input's encoding; nearest surface wins where several land on
one pixel; unknown where nothing landed) and ``depth_registered/camera_info`` (the colour
CameraInfo with that header).

Where the depth camera sits: ``depth_in_rgb`` (x y z qx qy qz qw: the depth optical
frame's pose in the colour optical frame, what ``tf2_echo rgb_frame depth_frame``
prints), or, left empty, the transform between the two images' frame ids from ``/tf``
and ``/tf_static`` (the latest of each edge: fixed extrinsics). tf2_msgs comes with every
ROS 2 install but not with the PyPI wheels: without it ``depth_in_rgb`` must be given.

Outputs are computed only while subscribed (lazy), or always offline: the depth is
registered only while ``depth_registered/image_rect`` is wanted.

Frames without output are counted and logged: ``no_transform`` (the two frames not
connected by the transforms received), ``unsupported_encoding``, the decoding reasons
(``malformed_image``: also a depth image with no pixel), ``uncalibrated``,
``bad_calibration`` (also a colour camera of more than 16 Mpx, the output's size),
``sync_*``.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.core.depth_image import from_metres, register_depth
from depth_nodes.core.transforms import TransformTree, rotation_matrix
from depth_nodes.errors import ArgumentError, ConfigError
from depth_nodes.nodes.depth_common import QUEUE_SIZE, DepthImageNode, depth_transport
from depth_nodes.ros.image import array_to_image
from depth_nodes.ros.params import NodeParameters, ParamSpec

try:  # every ROS 2 install has tf2_msgs, the PyPI wheels do not: depth_in_rgb is then needed
    from tf2_msgs.msg import TFMessage
except ImportError:
    TFMessage = None


def _check_pose(value: list[float]) -> str | None:
    if len(value) == 0:
        return None
    if len(value) != 7:
        return f'needs 7 values (x y z qx qy qz qw) or none, got {len(value)}'
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        return 'needs numbers'
    try:
        rotation_matrix(tuple(value[3:]))  # type: ignore[arg-type]
    except ArgumentError as exc:
        return str(exc)
    if not np.isfinite(value[:3]).all():
        return 'the translation must be finite'
    return None


PARAMETERS = [
    depth_transport('depth_image_transport'),
    QUEUE_SIZE,
    ParamSpec('depth_in_rgb', [0.0] * 0, 'Pose of the depth optical frame in the colour '
              'optical frame: x y z (m) qx qy qz qw; empty: from /tf and /tf_static '
              '(start-up only)', read_only=True, check=_check_pose, dynamic_typing=True),
]

#: /tf_static's QoS (tf2_ros's static broadcaster: latched).
TF_STATIC_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)


class RegisterNode(DepthImageNode):
    """Depth image + both CameraInfos -> depth in the colour camera."""

    def __init__(self, node_name: str = 'register_depth', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS)
        values = self.params.values
        self.tree = TransformTree()
        if not list(values['depth_in_rgb']):
            if TFMessage is None:
                raise ConfigError('register_depth: set depth_in_rgb (x y z qx qy qz qw), or run on '
                                  'a ROS 2 install, whose tf2_msgs lets it read /tf and '
                                  '/tf_static (the PyPI wheels have none)')
            self.add_input(TFMessage, '/tf_static', self.on_transforms, qos=TF_STATIC_QOS,
                           check_stamps=False)
            self.add_input(TFMessage, '/tf', self.on_transforms, qos=100, check_stamps=False)
        self.pub_depth = self.add_output(Image, 'depth_registered/image_rect')
        self.pub_info = self.add_output(CameraInfo, 'depth_registered/camera_info')
        self.add_synced_inputs(
            [(Image, 'depth/image_rect', values['depth_image_transport']),
             (CameraInfo, 'depth/camera_info'), (CameraInfo, 'rgb/camera_info')],
            self.on_frame, queue_size=values['queue_size'], approximate=True)

    def on_transforms(self, msg: Any) -> None:
        """Keep the transforms of a tf2_msgs/TFMessage (a bad one is logged and skipped)."""
        for tf in msg.transforms:
            t, q = tf.transform.translation, tf.transform.rotation
            try:
                self.tree.set(tf.header.frame_id, tf.child_frame_id, (t.x, t.y, t.z),
                              (q.x, q.y, q.z, q.w))
            except ArgumentError as exc:
                self.get_logger().warning(f'transform {tf.header.frame_id!r} -> '
                                          f'{tf.child_frame_id!r} skipped: {exc}',
                                          throttle_duration_sec=5.0)

    def _extrinsics(self, depth_frame: str, rgb_frame: str) -> Any:
        pose = list(self.params.values['depth_in_rgb'])
        if pose:
            return rotation_matrix(tuple(pose[3:])), np.asarray(pose[:3], dtype=np.float64)
        found = self.tree.lookup(rgb_frame, depth_frame)
        if found is None:
            self.drop('no_transform', f'no transform from {depth_frame!r} to {rgb_frame!r} '
                      'on /tf or /tf_static yet (or set depth_in_rgb)')
        return found

    def on_frame(self, depth_msg: Any, depth_info: CameraInfo, rgb_info: CameraInfo) -> None:
        """Register one depth image into the colour camera (for the outputs wanted)."""
        want_depth, want_info = self.pub_depth.wanted, self.pub_info.wanted
        if self.skip_unwanted(want_depth, want_info):
            return
        read = self.read_depth(depth_msg, 'depth/image_rect')
        if read is None:
            return
        depth, encoding = read
        source = self.camera(depth_info, 'depth/camera_info', depth.shape)
        target = self.camera(rgb_info, 'rgb/camera_info')
        if source is None or target is None:
            return
        extrinsics = self._extrinsics(depth_msg.header.frame_id, rgb_info.header.frame_id)
        if extrinsics is None:
            return
        header = copy.deepcopy(depth_msg.header)
        header.frame_id = rgb_info.header.frame_id
        if want_depth:
            registered = register_depth(depth, source, target, *extrinsics)
            self.pub_depth.publish(array_to_image(from_metres(registered, encoding), encoding,
                                                  header))
        if want_info:
            info = copy.deepcopy(rgb_info)
            info.header = header
            self.pub_info.publish(info)
