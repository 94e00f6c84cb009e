"""Depth-camera sequences for the depth filter: what a stereo or time-of-flight camera
measures of the stereo simulator's scenes, frame after frame, with the exact depth beside.

Kinds (:data:`KINDS`):

* ``static``: a camera that does not move, a scene that does not move;
* ``moving_camera``: the camera slides sideways ``step_m`` per frame and turns
  ``turn_deg`` per frame about its vertical axis, in a scene that does not move;
* ``moving_object``: a camera that does not move, the scene's objects moving a few cm per
  frame (:func:`~depth_nodes.sim.layout.build_scene`).

Every frame is measured the way depth cameras fail:

* noise: Gaussian, new every frame, of ``Z^2 disparity_sigma / (f B)`` (``noise:
  stereo``) or ``tof_noise`` times Z (``noise: tof``);
* mixed pixels: each pixel is ``supersample^2`` rays and measures their mean depth, so a
  pixel across a depth edge measures a depth between the two surfaces (a time-of-flight
  camera's flying pixels; a stereo camera's edges blur the same way);
* holes: a band on the left (``left_band`` of the width: a stereo camera's columns the
  right camera cannot see) and blobs that come and go (``hole_fraction`` of the image a
  frame: dark or shiny patches, lost for a frame or two).

Ground truth per frame: Z at the pixel centres, the mixed pixels (the measured depth, noise
included, lies in the middle half of a gap between surfaces of more than
``max(0.1 m, 6 sigma)``: a depth that belongs to neither), the holes, the pixels of
moving objects, the camera's pose.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.core.stamps import NS_PER_S
from depth_nodes.errors import ConfigError
from depth_nodes.sim.layout import build_scene
from depth_nodes.sim.sequence import pixel_rays

__all__ = ['HOLE', 'KINDS', 'MIXED', 'MOVING', 'STRADDLING', 'DepthFrame',
           'DepthSequenceConfig', 'labels', 'simulate_depth_sequence']

F32 = NDArray[np.float32]
B = NDArray[np.bool_]
KINDS = ('static', 'moving_camera', 'moving_object')
NOISES = ('stereo', 'tof')
#: Smallest gap between surfaces, metres, whose middle half makes a pixel mixed.
MIXED_GAP_M = 0.1
#: ... and in standard deviations of the far surface's noise.
MIXED_GAP_SIGMAS = 6.0
#: Bits of :func:`labels`.
MIXED, HOLE, MOVING, STRADDLING = 1, 2, 4, 8


@dataclass(frozen=True)
class DepthSequenceConfig:
    """Parameters of :func:`simulate_depth_sequence` (see the module notes).

    Attributes:
        kind: One of :data:`KINDS`.
        width: Image width, pixels (>= 16).
        height: Image height, pixels (>= 16).
        n_frames: Frames (>= 1).
        seed: Scene, noise and holes seed.
        noise: ``stereo`` or ``tof``.
        baseline_m: Stereo baseline, metres.
        disparity_sigma: Stereo disparity noise, pixels.
        tof_noise: Time-of-flight noise as a fraction of Z.
        supersample: Rays per pixel and axis (mixed pixels).
        hole_fraction: Share of the image in blobs lost each frame.
        left_band: Share of the width lost on the left (stereo).
        step_m: moving_camera: sideways motion per frame, metres.
        turn_deg: moving_camera: turn per frame, degrees.
        frame_rate_hz: Spacing of the stamps.
        start_stamp_ns: Stamp of the first frame.
    """

    kind: str = 'static'
    width: int = 320
    height: int = 240
    n_frames: int = 10
    seed: int = 0
    noise: str = 'stereo'
    baseline_m: float = 0.08
    disparity_sigma: float = 0.1
    tof_noise: float = 0.005
    supersample: int = 4
    hole_fraction: float = 0.03
    left_band: float = 0.05
    step_m: float = 0.02
    turn_deg: float = 0.3
    frame_rate_hz: float = 30.0
    start_stamp_ns: int = 1_700_000_000_000_000_000

    @property
    def camera(self) -> Intrinsics:
        """The pinhole camera (focal 0.8 x width, principal point at the centre)."""
        f = 0.8 * self.width
        return Intrinsics(f, f, (self.width - 1) / 2.0, (self.height - 1) / 2.0, self.width,
                          self.height)

    def sigma(self, depth: F32) -> F32:
        """The noise's standard deviation at ``depth``, metres."""
        if self.noise == 'tof':
            return (self.tof_noise * depth).astype(np.float32)
        f = self.camera.fx
        return (depth * depth * (self.disparity_sigma / (f * self.baseline_m))).astype(
            np.float32)

    def validate(self) -> DepthSequenceConfig:
        """Raises ConfigError naming the first invalid field; returns self."""
        checks = [
            ('kind', self.kind in KINDS, f'one of {", ".join(KINDS)}'),
            ('noise', self.noise in NOISES, f'one of {", ".join(NOISES)}'),
            ('width', self.width >= 16, 'at least 16'),
            ('height', self.height >= 16, 'at least 16'),
            ('n_frames', self.n_frames >= 1, 'at least 1'),
            ('seed', self.seed >= 0, 'not negative'),
            ('supersample', 1 <= self.supersample <= 8, 'in 1..8'),
            ('hole_fraction', 0 <= self.hole_fraction < 0.5, 'in [0, 0.5)'),
            ('left_band', 0 <= self.left_band < 0.5, 'in [0, 0.5)'),
            ('baseline_m', self.baseline_m > 0, 'positive'),
            ('frame_rate_hz', self.frame_rate_hz > 0, 'positive'),
        ]
        for name, ok, wanted in checks:
            if not ok:
                raise ConfigError(f'depth sequence {name}={getattr(self, name)!r}: must be '
                                  f'{wanted}')
        return self


@dataclass
class DepthFrame:
    """One measured frame and its truth.

    Attributes:
        index: Frame number.
        stamp_ns: Its stamp.
        depth: Measured Z, metres, NaN in holes.
        truth: Exact Z at the pixel centres (NaN where no surface).
        mixed: Mixed pixels (see the module notes).
        straddling: Pixels that see two surfaces more than ``max(0.1 m, 6 sigma)`` apart,
            mixed or not (a mixture close to one surface is not a mixed pixel, nor a
            valid one).
        holes: Pixels with no measurement.
        moving: Pixels that see a moving object (moving_object).
        pose: The camera's optical frame in the world.
        camera: The intrinsics.
    """

    index: int
    stamp_ns: int
    depth: F32
    truth: F32
    mixed: B
    straddling: B
    holes: B
    moving: B
    pose: Pose
    camera: Intrinsics


def labels(frame: DepthFrame) -> NDArray[np.uint8]:
    """A frame's truth as one image of bits: :data:`MIXED`, :data:`HOLE`, :data:`MOVING`,
    :data:`STRADDLING`."""
    out: NDArray[np.uint8] = (frame.mixed * MIXED | frame.holes * HOLE |
                              frame.moving * MOVING | frame.straddling * STRADDLING
                              ).astype(np.uint8)
    return out


def _pose(config: DepthSequenceConfig, index: int) -> Pose:
    if config.kind != 'moving_camera':
        return Pose()
    angle = math.radians(config.turn_deg * index)
    c, s = math.cos(angle), math.sin(angle)
    rotation = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return Pose(rotation, np.array([config.step_m * index, 0.0, 0.0]))


def _holes(config: DepthSequenceConfig, rng: np.random.Generator) -> B:
    h, w = config.height, config.width
    mask = np.zeros((h, w), np.uint8)
    target = config.hole_fraction * h * w
    while mask.sum() < target:
        r = max(1.0, rng.uniform(0.01, 0.04) * w)
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        cv2.ellipse(mask, (int(cx), int(cy)), (int(r), int(r * rng.uniform(0.4, 1.0))),
                    rng.uniform(0, 180), 0, 360, 1, -1)
    out: B = mask.astype(bool)
    out[:, :round(config.left_band * w)] = True
    return out


def simulate_depth_sequence(config: DepthSequenceConfig) -> Iterator[DepthFrame]:
    """Render the frames of ``config`` in time order.

    Raises:
        ConfigError: Naming the invalid field.
    """
    config.validate()
    return _simulate(config)


def _simulate(config: DepthSequenceConfig) -> Iterator[DepthFrame]:
    camera = config.camera
    s = config.supersample
    rays = pixel_rays(camera, s)
    centre_rays = pixel_rays(camera, 1)
    still = build_scene(config.seed, 0, camera.fx, camera.width, camera.height)
    later = build_scene(config.seed, 1, camera.fx, camera.width, camera.height)
    # the primitives that move from frame to frame
    movers = np.array([not np.array_equal(a.centre, b.centre)
                       for a, b in zip(still.primitives, later.primitives, strict=True)])
    shape = (camera.height, camera.width)
    for index in range(config.n_frames):
        scene = build_scene(config.seed, index, camera.fx, camera.width, camera.height) \
            if config.kind == 'moving_object' else still
        pose = _pose(config, index)
        t, _ = scene.cast(pose.position, rays @ pose.rotation.T)
        sub = np.where(np.isfinite(t), t, np.nan).reshape(*shape, s * s)
        t0, hit = scene.cast(pose.position, centre_rays @ pose.rotation.T)
        truth = np.where(np.isfinite(t0), t0, np.nan).reshape(shape).astype(np.float32)
        with np.errstate(invalid='ignore'), warnings.catch_warnings():
            warnings.simplefilter('ignore', RuntimeWarning)  # all-NaN pixels: the sky
            mix = np.nanmean(sub, axis=2).astype(np.float32)
            near, far = np.nanmin(sub, axis=2), np.nanmax(sub, axis=2)
        gap = far - near
        sigma_far = config.sigma(np.nan_to_num(far, nan=0.0).astype(np.float32))
        rng = np.random.default_rng([config.seed, index, 11])
        noise = rng.standard_normal(shape).astype(np.float32)
        depth = mix + noise * config.sigma(np.nan_to_num(mix, nan=0.0).astype(np.float32))
        with np.errstate(invalid='ignore'):
            straddling = gap > np.maximum(MIXED_GAP_M, MIXED_GAP_SIGMAS * sigma_far)
            mixed = straddling & (np.abs(depth - (near + far) / 2) < gap / 4)
        holes = _holes(config, rng) | ~np.isfinite(depth)
        depth[holes] = np.nan
        moving = np.zeros(shape, bool)
        if config.kind == 'moving_object':  # the centre ray hits a primitive that moves
            hit = hit.reshape(shape)
            seen = hit >= 0
            moving[seen] = movers[hit[seen]]
        stamp = config.start_stamp_ns + round(index * NS_PER_S / config.frame_rate_hz)
        yield DepthFrame(index, stamp, depth.astype(np.float32), truth, mixed & ~holes,
                         straddling & ~holes, holes, moving, pose, camera)
