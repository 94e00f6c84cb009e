"""Triangulation of decoded projector coordinates with the calibrated projector-camera pair.

The projector is an inverse camera. Its calibration is a :class:`CameraModel` (what its
CameraInfo carries) whose ``K`` and ``D`` are its intrinsics and lens distortion and whose
``P = K_p [R | t]`` maps points of the *camera's* optical frame to projector pixels:
``x_p = R X_c + t``. For a projector displaced by ``b`` metres along the camera's x axis
without rotation this is ``P[0, 3] = -fx_p * b``, the stereo right-camera convention of
sensor_msgs/CameraInfo.

Depth is Z in the camera's optical frame at each raw camera pixel (REP 118), from the
camera ray through the undistorted pixel centre and either the plane of the decoded
projector column (ray-plane; needs an undistorted projector) or the ray of the decoded
projector pixel (ray-ray, least-squares midpoint; any projector distortion).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import EQUIDISTANT, CameraModel
from depth_nodes.core.geometry.rotation import ROTATION_TOLERANCE, rotation_error
from depth_nodes.errors import CalibrationError

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]
_UNDISTORT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)


@dataclass(frozen=True)
class ProjectorGeometry:
    """A calibrated camera and projector.

    Attributes:
        camera: The camera of the delivered images (binning/ROI applied).
        projector: The projector (``K``, ``D``, size; ``P`` holds its pose).
        rotation: (3, 3) R, camera frame -> projector frame.
        translation: (3,) t, so that ``x_p = R X_c + t``.
    """

    camera: CameraModel
    projector: CameraModel
    rotation: F64
    translation: F64

    @classmethod
    def from_models(cls, camera: CameraModel, projector: CameraModel) -> ProjectorGeometry:
        """Validate both models and decompose the projector's pose from its ``P``.

        Raises:
            CalibrationError: Either model invalid, projector ``P`` all zero, or
                ``K_p^-1 P[:, :3]`` not a rotation.
        """
        camera.validate()
        projector.validate()
        P = np.asarray(projector.P, dtype=np.float64).reshape(3, 4)
        if not P.any():
            raise CalibrationError('projector P is all zero: it must be K_p [R | t], the '
                                   'projection of camera-frame points into projector pixels')
        K_inv = np.linalg.inv(np.asarray(projector.K, dtype=np.float64).reshape(3, 3))
        R = K_inv @ P[:, :3]
        t = K_inv @ P[:, 3]
        err = rotation_error(R)
        if err > ROTATION_TOLERANCE:
            raise CalibrationError(f'projector P is not K_p [R | t] with R a rotation: '
                                   f'|R R^T - I| = {err:.3g}, det {np.linalg.det(R):.6g}')
        return cls(camera, projector, R, t)

    @property
    def centre(self) -> F64:
        """Projector centre in the camera frame, ``-R^T t`` (metres)."""
        out: F64 = -self.rotation.T @ self.translation
        return out

    @property
    def baseline(self) -> float:
        """Distance between the camera and projector centres, metres."""
        return float(np.linalg.norm(self.translation))


def pixel_rays(camera: CameraModel, pixels: F64) -> F64:
    """Undistorted rays ``(x, y, 1)`` (N, 3) of raw pixels (N, 2) of ``camera``."""
    pts = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    K = np.asarray(camera.K, dtype=np.float64).reshape(3, 3)
    D = np.asarray(camera.D, dtype=np.float64).ravel()
    if not D.any():
        xy = (pts.reshape(-1, 2) - K[:2, 2]) @ np.linalg.inv(K[:2, :2]).T
    elif camera.distortion_model == EQUIDISTANT:
        xy = cv2.fisheye.undistortPoints(pts, K, D, criteria=_UNDISTORT)
        xy = xy.reshape(-1, 2)
    else:
        xy = cv2.undistortPoints(pts, K, D, criteria=_UNDISTORT).reshape(-1, 2)
    return np.column_stack([xy, np.ones(len(xy))])


def camera_rays(camera: CameraModel) -> F64:
    """(H, W, 3) rays of every pixel centre of ``camera`` (build once, reuse)."""
    u, v = np.meshgrid(np.arange(camera.width, dtype=np.float64),
                       np.arange(camera.height, dtype=np.float64))
    rays = pixel_rays(camera, np.column_stack([u.ravel(), v.ravel()]))
    return rays.reshape(camera.height, camera.width, 3)


def triangulate_columns(rays: F64, u: F32, geometry: ProjectorGeometry) -> F32:
    """Depth from the plane of each decoded projector column (ray-plane).

    Args:
        rays: (H, W, 3) camera rays from :func:`camera_rays`.
        u: (H, W) projector columns, NaN where unknown.
        geometry: The calibration; the projector must be undistorted.

    Returns:
        (H, W) float32 Z in metres, NaN where unknown or behind either device.

    Raises:
        CalibrationError: The projector has distortion (a column is then not a plane).
    """
    if np.asarray(geometry.projector.D).any():
        raise CalibrationError('columns-only triangulation needs an undistorted projector '
                               '(projector D all zero); decode both axes instead')
    if rays.shape[:2] != np.shape(u):
        raise CalibrationError(f'rays {rays.shape[:2]} and coordinates {np.shape(u)} differ')
    K = np.asarray(geometry.projector.K, dtype=np.float64).reshape(3, 3)
    R, t = geometry.rotation, geometry.translation
    fx, skew, cx = K[0, 0], K[0, 1], K[0, 2]
    # The column's plane in the projector frame: fx X + skew Y + (cx - u) Z = 0.
    a = fx * R[0] + skew * R[1]
    c = cx - u.astype(np.float64)
    denom = rays @ a + c * (rays @ R[2])
    numer = -(fx * t[0] + skew * t[1] + c * t[2])
    with np.errstate(divide='ignore', invalid='ignore'):
        depth = numer / denom
    return _finish(depth, rays, geometry)


def triangulate_pixels(rays: F64, u: F32, v: F32, geometry: ProjectorGeometry) -> F32:
    """Depth from the camera ray and the projector ray of (u, v) (least-squares midpoint).

    Args:
        rays: (H, W, 3) camera rays.
        u: (H, W) projector columns, NaN where unknown.
        v: (H, W) projector rows, NaN where unknown.
        geometry: The calibration (projector distortion is undone).

    Returns:
        (H, W) float32 Z in metres, NaN where unknown.
    """
    h, w = np.shape(u)
    ok = np.isfinite(u) & np.isfinite(v)
    proj = np.full((h, w, 3), np.nan)
    pix = np.column_stack([u[ok], v[ok]]).astype(np.float64)
    proj[ok] = pixel_rays(geometry.projector, pix) @ geometry.rotation  # R^T on row vectors
    centre = geometry.centre
    rr = np.einsum('hwk,hwk->hw', rays, rays)
    rd = np.einsum('hwk,hwk->hw', rays, proj)
    dd = np.einsum('hwk,hwk->hw', proj, proj)
    rc = rays @ centre
    dc = proj @ centre
    with np.errstate(divide='ignore', invalid='ignore'):
        lam = (rc * dd - rd * dc) / (rr * dd - rd * rd)
    return _finish(lam, rays, geometry)


def epipolar_distance(rays: F64, u: F32, v: F32, geometry: ProjectorGeometry) -> F32:
    """How far, in projector pixels, each decoded projector pixel lies from the epipolar
    line of its camera pixel.

    The points of a camera ray land, in the projector's undistorted image, on the line
    through the camera centre's image ``K_p t`` and the ray's vanishing point ``K_p R r``.
    A true code lies on it to within its noise; a false code (a wrong bit, a reflection,
    a second light source) rarely does, and ray-ray triangulation would give it a depth
    between the two rays all the same.

    Args:
        rays: (H, W, 3) camera rays.
        u: (H, W) projector columns, NaN where unknown.
        v: (H, W) projector rows, NaN where unknown.
        geometry: The calibration (projector distortion is undone).

    Returns:
        (H, W) float32 distances, NaN where a coordinate is unknown.
    """
    h, w = np.shape(u)
    ok = np.isfinite(u) & np.isfinite(v)
    out = np.full((h, w), np.nan, dtype=np.float32)
    if not ok.any():
        return out
    K = np.asarray(geometry.projector.K, dtype=np.float64).reshape(3, 3)
    pix = np.column_stack([u[ok], v[ok]]).astype(np.float64)
    points = pixel_rays(geometry.projector, pix) @ K.T  # undistorted, homogeneous
    epipole = K @ geometry.translation
    vanishing = rays[ok] @ (K @ geometry.rotation).T
    lines = np.cross(epipole[None, :], vanishing)
    with np.errstate(divide='ignore', invalid='ignore'):
        dist = np.abs(np.einsum('nk,nk->n', lines, points)) / np.hypot(lines[:, 0],
                                                                      lines[:, 1])
    out[ok] = dist.astype(np.float32)
    return out


def _finish(lam: F64, rays: F64, geometry: ProjectorGeometry) -> F32:
    """Depth ``lam * ray_z``; NaN where non-finite, beyond float32 or not in front of
    both devices."""
    depth = lam * rays[..., 2]
    with np.errstate(invalid='ignore', over='ignore'):
        points = rays * lam[..., None]
        z_proj = points @ geometry.rotation[2] + geometry.translation[2]
        bad = ~(depth < np.finfo(np.float32).max) | (depth <= 0) | ~(z_proj > 0)
    return np.where(bad, np.nan, depth).astype(np.float32)


def points_on_rays(rays: F64, depth: F32) -> F32:
    """(H, W, 3) float32 points ``Z * ray`` (rays with z = 1), NaN where depth is NaN."""
    return (rays * depth[..., None]).astype(np.float32)
