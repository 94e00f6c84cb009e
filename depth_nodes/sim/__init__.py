"""Synthetic scenes with exact ground truth, rendered as camera images.

No ROS imports here: plain numpy and OpenCV. The public entry point of the stereo simulator
is :func:`simulate_stereo`, configured by :class:`StereoSimConfig`, yielding
:class:`StereoFrame` objects.
"""

from depth_nodes.sim.rig import distort_rays, make_rig, rect_to_raw, undistort_pixels
from depth_nodes.sim.stereo import (
    OCCLUSION_OCCLUDED,
    OCCLUSION_OUTSIDE,
    OCCLUSION_VISIBLE,
    SimConfigError,
    StereoFrame,
    StereoSimConfig,
    left_label_map,
    scene_for_frame,
    simulate_stereo,
    stereo_rig,
    validate_config,
)

__all__ = [
    'OCCLUSION_OCCLUDED',
    'OCCLUSION_OUTSIDE',
    'OCCLUSION_VISIBLE',
    'SimConfigError',
    'StereoFrame',
    'StereoSimConfig',
    'distort_rays',
    'left_label_map',
    'make_rig',
    'rect_to_raw',
    'scene_for_frame',
    'simulate_stereo',
    'stereo_rig',
    'undistort_pixels',
    'validate_config',
]
