"""Continuous-wave time-of-flight simulator: raw correlation frames with exact ground truth.

Geometry (camera optical frame = world frame, metres): a room corner seen from inside
(two walls at 45 degrees meeting 4 m ahead: a concave corner), a floor, two boxes and a
sphere in front of them (depth edges), a bright board close to the camera (it saturates)
and a black patch on a wall (too little light returns). The light source sits at the
camera, so a point's range ``r`` is half the path the light travels.

Image formation per raw pixel, for each modulation frequency ``f``:

* ``supersample`` x ``supersample`` rays through the pixel (lens distortion applied: the
  raw pixel's rays are undistorted); each hit returns the phasor
  ``power * albedo * cos(incidence) / r^2 * exp(i 4 pi f r / c)``: a pixel on a depth edge
  sums the phasors of both surfaces (a mixed pixel, at a range in between);
* multipath: light that reaches the pixel's surface point after one bounce off another
  surface the camera sees (``emitter_step`` x ``emitter_step`` pixel patches), with the
  bounce's longer path: ``power * albedo_p * sum albedo_q * solid_angle_q * cos_q * cos_p
  / (pi d^2) * exp(i 2 pi f (r_q + d + r_p) / c)``; no occlusion between the bounces. It
  biases the range near the concave corner, where the walls light each other;
* the samples ``c_k = ambient * albedo + a (1 + contrast cos(phi - 2 pi k / N))`` per
  phasor, summed; shot noise (Poisson, one electron per count) and read noise, rounded,
  clipped at ``full_well`` (those pixels are saturated).

Ground truth: the range along each raw pixel's centre ray, and on the rectified grid of
``P`` (the raw ``K`` without distortion): depth Z, the 3-D points and the flags of the
noise-free signal (saturated, low amplitude) that the node computes too.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.rectify import rectification_maps
from depth_nodes.core.tof import LOW_AMPLITUDE, SATURATED, SPEED_OF_LIGHT, check_frequencies
from depth_nodes.errors import ConfigError
from depth_nodes.sim import texture as tx
from depth_nodes.sim.layout import rotation
from depth_nodes.sim.rig import undistort_pixels
from depth_nodes.sim.scene import Box, Material, Primitive, Rect, Scene, Sphere

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]

__all__ = ['ToFFrame', 'ToFSimConfig', 'simulate_tof', 'tof_camera', 'tof_scene']


@dataclass(frozen=True)
class ToFSimConfig:
    """Parameters of the simulator (see the module notes).

    Attributes:
        width: Image width, pixels (>= 16).
        height: Image height, pixels (>= 16).
        focal_px: Focal length, pixels.
        distortion: plumb_bob k1, k2, p1, p2, k3 of the lens.
        frequencies_mhz: Modulation frequencies, in the order of the planes.
        phase_steps: Samples per frequency.
        power: Amplitude, counts, returned by albedo 1 at 1 m, facing the camera.
        ambient: Counts of ambient light on albedo 1.
        contrast: Modulation contrast of the return (0..1].
        full_well: Largest sample value; samples there are saturated.
        read_noise: Read noise standard deviation, counts.
        supersample: Rays per pixel side (mixed pixels at edges).
        multipath: Add the one-bounce light.
        noise: Add shot and read noise (off: the exact expected samples, still rounded).
        emitter_step: Pixel patch side of the bounce sources.
        seed: Scene and noise seed.
        n_frames: Frames (the scene is static; the noise differs).
        frame_rate_hz: Frame rate of the stamps.
        start_stamp_ns: Stamp of the first frame.
    """

    width: int = 640
    height: int = 480
    focal_px: float = 500.0
    distortion: tuple[float, ...] = (-0.08, 0.02, 0.0005, -0.0003, 0.0)
    frequencies_mhz: tuple[float, ...] = (80.0, 100.0)
    phase_steps: int = 4
    power: float = 8000.0
    ambient: float = 100.0
    contrast: float = 0.7
    full_well: float = 4095.0
    read_noise: float = 2.0
    supersample: int = 3
    multipath: bool = True
    noise: bool = True
    emitter_step: int = 16
    seed: int = 5
    n_frames: int = 2
    frame_rate_hz: float = 15.0
    start_stamp_ns: int = 1_700_000_000_000_000_000

    def validate(self) -> ToFSimConfig:
        """Check the configuration; returns self.

        Raises:
            ConfigError: A value out of its range.
        """
        checks = [
            (self.width >= 16 and self.height >= 16, 'width and height must be >= 16'),
            (self.focal_px > 0, 'focal_px must be positive'),
            (len(self.distortion) == 5, 'distortion needs the 5 plumb_bob coefficients'),
            (self.phase_steps >= 3, 'phase_steps must be >= 3'),
            (self.power > 0 and self.ambient >= 0, 'power > 0 and ambient >= 0'),
            (0 < self.contrast <= 1, 'contrast must be in (0, 1]'),
            (self.full_well > 0 and self.read_noise >= 0, 'full_well > 0, read_noise >= 0'),
            (self.supersample >= 1 and self.emitter_step >= 1,
             'supersample and emitter_step must be >= 1'),
            (self.n_frames >= 1, f'n_frames must be >= 1, got {self.n_frames}'),
            (self.frame_rate_hz > 0, 'frame_rate_hz must be positive'),
        ]
        for ok, why in checks:
            if not ok:
                raise ConfigError(f'tof simulator: {why}')
        try:
            check_frequencies(self.frequencies_mhz)
        except Exception as exc:
            raise ConfigError(f'tof simulator: {exc}') from None
        return self


@dataclass
class ToFFrame:
    """One simulated frame.

    Attributes:
        index: Frame number.
        stamp_ns: Its stamp.
        samples: (n_freq * steps, H, W) uint16 raw correlation samples, frequency-major.
        camera: The raw camera (K, D; R = I; P the same K without distortion).
        range_gt: (H, W) float32 exact range along each raw pixel's centre ray (NaN: none).
        depth_gt: (H, W) float32 exact Z on the rectified grid.
        points_gt: (H, W, 3) float32 exact points on the rectified grid.
        flags_gt: (H, W) uint8 on the rectified grid: ``SATURATED`` / ``LOW_AMPLITUDE`` of
            the noise-free signal (for the node's default ``min_amplitude`` 10).
        labels: (H, W) int32 primitive seen by each rectified pixel centre (-1: none).
        label_names: Name of each primitive index.
        mixed_gt: (2, H, W) float32 on the rectified grid: for a pixel whose rays span more
            than :data:`MIXED_SPAN` of range (it sees two surfaces), the Z of the nearest
            and of the farthest surface; NaN elsewhere.
        corner_gt: (H, W) bool, the walls within :data:`CORNER_REACH` of the concave
            corner's edge (where they light each other most: multipath).
    """

    index: int
    stamp_ns: int
    samples: NDArray[np.uint16]
    camera: CameraModel
    range_gt: F32
    depth_gt: F32
    points_gt: F32
    flags_gt: NDArray[np.uint8]
    labels: NDArray[np.int32]
    label_names: list[str]
    mixed_gt: F32
    corner_gt: NDArray[np.bool_]


#: Range spread, metres, over a pixel's rays that makes it a mixed pixel in the ground truth.
MIXED_SPAN = 0.05
#: Distance, metres, from the corner's edge of the wall area called the corner.
CORNER_REACH = 0.6
#: The node's default min_amplitude, for the ground-truth flags.
GT_MIN_AMPLITUDE = 10.0


def _material(rng: np.random.Generator, lo: float, hi: float, period: float = 0.2) -> Material:
    texture = tx.Texture(tx.NOISE, period, int(rng.integers(1 << 30)), 3, 1.0, 0.5)
    return Material((lo, lo, lo), (hi, hi, hi), texture)


def corner_edge(seed: int) -> F64:
    """A point of the walls' common (vertical) edge in :func:`tof_scene`."""
    rng = np.random.default_rng([seed, 77])
    return np.array([0.3 + rng.uniform(-0.05, 0.05), 0.0, 4.0 + rng.uniform(-0.1, 0.1)])


def tof_scene(seed: int) -> Scene:
    """The room corner scene (see the module notes), 0.6 .. 4.2 m deep."""
    rng = np.random.default_rng([seed, 78])
    corner = corner_edge(seed)
    down = np.array([0.0, 1.0, 0.0])
    left_dir = np.array([-1.0, 0.0, -1.0]) / math.sqrt(2)
    right_dir = np.array([1.0, 0.0, -1.0]) / math.sqrt(2)
    big = 20.0
    prims: list[Primitive] = [
        Rect('left_wall', _material(rng, 0.45, 0.75), corner + left_dir * big,
             -left_dir, down, (big, big)),
        Rect('right_wall', _material(rng, 0.45, 0.75), corner + right_dir * big,
             down, -right_dir, (big, big)),
        Rect('floor', _material(rng, 0.3, 0.6), [0.0, 1.0, 3.0], [1.0, 0, 0], [0, 0, 1.0]),
        Box('box', _material(rng, 0.4, 0.8, 0.08), [-0.55, 0.55, 1.8],
            rotation(rng.uniform(20, 30)), (0.3, 0.45, 0.25)),
        Box('crate', _material(rng, 0.3, 0.7, 0.08), [0.75, 0.6, 2.5],
            rotation(rng.uniform(-15, -5)), (0.25, 0.4, 0.25)),
        Sphere('ball', _material(rng, 0.5, 0.8, 0.05), [0.15, 0.1, 2.9], 0.3),
        Rect('bright_board', _material(rng, 0.9, 0.95), [-0.25, -0.18, 0.65],
             [1.0, 0, 0], [0, -1.0, 0], (0.06, 0.05)),
        Rect('black_patch', _material(rng, 0.015, 0.02), corner + right_dir * 1.3
             + np.array([0.0, -0.5, 0.0]) + 0.01 * np.array([-1.0, 0.0, -1.0]) / math.sqrt(2),
             down, -right_dir, (0.35, 0.3)),
    ]
    return Scene(tuple(prims))


def tof_camera(config: ToFSimConfig) -> CameraModel:
    """The raw camera: K centred, plumb_bob D, R = I, P = [K | 0]."""
    f, w, h = config.focal_px, config.width, config.height
    K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
    return CameraModel(w, h, K, D=np.asarray(config.distortion, np.float64),
                       P=np.hstack([K, np.zeros((3, 1))]), frame_id='tof_optical_frame')


def _albedo_and_normal(scene: Scene, o: F64, d: F64, t: F64, idx: NDArray[np.int32]
                       ) -> tuple[F64, F64]:
    """Grey albedo (mean of the RGB reflectance) and unit normal at each hit."""
    albedo = np.zeros(len(d))
    normal = np.zeros((len(d), 3))
    for k, prim in enumerate(scene.primitives):
        sel = np.flatnonzero(idx == k)
        if len(sel) == 0:
            continue
        p = o + t[sel, None] * d[sel]
        n, s, tt = prim.surface(p)
        albedo[sel] = prim.material.reflectance(s, tt).mean(axis=1)
        facing = np.sum(n * d[sel], axis=1) > 0  # the side the ray arrives on
        normal[sel] = np.where(facing[:, None], -n, n)
    return albedo, normal


@numba.njit(cache=True, parallel=True)
def _bounce_kernel(points: F64, normals: F64, ranges: F64, src_points: F64,
                   src_normals: F64, src_weight: F64, src_ranges: F64,
                   wavenumbers: F64, out_re: F64, out_im: F64, out_dc: F64) -> None:
    """One-bounce phasor sums and their light (without the receiver's own albedo and
    range)."""
    for i in numba.prange(points.shape[0]):
        if not ranges[i] > 0.0:
            continue
        for q in range(src_points.shape[0]):
            dx = points[i, 0] - src_points[q, 0]
            dy = points[i, 1] - src_points[q, 1]
            dz = points[i, 2] - src_points[q, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < 1e-6:
                continue
            dist = math.sqrt(d2)
            cos_q = (src_normals[q, 0] * dx + src_normals[q, 1] * dy
                     + src_normals[q, 2] * dz) / dist
            cos_p = -(normals[i, 0] * dx + normals[i, 1] * dy + normals[i, 2] * dz) / dist
            if cos_q <= 0.0 or cos_p <= 0.0:
                continue
            g = src_weight[q] * cos_q * cos_p / (math.pi * d2)
            path = src_ranges[q] + dist
            out_dc[i] += g
            for j in range(wavenumbers.shape[0]):
                phase = wavenumbers[j] * path
                out_re[j, i] += g * math.cos(phase)
                out_im[j, i] += g * math.sin(phase)


class _Renderer:
    """The noise-free phasors of the raw image (per frequency) and the ground truth."""

    def __init__(self, config: ToFSimConfig) -> None:
        self.config = config.validate()
        self.camera = tof_camera(config)
        self.scene = tof_scene(config.seed)
        self.corner = corner_edge(config.seed)
        freqs = np.asarray(config.frequencies_mhz) * 1e6
        self.wavenumbers = 2 * np.pi * freqs / SPEED_OF_LIGHT  # phase per metre of path
        self._bounce_dc: F64 | float = 0.0
        self.direct, self.range_raw = self._direct()
        if config.multipath:
            self.direct = self.direct + self._bounces()

    def _rays(self, supersample: int) -> F64:
        c = self.config
        offs = (np.arange(supersample) + 0.5) / supersample - 0.5
        v = np.arange(c.height)[:, None, None, None] + offs[None, None, :, None]
        u = np.arange(c.width)[None, :, None, None] + offs[None, None, None, :]
        px = np.stack(np.broadcast_arrays(u, v), axis=-1).reshape(-1, 2)
        return undistort_pixels(self.camera, px)

    def _direct(self) -> tuple[NDArray[np.complex128], F32]:
        c = self.config
        s = c.supersample
        rays = self._rays(s)
        t, idx = self.scene.cast(np.zeros(3), rays)
        hit = np.isfinite(t)
        rng_m = np.where(hit, t * np.linalg.norm(rays, axis=1), np.inf)
        albedo, normal = _albedo_and_normal(self.scene, np.zeros(3), rays, np.where(hit, t, 0),
                                            idx)
        unit = rays / np.linalg.norm(rays, axis=1, keepdims=True)
        cos_i = np.abs(np.sum(normal * unit, axis=1))
        with np.errstate(divide='ignore', invalid='ignore'):
            a = np.where(hit, c.power * albedo * cos_i / rng_m ** 2, 0.0)
        phase = self.wavenumbers[:, None] * 2 * np.where(hit, rng_m, 0)[None, :]
        phasor = (a[None, :] * np.exp(1j * phase)).reshape(len(self.wavenumbers), c.height,
                                                          c.width, s * s).mean(axis=-1)
        # the ground truth range: the centre ray of each pixel
        centre = undistort_pixels(self.camera, np.stack(np.meshgrid(
            np.arange(c.width, dtype=float), np.arange(c.height, dtype=float)), -1).reshape(-1, 2))
        tc, _ = self.scene.cast(np.zeros(3), centre)
        range_raw = (tc * np.linalg.norm(centre, axis=1)).reshape(c.height, c.width)
        spread = np.where(hit, rng_m, np.nan).reshape(c.height, c.width, s * s)
        with np.errstate(invalid='ignore'):
            self._near = np.nanmin(np.where(np.isnan(spread), np.inf, spread), axis=-1)
            self._far = np.nanmax(np.where(np.isnan(spread), -np.inf, spread), axis=-1)
        self._ambient = (c.ambient * albedo).reshape(c.height, c.width, s * s).mean(axis=-1)
        self._a_dc = a.reshape(c.height, c.width, s * s).mean(axis=-1)
        return phasor, np.where(np.isfinite(range_raw), range_raw, np.nan).astype(
            np.float32)

    def _bounces(self) -> NDArray[np.complex128]:
        c = self.config
        rays = self._rays(1)
        t, idx = self.scene.cast(np.zeros(3), rays)
        hit = np.isfinite(t)
        albedo, normal = _albedo_and_normal(self.scene, np.zeros(3), rays, np.where(hit, t, 0),
                                            idx)
        points = rays * np.where(hit, t, 0)[:, None]
        ranges = np.where(hit, np.linalg.norm(points, axis=1), 0.0)
        # the bounce sources: the centres of emitter_step x emitter_step patches
        grid = np.zeros((c.height, c.width), bool)
        half = c.emitter_step // 2
        grid[half::c.emitter_step, half::c.emitter_step] = True
        src = np.flatnonzero(grid.ravel() & hit)
        unit = rays / np.linalg.norm(rays, axis=1, keepdims=True)
        cos_i = np.abs(np.sum(normal * unit, axis=1))
        # a patch's solid angle seen from the camera, and the light it receives
        cos_axis = unit[:, 2]
        solid = (c.emitter_step / c.focal_px) ** 2 * cos_axis ** 3
        with np.errstate(divide='ignore', invalid='ignore'):
            irradiance = np.where(hit, cos_i / ranges ** 2, 0.0)
            # patch area = solid * r^2 / cos_i: the light it sends on is albedo * solid
            weight = albedo * irradiance * solid * ranges ** 2 / np.maximum(cos_i, 1e-6)
        out_re = np.zeros((len(self.wavenumbers), len(rays)))
        out_im = np.zeros_like(out_re)
        out_dc = np.zeros(len(rays))
        _bounce_kernel(points, normal, ranges, points[src], normal[src], weight[src],
                       ranges[src], self.wavenumbers, out_re, out_im, out_dc)
        receive = c.power * albedo * np.exp(1j * self.wavenumbers[:, None] * ranges[None, :])
        bounce = np.where(hit[None, :], receive * (out_re + 1j * out_im), 0)
        self._bounce_dc = (c.power * albedo * out_dc).reshape(c.height, c.width)
        return bounce.reshape(len(self.wavenumbers), c.height, c.width)

    def samples(self, noise: np.random.Generator | None) -> F64:
        """(n_freq * steps, H, W) samples, noise-free when ``noise`` is None."""
        c = self.config
        steps = c.phase_steps
        theta = 2 * np.pi * np.arange(steps) / steps
        dc = self._ambient + self._a_dc + self._bounce_dc
        out = np.empty((len(self.wavenumbers) * steps, c.height, c.width))
        for j in range(len(self.wavenumbers)):
            for k in range(steps):
                wave = np.real(self.direct[j] * np.exp(-1j * theta[k]))
                out[j * steps + k] = dc + c.contrast * wave
        if noise is not None:
            out = noise.poisson(np.maximum(out, 0)).astype(np.float64)
            out += noise.normal(0.0, c.read_noise, out.shape)
        return np.clip(np.rint(out), 0, c.full_well)

    def ground_truth(self) -> tuple[F32, F32, NDArray[np.uint8], NDArray[np.int32], F32]:
        """Depth Z, points, flags, labels and the mixed pixels' two surfaces on the
        rectified grid."""
        c = self.config
        P = self.camera.projection
        u, v = np.meshgrid(np.arange(c.width, dtype=float), np.arange(c.height, dtype=float))
        rays = np.stack([(u - P[0, 2]) / P[0, 0], (v - P[1, 2]) / P[1, 1], np.ones_like(u)],
                        -1).reshape(-1, 3)
        t, idx = self.scene.cast(np.zeros(3), rays)
        depth = np.where(np.isfinite(t), t, np.nan).reshape(c.height, c.width)
        points = (rays * depth.reshape(-1, 1)).reshape(c.height, c.width, 3)
        clean = self.samples(None)
        saturated = (clean >= c.full_well).any(axis=0)
        amplitude = np.abs(self.direct) * c.contrast
        low = (amplitude < GT_MIN_AMPLITUDE).all(axis=0)
        flags = (np.where(saturated, SATURATED, 0) | np.where(low, LOW_AMPLITUDE, 0)).astype(
            np.uint8)
        map_x, map_y = rectification_maps(self.camera, fixed_point=False)
        flags_rect = cv2.remap(flags, map_x, map_y, cv2.INTER_NEAREST)
        # a pixel whose rays span more than MIXED_SPAN of range sees two surfaces
        mixed = (self._far - self._near > MIXED_SPAN) & np.isfinite(self._near)
        norm = np.linalg.norm(rays, axis=1).reshape(c.height, c.width)
        surfaces = np.stack([np.where(mixed, self._near, np.nan),
                             np.where(mixed & np.isfinite(self._far), self._far, np.nan)])
        surfaces_rect = np.stack([cv2.remap(sf.astype(np.float32), map_x, map_y,
                                            cv2.INTER_NEAREST, borderValue=float('nan'))
                                  for sf in surfaces]) / norm[None].astype(np.float32)
        flags_out: NDArray[np.uint8] = np.asarray(flags_rect, np.uint8)
        return (depth.astype(np.float32), points.astype(np.float32), flags_out,
                idx.reshape(c.height, c.width), surfaces_rect.astype(np.float32))


def simulate_tof(config: ToFSimConfig) -> Iterator[ToFFrame]:
    """Render ``config.n_frames`` frames of the static scene, each with its own noise."""
    renderer = _Renderer(config)
    depth, points, flags, labels, mixed = renderer.ground_truth()
    names = renderer.scene.labels
    walls = np.isin(labels, [names.index('left_wall'), names.index('right_wall')])
    edge = renderer.corner
    corner = walls & (np.hypot(points[..., 0] - edge[0], points[..., 2] - edge[2])
                      < CORNER_REACH)
    period = 1e9 / config.frame_rate_hz
    for index in range(config.n_frames):
        rng = np.random.default_rng([config.seed, 1000 + index]) if config.noise else None
        yield ToFFrame(index=index, stamp_ns=config.start_stamp_ns + round(index * period),
                       samples=renderer.samples(rng).astype(np.uint16),
                       camera=renderer.camera, range_gt=renderer.range_raw, depth_gt=depth,
                       points_gt=points, flags_gt=flags, labels=labels, label_names=names,
                       mixed_gt=mixed, corner_gt=corner)
