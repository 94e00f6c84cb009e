"""The matcher's own validity rules after selection: left-right consistency and how far
past the image border a disparity may be extrapolated.

Both views come from the same aggregated volume (``select.py``), so the check costs one
pass over the image. A left pixel ``x`` with disparity ``d`` is kept when

* its right pixel ``xr = round(x - d)`` is inside the image and the right view there
  agrees, ``|d - d_right(xr)| <= max_diff`` (``max_diff <= 0`` skips this test), or
* ``xr`` is outside the image (the disparity was extrapolated from the neighbours, see
  ``border.fill_outside``) by at most ``max_outside`` px.

Everything else becomes NaN. Each kernel here has a plain numpy reference
(``check_disparity_reference`` in ``test/reference/sgm.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

F32 = NDArray[np.float32]


@njit(parallel=True, cache=True, nogil=True)
def _check_kernel(disparity: F32, disparity_right: F32, max_diff: float,
                  max_outside: float) -> None:
    h, w = disparity.shape
    for y in prange(h):
        for x in range(w):
            d = disparity[y, x]
            if not math.isfinite(d):
                continue
            xr = math.floor(x - d + 0.5)
            if xr < 0 or xr >= w:
                outside = -xr if xr < 0 else xr - (w - 1)
                if outside > max_outside:
                    disparity[y, x] = math.nan
                continue
            if max_diff > 0.0:
                dr = disparity_right[y, xr]
                if not (abs(d - dr) <= max_diff):  # NaN partner fails too
                    disparity[y, x] = math.nan


def check_disparity(disparity: F32, disparity_right: F32, *, max_diff: float,
                    max_outside: float) -> None:
    """Apply the validity rules of this module to ``disparity`` in place.

    Args:
        disparity: (H, W) float32 left disparity, NaN where invalid; modified.
        disparity_right: (H, W) float32 right-view disparity (``x_left = x_right + d``).
        max_diff: Largest left-right difference in px; <= 0 skips the left-right test.
        max_outside: Largest distance in px past the image border of an extrapolated
            disparity's right pixel.
    """
    _check_kernel(disparity, disparity_right, float(max_diff), float(max_outside))
