"""Simulated stereo rig: raw distorted images and rectified ground truth of a 3D scene.

The world frame is the left rectified camera frame (X right, Y down, Z forward, metres),
with the left camera centre at the origin and the right one at ``(baseline, 0, 0)``. The
rectified cameras share the focal length ``f`` and ``cy``; ``cx`` of the right one is
shifted by ``right_cx_offset``. Each raw camera has the same centre as its rectified one,
a small rotation ``R`` (``x_rect = R @ x_raw``), its own intrinsics ``K`` and lens
distortion ``D``: exactly what its :class:`CameraModel` (CameraInfo) states.

Raw pixels are rendered by undistorting each (super)sample position to a ray in the raw
camera, rotating it into the world and ray casting the scene, so raw images are exact, not
resampled from a rectified image. Rectified ground-truth renders cast ``K_rect^-1 (u, v, 1)``
rays directly. Image formation: linear radiance -> supersample mean -> luminance (mono) ->
x vignetting (evaluated at the raw pixel) -> x 255 -> x gain + offset (right camera) ->
+ Gaussian noise (raw images only) -> round and clip to uint8.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import EQUIDISTANT, PLUMB_BOB, RATIONAL_POLYNOMIAL, CameraModel
from depth_nodes.core.stamps import NS_PER_S
from depth_nodes.errors import ConfigError
from depth_nodes.sim.layout import build_scene
from depth_nodes.sim.rig import make_rig, rect_to_raw, undistort_pixels
from depth_nodes.sim.scene import Scene

FloatArray = NDArray[np.float64]

DISTORTION_MODELS = (PLUMB_BOB, RATIONAL_POLYNOMIAL, EQUIDISTANT)
OCCLUSION_VISIBLE = 0
OCCLUSION_OUTSIDE = 128
OCCLUSION_OCCLUDED = 255
#: A surface nearer than (1 - this) x the distance to the point occludes it.
OCCLUSION_RTOL = 1e-6
_LUMA = np.array([0.299, 0.587, 0.114])


class SimConfigError(ConfigError, ValueError):
    """An invalid :class:`StereoSimConfig` field (also a ValueError)."""


@dataclass(frozen=True)
class StereoSimConfig:
    """Parameters of :func:`simulate_stereo`; see the module docstring for the model.

    Attributes:
        width: Image width in pixels (>= 16).
        height: Image height in pixels (>= 16).
        n_frames: Number of frames (>= 1).
        seed: Seed of the scene, the rig and the noise (>= 0).
        focal_px: Rectified focal length in pixels; ``None`` means ``0.8 * width``.
        baseline_m: Distance between the camera centres in metres.
        right_cx_offset: ``cx_right - cx_left`` of the rectified cameras in pixels.
        distortion_model: ``plumb_bob``, ``rational_polynomial`` or ``equidistant``.
        rotation_deg: Typical angle of each camera's raw -> rectified rotation (0..10).
        distortion_scale: Factor on the random distortion coefficients (0..2); 0 gives
            pinhole cameras whose only flaw is the rotation.
        colour: rgb8 images when True, mono8 when False.
        frame_rate_hz: Frame rate that spaces the time stamps.
        noise_sigma: Standard deviation of the Gaussian noise of raw images, grey levels.
        right_gain: Gain of the right camera relative to the left.
        right_offset: Offset of the right camera in grey levels.
        vignetting: Fractional brightness fall-off at the raw image corner (0 <= v < 1).
        supersample: Anti-aliasing samples per pixel and axis of the image renders.
        start_stamp_ns: Time stamp of frame 0 in nanoseconds.
    """

    width: int = 640
    height: int = 480
    n_frames: int = 3
    seed: int = 0
    focal_px: float | None = None
    baseline_m: float = 0.12
    right_cx_offset: float = 0.0
    distortion_model: str = PLUMB_BOB
    rotation_deg: float = 1.0
    distortion_scale: float = 1.0
    colour: bool = False
    frame_rate_hz: float = 10.0
    noise_sigma: float = 2.0
    right_gain: float = 1.08
    right_offset: float = -6.0
    vignetting: float = 0.25
    supersample: int = 2
    start_stamp_ns: int = 1_700_000_000_000_000_000

    @property
    def focal(self) -> float:
        """The rectified focal length in pixels (``focal_px`` or its default)."""
        return 0.8 * self.width if self.focal_px is None else float(self.focal_px)


@dataclass
class StereoFrame:
    """One simulated stereo frame with exact ground truth in the left rectified view.

    Attributes:
        index: Frame number, from 0.
        stamp_ns: Time stamp in nanoseconds.
        left_raw: (H, W) uint8, or (H, W, 3) uint8 RGB when colour: distorted, noisy.
        right_raw: Same for the right camera (with its gain and offset).
        left_rect_gt: Noise-free rectified render, same photometry as ``left_raw``.
        right_rect_gt: Same for the right camera.
        disparity_gt: (H, W) float32 ``x_left - x_right`` (includes the cx offset).
        depth_gt: (H, W) float32 Z in metres in the left rectified frame.
        occlusion_gt: (H, W) uint8: 0 visible in both views, 255 occluded in the right
            view, 128 projects outside the right image (128 wins over 255).
        left_camera: Calibration of the left camera (as its CameraInfo states it).
        right_camera: Calibration of the right camera.
    """

    index: int
    stamp_ns: int
    left_raw: NDArray[np.uint8]
    right_raw: NDArray[np.uint8]
    left_rect_gt: NDArray[np.uint8]
    right_rect_gt: NDArray[np.uint8]
    disparity_gt: NDArray[np.float32]
    depth_gt: NDArray[np.float32]
    occlusion_gt: NDArray[np.uint8]
    left_camera: CameraModel
    right_camera: CameraModel


def validate_config(config: StereoSimConfig) -> None:
    """Raise :class:`SimConfigError` (a ValueError) naming the first invalid field."""

    def bad(name: str, why: str) -> SimConfigError:
        return SimConfigError(f'StereoSimConfig.{name} {why}, got {getattr(config, name)!r}')

    for name in ('width', 'height', 'n_frames', 'seed', 'supersample', 'start_stamp_ns'):
        if not isinstance(getattr(config, name), int | np.integer):
            raise bad(name, 'must be an integer')
    for f in fields(config):
        value = getattr(config, f.name)
        if isinstance(value, float) and not math.isfinite(value):
            raise bad(f.name, 'must be finite')
    checks = (
        ('width', config.width >= 16, 'must be >= 16'),
        ('height', config.height >= 16, 'must be >= 16'),
        ('n_frames', config.n_frames >= 1, 'must be >= 1'),
        ('seed', config.seed >= 0, 'must be >= 0'),
        ('focal_px', config.focal_px is None or config.focal_px > 0, 'must be positive'),
        ('baseline_m', config.baseline_m > 0, 'must be positive'),
        (
            'right_cx_offset',
            abs(config.right_cx_offset) <= config.width / 4,
            'must be within +-width/4',
        ),
        (
            'distortion_model',
            config.distortion_model in DISTORTION_MODELS,
            f'must be one of {DISTORTION_MODELS}',
        ),
        ('rotation_deg', 0 <= config.rotation_deg <= 10, 'must be in [0, 10]'),
        ('distortion_scale', 0 <= config.distortion_scale <= 2, 'must be in [0, 2]'),
        ('frame_rate_hz', config.frame_rate_hz > 0, 'must be positive'),
        ('noise_sigma', config.noise_sigma >= 0, 'must be >= 0'),
        ('right_gain', config.right_gain > 0, 'must be positive'),
        ('vignetting', 0 <= config.vignetting < 1, 'must be in [0, 1)'),
        ('supersample', 1 <= config.supersample <= 8, 'must be in [1, 8]'),
        ('start_stamp_ns', config.start_stamp_ns >= 0, 'must be >= 0'),
    )
    for name, ok, why in checks:
        if not ok:
            raise bad(name, why)


def stereo_rig(config: StereoSimConfig) -> tuple[CameraModel, CameraModel]:
    """The (left, right) cameras of ``config``; see :func:`depth_nodes.sim.rig.make_rig`."""
    validate_config(config)
    return make_rig(width=config.width, height=config.height, focal_px=config.focal,
                    baseline_m=config.baseline_m, right_cx_offset=config.right_cx_offset,
                    distortion_model=config.distortion_model,
                    rotation_deg=config.rotation_deg, seed=config.seed,
                    distortion_scale=config.distortion_scale)


# ------------------------------------------------------------------ rendering


def _sample_grid(width: int, height: int, supersample: int) -> FloatArray:
    """(H*W*s*s, 2) sample positions ordered (v, u, sub_v, sub_u); centres are integers."""
    offs = (np.arange(supersample) + 0.5) / supersample - 0.5
    v = np.arange(height)[:, None, None, None] + offs[None, None, :, None]
    u = np.arange(width)[None, :, None, None] + offs[None, None, None, :]
    v, u = np.broadcast_arrays(v, u)
    return np.column_stack([u.ravel(), v.ravel()]).astype(np.float64)


def _vignetting(camera: CameraModel, raw_px: FloatArray, strength: float) -> FloatArray:
    """Brightness factor 1 - strength * (r / r_corner)^2 at raw pixel positions (N, 2)."""
    centre = camera.K[:2, 2]
    corners = np.array(
        [
            [0.0, 0.0],
            [camera.width - 1.0, 0.0],
            [0.0, camera.height - 1.0],
            [camera.width - 1.0, camera.height - 1.0],
        ]
    )
    r_corner2 = ((corners - centre) ** 2).sum(axis=1).max()
    factor: FloatArray = 1.0 - strength * ((raw_px - centre) ** 2).sum(axis=1) / r_corner2
    return factor


@dataclass
class _View:
    """Everything about one rendered view that does not change between frames."""

    origin: FloatArray
    dirs: FloatArray  # (H*W*s*s, 3) world ray directions
    vignette: FloatArray  # (H, W)
    gain: float
    offset: float


def _views(config: StereoSimConfig, cams: tuple[CameraModel, CameraModel]) -> list[_View]:
    """The raw and rectified views of both cameras: [left_raw, right_raw, left_rect, right_rect]."""
    w, h, s = config.width, config.height, config.supersample
    samples = _sample_grid(w, h, s)
    centres = _sample_grid(w, h, 1)
    raw, rect = [], []
    for cam, origin, (gain, offset) in zip(
        cams,
        (np.zeros(3), np.array([config.baseline_m, 0.0, 0.0])),
        ((1.0, 0.0), (config.right_gain, config.right_offset)),
        strict=True,
    ):
        dirs = undistort_pixels(cam, samples) @ cam.R.T
        vig = _vignetting(cam, centres, config.vignetting).reshape(h, w)
        raw.append(_View(origin, dirs, vig, gain, offset))
        k_inv = np.linalg.inv(cam.P[:, :3])
        rect_dirs = np.column_stack([samples, np.ones(len(samples))]) @ k_inv.T
        vig = _vignetting(cam, rect_to_raw(cam, centres), config.vignetting).reshape(h, w)
        rect.append(_View(origin, rect_dirs, vig, gain, offset))
    return raw + rect


def _render(
    scene: Scene, view: _View, config: StereoSimConfig, noise_rng: np.random.Generator | None
) -> NDArray[np.uint8]:
    """Render one view to uint8 (mono or RGB), with noise if ``noise_rng`` is given."""
    h, w, s = config.height, config.width, config.supersample
    rgb = scene.radiance(view.origin, view.dirs).reshape(h, w, s * s, 3).mean(axis=2)
    img = rgb if config.colour else rgb @ _LUMA
    scale = 255.0 * view.vignette * view.gain
    img = img * (scale[:, :, None] if config.colour else scale) + view.offset
    if noise_rng is not None and config.noise_sigma > 0:
        img = img + noise_rng.normal(0.0, config.noise_sigma, img.shape)
    out: NDArray[np.uint8] = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return out


def _ground_truth(
    scene: Scene, config: StereoSimConfig, right: CameraModel
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.uint8]]:
    """Disparity, depth and occlusion at the left rectified pixel centres."""
    h, w, f, baseline = config.height, config.width, config.focal, config.baseline_m
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    px = _sample_grid(w, h, 1)
    dirs = np.column_stack([(px[:, 0] - cx) / f, (px[:, 1] - cy) / f, np.ones(len(px))])
    depth, _ = scene.cast(np.zeros(3), dirs)  # d_z = 1, so t is Z
    hit = np.isfinite(depth)
    points = dirs * depth[:, None]
    u_right = (
        right.P[0, 0] * points[:, 0] + right.P[0, 2] * points[:, 2] + right.P[0, 3]
    ) / points[:, 2]
    disparity = np.where(hit, px[:, 0] - u_right, np.nan)
    occlusion = np.zeros(len(px), dtype=np.uint8)
    centre = np.array([baseline, 0.0, 0.0])
    t_occ, _ = scene.cast(centre, np.where(hit[:, None], points - centre, 1.0))
    occlusion[hit & (t_occ < 1.0 - OCCLUSION_RTOL)] = OCCLUSION_OCCLUDED
    outside = hit & ((u_right < -0.5) | (u_right >= w - 0.5))
    occlusion[outside] = OCCLUSION_OUTSIDE
    return (
        disparity.reshape(h, w).astype(np.float32),
        np.where(hit, depth, np.nan).reshape(h, w).astype(np.float32),
        occlusion.reshape(h, w),
    )


def scene_for_frame(config: StereoSimConfig, index: int) -> Scene:
    """The scene of frame ``index`` of ``config`` (for tests and label maps)."""
    return build_scene(config.seed, index, config.focal, config.width, config.height)


def left_label_map(config: StereoSimConfig, index: int = 0) -> tuple[NDArray[np.int32], list[str]]:
    """Which primitive each left rectified pixel centre sees.

    Returns:
        (H, W) int32 primitive indices (-1 where nothing is hit) and the label of each
        primitive index (``'pole'``, ``'weak'``, ``'repetitive'``...).
    """
    validate_config(config)
    scene = scene_for_frame(config, index)
    w, h, f = config.width, config.height, config.focal
    px = _sample_grid(w, h, 1)
    dirs = np.column_stack(
        [(px[:, 0] - (w - 1) / 2) / f, (px[:, 1] - (h - 1) / 2) / f, np.ones(len(px))]
    )
    _, idx = scene.cast(np.zeros(3), dirs)
    return idx.reshape(h, w), scene.labels


def simulate_stereo(config: StereoSimConfig) -> Iterator[StereoFrame]:
    """Render ``config.n_frames`` stereo frames of a moving scene with exact ground truth.

    Args:
        config: Simulation parameters; validated on entry.

    Yields:
        One :class:`StereoFrame` per frame, in order. Same config -> identical frames.

    Raises:
        SimConfigError: (a ValueError) naming the invalid config field.
    """
    validate_config(config)
    return _simulate(config)


def _simulate(config: StereoSimConfig) -> Iterator[StereoFrame]:
    left, right = stereo_rig(config)
    views = _views(config, (left, right))
    for index in range(config.n_frames):
        scene = scene_for_frame(config, index)
        rng = np.random.default_rng([config.seed, index, 11])
        images = [_render(scene, v, config, rng if k < 2 else None) for k, v in enumerate(views)]
        disparity, depth, occlusion = _ground_truth(scene, config, right)
        stamp = config.start_stamp_ns + round(index * NS_PER_S / config.frame_rate_hz)
        yield StereoFrame(
            index,
            stamp,
            images[0],
            images[1],
            images[2],
            images[3],
            disparity,
            depth,
            occlusion,
            left,
            right,
        )
