"""Disparity -> 3-D points and depth in the left rectified camera frame (no ROS).

Geometry from the rectified projection matrices ``P_left`` and ``P_right`` (CameraInfo
``P``; shared ``fx``, ``fy``, ``cy``), with ``d = x_left - x_right`` and
``delta_cx = cx_right - cx_left``::

    Z = f B / (d + delta_cx)             (f B = Tx_left - Tx_right, StereoModel.focal * baseline)
    X = ((x - cx_left) Z - Tx_left) / fx
    Y = ((y - cy_left) Z - Ty_left) / fy

which inverts ``P_left [X Y Z 1]^T ~ (x, y, 1)`` and ``P_right [X Y Z 1]^T ~ (x - d, y, 1)``
exactly (``Tx_left``/``Ty_left`` are zero for the usual left camera). A 1-sigma disparity
error ``dd`` gives, to first order, the depth standard deviation ``Z^2 / (f B) * dd``.

Decisions:
    * A pixel is invalid (NaN in every output) where the disparity is NaN or infinite,
      where ``d + delta_cx <= 0`` (at or behind infinity), where Z is outside
      ``[min_range, max_range]`` (0 = no limit; range is the depth Z along the optical axis,
      as depth images and PCL pass-through filters use it), or where a confidence is given
      and is below ``min_confidence`` or NaN.
    * Arithmetic is float64, outputs float32: the only rounding is the final cast.
    * One numba pass over the pixels (:func:`_reproject_kernel`); the numpy version it
      replaced, 5x slower at 640x480 (many float64 temporaries and a reduction over the
      points), is kept as the tests' reference (``reproject_reference`` in
      ``test/reference/reproject.py``) and the tests hold them equal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from depth_nodes.core.camera import StereoModel
from depth_nodes.core.settings import check_settings, setting
from depth_nodes.core.validate import check_float_map
from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]


@dataclass(frozen=True)
class Reprojection:
    """What :func:`reproject_disparity` returns.

    Attributes:
        points: (H, W, 3) float32 X, Y, Z in metres, NaN where invalid.
        depth: (H, W) float32 Z in metres, NaN where invalid (REP 118).
        valid: (H, W) bool, True where the point is kept.
    """

    points: F32
    depth: F32
    valid: NDArray[np.bool_]


@dataclass(frozen=True)
class ReprojectParams:
    """The point_cloud node's settings of the reprojection, named as its parameters."""

    min_range: float = setting(0.0, 'Nearest depth Z kept, metres (0: no limit)',
                               low=0.0, high=1.0e6)
    max_range: float = setting(0.0, 'Farthest depth Z kept, metres (0: no limit)',
                               low=0.0, high=1.0e6)
    min_confidence: float = setting(0.0, 'Smallest confidence kept (needs use_confidence)',
                                    low=0.0, high=1.0)
    disparity_std: float = setting(0.25, 'Disparity standard deviation, px, for depth_std',
                                   low=0.0, high=100.0)

    def validate(self) -> ReprojectParams:
        """Check every field and that the range is not empty; returns self.

        Raises:
            ArgumentError: The first rule broken.
        """
        check_settings(self, 'point cloud parameter')
        if self.max_range and self.max_range < self.min_range:
            raise ArgumentError(f'max_range ({self.max_range}) must be >= min_range '
                                f'({self.min_range}) or 0 (no limit)')
        return self


def reproject_disparity(
    disparity: NDArray[np.floating[Any]],
    stereo: StereoModel,
    *,
    min_range: float = 0.0,
    max_range: float = 0.0,
    confidence: NDArray[np.floating[Any]] | None = None,
    min_confidence: float = 0.0,
) -> Reprojection:
    """Reproject a left-view disparity map to organised 3-D points and a depth image.

    Args:
        disparity: (H, W) float disparities ``x_left - x_right`` in pixels, NaN where
            unknown; H x W must be the size of ``stereo``'s (effective) cameras.
        stereo: The rectified pair (binned / ROI-applied models of the delivered images).
        min_range: Nearest depth Z kept, metres (0: no limit).
        max_range: Farthest depth Z kept, metres (0: no limit).
        confidence: Optional (H, W) float confidence, same shape as ``disparity``.
        min_confidence: Pixels whose confidence is below this (or NaN) are invalid; only
            used with ``confidence``.

    Returns:
        The points, depth and validity mask (see :class:`Reprojection`).

    Raises:
        ArgumentError: A shape or dtype that does not fit, a size other than the cameras', a
            negative range or ``max_range`` below ``min_range``.
    """
    disparity = np.asarray(disparity)
    check_float_map('disparity', disparity)
    h, w = disparity.shape
    if (stereo.left.width, stereo.left.height) != (w, h):
        raise ArgumentError(f'disparity is {w}x{h} but the cameras are '
                            f'{stereo.left.width}x{stereo.left.height}')
    ReprojectParams(min_range=min_range, max_range=max_range).validate()
    if confidence is not None:
        confidence = np.asarray(confidence)
        check_float_map('confidence', confidence, disparity.shape)
    return _reproject(disparity, stereo, min_range, max_range, confidence, min_confidence)


def _reproject(disparity: NDArray[Any], stereo: StereoModel, min_range: float,
               max_range: float, confidence: NDArray[Any] | None,
               min_confidence: float) -> Reprojection:
    h, w = disparity.shape
    P = stereo.left.projection
    points = np.empty((h, w, 3), dtype=np.float32)
    depth = np.empty((h, w), dtype=np.float32)
    valid = np.empty((h, w), dtype=np.bool_)
    if confidence is None:
        conf, threshold = np.zeros((1, 1), np.float32), np.float32(0.0)
    else:  # compared in the confidence's own type, as numpy compares it with a float
        conf, threshold = confidence, confidence.dtype.type(min_confidence)
    _reproject_kernel(disparity, conf, confidence is not None, threshold,
                      float(stereo.focal * stereo.baseline), float(stereo.delta_cx),
                      float(P[0, 0]), float(P[1, 1]), float(P[0, 2]), float(P[1, 2]),
                      float(P[0, 3]), float(P[1, 3]), float(min_range), float(max_range),
                      points, depth, valid)
    return Reprojection(points=points, depth=depth, valid=valid)


@njit(cache=True, nogil=True)
def _reproject_kernel(disparity: NDArray[Any], confidence: NDArray[Any], use_confidence: bool,
                      threshold: Any, fb: float, delta_cx: float, fx: float, fy: float,
                      cx: float, cy: float, tx: float, ty: float, min_range: float,
                      max_range: float, points: F32, depth: F32,
                      valid: NDArray[np.bool_]) -> None:
    """The numpy reference's arithmetic (``reproject_reference``), one pixel at a time
    (float64, one cast)."""
    h, w = disparity.shape
    nan = np.float32(np.nan)
    for y in range(h):
        v = float(y) - cy
        for x in range(w):
            den = float(disparity[y, x]) + delta_cx
            ok = np.isfinite(den) and den > 0.0
            z = fb / den if ok else np.nan
            if ok and min_range > 0.0:
                ok = z >= min_range
            if ok and max_range > 0.0:
                ok = z <= max_range
            if ok and use_confidence:
                ok = confidence[y, x] >= threshold  # False for NaN
            px = py = pz = nan
            if ok:
                px = np.float32(((float(x) - cx) * z - tx) / fx)
                py = np.float32((v * z - ty) / fy)
                pz = np.float32(z)
                # an absurd but finite calibration can put points beyond float32
                ok = np.isfinite(px) and np.isfinite(py) and np.isfinite(pz)
                if not ok:
                    px = py = pz = nan
            points[y, x, 0] = px
            points[y, x, 1] = py
            points[y, x, 2] = pz
            depth[y, x] = pz
            valid[y, x] = ok


def depth_std(depth: NDArray[np.floating[Any]], focal: float, baseline: float,
              disparity_std: float) -> F32:
    """First-order depth standard deviation ``Z^2 / (f B) * disparity_std``.

    Args:
        depth: Depths Z in metres, any shape (NaN stays NaN).
        focal: Rectified focal length in pixels.
        baseline: Baseline in metres.
        disparity_std: Disparity standard deviation in pixels (>= 0).

    Returns:
        float32 array of the shape of ``depth``, metres.

    Raises:
        ArgumentError: ``focal * baseline`` not positive, or ``disparity_std`` negative.
    """
    if not focal * baseline > 0:
        raise ArgumentError(f'focal * baseline must be positive, got {focal} * {baseline}')
    if not disparity_std >= 0:
        raise ArgumentError(f'disparity_std must be >= 0, got {disparity_std}')
    z = np.asarray(depth, dtype=np.float64)
    return (z * z * (disparity_std / (focal * baseline))).astype(np.float32)


def depth_to_millimetres(depth: NDArray[np.floating[Any]]) -> NDArray[np.uint16]:
    """REP 118 16UC1: depth rounded to millimetres, 0 where unknown or beyond 65.535 m.

    Args:
        depth: Depths Z in metres, NaN where unknown.

    Returns:
        uint16 array of the same shape.
    """
    mm = np.rint(np.asarray(depth, dtype=np.float64) * 1000.0)
    with np.errstate(invalid='ignore'):
        ok = (mm >= 1) & (mm <= np.iinfo(np.uint16).max)
    return np.where(ok, mm, 0).astype(np.uint16)
