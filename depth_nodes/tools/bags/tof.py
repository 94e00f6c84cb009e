"""Time-of-flight bags: write them from the simulator (depth_nodes.sim.tof), read them back.

Topics (namespace ``/tof``; one stamp per frame; the bag timestamp equals the stamp):

===============================  ========================  ====================================
topic                            type                      content
===============================  ========================  ====================================
/tof/correlation/image_raw       sensor_msgs/Image 16UC1   the F x N correlation planes of a
                                                           frame stacked vertically (see
                                                           depth_nodes.nodes.tof)
/tof/camera_info                 sensor_msgs/CameraInfo    the raw camera (one plane's size)
/tof/depth_gt                    sensor_msgs/Image 32FC1   exact Z on the rectified grid
/tof/flags_gt                    sensor_msgs/Image mono8   1 saturated, 2 too little light
                                                           (noise-free signal)
/tof/mixed_near_gt,              sensor_msgs/Image 32FC1   Z of the nearest / farthest surface
/tof/mixed_far_gt                                          a mixed pixel sees; NaN elsewhere
/tof/corner_gt                   sensor_msgs/Image mono8   255: the walls near the concave
                                                           corner (multipath)
===============================  ========================  ====================================

The simulator configuration is stored in the bag's metadata (``custom_data``, key
:data:`CONFIG_KEY`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.image import array_to_image
from depth_nodes.sim.tof import ToFFrame, ToFSimConfig, simulate_tof
from depth_nodes.tools.bags.simulated import SimulatedBag, stamped_header

NAMESPACE = '/tof'
CONFIG_KEY = 'depth_nodes.sim.tof'

#: The committed bag.
PRESETS: dict[str, ToFSimConfig] = {'tof_vga': ToFSimConfig()}


def frame_messages(frame: ToFFrame) -> list[tuple[str, Any]]:
    """The (topic, message) pairs of one simulated frame."""
    h = stamped_header(frame.stamp_ns, frame.camera.frame_id)
    planes, height, width = frame.samples.shape
    stacked = np.ascontiguousarray(frame.samples.reshape(planes * height, width))
    return [
        (f'{NAMESPACE}/correlation/image_raw', array_to_image(stacked, '16UC1', h)),
        (f'{NAMESPACE}/camera_info', model_to_camera_info(frame.camera, h)),
        (f'{NAMESPACE}/depth_gt', array_to_image(frame.depth_gt, '32FC1', h)),
        (f'{NAMESPACE}/flags_gt', array_to_image(frame.flags_gt, 'mono8', h)),
        (f'{NAMESPACE}/mixed_near_gt', array_to_image(frame.mixed_gt[0], '32FC1', h)),
        (f'{NAMESPACE}/mixed_far_gt', array_to_image(frame.mixed_gt[1], '32FC1', h)),
        (f'{NAMESPACE}/corner_gt',
         array_to_image(np.where(frame.corner_gt, 255, 0).astype(np.uint8), 'mono8', h)),
    ]


def _parse(doc: dict[str, Any]) -> ToFSimConfig:
    for key in ('distortion', 'frequencies_mhz'):
        doc[key] = tuple(doc[key])
    return ToFSimConfig(**doc).validate()


BAG: SimulatedBag[ToFSimConfig] = SimulatedBag(
    CONFIG_KEY, 'a time-of-flight bag', 'depth-nodes generate --preset tof_vga, then '
    'process', _parse)


def write_tof_bag(path: str | Path, config: ToFSimConfig, *, overwrite: bool = False) -> int:
    """Simulate ``config`` and write the bag at ``path``; returns the number of messages.

    Raises:
        ConfigError: An invalid configuration.
        BagError: ``path`` exists and ``overwrite`` is False.
    """
    config.validate()
    frames = ((frame.stamp_ns, frame_messages(frame)) for frame in simulate_tof(config))
    return BAG.write(path, config, frames, overwrite=overwrite)


def config_from_metadata(custom_data: dict[str, str], path: str | Path) -> ToFSimConfig:
    """The simulator configuration a ToF bag (or a bag processed from one) records.

    Raises:
        BagError: No such metadata, or it does not parse.
    """
    return BAG.config(custom_data, path)


def read_topics(path: str | Path, topics: list[str]) -> tuple[ToFSimConfig,
                                                            dict[str, dict[int, Any]]]:
    """The simulator configuration of a ToF bag (or of a bag processed from one) and the
    messages, by stamp, of ``topics``.

    Raises:
        BagError: No bag, not a ToF bag, or a topic missing.
    """
    return BAG.read(path, topics)
