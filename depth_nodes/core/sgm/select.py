"""The upward and horizontal SGM paths fused with disparity selection, row by row.

While a row's total is still in cache it is turned into: the left disparity
(winner-take-all, sub-pixel, uniqueness), the right-view disparity (the minimum along the
diagonal of the same total, so no second matching), and the cost ratio best / second best.

Sub-pixel modes: 0 none, 1 parabola, 2 equiangular (symmetric V).

Performance note: inner loops index with unsigned integers wherever the index is not a
plain ``range(0, n)`` counter. numba guards signed indices against negative values
(Python's wraparound), and that guard stops LLVM from vectorising the loop: with it the
selection ran about 5x slower. Uniqueness follows
OpenCV's rule: a pixel is valid when second_best * (100 - ratio) >= best * 100, where
second_best excludes the two neighbours of the winner.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from depth_nodes.core.sgm.aggregate import (
    _ring,
    new_line,
    path_start,
    path_step,
    store_path,
    table_p2,
)

U8 = NDArray[np.uint8]
U16 = NDArray[np.uint16]
F32 = NDArray[np.float32]

SUBPIXEL_MODES = {'none': 0, 'parabola': 1, 'equiangular': 2}


#: Sub-pixel disparities are rounded to this step (published as DisparityImage.delta_d).
SUBPIXEL_STEP = 1.0 / 32.0


@njit(cache=True, nogil=True, inline='always')
def subpixel_offset(mode: int, left: float, centre: float, right: float) -> float:
    """Offset in [-0.5, 0.5] of the minimum through three costs around the winner,
    rounded to :data:`SUBPIXEL_STEP`."""
    offset = 0.0
    if mode == 1:
        denom = left + right - 2.0 * centre
        if denom > 0.0:
            offset = min(0.5, max(-0.5, (left - right) / (2.0 * denom)))
    elif mode == 2:
        slope = max(left - centre, right - centre)
        if slope > 0.0:
            offset = min(0.5, max(-0.5, (left - right) / (2.0 * slope)))
    return round(offset / SUBPIXEL_STEP) * SUBPIXEL_STEP


@njit(cache=True, nogil=True, inline='always')
def _keyed_min(total: U16, k_lo: int, k_hi: int) -> int:
    """min over k of (total[k] << 16 | k): the smallest cost and, on ties, the first k, in
    one reduction that vectorises (an argmin loop does not)."""
    best = np.uint32(0xFFFFFFFF)
    for k in range(k_lo, k_hi + 1):
        i = np.uint64(k)  # k >= 0: an unsigned index skips numba's wraparound check
        best = min(best, (np.uint32(total[i]) << np.uint32(16)) | np.uint32(k))
    return int(best)


@njit(cache=True, nogil=True, inline='always')
def _min_outside(total: U16, k_lo: int, k_hi: int, kbest: int) -> int:
    """min total[k] over [k_lo, k_hi] without kbest - 1 .. kbest + 1 (65535 if none)."""
    best = np.uint16(65535)
    for k in range(k_lo, k_hi + 1):
        v = total[np.uint64(k)] if abs(k - kbest) > 1 else np.uint16(65535)
        best = min(best, v)
    return int(best)


@njit(cache=True, nogil=True, inline='always')
def select_pixel(total: U16, k_lo: int, k_hi: int, subpixel: int,
                 uniqueness: float) -> tuple[float, float]:
    """Winner over k in [k_lo, k_hi]: (k + sub-pixel offset or NaN, best / second best)."""
    if k_lo > k_hi:
        return math.nan, 1.0
    key = _keyed_min(total, k_lo, k_hi)
    best, kbest = key >> 16, key & 0xFFFF
    second = _min_outside(total, k_lo, k_hi, kbest)
    no_second = k_hi - k_lo < 3 and second == 65535
    ratio = 1.0 if no_second or second == 0 else best / second
    if not no_second and second * (100 - uniqueness) < best * 100:
        return math.nan, ratio
    offset = 0.0
    if k_lo < kbest < k_hi:
        offset = subpixel_offset(subpixel, float(total[kbest - 1]), float(best),
                                 float(total[kbest + 1]))
    return kbest + offset, ratio


@njit(cache=True, nogil=True, inline='always')
def _right_candidates(column: U16, xr0: int, k_lo: int, k_hi: int,
                      keys: NDArray[np.uint32]) -> None:
    """Offer column[k] (x fixed) to the right pixel xr0 - k as the key (cost << 16 | k):
    each right pixel keeps the smallest cost and, on ties, the first k (a plain min, so
    the loop vectorises)."""
    for k in range(k_lo, k_hi + 1):
        key = (np.uint32(column[np.uint64(k)]) << np.uint32(16)) | np.uint32(k)
        xr = np.uint64(xr0 - k)  # >= 0; unsigned, so no negative-index wraparound check
        keys[xr] = min(keys[xr], key)


@njit(parallel=True, cache=True, nogil=True)
def upward_horizontal_select(cost: U8, image: F32, partial: U16, dxs: NDArray[np.int64],
                             dys: NDArray[np.int64], p1: int, p2: int,
                             p2_table: NDArray[np.int64], lb0: U16, lb1: U16, lb2: U16,
                             mbuf: U16, min_disparity: int, uniqueness: float, subpixel: int,
                             total: U16, left_to_right: U16, right_to_left: U16,
                             keys: NDArray[np.uint32], disparity: F32, disparity_right: F32,
                             ratio: F32, store_total: bool, chunks: int) -> None:
    """The rest of SGM, one row at a time from the bottom up, without a second volume pass.

    For each row: (1) the upward paths (the downward ones mirrored) are added to the
    downward sum ``partial`` in a row buffer, in parallel across x; (2) the two horizontal
    paths run one per thread; (3) the total is formed and the left disparity selected,
    while each chunk of x offers its totals to the right-view pixels; (4) the right view
    is merged and refined. The full volume is thus read once here and never rewritten.

    Args:
        cost: (H, W, D) uint8 cost volume.
        image: (H, W) float32 left image (adaptive P2).
        partial: (H, W, D) uint16 sum of the downward paths (``aggregate.sweep_down``);
            overwritten with the full sum when ``store_total`` (tests).
        dxs, dys: The downward directions, as given to ``sweep_down``.
        p1, p2, p2_table: Penalties, as in ``aggregate.sweep_down``.
        lb0, lb1, lb2, mbuf: Ring buffers, as in ``aggregate.sweep_down``.
        min_disparity: Disparity of index 0.
        uniqueness: OpenCV-style uniqueness ratio in percent (0 disables).
        subpixel: 0 none, 1 parabola, 2 equiangular.
        total, left_to_right, right_to_left: (W, D) uint16 row scratch, three arrays.
        keys: (chunks, W) uint32 scratch for the right view.
        disparity: (H, W) float32 out: left disparity, NaN where invalid.
        disparity_right: (H, W) float32 out: right-view disparity, NaN where invalid.
        ratio: (H, W) float32 out: best / second-best aggregated cost of the left winner.
        store_total: Write the full sum back into ``partial``.
        chunks: Pieces each row is split into for the threads.
    """
    h, w, n = cost.shape
    ndir = dxs.shape[0]
    chunks = max(1, min(w, chunks, keys.shape[0]))
    for i in range(h):
        y = h - 1 - i
        ring = i % 3
        cur_ring = _ring(lb0, lb1, lb2, ring)
        for c in prange(chunks):  # (1) upward paths + downward sum
            for x in range(c * w // chunks, (c + 1) * w // chunks):
                out = total[x]
                part = partial[y, x]
                for d in range(n):
                    out[d] = part[d]
                for j in range(ndir):
                    step = dys[j]
                    xp = x + dxs[j]
                    cur = cur_ring[j, x]
                    if i - step < 0 or xp < 0 or xp >= w:
                        best = path_start(cost[y, x], cur)
                    else:
                        pring = (i - step) % 3
                        p2e = table_p2(p2, p2_table, image[y, x], image[y + step, xp])
                        best = path_step(cost[y, x], _ring(lb0, lb1, lb2, pring)[j, xp],
                                         int(mbuf[j, pring, xp]), p1, p2e, cur)
                    mbuf[j, ring, x] = best
                    store_path(cur, out, True)
        for task in prange(2):  # (2) left-to-right and right-to-left, one each
            line_a, line_b = new_line(n), new_line(n)
            dst = left_to_right if task == 0 else right_to_left
            best = 0
            for s in range(w):
                x = s if task == 0 else w - 1 - s
                cur, prev = (line_a, line_b) if s & 1 else (line_b, line_a)
                if s == 0:
                    best = path_start(cost[y, x], cur)
                else:
                    xn = x - 1 if task == 0 else x + 1
                    p2e = table_p2(p2, p2_table, image[y, x], image[y, xn])
                    best = path_step(cost[y, x], prev, best, p1, p2e, cur)
                row = dst[x]
                for d in range(n):
                    row[d] = cur[d + 1]
        for c in prange(chunks):  # (3) totals, left selection, right-view candidates
            ck = keys[c]
            for xr in range(w):
                ck[xr] = np.uint32(0xFFFFFFFF)
            for x in range(c * w // chunks, (c + 1) * w // chunks):
                tot = total[x]
                ltr = left_to_right[x]
                rtl = right_to_left[x]
                for d in range(n):
                    tot[d] += ltr[d] + rtl[d]
                if store_total:
                    part = partial[y, x]
                    for d in range(n):
                        part[d] = tot[d]
                k_lo = max(0, x - min_disparity - (w - 1))
                k_hi = min(n - 1, x - min_disparity)
                k, r = select_pixel(tot, k_lo, k_hi, subpixel, uniqueness)
                disparity[y, x] = min_disparity + k
                ratio[y, x] = r
                if k_lo <= k_hi:
                    _right_candidates(tot, x - min_disparity, k_lo, k_hi, ck)
        for c in prange(chunks):  # (4) right view: merge the chunks' candidates, refine
            for xr in range(c * w // chunks, (c + 1) * w // chunks):
                key = np.uint32(0xFFFFFFFF)
                for cc in range(chunks):
                    key = min(key, keys[cc, xr])
                if key == np.uint32(0xFFFFFFFF):
                    disparity_right[y, xr] = math.nan
                    continue
                kbest = int(key & np.uint32(0xFFFF))
                xl = xr + min_disparity + kbest
                offset = 0.0
                if 0 < kbest < n - 1 and 0 < xl < w - 1:
                    offset = subpixel_offset(subpixel, float(total[xl - 1, kbest - 1]),
                                             float(key >> np.uint32(16)),
                                             float(total[xl + 1, kbest + 1]))
                disparity_right[y, xr] = min_disparity + kbest + offset


# --------------------------------------------------------------------- references
def select_reference(total: NDArray[np.integer], *, min_disparity: int, uniqueness: float,
                     subpixel: str) -> tuple[F32, F32, F32]:
    """Plain numpy selection from a full (H, W, D) total: (left, right, ratio)."""
    h, w, n = total.shape
    tot = total.astype(np.float64)
    ks = np.arange(n)
    xs = np.arange(w)
    xr_of = xs[:, None] - (min_disparity + ks)[None, :]  # (W, D) right pixel of (x, k)
    valid = (xr_of >= 0) & (xr_of < w)
    masked = np.where(valid[None], tot, np.inf)
    kbest = np.argmin(masked, axis=2)
    best = np.take_along_axis(masked, kbest[..., None], axis=2)[..., 0]
    near = np.abs(ks[None, None, :] - kbest[..., None]) <= 1
    second = np.where(near, np.inf, masked).min(axis=2)
    has_second = np.isfinite(second)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(has_second & (second > 0), best / np.where(second > 0, second, 1), 1.0)
    unique = ~has_second | (second * (100 - uniqueness) >= best * 100)
    mode = SUBPIXEL_MODES[subpixel]
    offset = np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            k = kbest[y, x]
            if 0 < k < n - 1 and valid[x, k - 1] and valid[x, k + 1]:
                offset[y, x] = subpixel_offset.py_func(mode, tot[y, x, k - 1], tot[y, x, k],
                                                       tot[y, x, k + 1])
    any_valid = valid.any(axis=1)[None, :]
    left = np.where(unique & any_valid, min_disparity + kbest + offset, np.nan)
    ratio = np.where(any_valid, ratio, 1.0)
    right = np.full((h, w), np.nan)
    for xr in range(w):
        xl = xr + min_disparity + ks
        ok = (xl >= 0) & (xl < w)
        if not ok.any():
            continue
        diag = np.full((h, n), np.inf)
        diag[:, ok] = tot[:, xl[ok], ks[ok]]
        kb = np.argmin(diag, axis=1)
        for y in range(h):
            k = kb[y]
            off = 0.0
            if 0 < k < n - 1 and ok[k - 1] and ok[k + 1]:
                off = subpixel_offset.py_func(mode, diag[y, k - 1], diag[y, k], diag[y, k + 1])
            right[y, xr] = min_disparity + k + off
    return left.astype(np.float32), right.astype(np.float32), ratio.astype(np.float32)
