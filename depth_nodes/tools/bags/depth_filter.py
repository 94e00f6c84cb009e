"""Depth-camera bags for the depth filter: simulated sequences (depth_nodes.sim.depth_sequence)
written as a depth camera driver publishes them, with the truth beside, and read back.

Topics (namespace ``/camera``; one stamp per frame; the bag timestamp equals it):

=============================  ===========================  =================================
topic                          type                         content
=============================  ===========================  =================================
/camera/depth/image_rect_raw   sensor_msgs/Image 16UC1      measured Z, mm, 0 unknown
/camera/depth/camera_info      sensor_msgs/CameraInfo       its pinhole camera
/camera/odom                   nav_msgs/Odometry            the camera optical frame in
                                                            ``world``
/camera/depth_gt               sensor_msgs/Image 32FC1      exact Z, NaN where nothing is hit
/camera/labels_gt              sensor_msgs/Image mono8      bits (sim.depth_sequence.labels):
                                                            1 mixed pixel, 2 hole,
                                                            4 moving object, 8 a pixel that
                                                            sees two surfaces
=============================  ===========================  =================================

The simulator configuration is stored in the bag's metadata (``custom_data``, key
:data:`CONFIG_KEY`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from depth_nodes.core.depth_image import from_metres
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.image import array_to_image
from depth_nodes.sim.depth_sequence import (
    STRADDLING,
    DepthFrame,
    DepthSequenceConfig,
    labels,
    simulate_depth_sequence,
)
from depth_nodes.tools.bags.multiview import camera_model, odometry_message
from depth_nodes.tools.bags.simulated import SimulatedBag, stamped_header

NAMESPACE = '/camera'
FRAME_ID = 'camera_depth_optical_frame'
CONFIG_KEY = 'depth_nodes.sim.depth_sequence'
__all__ = ['BUNDLED', 'PRESETS', 'STRADDLING', 'config_from_metadata', 'frame_messages',
           'labels', 'read_topics', 'write_depth_bag']

#: The presets (320 x 240, 30 frames/s, 12 frames: 0.4 s), and three for volumetric fusion
#: (a TSDF's truth is the scene's surface: depth_nodes.sim.depth_sequence.scene_at):
#: depth_orbit: 20 frames at 640 x 480 around the scene, noise 0.0015 Z^2 (a 50 mm baseline,
#: 0.0384 px of disparity noise);
#: 2 x 2 rays a pixel, the 320 x 240 presets' 4 x 4 per degree), depth_object_leaves, and
#: depth_long, 10 s through a room (2 x 2 rays a pixel: 300 frames in a quarter of the
#: time).
PRESETS: dict[str, DepthSequenceConfig] = {
    'depth_static': DepthSequenceConfig(kind='static', n_frames=12),
    'depth_moving_camera': DepthSequenceConfig(kind='moving_camera', n_frames=12),
    'depth_moving_object': DepthSequenceConfig(kind='moving_object', n_frames=12),
    'depth_tof_static': DepthSequenceConfig(kind='static', n_frames=12, noise='tof',
                                            left_band=0.0),
    'depth_orbit': DepthSequenceConfig(kind='orbit', width=640, height=480, n_frames=20,
                                       orbit_deg=40.0, baseline_m=0.05, disparity_sigma=0.0384,
                                       supersample=2),
    'depth_object_leaves': DepthSequenceConfig(kind='object_leaves', n_frames=20),
    'depth_long': DepthSequenceConfig(kind='long', n_frames=300, step_m=0.02, supersample=2),
}
#: The preset committed in bags/.
BUNDLED = ('depth_moving_camera',)


def frame_messages(frame: DepthFrame) -> list[tuple[str, Any]]:
    """The (topic, message) pairs of one frame."""
    h = stamped_header(frame.stamp_ns, FRAME_ID)
    return [
        (f'{NAMESPACE}/depth/image_rect_raw',
         array_to_image(from_metres(frame.depth, '16UC1'), '16UC1', h)),
        (f'{NAMESPACE}/depth/camera_info',
         model_to_camera_info(camera_model(frame.camera, FRAME_ID), h)),
        (f'{NAMESPACE}/odom', odometry_message(frame.pose, frame.stamp_ns, FRAME_ID)),
        (f'{NAMESPACE}/depth_gt', array_to_image(frame.truth, '32FC1', h)),
        (f'{NAMESPACE}/labels_gt', array_to_image(labels(frame), 'mono8', h)),
    ]


BAG: SimulatedBag[DepthSequenceConfig] = SimulatedBag(
    CONFIG_KEY, 'a depth-filter bag', 'depth-nodes generate --preset depth_static (or '
    'another depth_*)', lambda doc: DepthSequenceConfig(**doc).validate())


def write_depth_bag(path: str | Path, config: DepthSequenceConfig, *,
                    overwrite: bool = False) -> int:
    """Simulate ``config`` and write the bag at ``path``; returns the number of messages.

    Raises:
        ConfigError: An invalid configuration.
        BagError: ``path`` exists and ``overwrite`` is False.
    """
    config.validate()
    frames = ((frame.stamp_ns, frame_messages(frame))
              for frame in simulate_depth_sequence(config))
    return BAG.write(path, config, frames, overwrite=overwrite)


def config_from_metadata(custom_data: dict[str, str], path: str | Path) -> DepthSequenceConfig:
    """The simulator configuration a depth bag (or a bag processed from one) records.

    Raises:
        BagError: No such metadata, or it does not parse.
    """
    return BAG.config(custom_data, path)


def read_topics(path: str | Path, topics: list[str], *, optional: tuple[str, ...] = ()
                ) -> tuple[DepthSequenceConfig, dict[str, dict[int, Any]]]:
    """The simulator configuration of a depth bag (or of a bag processed from one) and the
    messages, by stamp, of ``topics`` (those in ``optional`` may be missing).

    Raises:
        BagError: No bag, not a depth bag, or a topic missing.
    """
    return BAG.read(path, topics, optional=optional)
