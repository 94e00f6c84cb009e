"""Hole filling, librealsense's three modes, and how unsure a filled pixel is.

* ``fill_from_left``: along each row, a missing pixel takes the value on its left (already
  filled): a hole takes the depth at its left border;
* ``farthest_from_around`` / ``nearest_from_around``: in raster order, a missing pixel
  takes the farthest / nearest of its valid neighbours among left, upper-left and upper
  (already filled) and lower-left and lower (as measured): librealsense's neighbours, so a
  hole fills from its left and from above and below, never from its right. The farthest
  is usually the background an object hides. Where librealsense leaves the first and last
  rows and the first column as they are, and its nearest mode fills nothing when the
  upper neighbour is missing, these use the neighbours there are.

A pixel with no such neighbour stays missing. :func:`fill_spread` gives each filled pixel
the gap between the depths at the two ends of its hole along the row: a hole inside a
surface has a small one, a hole at an edge the size of the step, and the filled pixel's
standard deviation comes from it.

:func:`fill_depth_holes` is the kernel's wrapper; the plain definition the tests compare it
with is ``fill_reference`` in ``test/reference/depth_filter.py``.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.depth_filter.params import HOLE_FILLING
from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]
B = NDArray[np.bool_]


@numba.njit(cache=True, nogil=True, error_model='numpy')
def _fill_kernel(z: F32, mode: int, out: F32, filled: B) -> None:
    h, w = z.shape
    for y in range(h):
        for x in range(w):
            if z[y, x] == z[y, x]:
                out[y, x] = z[y, x]
                continue
            best = np.nan
            if mode == 1:
                if x > 0:
                    best = out[y, x - 1]
            else:
                for k in range(5):
                    dy = 0 if k == 0 else (-1 if k < 3 else 1)
                    dx = -1 if k in (0, 1, 3) else 0
                    yy, xx = y + dy, x + dx
                    if yy < 0 or yy >= h or xx < 0:
                        continue
                    n = out[yy, xx] if k < 3 else z[yy, xx]
                    if n != n:
                        continue
                    if best != best or (mode == 2 and n > best) or (mode == 3 and n < best):
                        best = n
            out[y, x] = best
            filled[y, x] = best == best


def _mode(mode: str) -> int:
    if mode not in HOLE_FILLING:
        raise ArgumentError(f'hole_filling {mode!r}: must be one of {", ".join(HOLE_FILLING)}')
    return HOLE_FILLING.index(mode)


def fill_depth_holes(depth: F32, mode: str) -> tuple[F32, B]:
    """Fill the missing pixels (NaN) of ``depth`` (Z metres) by ``mode``.

    Returns:
        The filled depth and the mask of the pixels filled.

    Raises:
        ArgumentError: An unknown mode or an image that is not 2-D.
    """
    m = _mode(mode)
    z = np.ascontiguousarray(depth, np.float32)
    if z.ndim != 2:
        raise ArgumentError(f'depth must be (H, W), got shape {z.shape}')
    filled = np.zeros(z.shape, np.bool_)
    if m == 0:
        return z.copy(), filled
    out = np.empty_like(z)
    _fill_kernel(z, m, out, filled)
    return out, filled


@numba.njit(cache=True, nogil=True, error_model='numpy')
def _spread_kernel(z: F32, filled: B, out: F32) -> None:
    h, w = z.shape
    for y in range(h):
        left = np.nan
        for x in range(w):  # the measured depth at each hole's left end
            if z[y, x] == z[y, x]:
                left = z[y, x]
            else:
                out[y, x] = left
        right = np.nan
        for x in range(w - 1, -1, -1):  # ... and at its right end
            if z[y, x] == z[y, x]:
                right = z[y, x]
                out[y, x] = np.nan
            elif filled[y, x]:
                out[y, x] = abs(right - out[y, x])
            else:
                out[y, x] = np.nan


def fill_spread(depth: F32, filled: B) -> F32:
    """For each filled pixel, the difference between the measured depths at the two ends
    of its hole along the row (NaN where the hole reaches the image's border); NaN
    elsewhere. ``depth`` is the depth before the filling (NaN in the holes)."""
    z = np.ascontiguousarray(depth, np.float32)
    out = np.empty(z.shape, np.float32)
    _spread_kernel(z, np.ascontiguousarray(filled), out)
    return out
