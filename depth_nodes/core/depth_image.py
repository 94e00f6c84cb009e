"""Depth images (REP 118) as depth_image_proc processes them: units, points, disparity
and registration into another camera (no ROS).

A depth image holds Z, the distance along the camera's optical axis: 32FC1 in metres with
NaN (or 0, or anything not finite and positive) unknown, or 16UC1 in millimetres with 0
unknown. The functions here work on metres as float32 with NaN unknown; :func:`to_metres`
and :func:`from_metres` convert at the message boundary.

Intrinsics come from the rectified projection ``P`` of the image's CameraInfo (binning
and ROI applied), as image_geometry's ``PinholeCameraModel`` reads them. When the image's
size differs from the CameraInfo's (a depth image registered at another resolution, a
colour image of another size), :func:`intrinsics` scales them to the image, pixel centres
mapping to pixel centres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.reproject import depth_to_millimetres
from depth_nodes.errors import ArgumentError, CalibrationError

__all__ = ['DEPTH_ENCODINGS', 'Intrinsics', 'colour_at_depth_pixels', 'depth_to_disparity',
           'depth_to_points', 'from_metres', 'intrinsics', 'register_depth', 'to_metres']

#: The depth encodings of REP 118.
DEPTH_ENCODINGS = ('16UC1', '32FC1')

FloatImage = NDArray[np.float32]


@dataclass(frozen=True)
class Intrinsics:
    """A rectified pinhole camera at one image size (pixel centres are integers).

    Attributes:
        fx: Focal length along x, pixels.
        fy: Focal length along y, pixels.
        cx: Principal point x, pixels.
        cy: Principal point y, pixels.
        width: Image width the values are for.
        height: Image height the values are for.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int


def intrinsics(camera: CameraModel, shape: tuple[int, int] | None = None) -> Intrinsics:
    """The pinhole intrinsics of the images a CameraInfo describes, optionally scaled to
    another image size.

    Args:
        camera: The camera (``P`` used; binning and ROI applied here).
        shape: (height, width) of the image the intrinsics are for; ``None`` for the
            CameraInfo's own (binned) size. Scaling maps the pixel centres of one size onto
            those of the other: ``cx' = (cx + 0.5) * sx - 0.5``.

    Raises:
        CalibrationError: Focal lengths that are not positive.
    """
    model = camera.binned()
    fx, fy, cx, cy = model.fx, model.fy, model.cx, model.cy
    if not (fx > 0 and fy > 0):
        raise CalibrationError(f'rectified focal lengths must be positive, got fx {fx:g}, '
                               f'fy {fy:g}')
    width, height = int(model.width), int(model.height)
    if shape is None or (int(shape[0]), int(shape[1])) == (height, width):
        return Intrinsics(fx, fy, cx, cy, width, height)
    sy, sx = shape[0] / height, shape[1] / width
    return Intrinsics(fx * sx, fy * sy, (cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5,
                      int(shape[1]), int(shape[0]))


def to_metres(pixels: NDArray[Any], encoding: str) -> FloatImage:
    """A depth image's pixels as float32 metres, NaN unknown.

    Args:
        pixels: (H, W) uint16 millimetres (``16UC1``) or float32 metres (``32FC1``).
        encoding: ``16UC1`` or ``32FC1``.

    Raises:
        ArgumentError: Another encoding, or pixels that do not fit it.
    """
    _check_encoding(encoding)
    arr = np.asarray(pixels)
    if arr.ndim != 2:
        raise ArgumentError(f'a depth image is (H, W), got shape {arr.shape}')
    if encoding == '16UC1':
        if arr.dtype != np.uint16:
            raise ArgumentError(f'16UC1 depth must be uint16, got {arr.dtype}')
        out = arr.astype(np.float32) * np.float32(0.001)
        out[arr == 0] = np.nan
        return out
    if arr.dtype != np.float32:
        raise ArgumentError(f'32FC1 depth must be float32, got {arr.dtype}')
    with np.errstate(invalid='ignore'):
        known = np.isfinite(arr) & (arr > 0)
    return np.where(known, arr, np.float32(np.nan)).astype(np.float32)


def from_metres(depth: NDArray[np.floating[Any]], encoding: str) -> NDArray[Any]:
    """Metres (NaN unknown) in a REP 118 encoding: 16UC1 millimetres rounded, 0 unknown
    (and beyond 65.535 m); 32FC1 metres, NaN unknown."""
    _check_encoding(encoding)
    if encoding == '16UC1':
        return depth_to_millimetres(depth)
    out = np.asarray(depth, dtype=np.float32)
    with np.errstate(invalid='ignore'):
        return np.where(out > 0, out, np.float32(np.nan)).astype(np.float32)


def _check_encoding(encoding: str) -> None:
    if encoding not in DEPTH_ENCODINGS:
        raise ArgumentError(f'depth encoding must be one of {", ".join(DEPTH_ENCODINGS)}, '
                            f'got {encoding!r}')


def _check_depth(depth: NDArray[Any], camera: Intrinsics) -> NDArray[np.float32]:
    arr = np.asarray(depth, dtype=np.float32)
    if arr.shape != (camera.height, camera.width):
        raise ArgumentError(f'depth is {arr.shape[1] if arr.ndim == 2 else arr.shape}'
                            f'{"x" + str(arr.shape[0]) if arr.ndim == 2 else ""} but the '
                            f'intrinsics are for {camera.width}x{camera.height}')
    return arr


def depth_to_points(depth: NDArray[np.floating[Any]], camera: Intrinsics) -> FloatImage:
    """The organised 3-D points of a depth image, in its camera's optical frame.

    Args:
        depth: (H, W) Z in metres, NaN unknown.
        camera: Intrinsics of the depth image (:func:`intrinsics`).

    Returns:
        (H, W, 3) float32 x, y, z; NaN where the depth is unknown.
    """
    z = _check_depth(depth, camera).astype(np.float64)
    u = (np.arange(camera.width) - camera.cx) / camera.fx
    v = (np.arange(camera.height) - camera.cy) / camera.fy
    return np.dstack([z * u[None, :], z * v[:, None], z]).astype(np.float32)


def depth_to_disparity(depth: NDArray[np.floating[Any]], *, focal: float,
                       baseline: float) -> FloatImage:
    """Disparity ``f * B / Z`` of each known depth (NaN where unknown).

    Raises:
        ArgumentError: ``focal * baseline`` not positive.
    """
    if not focal * baseline > 0:
        raise ArgumentError(f'focal * baseline must be positive, got {focal:g} * {baseline:g}')
    z = np.asarray(depth, dtype=np.float64)
    with np.errstate(divide='ignore', invalid='ignore'):
        out: FloatImage = np.where(z > 0, focal * baseline / z, np.nan).astype(np.float32)
    return out


def colour_at_depth_pixels(colour: NDArray[Any], shape: tuple[int, int]) -> NDArray[Any]:
    """A colour image resampled (nearest pixel) to a depth image's size, pixel centres
    mapping to pixel centres; the image itself when the sizes agree."""
    height, width = colour.shape[:2]
    if (height, width) == tuple(shape):
        return colour
    rows = np.clip(np.floor((np.arange(shape[0]) + 0.5) * height / shape[0]), 0, height - 1)
    cols = np.clip(np.floor((np.arange(shape[1]) + 0.5) * width / shape[1]), 0, width - 1)
    out: NDArray[Any] = colour[rows.astype(np.intp)[:, None], cols.astype(np.intp)[None, :]]
    return out


def register_depth(depth: NDArray[np.floating[Any]], source: Intrinsics, target: Intrinsics,
                   rotation: NDArray[np.floating[Any]],
                   translation: NDArray[np.floating[Any]]) -> FloatImage:
    """Depth seen by another camera: each depth pixel moved into the target camera.

    Each known pixel's point ``X`` goes to ``R X + t`` in the target's optical frame. The
    pixel's footprint (its corners at its depth) is projected there and every target pixel
    whose centre it covers gets the point's Z; a footprint covering no centre (target
    coarser than the source) gives its Z to the target pixel holding its centre. Where
    several points land on one pixel the nearest wins (z-buffer), so a foreground edge
    hides the background behind it.

    Args:
        depth: (H, W) Z in metres of the source camera, NaN unknown.
        source: Intrinsics of the depth image.
        target: Intrinsics of the target camera at the output size.
        rotation: (3, 3) rotation, source optical frame -> target optical frame.
        translation: (3,) the source's origin in the target frame, metres.

    Returns:
        (target.height, target.width) float32 Z in the target frame, NaN where nothing
        landed (a Z beyond float32's range does not land).

    Raises:
        ArgumentError: Shapes that do not fit, or a rotation that is not one.
    """
    z = _check_depth(depth, source)
    R = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64).reshape(-1)
    if R.shape != (3, 3) or t.shape != (3,):
        raise ArgumentError(f'rotation must be (3, 3) and translation (3,), got {R.shape} '
                            f'and {t.shape}')
    if not (np.isfinite(R).all() and np.isfinite(t).all()):
        raise ArgumentError('rotation and translation must be finite')
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ArgumentError('rotation is not a rotation matrix')
    out = np.full((target.height, target.width), np.inf, dtype=np.float32)
    _register_kernel(np.ascontiguousarray(z), _pinhole(source), _pinhole(target), R, t, out)
    out[np.isinf(out)] = np.nan
    return out


def _pinhole(camera: Intrinsics) -> NDArray[np.float64]:
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy])


@numba.njit(cache=True, nogil=True)
def _project(x: float, y: float, z: float, R: NDArray[np.float64], t: NDArray[np.float64],
             cam: NDArray[np.float64]) -> tuple[float, float, float]:
    """Target pixel (u, v) and Z of the source point (x, y, z); Z <= 0 behind it."""
    xt = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]
    yt = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]
    zt = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
    if zt <= 0.0:
        return 0.0, 0.0, zt
    return cam[0] * xt / zt + cam[2], cam[1] * yt / zt + cam[3], zt


@numba.njit(cache=True, nogil=True)
def _register_kernel(depth: NDArray[np.float32], src: NDArray[np.float64],
                     dst: NDArray[np.float64], R: NDArray[np.float64], t: NDArray[np.float64],
                     out: NDArray[np.float32]) -> None:
    height, width = depth.shape
    out_h, out_w = out.shape
    h_end, w_end = float(out_h), float(out_w)
    for v in range(height):
        for u in range(width):
            z = depth[v, u]
            if not z > 0.0:  # NaN too
                continue
            uc, vc, zc = _project((u - src[2]) / src[0] * z, (v - src[3]) / src[1] * z, z,
                                  R, t, dst)
            if zc <= 0.0:
                continue
            zf = np.float32(zc)
            # the footprint: the pixel's corners at its depth, projected
            u_lo, v_lo, u_hi, v_hi = np.inf, np.inf, -np.inf, -np.inf
            for du in (-0.5, 0.5):
                for dv in (-0.5, 0.5):
                    pu, pv, pz = _project((u + du - src[2]) / src[0] * z,
                                          (v + dv - src[3]) / src[1] * z, z, R, t, dst)
                    if pz <= 0.0:
                        continue
                    u_lo, u_hi = min(u_lo, pu), max(u_hi, pu)
                    v_lo, v_hi = min(v_lo, pv), max(v_hi, pv)
            if not (u_lo <= u_hi and v_lo <= v_hi):
                u_lo, u_hi, v_lo, v_hi = uc, uc, vc, vc  # no corner ahead of the camera
            # pixel centres inside the footprint, before clipping to the image
            c0, c1 = np.ceil(u_lo), np.ceil(u_hi) - 1.0
            r0, r1 = np.ceil(v_lo), np.ceil(v_hi) - 1.0
            if not (c0 <= c1 and r0 <= r1):
                # covers no pixel centre: the pixel that holds its centre
                cu, cv = np.floor(uc + 0.5), np.floor(vc + 0.5)
                if 0 <= cu < out_w and 0 <= cv < out_h and zf < out[int(cv), int(cu)]:
                    out[int(cv), int(cu)] = zf
                continue
            # clipped to the image before int(): a float beyond int64 (a depth of 1e-30 m
            # projects ~1e30 px away) has no defined int, and it came out as the most
            # negative one, so such a footprint filled a whole row
            r_first, r_last = min(max(r0, 0.0), h_end), max(min(r1, h_end - 1.0), -1.0)
            c_first, c_last = min(max(c0, 0.0), w_end), max(min(c1, w_end - 1.0), -1.0)
            for r in range(int(r_first), int(r_last) + 1):
                for c in range(int(c_first), int(c_last) + 1):
                    if zf < out[r, c]:
                        out[r, c] = zf


def register_reference(depth: NDArray[np.floating[Any]], source: Intrinsics,
                       target: Intrinsics, rotation: NDArray[np.floating[Any]],
                       translation: NDArray[np.floating[Any]]) -> FloatImage:
    """Plain numpy reference of :func:`register_depth` (for the tests): one target pixel
    at a time, every source footprint tested against it. Slow; small images only."""
    z = np.asarray(depth, dtype=np.float64)
    R = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    out = np.full((target.height, target.width), np.nan, dtype=np.float32)

    def project(u: NDArray[Any], v: NDArray[Any], zz: NDArray[Any]) -> tuple[Any, Any, Any]:
        pts = np.stack([(u - source.cx) / source.fx * zz, (v - source.cy) / source.fy * zz,
                        zz], axis=-1) @ R.T + t
        with np.errstate(divide='ignore', invalid='ignore'):
            return (target.fx * pts[..., 0] / pts[..., 2] + target.cx,
                    target.fy * pts[..., 1] / pts[..., 2] + target.cy, pts[..., 2])

    vs, us = np.nonzero(z > 0)
    zs = z[vs, us]
    uc, vc, zc = project(us.astype(float), vs.astype(float), zs)
    corners = [project(us + du, vs + dv, zs) for du in (-0.5, 0.5) for dv in (-0.5, 0.5)]
    cu = np.array([np.where(c[2] > 0, c[0], np.nan) for c in corners])
    cv = np.array([np.where(c[2] > 0, c[1], np.nan) for c in corners])
    u_lo, u_hi = np.fmin.reduce(cu, axis=0), np.fmax.reduce(cu, axis=0)  # NaN ignored
    v_lo, v_hi = np.fmin.reduce(cv, axis=0), np.fmax.reduce(cv, axis=0)
    none = np.isnan(u_lo)  # no corner ahead of the camera: the centre alone
    u_lo, u_hi = np.where(none, uc, u_lo), np.where(none, uc, u_hi)
    v_lo, v_hi = np.where(none, vc, v_lo), np.where(none, vc, v_hi)
    with np.errstate(over='ignore'):
        zf = zc.astype(np.float32)
    lands = zf < np.inf  # a Z beyond float32's range never beats the kernel's start, inf
    for r in range(target.height):
        for c in range(target.width):
            covers = (zc > 0) & (u_lo <= c) & (c < u_hi) & (v_lo <= r) & (r < v_hi)
            with np.errstate(invalid='ignore'):
                holds = (zc > 0) & ~((np.ceil(u_lo) <= np.ceil(u_hi) - 1)
                                     & (np.ceil(v_lo) <= np.ceil(v_hi) - 1)) \
                    & (np.floor(uc + 0.5) == c) & (np.floor(vc + 0.5) == r)
            hits = zf[(covers | holds) & lands]
            if hits.size:
                out[r, c] = hits.min()
    return out
