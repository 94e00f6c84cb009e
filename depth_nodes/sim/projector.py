"""Projector-camera simulator: a calibrated projector lights a scene, a camera images it.

Geometry (camera optical frame = world frame: X right, Y down, Z forward, metres). The
camera has ``K`` (focal ``focal_px``, centre of the image) and plumb_bob distortion
``camera_distortion``, ``R = I``, ``P = [K | 0]``. The projector is an inverse camera at
``(baseline_m, 0, 0)``, turned by ``projector_yaw_deg`` about its y axis, with intrinsics
``K_p`` (its principal point shifted so that its image is centred on the camera's view at
``aim_depth_m``) and distortion ``projector_distortion``. Its CameraInfo carries
``P = K_p [R | t]``, which maps camera-frame points to projector pixels (see
:mod:`depth_nodes.core.structured_light.triangulate`).

Image formation, per camera (super)sample: the camera ray is ray cast into the scene
(:class:`depth_nodes.sim.scene.Scene`); the hit point is projected into the projector (lens
distortion included) and a ray from the projector centre to it is cast to find projector
shadows. The projected pattern is the projector image with square pixels (fill factor 1)
blurred by a Gaussian defocus of ``defocus_sigma`` projector pixels, sampled at the point's
projector coordinate. Grey level = albedo x (ambient + power x pattern x cos(incidence) x
(aim_depth / distance)^2) -> supersample mean -> + Gaussian noise -> round and clip to uint8.

Ground truth at the camera pixel centres: depth Z, the exact projector coordinates
(column, row; pixel centres at integers) and a shadow map (0 lit, 255 in the projector's
shadow or facing away from it, 128 outside the projector's image or nothing hit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import CameraModel
from depth_nodes.errors import ConfigError
from depth_nodes.sim import texture as tx
from depth_nodes.sim.layout import rotation
from depth_nodes.sim.rig import distort_rays, undistort_pixels
from depth_nodes.sim.scene import Box, Material, Primitive, Rect, Scene, Sphere

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]
SHADOW_LIT = 0
SHADOW_OUTSIDE = 128
SHADOW_OCCLUDED = 255
#: A surface nearer than (1 - this) x the distance to the point shadows it.
SHADOW_RTOL = 1e-6
_LUMA = np.array([0.299, 0.587, 0.114])
_UP = 4  # projector image upsampling for the defocus blur


@dataclass(frozen=True)
class ProjectorSimConfig:
    """Parameters of the projector-camera simulator (see the module docstring).

    Attributes:
        width: Camera image width (>= 16).
        height: Camera image height (>= 16).
        focal_px: Camera focal length, pixels.
        camera_distortion: Camera plumb_bob coefficients (k1, k2, p1, p2, k3).
        projector_width: Projector width, pixels (>= 8).
        projector_height: Projector height, pixels (>= 8).
        projector_focal_px: Projector focal length, pixels.
        projector_distortion: Projector plumb_bob coefficients.
        baseline_m: Projector x offset from the camera, metres (nonzero).
        projector_yaw_deg: Projector rotation about its y axis, degrees (|yaw| <= 30).
        aim_depth_m: Depth at which the projector image is centred on the camera's view.
        ambient: Grey level of ambient light on albedo 1.
        projector_power: Grey level of a white pattern on albedo 1, head-on at ``aim_depth_m``.
        defocus_sigma: Projector defocus, Gaussian sigma in projector pixels (0 .. 8).
        noise_sigma: Camera noise, grey levels.
        supersample: Samples per camera pixel and axis (1 .. 4).
        speckle_density: Fraction of lit projector pixels of the speckle pattern.
        seed: Seed of the scene jitter, textures, speckle pattern and noise.
    """

    width: int = 640
    height: int = 480
    focal_px: float = 560.0
    camera_distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    projector_width: int = 640
    projector_height: int = 480
    projector_focal_px: float = 500.0
    projector_distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    baseline_m: float = 0.1
    projector_yaw_deg: float = 0.0
    aim_depth_m: float = 1.2
    ambient: float = 20.0
    projector_power: float = 200.0
    defocus_sigma: float = 0.7
    noise_sigma: float = 1.5
    supersample: int = 2
    speckle_density: float = 0.12
    seed: int = 0
    frame_id: str = field(default='sl_camera_optical_frame')

    def validate(self) -> ProjectorSimConfig:
        """Raise :class:`ConfigError` naming the first invalid field; returns ``self``."""
        checks = (
            ('width', self.width >= 16), ('height', self.height >= 16),
            ('focal_px', self.focal_px > 0), ('projector_width', self.projector_width >= 8),
            ('projector_height', self.projector_height >= 8),
            ('projector_focal_px', self.projector_focal_px > 0),
            ('camera_distortion', len(self.camera_distortion) == 5),
            ('projector_distortion', len(self.projector_distortion) == 5),
            ('baseline_m', self.baseline_m != 0 and math.isfinite(self.baseline_m)),
            ('projector_yaw_deg', abs(self.projector_yaw_deg) <= 30),
            ('aim_depth_m', self.aim_depth_m > 0), ('ambient', self.ambient >= 0),
            ('projector_power', self.projector_power > 0),
            ('defocus_sigma', 0 <= self.defocus_sigma <= 8),
            ('noise_sigma', self.noise_sigma >= 0), ('supersample', 1 <= self.supersample <= 4),
            ('speckle_density', 0 < self.speckle_density < 1), ('seed', self.seed >= 0),
        )
        for name, ok in checks:
            if not ok:
                raise ConfigError(f'ProjectorSimConfig.{name} is invalid: {getattr(self, name)!r}')
        return self


def projector_rig(config: ProjectorSimConfig) -> tuple[CameraModel, CameraModel]:
    """(camera, projector) models; the projector's ``P`` is ``K_p [R | t]``."""
    config.validate()
    w, h, f = config.width, config.height, config.focal_px
    K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
    camera = CameraModel(w, h, K, np.array(config.camera_distortion, dtype=np.float64),
                         np.eye(3), np.hstack([K, np.zeros((3, 1))]),
                         frame_id=config.frame_id)
    R = rotation(config.projector_yaw_deg).T  # camera -> projector frame
    centre = np.array([config.baseline_m, 0.0, 0.0])
    t = -R @ centre
    fp = config.projector_focal_px
    aim = R @ np.array([0.0, 0.0, config.aim_depth_m]) + t  # camera axis point, projector frame
    cx = (config.projector_width - 1) / 2 - fp * aim[0] / aim[2]
    cy = (config.projector_height - 1) / 2
    Kp = np.array([[fp, 0.0, cx], [0.0, fp, cy], [0.0, 0.0, 1.0]])
    projector = CameraModel(config.projector_width, config.projector_height, Kp,
                            np.array(config.projector_distortion, dtype=np.float64), np.eye(3),
                            Kp @ np.hstack([R, t[:, None]]), frame_id='sl_projector_optical_frame')
    return camera, projector


def _material(rng: np.random.Generator, period_m: float, lo: float, hi: float,
              kind: str = tx.NOISE) -> Material:
    texture = tx.Texture(kind, period_m, int(rng.integers(1 << 30)), 3, 1.0, 0.5)
    return Material((lo, lo, lo), (hi, hi, hi), texture)


def structured_light_scene(seed: int) -> Scene:
    """The test scene: slanted wall and floor, a 45-degree board, a sphere, a box (a step
    edge that casts projector shadows) and a dark low-albedo patch; 0.8 .. 2 m deep."""
    rng = np.random.default_rng([seed, 31])

    def jitter(v: tuple[float, float, float], scale: float = 0.02) -> F64:
        return np.asarray(v) + rng.uniform(-scale, scale, 3)

    def rect(label: str, mat: Material, centre: F64, rot: F64,
             half: tuple[float, float] = (np.inf, np.inf)) -> Rect:
        return Rect(label, mat, centre, rot @ [1.0, 0, 0], rot @ [0, -1.0, 0], half)

    prims: list[Primitive] = [
        rect('wall', _material(rng, 0.12, 0.35, 0.9), jitter((0.0, 0.0, 1.6)),
             rotation(rng.uniform(8, 14), rng.uniform(-4, 4))),
        Rect('floor', _material(rng, 0.15, 0.4, 0.85), jitter((0.0, 0.42, 1.0)),
             [1.0, 0, 0], rotation(0, rng.uniform(13, 17)) @ [0, 0, 1.0]),
        rect('slanted', _material(rng, 0.06, 0.35, 0.85, tx.CHECKER),
             jitter((-0.32, -0.12, 1.2)), rotation(rng.uniform(40, 50)), (0.13, 0.13)),
        Sphere('sphere', _material(rng, 0.05, 0.4, 0.9), jitter((0.24, 0.04, 1.0)), 0.14),
        Box('box', _material(rng, 0.04, 0.4, 0.7), jitter((-0.06, 0.22, 0.9)),
            rotation(rng.uniform(-10, 10)), (0.12, 0.08, 0.1)),
        rect('dark', _material(rng, 0.05, 0.12, 0.18), jitter((0.33, -0.25, 1.35)),
             np.eye(3), (0.08, 0.06)),
    ]
    return Scene(tuple(prims))


def _sample_grid(width: int, height: int, supersample: int) -> F64:
    """(H*W*s*s, 2) sample positions ordered (v, u, sub_v, sub_u); centres are integers."""
    offs = (np.arange(supersample) + 0.5) / supersample - 0.5
    v = np.arange(height)[:, None, None, None] + offs[None, None, :, None]
    u = np.arange(width)[None, :, None, None] + offs[None, None, None, :]
    v, u = np.broadcast_arrays(v, u)
    return np.column_stack([u.ravel(), v.ravel()]).astype(np.float64)


@dataclass
class _Lighting:
    """Per sample: albedo, projector coordinates and projector irradiance factor."""

    albedo: F64
    u: F64
    v: F64
    gain: F64  # cos(incidence) / distance^2, 0 in shadow / outside
    depth: F64
    shadow: NDArray[np.uint8]


def _lighting(scene: Scene, camera: CameraModel, projector: CameraModel, R: F64, t: F64,
              pixels: F64, aim_depth: float) -> _Lighting:
    rays = undistort_pixels(camera, pixels)  # z = 1: t is the depth
    depth, idx = scene.cast(np.zeros(3), rays)
    hit = np.isfinite(depth)
    points = rays * np.where(hit, depth, 1.0)[:, None]
    albedo = np.zeros(len(rays))
    normals = np.zeros((len(rays), 3))
    for k, prim in enumerate(scene.primitives):
        sel = np.flatnonzero(idx == k)
        if len(sel):
            n, s, tt = prim.surface(points[sel])
            normals[sel] = n
            albedo[sel] = prim.material.reflectance(s, tt) @ _LUMA
    proj_pts = points @ R.T + t
    front = hit & (proj_pts[:, 2] > 1e-6)
    uv = np.full((len(rays), 2), np.nan)
    if front.any():
        uv[front] = distort_rays(projector, proj_pts[front])
    inside = front & (uv[:, 0] >= -0.5) & (uv[:, 0] <= projector.width - 0.5) & (
        uv[:, 1] >= -0.5) & (uv[:, 1] <= projector.height - 0.5)
    centre = -R.T @ t
    to_proj = centre - points
    dist = np.linalg.norm(to_proj, axis=1)
    cos = np.einsum('ij,ij->i', normals, to_proj) / np.maximum(dist, 1e-12)
    t_occ, _ = scene.cast(centre, np.where(hit[:, None], -to_proj, 1.0))
    occluded = hit & ((t_occ < 1.0 - SHADOW_RTOL) | (cos <= 0))
    shadow = np.full(len(rays), SHADOW_OUTSIDE, dtype=np.uint8)
    shadow[inside] = SHADOW_LIT
    shadow[inside & occluded] = SHADOW_OCCLUDED
    falloff = (aim_depth / np.maximum(dist, 1e-6))**2
    gain = np.where(shadow == SHADOW_LIT, np.maximum(cos, 0) * falloff, 0.0)
    return _Lighting(albedo, uv[:, 0], uv[:, 1], gain, np.where(hit, depth, np.nan), shadow)


@dataclass
class StructuredLightCapture:
    """A rendered pattern sequence with exact ground truth at the camera pixel centres.

    Attributes:
        images: (F, H, W) uint8 camera images, one per pattern.
        depth: (H, W) float32 Z in metres (NaN: nothing hit).
        u: (H, W) float32 projector column (NaN: nothing hit or behind the projector).
        v: (H, W) float32 projector row.
        shadow: (H, W) uint8, 0 lit, 255 projector shadow, 128 outside its image.
        camera: The camera model.
        projector: The projector model (``P = K_p [R | t]``).
    """

    images: NDArray[np.uint8]
    depth: F32
    u: F32
    v: F32
    shadow: NDArray[np.uint8]
    camera: CameraModel
    projector: CameraModel


class ProjectorCameraSim:
    """Renders pattern sequences of one static scene (ray casting done once).

    Args:
        config: Simulator parameters (validated).
        scene: The scene; :func:`structured_light_scene` of ``config.seed`` by default.
    """

    def __init__(self, config: ProjectorSimConfig, scene: Scene | None = None) -> None:
        self.config = config.validate()
        self.camera, self.projector = projector_rig(config)
        self.scene = scene if scene is not None else structured_light_scene(config.seed)
        P = self.projector.P
        Kinv = np.linalg.inv(self.projector.K)
        self._R, self._t = Kinv @ P[:, :3], Kinv @ P[:, 3]
        w, h, s = config.width, config.height, config.supersample
        self._samples = _lighting(self.scene, self.camera, self.projector, self._R, self._t,
                                  _sample_grid(w, h, s), config.aim_depth_m)
        self._centres = _lighting(self.scene, self.camera, self.projector, self._R, self._t,
                                  _sample_grid(w, h, 1), config.aim_depth_m)
        lit = self._samples.gain > 0
        self._map_u = np.where(lit, _UP * self._samples.u + (_UP - 1) / 2, -10).astype(np.float32)
        self._map_v = np.where(lit, _UP * self._samples.v + (_UP - 1) / 2, -10).astype(np.float32)

    def illumination(self, pattern: NDArray[np.floating]) -> F64:
        """Projected intensity in [0, 1] at every sample: defocused ``pattern`` (H_p, W_p)."""
        big: NDArray[Any] = np.repeat(np.repeat(np.asarray(pattern, dtype=np.float32), _UP, 0),
                                      _UP, 1)
        if self.config.defocus_sigma > 0:
            big = cv2.GaussianBlur(big, (0, 0), self.config.defocus_sigma * _UP)
        cols = self.config.width
        out = cv2.remap(big, self._map_u.reshape(-1, cols), self._map_v.reshape(-1, cols),
                        cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return np.asarray(out, dtype=np.float64).ravel()

    def render(self, patterns: NDArray[np.floating], *, noise_seed: int = 0,
               noise_sigma: float | None = None) -> NDArray[np.uint8]:
        """Camera images (F, H, W) uint8 of the projector images ``patterns`` (F, H_p, W_p).

        Raises:
            ConfigError: Patterns of the wrong size.
        """
        c = self.config
        pats = np.asarray(patterns)
        if pats.ndim != 3 or pats.shape[1:] != (c.projector_height, c.projector_width):
            raise ConfigError(f'patterns must be (F, {c.projector_height}, '
                              f'{c.projector_width}), got {pats.shape}')
        sigma = c.noise_sigma if noise_sigma is None else noise_sigma
        rng = np.random.default_rng([c.seed, noise_seed, 17])
        s2 = c.supersample**2
        out = np.empty((len(pats), c.height, c.width), dtype=np.uint8)
        for i, pattern in enumerate(pats):
            light = self.illumination(pattern)
            grey = self._samples.albedo * (c.ambient + c.projector_power * self._samples.gain
                                           * light)
            img = grey.reshape(c.height, c.width, s2).mean(axis=2)
            if sigma > 0:
                img = img + rng.normal(0.0, sigma, img.shape)
            out[i] = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        return out

    def capture(self, patterns: NDArray[np.floating], *, noise_seed: int = 0
                ) -> StructuredLightCapture:
        """Render ``patterns`` and attach the ground truth."""
        c = self.config
        g = self._centres
        shape = (c.height, c.width)
        return StructuredLightCapture(
            self.render(patterns, noise_seed=noise_seed),
            g.depth.reshape(shape).astype(np.float32), g.u.reshape(shape).astype(np.float32),
            g.v.reshape(shape).astype(np.float32), g.shadow.reshape(shape), self.camera,
            self.projector)


def reference_plane_scene(depth: float, albedo: float = 0.5) -> Scene:
    """A fronto-parallel plane of uniform ``albedo`` at ``depth`` (speckle reference)."""
    a = (albedo, albedo, albedo)
    flat = Material(a, a, tx.Texture(tx.WEAK, 1.0, contrast=0.0, mean=1.0))
    return Scene((Rect('reference', flat, [0.0, 0.0, depth], [1.0, 0, 0], [0, -1.0, 0]),))
