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

from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.core.depth_image import from_metres, register_depth
from depth_nodes.core.geometry import Motion, Pose, PoseMiss
from depth_nodes.errors import ArgumentError, ConfigError
from depth_nodes.nodes.depth_common import QUEUE_SIZE, DepthImageNode, depth_transport
from depth_nodes.ros.image import array_to_image
from depth_nodes.ros.params import NodeParameters, ParamSpec


def _check_pose(value: list[float]) -> str | None:
    if len(value) == 0:
        return None
    try:
        Pose.from_values(value)
    except ArgumentError as exc:
        return str(exc)
    return None


PARAMETERS = [
    depth_transport('depth_image_transport'),
    QUEUE_SIZE,
    ParamSpec('depth_in_rgb', [0.0] * 0, 'Pose of the depth optical frame in the colour '
              'optical frame: x y z (m) qx qy qz qw; empty: from /tf and /tf_static '
              '(start-up only)', read_only=True, check=_check_pose, dynamic_typing=True),
]

class RegisterNode(DepthImageNode):
    """Depth image + both CameraInfos -> depth in the colour camera."""

    def __init__(self, node_name: str = 'register_depth', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS)
        values = self.params.values
        self.fixed: Motion | None = None
        self.tf = None
        if list(values['depth_in_rgb']):
            pose = Pose.from_values(values['depth_in_rgb'])
            self.fixed = (pose.rotation, pose.position)
        else:
            try:
                self.tf = self.add_tf_input()
            except ConfigError:
                raise ConfigError('register_depth: set depth_in_rgb (x y z qx qy qz qw), or '
                                  'run on a ROS 2 install, whose tf2_msgs lets it read /tf and '
                                  '/tf_static (the PyPI wheels have none)') from None
        self.pub_depth = self.add_output(Image, 'depth_registered/image_rect')
        self.pub_info = self.add_output(CameraInfo, 'depth_registered/camera_info')
        self.add_synced_inputs(
            [(Image, 'depth/image_rect', values['depth_image_transport']),
             (CameraInfo, 'depth/camera_info'), (CameraInfo, 'rgb/camera_info')],
            self.on_frame, queue_size=values['queue_size'], approximate=True)

    def _extrinsics(self, depth_frame: str, rgb_frame: str) -> Motion | None:
        if self.fixed is not None:
            return self.fixed
        assert self.tf is not None
        found = self.tf.lookup(rgb_frame, depth_frame)  # the latest of each edge
        if isinstance(found, PoseMiss):
            self.drop('no_transform', f'no transform from {depth_frame!r} to {rgb_frame!r} '
                      f'on /tf or /tf_static yet ({found.detail}; or set depth_in_rgb)')
            return None
        return found.rotation, found.position

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
            registered = register_depth(depth, source, target, extrinsics)
            self.pub_depth.publish(array_to_image(from_metres(registered, encoding), encoding,
                                                  header))
        if want_info:
            info = copy.deepcopy(rgb_info)
            info.header = header
            self.pub_info.publish(info)
