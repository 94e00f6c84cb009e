"""`depth-nodes generate`: write synthetic stereo bags with exact ground truth.

Topics (all frames share one stamp per frame; the bag timestamp is that stamp):

==============================  ===========================  ==============================
topic                           type                         content
==============================  ===========================  ==============================
/stereo/left/image_raw          sensor_msgs/Image            distorted, rotated, noisy
/stereo/left/camera_info        sensor_msgs/CameraInfo       K, D, R, P of the left camera
/stereo/right/image_raw         sensor_msgs/Image            as left, with gain/offset
/stereo/right/camera_info       sensor_msgs/CameraInfo       right P[0,3] = -f * baseline
/stereo/left/image_rect_gt      sensor_msgs/Image            noise-free rectified render
/stereo/right/image_rect_gt     sensor_msgs/Image            noise-free rectified render
/stereo/left/disparity_gt       stereo_msgs/DisparityImage   exact disparity, left rect.
/stereo/left/depth_gt           sensor_msgs/Image (32FC1)    exact Z in metres
/stereo/left/occlusion_gt       sensor_msgs/Image (mono8)    0 visible, 255 occluded in
                                                             the right view, 128 outside it
==============================  ===========================  ==============================
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from depth_nodes.errors import ConfigError
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image
from depth_nodes.sim import StereoFrame, StereoSimConfig, simulate_stereo, validate_config
from depth_nodes.tools.bags.simulated import Frame, SimulatedBag, stamped_header

NAMESPACE = '/stereo'

#: The committed bags: name -> simulator configuration.
PRESETS: dict[str, StereoSimConfig] = {
    'stereo_vga': StereoSimConfig(
        width=640, height=480, n_frames=2, seed=11, distortion_model='plumb_bob'),
    'stereo_qvga_color': StereoSimConfig(
        width=320, height=240, n_frames=3, seed=12, distortion_model='rational_polynomial',
        colour=True),
    'stereo_qvga_fisheye': StereoSimConfig(
        width=320, height=240, n_frames=3, seed=13, distortion_model='equidistant',
        right_cx_offset=3.0),
}

#: The metadata key under which a bag stores the simulator configuration that made it.
CONFIG_KEY = 'depth_nodes.sim.stereo'


def frame_messages(frame: StereoFrame, namespace: str = NAMESPACE) -> list[tuple[str, Any]]:
    """The (topic, message) pairs of one simulated frame, in publishing order."""
    encoding = 'rgb8' if frame.left_raw.ndim == 3 else 'mono8'
    left, right = frame.left_camera, frame.right_camera
    left_h = stamped_header(frame.stamp_ns, left.frame_id)
    right_h = stamped_header(frame.stamp_ns, right.frame_id)
    focal = float(left.P[0, 0])
    baseline = float(left.P[0, 3] / left.P[0, 0] - right.P[0, 3] / right.P[0, 0])
    finite = frame.disparity_gt[np.isfinite(frame.disparity_gt)]
    d_min = float(np.floor(finite.min())) if finite.size else 0.0
    d_max = float(np.ceil(finite.max())) if finite.size else 0.0
    return [
        (f'{namespace}/left/image_raw', array_to_image(frame.left_raw, encoding, left_h)),
        (f'{namespace}/left/camera_info', model_to_camera_info(left, left_h)),
        (f'{namespace}/right/image_raw', array_to_image(frame.right_raw, encoding, right_h)),
        (f'{namespace}/right/camera_info', model_to_camera_info(right, right_h)),
        (f'{namespace}/left/image_rect_gt',
         array_to_image(frame.left_rect_gt, encoding, left_h)),
        (f'{namespace}/right/image_rect_gt',
         array_to_image(frame.right_rect_gt, encoding, right_h)),
        (f'{namespace}/left/disparity_gt', build_disparity(
            frame.disparity_gt.astype(np.float32), left_h, focal=focal, baseline=baseline,
            min_disparity=d_min, max_disparity=d_max, delta_d=0.0)),
        (f'{namespace}/left/depth_gt',
         array_to_image(frame.depth_gt.astype(np.float32), '32FC1', left_h)),
        (f'{namespace}/left/occlusion_gt', array_to_image(frame.occlusion_gt, 'mono8', left_h)),
    ]


BAG: SimulatedBag[StereoSimConfig] = SimulatedBag(
    CONFIG_KEY, 'a simulated stereo bag', 'depth-nodes generate --preset stereo_vga (or '
    'another stereo_*)', lambda doc: StereoSimConfig(**doc))


def write_stereo_bag(
    path: str | Path,
    config: StereoSimConfig,
    *,
    overwrite: bool = False,
    on_frame: Callable[[int], None] | None = None,
) -> int:
    """Simulate ``config`` and write the bag at ``path``; returns the number of messages.

    ``on_frame`` is called with each frame's index once it is written.

    Raises:
        SimConfigError: An invalid configuration (checked before anything is written).
        BagError: ``path`` exists and ``overwrite`` is False.
    """
    validate_config(config)
    return BAG.write(path, config, _frames(config, on_frame), overwrite=overwrite)


def _frames(config: StereoSimConfig, on_frame: Callable[[int], None] | None
            ) -> Iterator[Frame]:
    for frame in simulate_stereo(config):
        yield frame.stamp_ns, frame_messages(frame)
        if on_frame is not None:  # resumed for the next frame: this one is written
            on_frame(frame.index)


def config_from_metadata(custom_data: dict[str, str], path: str | Path) -> StereoSimConfig:
    """The simulator configuration a generated stereo bag (or one processed from it)
    records.

    Raises:
        BagError: No such metadata (not made by ``depth-nodes generate``), or it does not
            parse.
    """
    return BAG.config(custom_data, path)


def preset(name: str) -> StereoSimConfig:
    """Look up a preset by name.

    Raises:
        ConfigError: Unknown preset.
    """
    if name not in PRESETS:
        raise ConfigError(f'unknown preset {name!r} (presets: {", ".join(PRESETS)}, all)')
    return PRESETS[name]
