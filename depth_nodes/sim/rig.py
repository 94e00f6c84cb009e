"""The simulated stereo rig: random but realistic calibrations, and exact lens maths.

Conventions are those of sensor_msgs/CameraInfo (see :mod:`depth_nodes.core.camera`):
``x_rect = R @ x_raw``, ``K`` and ``D`` describe the raw (distorted) image, ``P`` the
rectified one. The world frame of the simulator is the left rectified camera frame.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import EQUIDISTANT, PLUMB_BOB, RATIONAL_POLYNOMIAL, CameraModel

FloatArray = NDArray[np.float64]

#: Undistortion iterations stop at 1e-10 (OpenCV's reprojection criterion) or 200 steps.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-10)


def undistort_pixels(camera: CameraModel, pixels: FloatArray) -> FloatArray:
    """Rays in the raw camera frame, ``(x, y, 1)``, that the lens images at ``pixels``.

    Args:
        camera: Raw camera (``K``, ``D``, ``distortion_model``).
        pixels: (N, 2) raw pixel coordinates (pixel centres are integers).

    Returns:
        (N, 3) float64 rays with z = 1 (re-distorting them gives back ``pixels`` to
        about 1e-9 px).
    """
    pts = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    if camera.distortion_model == EQUIDISTANT:
        xy = cv2.fisheye.undistortPoints(pts, camera.K, camera.D, criteria=_UNDISTORT_CRITERIA)
    else:
        xy = cv2.undistortPoints(pts, camera.K, camera.D, criteria=_UNDISTORT_CRITERIA)
    xy = xy.reshape(-1, 2)
    return np.column_stack([xy, np.ones(len(xy))])


def distort_rays(camera: CameraModel, rays: FloatArray) -> FloatArray:
    """(N, 2) raw pixel coordinates of rays (N, 3) given in the raw camera frame."""
    obj = np.ascontiguousarray(rays, dtype=np.float64).reshape(1, -1, 3)
    zero = np.zeros((3, 1))
    if camera.distortion_model == EQUIDISTANT:
        px, _ = cv2.fisheye.projectPoints(obj, zero, zero, camera.K, camera.D)
    else:
        px, _ = cv2.projectPoints(obj, zero, zero, camera.K, camera.D)
    return np.asarray(px, dtype=np.float64).reshape(-1, 2)


def _random_rotation(rng: np.random.Generator, angle_deg: float) -> FloatArray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = np.radians(angle_deg * rng.uniform(0.8, 1.2))
    rot, _ = cv2.Rodrigues(axis * angle)
    return np.asarray(rot, dtype=np.float64)


def _random_distortion(rng: np.random.Generator, model: str) -> FloatArray:
    p1, p2 = rng.uniform(-1e-3, 1e-3, 2)
    if model == PLUMB_BOB:
        return np.array(
            [rng.uniform(-0.3, -0.2), rng.uniform(0.05, 0.1), p1, p2, rng.uniform(-0.005, 0.005)]
        )
    if model == RATIONAL_POLYNOMIAL:
        k4 = rng.uniform(0.3, 0.6)
        return np.array(
            [
                k4 - rng.uniform(0.2, 0.3),
                rng.uniform(0.0, 0.05),
                p1,
                p2,
                0.0,
                k4,
                rng.uniform(0.0, 0.05),
                0.0,
            ]
        )
    return np.array(
        [rng.uniform(-0.03, 0.03), rng.uniform(-0.01, 0.01), rng.uniform(-0.005, 0.005), 0.0]
    )


def _rect_border_in_raw(camera: CameraModel) -> FloatArray:
    """Raw pixel positions of the rectified image's border pixel centres, (N, 2)."""
    w, h = camera.width, camera.height
    us = np.arange(w, dtype=np.float64)
    vs = np.arange(h, dtype=np.float64)
    border = np.concatenate(
        [
            np.column_stack([us, np.zeros(w)]),
            np.column_stack([us, np.full(w, h - 1.0)]),
            np.column_stack([np.zeros(h), vs]),
            np.column_stack([np.full(h, w - 1.0), vs]),
        ]
    )
    return rect_to_raw(camera, border)


def rect_to_raw(camera: CameraModel, pixels: FloatArray) -> FloatArray:
    """Raw pixel positions (N, 2) of rectified pixels (N, 2) of the same camera."""
    k_rect = camera.P[:, :3]
    rays = np.column_stack([pixels, np.ones(len(pixels))]) @ np.linalg.inv(k_rect).T
    return distort_rays(camera, rays @ camera.R)  # R^T applied to row vectors


def make_rig(
    *,
    width: int,
    height: int,
    focal_px: float,
    baseline_m: float,
    right_cx_offset: float,
    distortion_model: str,
    rotation_deg: float,
    seed: int,
    distortion_scale: float = 1.0,
) -> tuple[CameraModel, CameraModel]:
    """Left and right cameras of a simulated rig (deterministic from ``seed``).

    The rectified cameras have ``K_rect = [[f, 0, cx], [0, f, cy], [0, 0, 1]]`` with
    ``cx, cy = (W - 1) / 2, (H - 1) / 2`` (right: ``cx + right_cx_offset``). Each raw
    camera gets a random rotation of about ``rotation_deg`` (own axis), realistic
    distortion of ``distortion_model``, a principal point a few pixels off and a focal
    length that starts 1-3 % shorter than ``f`` and is shortened further in 2 % steps
    until the whole rectified image maps inside the raw image, so rectified images have
    no black border.

    Args:
        width: Image width in pixels.
        height: Image height in pixels.
        focal_px: Rectified focal length ``f`` in pixels.
        baseline_m: Baseline in metres (right ``P[0, 3] = -f * baseline_m``).
        right_cx_offset: ``cx_right - cx_left`` of the rectified cameras.
        distortion_model: ``plumb_bob``, ``rational_polynomial`` or ``equidistant``.
        rotation_deg: Typical raw -> rectified rotation angle in degrees.
        seed: Random seed.
        distortion_scale: Factor on every distortion coefficient (0: a pinhole camera that
            still needs its rotation R undone).

    Returns:
        (left, right) camera models in the CameraInfo conventions.
    """
    rng = np.random.default_rng([seed, 3])
    w, h, f = width, height, focal_px
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    cameras = []
    for side, cx_rect in (('left', cx), ('right', cx + right_cx_offset)):
        p = np.array([[f, 0.0, cx_rect, 0.0], [0.0, f, cy, 0.0], [0.0, 0.0, 1.0, 0.0]])
        if side == 'right':
            p[0, 3] = -f * baseline_m
        rot = _random_rotation(rng, rotation_deg)
        dist = _random_distortion(rng, distortion_model) * distortion_scale
        fx = f * (1.0 - rng.uniform(0.01, 0.03))
        fy = fx * (1.0 + rng.uniform(-0.004, 0.004))
        centre = (cx_rect + rng.uniform(-4, 4) * w / 640, cy + rng.uniform(-4, 4) * h / 480)
        for attempt in range(30):
            shrink = 0.98**attempt
            k = np.array(
                [[fx * shrink, 0.0, centre[0]], [0.0, fy * shrink, centre[1]], [0.0, 0.0, 1.0]]
            )
            cam = CameraModel(
                w, h, k, dist, rot, p, distortion_model, frame_id=f'{side}_camera_optical_frame'
            )
            raw = _rect_border_in_raw(cam)
            if raw.min() >= 0 and raw[:, 0].max() <= w - 1 and raw[:, 1].max() <= h - 1:
                break
        cameras.append(cam)
    return cameras[0], cameras[1]
