"""Plain references of the cross-check's kernels (``depth_nodes/core/cross_check.py``):
the left-right check and the disparity hole filling; for ``test_cross_check.py``."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.cross_check import (
    _DIRECTIONS,
    INVALID,
    MISMATCH,
    OCCLUDED,
    OUTSIDE,
    SPECKLE,
    VALID,
)

F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]
Bool = NDArray[np.bool_]


# -- depth_nodes.core.cross_check --------------------------------------------------------------
def left_right_check_reference(disparity: F32, disparity_right: F32,
                               max_diff: float) -> tuple[F32, U8]:
    """Plain numpy version of the left-right check kernel (tests compare against it)."""
    h, w = disparity.shape
    finite = np.isfinite(disparity)
    xs = np.arange(w)[None, :]
    with np.errstate(invalid='ignore'):
        xr = np.floor(xs - np.where(finite, disparity, 0) + 0.5).astype(np.int64)
    inside = finite & (xr >= 0) & (xr < w)
    dr = np.full((h, w), np.nan, np.float32)
    ys = np.nonzero(inside)[0]
    dr[inside] = disparity_right[ys, xr[inside]]
    has = inside & np.isfinite(dr)
    diff = np.where(has, np.abs(disparity - dr), np.nan).astype(np.float32)
    labels = np.full((h, w), INVALID, np.uint8)
    labels[finite & ~has] = OCCLUDED
    labels[finite & ~((xr >= 0) & (xr < w))] = OUTSIDE
    with np.errstate(invalid='ignore'):
        labels[has & (diff <= max_diff)] = VALID
        labels[has & (diff > max_diff) & (dr > disparity + max_diff)] = OCCLUDED
        labels[has & (diff > max_diff) & ~(dr > disparity + max_diff)] = MISMATCH
    return diff, labels


def fill_disparity_holes_reference(disparity: F32, valid: Bool, labels: U8,
                         mode: str = 'labels') -> F32:
    """Plain Python version of the hole-filling kernel (tests compare against it)."""
    h, w = disparity.shape
    out = np.where(valid, disparity, np.nan).astype(np.float32)

    def nearest(y: int, x: int, dy: int, dx: int) -> float:
        y, x = y + dy, x + dx
        while 0 <= y < h and 0 <= x < w:
            if valid[y, x]:
                return float(disparity[y, x])
            y, x = y + dy, x + dx
        return math.nan

    for y in range(h):
        for x in range(w):
            if valid[y, x]:
                continue
            if mode == 'background' or labels[y, x] == OCCLUDED:
                side = [v for v in (nearest(y, x, 0, -1), nearest(y, x, 0, 1))
                        if math.isfinite(v)]
                if side:
                    out[y, x] = min(side)
            elif labels[y, x] in (MISMATCH, SPECKLE):
                around = [v for v in (nearest(y, x, int(dy), int(dx)) for dy, dx in _DIRECTIONS)
                          if math.isfinite(v)]
                if around:
                    out[y, x] = float(np.median(around))
    return out
