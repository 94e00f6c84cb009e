"""Plain numpy reference of structured light's speckle matcher
(``depth_nodes/core/structured_light/speckle.py``), for ``test_sl_speckle.py``: small
images only."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.structured_light.speckle import CENSUS_WINDOW, OUTSIDE, _check_pair
from reference.sgm import census_transform_reference

F32 = NDArray[np.float32]


# -- depth_nodes.core.structured_light.speckle -------------------------------------------------
def match_speckle_reference(image: NDArray[np.generic], reference: NDArray[np.generic], *,
                            shift_min: int, shift_max: int, window: int = 9,
                            min_score: float = 0.42, uniqueness: float = 0.05
                            ) -> tuple[F32, F32]:
    """Plain numpy definition of :func:`match_speckle` (for the tests; small images)."""
    margin = _check_pair(image, reference, window)
    ci = census_transform_reference(image, CENSUS_WINDOW)
    cr = census_transform_reference(reference, CENSUS_WINDOW)
    h, w = ci.shape
    wr = cr.shape[1]
    shifts = np.arange(shift_min, shift_max + 1)
    xs = np.arange(w)[:, None] - shifts[None, :] + margin  # (W, S) reference columns
    inside = (xs >= 0) & (xs < wr)
    xor = ci[:, :, None] ^ cr[:, np.clip(xs, 0, wr - 1)]
    table = np.array([bin(v).count('1') for v in range(256)], np.int64)
    ham = sum(table[(xor >> np.uint64(8 * i)) & np.uint64(255)] for i in range(8))
    costs = np.where(inside[None], ham, OUTSIDE)
    r = window // 2
    padded = np.pad(costs, ((r, r), (r, r), (0, 0)), mode='edge')
    column: NDArray[np.int64] = np.zeros((h, w, len(shifts)), np.int64)
    for dy in range(window):
        for dx in range(window):
            column += padded[dy:dy + h, dx:dx + w]
    bits = window * window * (CENSUS_WINDOW[0] * CENSUS_WINDOW[1] - 1)
    kb = np.argmin(column, axis=2)
    cb = np.take_along_axis(column, kb[..., None], 2)[..., 0]
    score = (1.0 - 2.0 * cb / bits).astype(np.float32)
    k = np.arange(len(shifts))[None, None, :]
    second = np.where(np.abs(k - kb[..., None]) > 1, column, 1 << 30).min(axis=2)
    # the reference side: for each reference column, the shift of its lowest sum
    ref_k = np.full((h, wr), -1)
    ref_min = np.full((h, wr), 1 << 30)
    for x in range(w):
        for i in range(len(shifts)):
            if inside[x, i]:
                better = column[:, x, i] < ref_min[:, xs[x, i]]
                ref_min[better, xs[x, i]] = column[better, x, i]
                ref_k[better, xs[x, i]] = i
    xr = np.arange(w)[None, :] - shifts[kb] + margin
    ok_ref = (xr >= 0) & (xr < wr)
    back = np.take_along_axis(ref_k, np.clip(xr, 0, wr - 1), 1)
    ok = (kb > 0) & (kb < len(shifts) - 1) & (score >= min_score) & ok_ref & \
        (np.abs(back - kb) <= 1) & (second - cb >= uniqueness * second)
    kc = np.clip(kb, 1, len(shifts) - 2)
    left = np.take_along_axis(column, (kc - 1)[..., None], 2)[..., 0].astype(np.float64)
    right = np.take_along_axis(column, (kc + 1)[..., None], 2)[..., 0].astype(np.float64)
    curve = left - 2 * cb + right
    with np.errstate(divide='ignore', invalid='ignore'):
        delta = np.clip(np.where(curve > 0, 0.5 * (left - right) / curve, 0.0), -0.5, 0.5)
    shift = np.where(ok, shift_min + kb + delta, np.nan).astype(np.float32)
    return shift, score
