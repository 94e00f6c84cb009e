"""Camera sequences for multi-view stereo: one moving camera, or a rig of cameras, looking at
a static scene, with exact depth and poses.

The scene is the stereo simulator's (:func:`~depth_nodes.sim.layout.build_scene`, frame 0,
so nothing in it moves). Each view is a rectified pinhole camera (no distortion: a
multi-view node takes rectified images) rendered with anti-aliasing, a vignette, a gain
that drifts from frame to frame (auto exposure) and Gaussian noise; its ground truth is Z
at the pixel centres in its own optical frame.

Motions (:data:`MOTIONS`):

* ``forward``: along the optical axis, ``step_m`` per frame, from :data:`FORWARD_START`
  behind the stereo simulator's camera (the epipole in the image: the hard case of a
  drone or a car);
* ``sideways``: along x, ``step_m`` per frame (an arm's wrist camera sweeping a shelf);
* ``orbit``: on a horizontal circle around a point of the scene, ``orbit_deg`` per frame,
  always looking at it;
* ``rig``: ``rig_cameras`` cameras side by side, ``rig_baseline_m`` apart along x, on a
  body that moves sideways by ``step_m`` per frame; camera 0 is the leftmost.

``pose_noise_deg`` / ``pose_noise_m`` perturb the poses the sequence *reports* (what a VIO
would publish), never the rendering, so the effect of pose errors can be measured.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.core.stamps import NS_PER_S
from depth_nodes.errors import ConfigError
from depth_nodes.sim.layout import build_scene
from depth_nodes.sim.scene import Scene

__all__ = ['MOTIONS', 'SequenceConfig', 'SequenceView', 'look_at', 'simulate_sequence',
           'visible_in']

F64 = NDArray[np.float64]
MOTIONS = ('forward', 'sideways', 'orbit', 'rig')
_LUMA = np.array([0.299, 0.587, 0.114])
#: The point the orbit circles (world frame: the middle of the scene's objects).
ORBIT_CENTRE = (0.0, 0.2, 3.0)
#: Where the forward motion starts, metres behind the origin: its nearest object is then
#: 1.4 m away, and 24 frames of 2 cm leave it 0.9 m away, inside the shipped depth range.
FORWARD_START = 0.5
#: Relative tolerance of the visibility test (a point is hidden when something is hit
#: this much before it).
VISIBILITY_RTOL = 1e-3


@dataclass(frozen=True)
class SequenceConfig:
    """Parameters of :func:`simulate_sequence` (see the module notes).

    Attributes:
        motion: One of :data:`MOTIONS`.
        width: Image width, pixels (>= 16).
        height: Image height, pixels (>= 16).
        n_frames: Time steps (>= 1); a rig gives ``rig_cameras`` views per step.
        seed: Scene, exposure and noise seed.
        focal_px: Focal length, pixels (None: 0.8 x width).
        step_m: Forward / sideways / rig translation per frame, metres.
        orbit_deg: Orbit angle per frame, degrees.
        rig_cameras: Cameras of the rig (>= 2).
        rig_baseline_m: Distance between neighbouring rig cameras, metres.
        noise_sigma: Gaussian image noise, grey levels.
        gain_jitter: Standard deviation of the per-view exposure gain around 1.
        vignetting: Fractional brightness fall-off at the image corners.
        supersample: Anti-aliasing samples per pixel and axis.
        pose_noise_deg: Standard deviation of the reported poses' rotation error, degrees.
        pose_noise_m: Standard deviation of the reported poses' position error per axis, m.
        frame_rate_hz: Spacing of the stamps.
        start_stamp_ns: Stamp of the first frame.
    """

    motion: str = 'sideways'
    width: int = 320
    height: int = 240
    n_frames: int = 8
    seed: int = 0
    focal_px: float | None = None
    step_m: float = 0.03
    orbit_deg: float = 1.0
    rig_cameras: int = 3
    rig_baseline_m: float = 0.08
    noise_sigma: float = 2.0
    gain_jitter: float = 0.04
    vignetting: float = 0.15
    supersample: int = 2
    pose_noise_deg: float = 0.0
    pose_noise_m: float = 0.0
    frame_rate_hz: float = 10.0
    start_stamp_ns: int = 1_700_000_000_000_000_000

    @property
    def focal(self) -> float:
        """The focal length in pixels."""
        return 0.8 * self.width if self.focal_px is None else float(self.focal_px)

    @property
    def intrinsics(self) -> Intrinsics:
        """Every view's pinhole camera (principal point at the image centre)."""
        return Intrinsics(self.focal, self.focal, (self.width - 1) / 2.0,
                          (self.height - 1) / 2.0, self.width, self.height)

    def validate(self) -> SequenceConfig:
        """Raises ConfigError naming the first invalid field; returns self."""
        checks = [
            ('motion', self.motion in MOTIONS, f'one of {", ".join(MOTIONS)}'),
            ('width', self.width >= 16, 'at least 16'),
            ('height', self.height >= 16, 'at least 16'),
            ('n_frames', self.n_frames >= 1, 'at least 1'),
            ('seed', self.seed >= 0, 'not negative'),
            ('focal_px', self.focal_px is None or self.focal_px > 0, 'positive'),
            ('rig_cameras', self.rig_cameras >= 2, 'at least 2'),
            ('supersample', 1 <= self.supersample <= 8, 'in 1..8'),
            ('noise_sigma', self.noise_sigma >= 0, 'not negative'),
            ('gain_jitter', 0 <= self.gain_jitter < 0.5, 'in [0, 0.5)'),
            ('vignetting', 0 <= self.vignetting < 1, 'in [0, 1)'),
            ('pose_noise_deg', self.pose_noise_deg >= 0, 'not negative'),
            ('pose_noise_m', self.pose_noise_m >= 0, 'not negative'),
            ('frame_rate_hz', self.frame_rate_hz > 0, 'positive'),
        ]
        for name, ok, wanted in checks:
            if not ok:
                raise ConfigError(f'sequence {name}={getattr(self, name)!r}: must be {wanted}')
        return self


@dataclass
class SequenceView:
    """One camera's view at one time step.

    Attributes:
        index: Time step, from 0.
        camera: Camera of the rig (0 for a single camera).
        stamp_ns: Stamp (every camera of a rig step shares it).
        image: (H, W) uint8 grey image.
        depth: (H, W) float32 Z in metres at the pixel centres, NaN where nothing is hit.
        pose: The true pose.
        reported_pose: The pose a pose source reports (``pose`` plus the configured noise).
        body_pose: The rig body's true pose (the camera's own for a single camera).
        intrinsics: The pinhole camera.
    """

    index: int
    camera: int
    stamp_ns: int
    image: NDArray[np.uint8]
    depth: NDArray[np.float32]
    pose: Pose
    reported_pose: Pose
    body_pose: Pose
    intrinsics: Intrinsics


def look_at(position: F64, target: F64) -> Pose:
    """A camera at ``position`` looking at ``target``, its x axis level (image y down)."""
    z = np.asarray(target, np.float64) - np.asarray(position, np.float64)
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return Pose(np.column_stack([x, y, z]), np.asarray(position, np.float64))


def rig_extrinsics(config: SequenceConfig) -> list[Pose]:
    """Each rig camera's pose on the body (camera 0 leftmost, all looking forward)."""
    return [Pose(np.eye(3), np.array([k * config.rig_baseline_m, 0.0, 0.0]))
            for k in range(config.rig_cameras)]


def body_pose(config: SequenceConfig, index: int) -> Pose:
    """The camera's (or the rig body's) true pose at time step ``index``."""
    if config.motion == 'forward':
        return Pose(np.eye(3), np.array([0.0, 0.0, config.step_m * index - FORWARD_START]))
    if config.motion in ('sideways', 'rig'):
        return Pose(np.eye(3), np.array([config.step_m * index, 0.0, 0.0]))
    centre = np.asarray(ORBIT_CENTRE, np.float64)
    radius = float(np.linalg.norm(centre[[0, 2]]))
    angle = math.radians(config.orbit_deg * index)
    position = centre + radius * np.array([math.sin(angle), 0.0, -math.cos(angle)])
    position[1] = 0.0
    return look_at(position, centre)


def _noisy(pose: Pose, rng: np.random.Generator, deg: float, metres: float) -> Pose:
    """``pose`` with a random rotation of about ``deg`` and a shift of about ``metres``."""
    if deg <= 0 and metres <= 0:
        return pose
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = math.radians(rng.normal(0.0, deg)) if deg > 0 else 0.0
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    delta = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)
    shift = rng.normal(0.0, metres, 3) if metres > 0 else np.zeros(3)
    return Pose(pose.rotation @ delta, pose.position + shift)


def pixel_rays(camera: Intrinsics, supersample: int) -> F64:
    """(H * W * s * s, 3) camera-frame rays (z = 1) through the samples of every pixel,
    ordered (v, u, sub_v, sub_u)."""
    offs = (np.arange(supersample) + 0.5) / supersample - 0.5
    v = np.arange(camera.height)[:, None, None, None] + offs[None, None, :, None]
    u = np.arange(camera.width)[None, :, None, None] + offs[None, None, None, :]
    v, u = np.broadcast_arrays(v, u)
    rays = np.stack([(u.ravel() - camera.cx) / camera.fx, (v.ravel() - camera.cy) / camera.fy,
                     np.ones(u.size)], axis=-1)
    return rays


def render_grey(scene: Scene, camera: Intrinsics, pose: Pose, config: SequenceConfig,
                rng: np.random.Generator) -> NDArray[np.uint8]:
    """The grey image a camera at ``pose`` records (exposure, vignette, noise)."""
    s = config.supersample
    dirs = pixel_rays(camera, s) @ pose.rotation.T
    rgb = scene.radiance(pose.position, dirs).reshape(camera.height, camera.width, s * s, 3)
    grey = rgb.mean(axis=2) @ _LUMA
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    r2 = ((u - camera.cx) / camera.width * 2) ** 2 + ((v - camera.cy) / camera.height * 2) ** 2
    vignette = 1.0 - config.vignetting * r2 / 2.0
    gain = 1.0 + config.gain_jitter * rng.standard_normal()
    image = 255.0 * gain * vignette * grey
    if config.noise_sigma > 0:
        image = image + rng.normal(0.0, config.noise_sigma, image.shape)
    out: NDArray[np.uint8] = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    return out


def render_depth(scene: Scene, camera: Intrinsics, pose: Pose) -> NDArray[np.float32]:
    """Z at the pixel centres of a camera at ``pose`` (NaN where nothing is hit)."""
    rays = pixel_rays(camera, 1)
    t, _ = scene.cast(pose.position, rays @ pose.rotation.T)  # rays have z = 1: t is Z
    depth: NDArray[np.float32] = np.where(np.isfinite(t), t, np.nan).reshape(
        camera.height, camera.width).astype(np.float32)
    return depth


def visible_in(scene: Scene, depth: NDArray[np.float32], camera: Intrinsics, pose: Pose,
               other_camera: Intrinsics, other_pose: Pose) -> NDArray[np.bool_]:
    """Which pixels of a view (its depth ``depth`` at ``pose``) another camera sees: inside
    its image and not hidden behind another surface."""
    rays = pixel_rays(camera, 1)
    points = pose.position + (rays * depth.reshape(-1, 1).astype(np.float64)) @ pose.rotation.T
    local = (points - other_pose.position) @ other_pose.rotation
    with np.errstate(invalid='ignore', divide='ignore'):
        u = other_camera.fx * local[:, 0] / local[:, 2] + other_camera.cx
        v = other_camera.fy * local[:, 1] / local[:, 2] + other_camera.cy
        inside = (local[:, 2] > 0) & (u > -0.5) & (u < other_camera.width - 0.5) & \
            (v > -0.5) & (v < other_camera.height - 0.5)
    seen = np.zeros(len(points), bool)
    sel = np.flatnonzero(inside & np.isfinite(points).all(axis=1))
    if len(sel):
        t, _ = scene.cast(other_pose.position, points[sel] - other_pose.position)
        seen[sel] = t >= 1.0 - VISIBILITY_RTOL
    return seen.reshape(depth.shape)


def simulate_sequence(config: SequenceConfig) -> Iterator[SequenceView]:
    """Render the views of ``config``, in time order (a rig's cameras in turn).

    Raises:
        ConfigError: Naming the invalid field.
    """
    config.validate()
    return _simulate(config)


def _simulate(config: SequenceConfig) -> Iterator[SequenceView]:
    camera = config.intrinsics
    scene = build_scene(config.seed, 0, config.focal, config.width, config.height)
    mounts = rig_extrinsics(config) if config.motion == 'rig' else [Pose()]
    pose_rng = np.random.default_rng([config.seed, 23])
    for index in range(config.n_frames):
        body = body_pose(config, index)
        reported_body = _noisy(body, pose_rng, config.pose_noise_deg, config.pose_noise_m)
        stamp = config.start_stamp_ns + round(index * NS_PER_S / config.frame_rate_hz)
        for k, mount in enumerate(mounts):
            pose = body.compose(mount)
            rng = np.random.default_rng([config.seed, index, k, 7])
            yield SequenceView(index, k, stamp, render_grey(scene, camera, pose, config, rng),
                               render_depth(scene, camera, pose), pose,
                               reported_body.compose(mount), body, camera)
