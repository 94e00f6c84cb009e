"""Decimation: each ``n x n`` block of a depth image becomes one pixel, the median of its
valid pixels for ``n`` of 2 or 3 and their mean above (librealsense's rule); a block with
no valid pixel is unknown. The variance of the result is that of a mean of the block's
valid pixels (times pi / 2 for a median of three or more).

:func:`decimate` is the kernel's wrapper; the plain numpy definition the tests compare
it with is ``decimate_reference`` in ``test/reference/depth_filter.py``.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics
from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]
#: Variance of a median of n >= 3 normal samples, relative to their mean's (large n).
MEDIAN_VARIANCE = math.pi / 2.0


def decimated_camera(camera: Intrinsics, factor: int) -> Intrinsics:
    """The intrinsics of the decimated image: focal lengths over ``factor``, the principal
    point moved with the pixel centres (``(c + 0.5) / n - 0.5``), the size rounded down."""
    return Intrinsics(camera.fx / factor, camera.fy / factor,
                      (camera.cx + 0.5) / factor - 0.5, (camera.cy + 0.5) / factor - 0.5,
                      camera.width // factor, camera.height // factor)


@numba.njit(cache=True, nogil=True, parallel=True, error_model='numpy')
def _decimate_kernel(depth: F32, var: F32, factor: int, median: bool, out: F32,
                     out_var: F32) -> None:
    oh, ow = out.shape
    n2 = factor * factor
    for oy in numba.prange(oh):
        block = np.empty(n2, np.float32)
        for ox in range(ow):
            count = 0
            total = 0.0
            total_var = 0.0
            for dy in range(factor):
                for dx in range(factor):
                    z = depth[oy * factor + dy, ox * factor + dx]
                    if z > 0.0 and z < np.inf:  # not NaN, zero, negative or infinite
                        block[count] = z
                        total += z
                        total_var += var[oy * factor + dy, ox * factor + dx]
                        count += 1
            if count == 0:
                out[oy, ox] = np.nan
                out_var[oy, ox] = np.nan
                continue
            spread = total_var / (count * count)
            if median and count > 2 and count <= 4:  # the middle of 3 or 4, no sorting
                low, high = block[0], block[0]
                for i in range(1, count):
                    low, high = min(low, block[i]), max(high, block[i])
                rest = total - low - high  # the one or two in the middle
                out[oy, ox] = rest if count == 3 else 0.5 * rest
                out_var[oy, ox] = spread * MEDIAN_VARIANCE
            elif median and count > 2:
                for i in range(1, count):  # insertion sort: at most 9 values
                    value = block[i]
                    j = i - 1
                    while j >= 0 and block[j] > value:
                        block[j + 1] = block[j]
                        j -= 1
                    block[j + 1] = value
                half = count // 2
                out[oy, ox] = block[half] if count % 2 == 1 else \
                    np.float32(0.5 * (block[half - 1] + block[half]))
                out_var[oy, ox] = spread * MEDIAN_VARIANCE
            else:
                out[oy, ox] = total / count
                out_var[oy, ox] = spread


def _check(depth: F32, var: F32 | None, factor: int) -> tuple[F32, F32]:
    z = np.asarray(depth)
    if z.ndim != 2:
        raise ArgumentError(f'depth must be (H, W), got shape {z.shape}')
    if not 1 <= factor <= 8:
        raise ArgumentError(f'decimation factor must be in [1, 8], got {factor}')
    if z.shape[0] < factor or z.shape[1] < factor:
        raise ArgumentError(f'a {z.shape[1]}x{z.shape[0]} image is smaller than the '
                            f'decimation factor {factor}')
    v = np.zeros(z.shape, np.float32) if var is None else np.asarray(var, np.float32)
    if v.shape != z.shape:
        raise ArgumentError(f'variance shape {v.shape} differs from the depth\'s {z.shape}')
    return np.ascontiguousarray(z, np.float32), np.ascontiguousarray(v)


def decimate(depth: F32, factor: int, var: F32 | None = None) -> tuple[F32, F32]:
    """Decimate ``depth`` (Z metres, NaN or 0 unknown) by ``factor``.

    Returns:
        ``(H // n, W // n)`` depth (NaN unknown) and variance (m^2; zero without ``var``).

    Raises:
        ArgumentError: A factor outside [1, 8], an image smaller than it, mismatched shapes.
    """
    z, v = _check(depth, var, factor)
    if factor == 1:
        known = (z > 0) & (z < np.inf)
        return np.where(known, z, np.nan).astype(np.float32), np.where(known, v, np.nan)
    shape = (z.shape[0] // factor, z.shape[1] // factor)
    out = np.empty(shape, np.float32)
    out_var = np.empty(shape, np.float32)
    _decimate_kernel(z, v, factor, factor <= 3, out, out_var)
    return out, out_var
