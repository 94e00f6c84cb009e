"""Filters of a disparity map that any matcher's output may go through: OpenCV's speckle
removal on a fixed-point copy (:func:`remove_speckles`, used by the census matcher and the
cross_check node) and a median that keeps invalid pixels invalid (:func:`median_filter`).
Misuse raises ``ArgumentError`` naming the argument.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
from numba import njit
from numpy.typing import NDArray

from depth_nodes.core.validate import float_map, non_negative
from depth_nodes.errors import ArgumentError

__all__ = ['SPECKLE_SCALE', 'median_filter', 'remove_speckles']

F32 = NDArray[np.float32]
Bool = NDArray[np.bool_]
#: int16 steps per pixel of the speckle filter's copy (OpenCV's fixed point).
SPECKLE_SCALE = 16


# -- speckles -----------------------------------------------------------------------------


def remove_speckles(disparity: Any, *, max_size: int, max_diff: float) -> Bool:
    """The pixels of small disparity regions (speckles), as OpenCV's filterSpeckles sees
    them on a fixed-point copy.

    Args:
        disparity: (H, W) float disparity, NaN where invalid (invalid pixels separate
            regions). Not modified.
        max_size: Largest speckle area in pixels (0: none removed).
        max_diff: Largest difference in px between 4-neighbours of one region.

    Returns:
        (H, W) bool, True on the pixels of removed speckles.

    Raises:
        ArgumentError: Bad shapes or negative sizes.
    """
    disp = float_map('disparity', disparity)
    if isinstance(max_size, bool) or not isinstance(max_size, (int, np.integer)) or max_size < 0:
        raise ArgumentError(f'max_size must be an int >= 0, got {max_size!r}')
    diff = non_negative('max_diff', max_diff)
    finite = np.isfinite(disp)
    if max_size == 0 or not finite.any():
        return np.zeros(disp.shape, np.bool_)
    lo = float(np.nanmin(disp))
    span = float(np.nanmax(disp)) - lo + 1.0
    scale = min(SPECKLE_SCALE, max(1, int(32000 // span)))
    fixed = np.empty(disp.shape, np.int16)
    _to_fixed(disp, lo, float(scale), fixed)
    cv2.filterSpeckles(fixed, -1, int(max_size), round(diff * scale))
    removed: Bool = (fixed == -1) & finite
    return removed


@njit(cache=True, nogil=True)
def _to_fixed(disp: F32, lo: float, scale: float, out: NDArray[np.int16]) -> None:
    """out = round((disp - lo) * scale), -1 where disp is NaN (one pass)."""
    h, w = disp.shape
    for y in range(h):
        for x in range(w):
            d = disp[y, x]
            out[y, x] = np.int16(round((d - lo) * scale)) if math.isfinite(d) else np.int16(-1)


# -- median -------------------------------------------------------------------------------


def median_filter(disparity: Any, size: int) -> F32:
    """Median of the valid disparities in a ``size`` x ``size`` box (3 or 5); invalid
    pixels stay invalid and enter the median as very small values, so a pixel with mostly
    invalid neighbours keeps its own value.

    Raises:
        ArgumentError: Bad shapes or a size other than 3 or 5 (OpenCV's float medians).
    """
    disp = float_map('disparity', disparity)
    if size not in (3, 5):
        raise ArgumentError(f'size must be 3 or 5, got {size!r}')
    invalid = ~np.isfinite(disp)
    finite = disp[~invalid]
    if not finite.size:
        return disp.copy()
    marker = np.float32(float(finite.min()) - 1e4)
    smoothed = cv2.medianBlur(np.where(invalid, marker, disp).astype(np.float32), size)
    out = disp.copy()
    keep = ~invalid & (smoothed > marker)
    out[keep] = smoothed[keep]
    return out
