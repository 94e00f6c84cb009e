"""depth_disparity node: a depth image -> stereo_msgs/DisparityImage (depth_image_proc's
DisparityNode, same topics and parameters), for nodes that take disparity.

Subscribes ``left/image_rect`` (16UC1 mm or 32FC1 m; ``image_transport`` raw or
compressedDepth) and ``right/camera_info``, whose ``P`` gives the focal length and the
baseline (``P[0, 3] = -fx * B``), matched by exact stamp. Publishes ``left/disparity``:
``f * B / Z`` per pixel, with ``min_disparity = f B / max_range`` and ``max_disparity =
f B / min_range`` (a ``min_range`` of 0 is taken as 1 mm, the nearest depth 16UC1 holds:
the message needs finite bounds), ``delta_d`` as set; a pixel without depth, or outside
[``min_range``, ``max_range``], is invalid (stored below ``min_disparity``, see
docs/design.md).

The executable is ``depth_disparity_node``: ``disparity_node`` is stereo_image_proc's
matcher here (the two upstream packages use the same name).

Outputs are computed only while subscribed (lazy), or always offline.

Frames without output are counted and logged: ``unsupported_encoding``, the decoding
reasons (``malformed_image``: also a depth image with no pixel), ``uncalibrated``,
``bad_calibration`` (also a right camera_info without a baseline, or whose ``f * B`` is
not a finite positive number), ``sync_*``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from sensor_msgs.msg import CameraInfo, Image
from stereo_msgs.msg import DisparityImage

from depth_nodes.core.depth_image import depth_to_disparity
from depth_nodes.nodes.depth_common import QUEUE_SIZE, DepthImageNode, depth_transport
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.params import NodeParameters, ParamSpec

#: The nearest depth taken when ``min_range`` is 0, metres (16UC1's smallest).
NEAREST_DEPTH = 0.001
#: The disparities the message can hold: positive normal float32.
FLOAT32_RANGE = (float(np.finfo(np.float32).tiny), float(np.finfo(np.float32).max))


def _positive_or_inf(value: float) -> str | None:
    return None if value > 0 else 'must be > 0 (.inf: no limit)'


PARAMETERS = [
    depth_transport('image_transport'),
    QUEUE_SIZE,
    ParamSpec('delta_d', 0.125, 'Smallest disparity increment the message states, px',
              1e-6, 1e3),
    ParamSpec('min_range', 0.0, 'Nearest depth with a valid disparity, metres', 0.0, 1e6),
    ParamSpec('max_range', math.inf, 'Farthest depth with a valid disparity, metres '
              '(.inf: no limit)', check=_positive_or_inf),
]


def _check_values(values: Mapping[str, Any]) -> str | None:
    if values['max_range'] <= values['min_range']:
        return (f'max_range ({values["max_range"]:g}) must be greater than min_range '
                f'({values["min_range"]:g})')
    return None


class DepthDisparityNode(DepthImageNode):
    """``left/image_rect`` (depth) + ``right/camera_info`` -> ``left/disparity``."""

    def __init__(self, node_name: str = 'depth_disparity', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS, check_values=_check_values)
        values = self.params.values
        self.pub_disparity = self.add_output(DisparityImage, 'left/disparity')
        self.add_synced_inputs(
            [(Image, 'left/image_rect', values['image_transport']),
             (CameraInfo, 'right/camera_info')], self.on_frame,
            queue_size=values['queue_size'])

    def on_frame(self, depth_msg: Any, right_info: CameraInfo) -> None:
        """Turn one depth image into ``left/disparity`` (while it is wanted)."""
        if self.skip_unwanted(self.pub_disparity.wanted):
            return
        read = self.read_depth(depth_msg, 'left/image_rect')
        if read is None:
            return
        depth = read[0]
        camera = self.camera(right_info, 'right/camera_info', depth.shape)
        if camera is None:
            return
        # P of the model: an all-zero P is [K | 0] (no baseline), its fx checked positive
        model = self.camera_model(right_info, 'right/camera_info')
        focal, baseline = camera.fx, -model.Tx / model.fx
        if not baseline > 0:
            self.drop('bad_calibration', f'right/camera_info has no baseline: P[0, 3] is '
                      f'{model.Tx:g}, a right camera\'s is -fx * B < 0')
            return
        values = self.params.values
        nearest = max(values['min_range'], NEAREST_DEPTH)
        if not FLOAT32_RANGE[0] <= focal * baseline / nearest <= FLOAT32_RANGE[1]:
            self.drop('bad_calibration', f'right/camera_info gives f * B = {focal:g} px * '
                      f'{baseline:g} m, whose disparities are not finite positive float32')
            return
        with np.errstate(invalid='ignore'):
            depth = np.where((depth >= nearest) & (depth <= values['max_range']), depth,
                             np.nan)
        self.pub_disparity.publish(build_disparity(
            depth_to_disparity(depth, focal=focal, baseline=baseline), depth_msg.header,
            focal=focal, baseline=baseline,
            min_disparity=focal * baseline / values['max_range'],
            max_disparity=focal * baseline / nearest, delta_d=values['delta_d']))
