"""Stereo bags for volumetric fusion: a rectified stereo pair that moves along a depth
sequence's camera path (:mod:`depth_nodes.sim.depth_sequence`, the ``orbit`` by default)
through its scene, rendered by the multi-view simulator's grey renderer
(:func:`~depth_nodes.sim.sequence.render_grey`), with the left camera's odometry and exact
depth, so the stereo graph runs on it (`depth-nodes process`), `depth-nodes eval` scores
its disparity, and a fusion of its depth is scored against the scene's exact surface.

Topics (namespace ``/stereo``; one stamp per frame; the bag timestamp equals it):

=========================  =============================  ====================================
topic                      type                           content
=========================  =============================  ====================================
/stereo/left/image_raw     sensor_msgs/Image mono8        the left image (rectified already)
/stereo/left/camera_info   sensor_msgs/CameraInfo         D zero, R identity, P = [K | 0]
/stereo/right/image_raw    sensor_msgs/Image mono8        the right image: the left camera
                                                          moved ``baseline_m`` along its x
/stereo/right/camera_info  sensor_msgs/CameraInfo         as the left, P[0, 3] = -fx B
/stereo/odom               nav_msgs/Odometry              the left optical frame in ``world``
/stereo/left/depth_gt      sensor_msgs/Image 32FC1        exact Z, NaN where nothing is hit
/stereo/left/disparity_gt  stereo_msgs/DisparityImage     exact f B / Z (what eval scores)
/stereo/left/occlusion_gt  sensor_msgs/Image mono8        0 seen by the right camera, 255
                                                          hidden from it, 128 outside its image
=========================  =============================  ====================================

The configuration (:class:`FusionStereoConfig`) is stored in the bag's metadata
(``custom_data``, key :data:`CONFIG_KEY`): the scene of frame ``i`` is
``scene_at(config.sequence, i)``, the left camera's pose ``pose_at(config.sequence, i)``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.errors import ConfigError
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image
from depth_nodes.sim import OCCLUSION_OCCLUDED, OCCLUSION_OUTSIDE, OCCLUSION_VISIBLE
from depth_nodes.sim.depth_sequence import DepthSequenceConfig, pose_at, scene_at, stamp_at
from depth_nodes.sim.scene import Scene
from depth_nodes.sim.sequence import SequenceConfig, render_depth, render_grey, visible_in
from depth_nodes.tools.bags.multiview import camera_model, odometry_message
from depth_nodes.tools.bags.simulated import Frame, SimulatedBag, stamped_header

__all__ = ['CONFIG_KEY', 'NAMESPACE', 'PRESETS', 'FusionStereoConfig', 'config_from_metadata',
           'frame_messages', 'right_pose', 'with_sequence', 'write_fusion_stereo_bag']

NAMESPACE = '/stereo'
CONFIG_KEY = 'depth_nodes.sim.fusion_stereo'
LEFT_FRAME = 'stereo_left_optical'
RIGHT_FRAME = 'stereo_right_optical'


@dataclass(frozen=True)
class FusionStereoConfig:
    """What a fusion stereo bag holds.

    Attributes:
        sequence: The depth sequence whose scene, camera path, image size, frames, stamps
            and seed the pair takes; its ``baseline_m`` is the pair's baseline (its depth
            noise, holes and supersampling play no part).
        noise_sigma: Gaussian image noise, grey levels.
        gain_jitter: Standard deviation of each image's exposure gain around 1.
        vignetting: Fractional brightness fall-off at the image corners.
        supersample: Anti-aliasing rays per pixel and axis.
    """

    sequence: DepthSequenceConfig = field(default_factory=lambda: DepthSequenceConfig(
        kind='orbit', baseline_m=0.12))
    noise_sigma: float = 2.0
    gain_jitter: float = 0.02
    vignetting: float = 0.15
    supersample: int = 2

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> FusionStereoConfig:
        """Inverse of :func:`dataclasses.asdict` (the bag metadata's JSON document),
        validated.

        Raises:
            ConfigError: Naming the invalid field.
            TypeError: An unknown field.
            KeyError: No ``sequence``.
        """
        doc = dict(doc)
        sequence = DepthSequenceConfig(**doc.pop('sequence'))
        return cls(sequence=sequence, **doc).validate()

    @property
    def renderer(self) -> SequenceConfig:
        """The grey renderer's settings (:func:`~depth_nodes.sim.sequence.render_grey`)."""
        seq = self.sequence
        return SequenceConfig(width=seq.width, height=seq.height, n_frames=seq.n_frames,
                              seed=seq.seed, focal_px=seq.camera.fx,
                              noise_sigma=self.noise_sigma, gain_jitter=self.gain_jitter,
                              vignetting=self.vignetting, supersample=self.supersample)

    def validate(self) -> FusionStereoConfig:
        """Raises ConfigError naming the first invalid field; returns self."""
        self.sequence.validate()
        try:
            self.renderer.validate()
        except ConfigError as exc:
            raise ConfigError(f'fusion stereo {str(exc).removeprefix("sequence ")}') from None
        return self


#: The presets (not committed in bags/): 40 degrees of the orbit, 640 x 480, 30 frames,
#: a 12 cm baseline.
PRESETS: dict[str, FusionStereoConfig] = {
    'stereo_orbit': FusionStereoConfig(DepthSequenceConfig(
        kind='orbit', width=640, height=480, n_frames=30, orbit_deg=40.0, baseline_m=0.12)),
}


def right_pose(config: FusionStereoConfig, left: Pose) -> Pose:
    """The right camera of the pair whose left camera is at ``left``."""
    return left.compose(Pose(np.eye(3), np.array([config.sequence.baseline_m, 0.0, 0.0])))


def frame_messages(config: FusionStereoConfig, index: int) -> list[tuple[str, Any]]:
    """Render frame ``index`` of ``config``: its (topic, message) pairs, in writing order.

    Raises:
        ConfigError: An invalid configuration.
        ArgumentError: ``index`` is not a frame of the sequence.
    """
    seq = config.validate().sequence
    camera = seq.camera
    scene = scene_at(seq, index)
    left = pose_at(seq, index)
    right = right_pose(config, left)
    stamp = stamp_at(seq, index)
    baseline = seq.baseline_m
    images = [render_grey(scene, camera, pose, config.renderer,
                          np.random.default_rng([seq.seed, index, side, 29]))
              for side, pose in enumerate((left, right))]
    depth = render_depth(scene, camera, left)
    with np.errstate(divide='ignore', invalid='ignore'):
        disparity = (camera.fx * baseline / depth).astype(np.float32)
    finite = disparity[np.isfinite(disparity)]
    out: list[tuple[str, Any]] = []
    for side, frame_id, image, tx in (('left', LEFT_FRAME, images[0], 0.0),
                                      ('right', RIGHT_FRAME, images[1],
                                       -camera.fx * baseline)):
        header = stamped_header(stamp, frame_id)
        out += [(f'{NAMESPACE}/{side}/image_raw', array_to_image(image, 'mono8', header)),
                (f'{NAMESPACE}/{side}/camera_info',
                 model_to_camera_info(camera_model(camera, frame_id, tx), header))]
    header = stamped_header(stamp, LEFT_FRAME)
    return [
        *out,
        (f'{NAMESPACE}/odom', odometry_message(left, stamp, LEFT_FRAME)),
        (f'{NAMESPACE}/left/depth_gt', array_to_image(depth, '32FC1', header)),
        (f'{NAMESPACE}/left/disparity_gt', build_disparity(
            disparity, header, focal=camera.fx, baseline=baseline,
            min_disparity=float(np.floor(finite.min())) if finite.size else 0.0,
            max_disparity=float(np.ceil(finite.max())) if finite.size else 0.0,
            delta_d=0.0)),
        (f'{NAMESPACE}/left/occlusion_gt', array_to_image(
            _occlusion(scene, camera, left, right, depth, disparity), 'mono8', header)),
    ]


def _occlusion(scene: Scene, camera: Intrinsics, left: Pose, right: Pose,
               depth: NDArray[np.float32], disparity: NDArray[np.float32]
               ) -> NDArray[np.uint8]:
    """Each left pixel: seen by the right camera, hidden from it, or outside its image (or
    on no surface)."""
    seen = visible_in(scene, depth, camera, left, camera, right)
    column = np.arange(camera.width, dtype=np.float32)[None, :]
    with np.errstate(invalid='ignore'):
        outside = ~np.isfinite(depth) | (column - disparity < -0.5)
    out = np.full(depth.shape, OCCLUSION_OCCLUDED, np.uint8)
    out[seen] = OCCLUSION_VISIBLE
    out[outside] = OCCLUSION_OUTSIDE
    return out


BAG: SimulatedBag[FusionStereoConfig] = SimulatedBag(
    CONFIG_KEY, 'a fusion stereo bag', 'depth-nodes generate --preset stereo_orbit',
    FusionStereoConfig.from_dict)


def write_fusion_stereo_bag(path: str | Path, config: FusionStereoConfig, *,
                            overwrite: bool = False) -> int:
    """Render ``config`` and write the bag at ``path``; returns the number of messages. A
    signal stops between frames.

    Raises:
        ConfigError: An invalid configuration (before anything is written).
        BagError: ``path`` exists and ``overwrite`` is False.
    """
    config.validate()
    return BAG.write(path, config, _frames(config), overwrite=overwrite)


def _frames(config: FusionStereoConfig) -> Iterator[Frame]:
    for index in range(config.sequence.n_frames):
        yield stamp_at(config.sequence, index), frame_messages(config, index)


def config_from_metadata(custom_data: dict[str, str], path: str | Path) -> FusionStereoConfig:
    """The configuration a fusion stereo bag (or a bag processed from one) records.

    Raises:
        BagError: No such metadata, or it does not parse.
    """
    return BAG.config(custom_data, path)


def with_sequence(config: FusionStereoConfig, **changes: Any) -> FusionStereoConfig:
    """``config`` with fields of its sequence replaced (``seed``, ``n_frames``, ``width``)."""
    return dataclasses.replace(config, sequence=dataclasses.replace(config.sequence, **changes))
