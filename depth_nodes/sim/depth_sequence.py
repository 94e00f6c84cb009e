"""Depth-camera sequences for the depth filter: what a stereo or time-of-flight camera
measures of the stereo simulator's scenes, frame after frame, with the exact depth beside.

Kinds (:data:`KINDS`):

* ``static``: a camera that does not move, a scene that does not move;
* ``moving_camera``: the camera slides sideways ``step_m`` per frame and turns
  ``turn_deg`` per frame about its vertical axis, in a scene that does not move;
* ``moving_object``: a camera that does not move, the scene's objects moving a few cm per
  frame (:func:`~depth_nodes.sim.layout.build_scene`);
* ``orbit``: the static scene, the camera on a horizontal arc around a point in the middle
  of it (:data:`~depth_nodes.sim.sequence.ORBIT_CENTRE`), always looking at it, sweeping
  ``orbit_deg`` from the first frame to the last (the middle frame is the static camera);
* ``object_leaves``: the static camera and scene, plus a box (label ``leaving``) in front
  of the background for the first ``n_frames // 2`` frames, gone afterwards;
* ``long``: a closed room (:data:`ROOM_HALF_M`: 9 - 10 m across) of cabinets, boxes,
  spheres and pillars, deterministic from the seed, and a camera that drives ``step_m``
  per frame round a circle of :data:`LONG_RADIUS_M` inside it, looking ahead,
  :data:`LONG_INWARD_DEG` inwards and :data:`LONG_PITCH_DEG` down (0.46 degrees a frame
  at 2 cm): hundreds of frames, every pixel on a surface, objects coming into view and
  going again.

The scene of every frame is :func:`scene_at`, the camera's pose :func:`pose_at`: an
evaluator rebuilds the exact truth (depth, or the distance of any point to the surface:
:meth:`~depth_nodes.sim.scene.Scene.distance`) from the configuration alone.

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
from depth_nodes.errors import ArgumentError, ConfigError
from depth_nodes.sim import texture as tx
from depth_nodes.sim.layout import build_scene, rotation
from depth_nodes.sim.scene import Box, Cylinder, Material, Primitive, Scene, Sphere
from depth_nodes.sim.sequence import ORBIT_CENTRE, look_at, pixel_rays

__all__ = ['HOLE', 'KINDS', 'MIXED', 'MOVING', 'STRADDLING', 'DepthFrame',
           'DepthSequenceConfig', 'labels', 'pose_at', 'scene_at', 'simulate_depth_sequence',
           'stamp_at']

F32 = NDArray[np.float32]
B = NDArray[np.bool_]
KINDS = ('static', 'moving_camera', 'moving_object', 'orbit', 'object_leaves', 'long')
NOISES = ('stereo', 'tof')
#: Smallest gap between surfaces, metres, whose middle half makes a pixel mixed.
MIXED_GAP_M = 0.1
#: ... and in standard deviations of the far surface's noise.
MIXED_GAP_SIGMAS = 6.0
#: Bits of :func:`labels`.
MIXED, HOLE, MOVING, STRADDLING = 1, 2, 4, 8
#: long: radius of the camera's circle, metres, and the room's half extent (x, z) around
#: its centre (drawn from the seed in this range).
LONG_RADIUS_M = 2.5
ROOM_HALF_M = (4.5, 5.0)
#: long: how far the camera looks inwards of its heading, and down, degrees.
LONG_INWARD_DEG = 20.0
LONG_PITCH_DEG = 8.0
#: long: free space kept on either side of the camera's circle, metres.
LONG_CLEARANCE_M = 0.5
#: object_leaves: the box's depth as a share of the background's behind its centre.
LEAVING_DEPTH_SHARE = 0.75


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
        step_m: moving_camera: sideways motion per frame; long: along the circle, metres.
        turn_deg: moving_camera: turn per frame, degrees.
        orbit_deg: orbit: the arc swept from the first frame to the last, degrees.
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
    orbit_deg: float = 40.0
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
            ('orbit_deg', 0 <= self.orbit_deg <= 90, 'in [0, 90]'),
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
        moving: Pixels that see a moving object (moving_object; object_leaves: the box
            while it is there).
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


def pose_at(config: DepthSequenceConfig, index: int) -> Pose:
    """The camera's optical frame in the world at frame ``index``.

    Raises:
        ConfigError: Naming the invalid field of ``config``.
        ArgumentError: ``index`` is not a frame of ``config``.
    """
    _check_index(config.validate(), index)
    return _pose(config, index)


def scene_at(config: DepthSequenceConfig, index: int) -> Scene:
    """The exact scene of frame ``index``, the one its frame was rendered from.

    Raises:
        ConfigError: Naming the invalid field of ``config``.
        ArgumentError: ``index`` is not a frame of ``config``.
    """
    _check_index(config.validate(), index)
    return _scene(config, index)


def stamp_at(config: DepthSequenceConfig, index: int) -> int:
    """The stamp of frame ``index``, nanoseconds."""
    return config.start_stamp_ns + round(index * NS_PER_S / config.frame_rate_hz)


def _check_index(config: DepthSequenceConfig, index: int) -> None:
    if not 0 <= index < config.n_frames:
        raise ArgumentError(f'index {index}: not a frame of the sequence (0..'
                            f'{config.n_frames - 1})')


def _pose(config: DepthSequenceConfig, index: int) -> Pose:
    if config.kind == 'orbit':
        return _orbit_pose(config, index)
    if config.kind == 'long':
        return _long_pose(config, index)
    if config.kind != 'moving_camera':
        return Pose()
    angle = math.radians(config.turn_deg * index)
    c, s = math.cos(angle), math.sin(angle)
    rotation = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return Pose(rotation, np.array([config.step_m * index, 0.0, 0.0]))


def _orbit_pose(config: DepthSequenceConfig, index: int) -> Pose:
    """On the horizontal circle through the origin around ORBIT_CENTRE, -orbit_deg / 2 at
    the first frame to +orbit_deg / 2 at the last, looking at the centre."""
    centre = np.asarray(ORBIT_CENTRE, np.float64)
    share = index / (config.n_frames - 1) - 0.5 if config.n_frames > 1 else 0.0
    angle = math.radians(config.orbit_deg * share)
    radius = math.hypot(centre[0], centre[2])
    position = np.array([centre[0] + radius * math.sin(angle), 0.0,
                         centre[2] - radius * math.cos(angle)])
    return look_at(position, centre)


def _long_pose(config: DepthSequenceConfig, index: int) -> Pose:
    """On the circle of LONG_RADIUS_M round the room's centre (the origin), heading
    along it, looking LONG_INWARD_DEG inwards and LONG_PITCH_DEG down."""
    phi = config.step_m * index / LONG_RADIUS_M
    position = LONG_RADIUS_M * np.array([math.cos(phi), 0.0, math.sin(phi)])
    heading = np.array([-math.sin(phi), 0.0, math.cos(phi)])
    inward = -position / LONG_RADIUS_M
    inward_rad, pitch = math.radians(LONG_INWARD_DEG), math.radians(LONG_PITCH_DEG)
    look = math.cos(inward_rad) * heading + math.sin(inward_rad) * inward
    look = math.cos(pitch) * look + math.sin(pitch) * np.array([0.0, 1.0, 0.0])  # y is down
    return look_at(position, position + look)


def _scene(config: DepthSequenceConfig, index: int) -> Scene:
    camera = config.camera
    if config.kind == 'long':
        return _room(config.seed)
    scene = build_scene(config.seed, index if config.kind == 'moving_object' else 0,
                        camera.fx, camera.width, camera.height)
    if config.kind == 'object_leaves' and index < config.n_frames // 2:
        return Scene((*scene.primitives, _leaving_box(config, scene)))
    return scene


def _noise_material(rng: np.random.Generator, period_m: float) -> Material:
    """A random colour with a strong noise texture of ``period_m``."""
    colour = rng.uniform(0.5, 0.9, 3)
    texture = tx.Texture(tx.NOISE, period_m, int(rng.integers(1 << 30)), 4, 1.0, 0.5)
    return Material((0.3 * colour[0], 0.3 * colour[1], 0.3 * colour[2]),
                    (colour[0], colour[1], colour[2]), texture)


def _leaving_box(config: DepthSequenceConfig, scene: Scene) -> Box:
    """object_leaves' box: centred on the ray of a pixel of the upper half (the seed's
    first that sees the background), at LEAVING_DEPTH_SHARE of the background's depth."""
    camera = config.camera
    rng = np.random.default_rng([config.seed, 31])
    background = scene.labels.index('background')
    for _ in range(100):  # the objects hide the background at a few pixels of the band
        ray = np.array([[rng.uniform(-0.35, 0.35) * camera.width / camera.fx,
                         rng.uniform(-0.3, 0.0) * camera.height / camera.fy, 1.0]])
        t, hit = scene.cast(np.zeros(3), ray)
        if hit[0] == background:
            break
    depth = LEAVING_DEPTH_SHARE * float(t[0])
    half = rng.uniform(0.08, 0.11, 3) * depth
    return Box('leaving', _noise_material(rng, 0.3), ray[0] * depth,
               rotation(rng.uniform(20, 50), rng.uniform(-10, 10)), half)


def _room(seed: int) -> Scene:
    """long's room: a box the camera is inside (its inner faces: walls, floor, ceiling);
    cabinets against the walls, boxes and spheres on the floor, pillars from floor to
    ceiling, none overlapping another and all LONG_CLEARANCE_M off the camera's circle."""
    rng = np.random.default_rng([seed, 41])
    half_x, half_z = rng.uniform(*ROOM_HALF_M, 2)
    floor, ceiling = rng.uniform(1.2, 1.4), -rng.uniform(1.4, 1.8)
    middle, half_height = (floor + ceiling) / 2, (floor - ceiling) / 2
    prims: list[Primitive] = [Box('room', _noise_material(rng, 0.4), [0.0, middle, 0.0],
                                  np.eye(3), [half_x, half_height, half_z])]
    taken: list[tuple[float, float, float]] = []  # x, z, reach of what stands on the floor

    def free(x: float, z: float, reach: float) -> bool:
        """Whether a footprint of radius ``reach`` at (x, z) keeps clear of the circle and
        of every footprint taken, and takes it if so."""
        ok = abs(math.hypot(x, z) - LONG_RADIUS_M) > reach + LONG_CLEARANCE_M and all(
            math.hypot(x - x2, z - z2) > reach + r2 + 0.1 for x2, z2, r2 in taken)
        if ok:
            taken.append((x, z, reach))
        return ok

    def spot(reach: float) -> tuple[float, float] | None:
        """A free (x, z) inside the walls for a footprint of radius ``reach``."""
        for _ in range(200):
            x = rng.uniform(-half_x + reach, half_x - reach)
            z = rng.uniform(-half_z + reach, half_z - reach)
            if free(x, z, reach):
                return x, z
        return None

    for _ in range(8):  # cabinets, 2 cm off a wall, on the floor
        width, height, depth = rng.uniform([0.3, 0.3, 0.15], [0.8, 1.0, 0.3])
        wall, sign = int(rng.integers(2)), float(rng.choice([-1.0, 1.0]))
        along = rng.uniform(-1.0, 1.0)
        if wall == 0:  # a wall of constant x
            half = np.array([depth, height, width])
            centre = [sign * (half_x - depth - 0.02), floor - height,
                      along * (half_z - width)]
        else:
            half = np.array([width, height, depth])
            centre = [along * (half_x - width), floor - height,
                      sign * (half_z - depth - 0.02)]
        if free(centre[0], centre[2], float(np.hypot(half[0], half[2]))):
            prims.append(Box('cabinet', _noise_material(rng, 0.15), centre, np.eye(3), half))
    for _ in range(4):
        radius = rng.uniform(0.12, 0.25)
        if (xz := spot(radius)) is not None:
            prims.append(Cylinder('pillar', _noise_material(rng, 0.2), [xz[0], middle, xz[1]],
                                  [0.0, 1.0, 0.0], radius, half_height))
    for _ in range(12):
        half = rng.uniform([0.2, 0.15, 0.2], [0.5, 0.6, 0.5])
        if (xz := spot(float(np.hypot(half[0], half[2])))) is not None:
            prims.append(Box('box', _noise_material(rng, 0.15), [xz[0], floor - half[1], xz[1]],
                             rotation(rng.uniform(0, 90)), half))
    for _ in range(5):
        radius = rng.uniform(0.2, 0.4)
        if (xz := spot(radius)) is not None:
            prims.append(Sphere('sphere', _noise_material(rng, 0.15),
                                [xz[0], floor - radius, xz[1]], radius))
    return Scene(tuple(prims))


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
    movers = _movers(config)
    shape = (camera.height, camera.width)
    for index in range(config.n_frames):
        scene = _scene(config, index)
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
        hit = hit.reshape(shape)
        seen = hit >= 0
        if config.kind == 'moving_object':  # the centre ray hits a primitive that moves
            moving[seen] = movers[hit[seen]]
        elif config.kind == 'object_leaves':  # ... or the leaving box (the last primitive)
            moving[seen] = np.asarray(scene.labels)[hit[seen]] == 'leaving'
        yield DepthFrame(index, stamp_at(config, index), depth.astype(np.float32), truth,
                         mixed & ~holes, straddling & ~holes, holes, moving, pose, camera)


def _movers(config: DepthSequenceConfig) -> B:
    """moving_object: which primitives of the scene move from frame to frame."""
    camera = config.camera
    still = build_scene(config.seed, 0, camera.fx, camera.width, camera.height)
    later = build_scene(config.seed, 1, camera.fx, camera.width, camera.height)
    out: B = np.array([not np.array_equal(a.centre, b.centre)
                       for a, b in zip(still.primitives, later.primitives, strict=True)])
    return out
