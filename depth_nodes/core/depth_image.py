"""Depth images (REP 118) as depth_image_proc processes them: units, points, disparity
and registration into another camera (no ROS).

A depth image holds Z, the distance along the camera's optical axis: 32FC1 in metres with
NaN (or 0, or anything not finite and positive) unknown, or 16UC1 in millimetres with 0
unknown. The functions here work on metres as float32 with NaN unknown; :func:`to_metres`
and :func:`from_metres` convert at the message boundary.

The camera of a depth image is a :class:`~depth_nodes.core.geometry.pinhole.Intrinsics`
(:func:`~depth_nodes.core.geometry.pinhole.intrinsics` reads it from a CameraInfo).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics, Motion, splat
from depth_nodes.core.reproject import depth_to_millimetres
from depth_nodes.errors import ArgumentError

__all__ = ['DEPTH_ENCODINGS', 'colour_at_depth_pixels', 'depth_to_disparity',
           'depth_to_points', 'from_metres', 'register_depth', 'to_metres']

#: The depth encodings of REP 118.
DEPTH_ENCODINGS = ('16UC1', '32FC1')

FloatImage = NDArray[np.float32]


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
                   motion: Motion) -> FloatImage:
    """Depth seen by another camera: each depth pixel moved into the target camera.

    Each known pixel's point ``X`` goes to ``R X + t`` in the target's optical frame. The
    pixel's footprint (its corners at its depth) is projected there and every target pixel
    whose centre it covers gets the point's Z; a footprint covering no centre (target
    coarser than the source) gives its Z to the target pixel holding its centre. Where
    several points land on one pixel the nearest wins (z-buffer), so a foreground edge
    hides the background behind it: :func:`~depth_nodes.core.geometry.splat.splat` with
    the ``corners`` footprint.

    Args:
        depth: (H, W) Z in metres of the source camera, NaN unknown.
        source: Intrinsics of the depth image.
        target: Intrinsics of the target camera at the output size.
        motion: ``(R, t)``: rotation source optical frame -> target optical frame, and the
            source's origin in the target frame, metres.

    Returns:
        (target.height, target.width) float32 Z in the target frame, NaN where nothing
        landed (a Z beyond float32's range does not land).

    Raises:
        ArgumentError: Shapes that do not fit, or a motion that is not rigid.
    """
    z = _check_depth(depth, source)
    landed = splat(z, source, target, motion, footprint='corners')
    with np.errstate(over='ignore'):
        out = landed.depth.astype(np.float32)
    out[~np.isfinite(out)] = np.nan
    return out
