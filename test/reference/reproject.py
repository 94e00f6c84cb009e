"""Plain numpy reference of the reprojection kernel (``depth_nodes/core/reproject.py``):
the numpy version the kernel replaced; for ``test_reproject.py``."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import StereoModel
from depth_nodes.core.reproject import Reprojection


# -- depth_nodes.core.reproject ----------------------------------------------------------------
def reproject_reference(disparity: NDArray[Any], stereo: StereoModel, min_range: float,
                        max_range: float, confidence: NDArray[Any] | None,
                        min_confidence: float) -> Reprojection:
    """The reprojection in plain numpy (the kernel's reference in the tests)."""
    h, w = disparity.shape
    P = stereo.left.projection
    fx, fy, cx, cy, tx, ty = P[0, 0], P[1, 1], P[0, 2], P[1, 2], P[0, 3], P[1, 3]
    fb = stereo.focal * stereo.baseline
    den = disparity.astype(np.float64) + stereo.delta_cx
    with np.errstate(invalid='ignore', divide='ignore'):
        valid = np.isfinite(den) & (den > 0)
        z = fb / np.where(valid, den, np.nan)
        if min_range > 0:
            valid &= z >= min_range
        if max_range > 0:
            valid &= z <= max_range
        if confidence is not None:
            valid &= confidence >= min_confidence
    z[~valid] = np.nan
    points = np.empty((h, w, 3), dtype=np.float32)
    u = np.arange(w, dtype=np.float64) - cx
    v = np.arange(h, dtype=np.float64) - cy
    # an absurd but finite calibration can put points beyond float32: those are invalid
    with np.errstate(over='ignore', invalid='ignore'):
        points[..., 0] = (u[None, :] * z - tx) / fx
        points[..., 1] = (v[:, None] * z - ty) / fy
        points[..., 2] = z
    beyond = valid & ~np.isfinite(points).all(axis=2)
    if beyond.any():
        valid &= ~beyond
        points[beyond] = np.nan
    return Reprojection(points=points, depth=points[..., 2].copy(), valid=valid)
