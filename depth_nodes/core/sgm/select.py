"""The upward and horizontal SGM paths fused with disparity selection, row by row.

For the single-pass path counts (5: ``aggregate.SINGLE_PASS``) there are no upward paths:
the kernel adds the horizontal paths to the downward sum and selects.

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
from typing import Any

import numpy as np
from numba import njit, prange, types
from numpy.typing import NDArray

from depth_nodes.core.jit import intrinsic, no_nrt_kernel
from depth_nodes.core.sgm.aggregate import path_start, path_step, ring_slot, store_path, table_p2

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


def _cost_key_plain(cost: Any, k: Any) -> np.uint32:
    """:func:`cost_key` in Python (the JIT off)."""
    return np.uint32((int(cost) << 16) | (int(k) & 0xFFFFFFFF))


@intrinsic(_cost_key_plain)
def cost_key(typingctx: Any, cost: Any, k: Any) -> Any:
    """(uint32(cost) << 16) | uint32(k), computed in 32 bits.

    numba widens integer arithmetic to 64 bits, and LLVM then runs the loops that build
    these keys on 8 64-bit lanes per vector; emitted directly in 32 bits they run on 16.
    ``cost`` must be an unsigned integer of at most 16 bits, ``k`` any integer (< 65536).
    The coarse search's selection (``ranged.py``) builds its right-view keys with it.
    """
    if cost not in (types.uint8, types.uint16) or k not in types.integer_domain:
        return None
    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        value, index = args
        i32 = context.get_value_type(types.uint32)
        high = builder.shl(builder.zext(value, i32), context.get_constant(types.uint32, 16))
        low = builder.trunc(index, i32) if k.bitwidth > 32 else builder.zext(index, i32)
        return builder.or_(high, low)

    return types.uint32(cost, k), codegen


@njit(cache=True, nogil=True, inline='always')
def keyed_min(total: U16, k_lo: int, k_hi: int) -> int:
    """min over k of (total[k] << 16 | k): the smallest cost and, on ties, the first k, in
    one reduction that vectorises (an argmin loop does not)."""
    best = np.uint32(0xFFFFFFFF)
    for k in range(k_lo, k_hi + 1):
        i = np.uint64(k)  # k >= 0: an unsigned index skips numba's wraparound check
        best = min(best, cost_key(total[i], k))
    return int(best)


@njit(cache=True, nogil=True, inline='always')
def _min_outside(total: U16, k_lo: int, k_hi: int, kbest: int) -> int:
    """min total[k] over [k_lo, k_hi] without kbest - 1 .. kbest + 1 (65535 if none).

    The (at most three) excluded entries are set to 65535, the largest uint16, for one
    plain reduction over the whole range, then put back: the same minimum. (Two reductions
    either side of the winner, as before, each ended in a scalar remainder of random
    length; a masked single loop ran on 64-bit lanes. docs/speed.md has the times.)
    ``total`` is the caller's scratch row, so writable."""
    a = max(k_lo, kbest - 1)
    b = min(k_hi, kbest + 1)
    s0 = total[a]
    s1 = total[a + 1] if a + 1 <= b else np.uint16(0)
    s2 = total[a + 2] if a + 2 <= b else np.uint16(0)
    for j in range(a, b + 1):
        total[j] = np.uint16(65535)
    best = np.uint16(65535)
    for k in range(k_lo, k_hi + 1):
        best = min(best, total[np.uint64(k)])
    total[a] = s0
    if a + 1 <= b:
        total[a + 1] = s1
    if a + 2 <= b:
        total[a + 2] = s2
    return int(best)


@njit(cache=True, nogil=True, inline='always')
def _add_rows_keyed_min(total: U16, a: U16, b: U16) -> int:
    """total += a + b over every k, returning :func:`keyed_min` of the result over every
    k: one pass instead of two."""
    best = np.uint32(0xFFFFFFFF)
    for k in range(total.shape[0]):
        i = np.uint64(k)
        value = np.uint16(total[i] + a[i] + b[i])
        total[i] = value
        best = min(best, cost_key(value, k))
    return int(best)


@njit(cache=True, nogil=True, inline='always')
def _sum_rows_keyed_min(total: U16, part: U16, a: U16, b: U16) -> int:
    """total = part + a + b over every k, returning :func:`keyed_min` of the result: the
    partial sum is read where it is used, not copied into ``total`` first. (Kept apart from
    :func:`_add_rows_keyed_min`: that one called as this with ``part`` being ``total``
    made the bounded 8-path frame 9 % slower, the loop no longer proven alias-free.)"""
    best = np.uint32(0xFFFFFFFF)
    for k in range(total.shape[0]):
        i = np.uint64(k)
        value = np.uint16(part[i] + a[i] + b[i])
        total[i] = value
        best = min(best, cost_key(value, k))
    return int(best)


@njit(cache=True, nogil=True, inline='always')
def select_pixel(total: U16, key: int, k_lo: int, k_hi: int, subpixel: int,
                 uniqueness: float) -> tuple[float, float]:
    """Winner over k in [k_lo, k_hi]: (k + sub-pixel offset or NaN, best / second best).
    ``key`` is :func:`keyed_min` over that range (unused when the range is empty)."""
    if k_lo > k_hi:
        return math.nan, 1.0
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
def _right_candidates(column: U16, xm0: int, k_lo: int, k_hi: int, cost_m: U16,
                      k_m: U16) -> None:
    """Offer column[k] (x fixed) to the right pixel xr0 - k: each right pixel keeps the
    smallest cost and, on ties, the smallest k (the pair compared as the key cost << 16 |
    k would be, so ``cost_m`` = ``k_m`` = 65535 stands for no candidate yet). Both are
    uint16, so the loop runs on 16 lanes per vector (32-bit keys ran on 8). Indexed
    mirrored, W - 1 - xr (xm0 = W - 1 - xr0), so the loop runs forward through them."""
    for k in range(k_lo, k_hi + 1):
        c = column[np.uint64(k)]
        k16 = np.uint16(k)
        xm = np.uint64(xm0 + k)  # unsigned: no negative-index wraparound check
        old = cost_m[xm]
        better = (c < old) | ((c == old) & (k16 < k_m[xm]))
        cost_m[xm] = min(c, old)
        k_m[xm] = k16 if better else k_m[xm]


@njit(cache=True, nogil=True, inline='always')
def _horizontal_pair(cost: U8, image: F32, p1: int, p2: int, p2_table: NDArray[np.int64],
                     y_a: int, y_b: int, y0: int, forward: bool, dst: U16,
                     lines: U16) -> None:
    """One horizontal path (left to right when ``forward``) along rows ``y_a`` and ``y_b``
    of ``cost`` at once (image rows y0 + y_a and y0 + y_b), into dst[0] and dst[1].

    Along a row every step waits for the previous step's minimum over d; two independent
    rows interleaved give the core work to do while it waits (about 20% faster than one
    row at a time). ``lines``: (4, D + 2) uint16 scratch, SENTINEL at both ends of each.
    """
    n = cost.shape[2]
    w = cost.shape[1]
    a_even, a_odd, b_even, b_odd = lines[0], lines[1], lines[2], lines[3]
    best_a = best_b = 0
    for s in range(w):
        x = s if forward else w - 1 - s
        cur_a, prev_a = (a_odd, a_even) if s & 1 else (a_even, a_odd)
        cur_b, prev_b = (b_odd, b_even) if s & 1 else (b_even, b_odd)
        if s == 0:
            best_a = path_start(cost[y_a, x], cur_a)
            best_b = path_start(cost[y_b, x], cur_b)
        else:
            xn = x - 1 if forward else x + 1
            ia, ib = y0 + y_a, y0 + y_b
            best_a = path_step(cost[y_a, x], prev_a, best_a, p1,
                               table_p2(p2, p2_table, image[ia, x], image[ia, xn]), cur_a)
            best_b = path_step(cost[y_b, x], prev_b, best_b, p1,
                               table_p2(p2, p2_table, image[ib, x], image[ib, xn]), cur_b)
        row_a = dst[0, x]
        row_b = dst[1, x]
        for d in range(n):
            row_a[d] = cur_a[d + 1]
        for d in range(n):
            row_b[d] = cur_b[d + 1]


@no_nrt_kernel(parallel=True)
def band_select(cost: U8, image: F32, partial: U16, y0: int, rows: int,
                dxs: NDArray[np.int64], dys: NDArray[np.int64], p1: int, p2: int,
                p2_table: NDArray[np.int64], lb0: U16, lb1: U16, lb2: U16, mbuf: U16,
                min_disparity: int, uniqueness: float, subpixel: int, total: U16,
                left_to_right: U16, right_to_left: U16, keys: NDArray[np.uint32],
                disparity: F32, disparity_right: F32, ratio: F32, total_out: U16,
                store_total: bool, upward: bool, extrapolate: bool, ring0: int,
                lines: U16) -> None:
    """The rest of SGM for one band of rows, bottom up, on one thread.

    For each row: (1) the upward paths (the downward ones mirrored) are added to the
    downward sum ``partial`` in a row buffer; (2) the two horizontal paths (of this row
    and the next, interleaved); (3) the total is formed and the left disparity selected,
    while the totals are offered to the right-view pixels; (4) the right view is refined.
    The band's volume is read once here and never rewritten.

    The upward paths start at the last row of ``cost``: with R > ``rows`` the R - rows
    rows below the band are swept first (their paths only), so that the paths reaching
    the band carry that much context (exact when the band reaches the image bottom).
    ``ring0`` > 0 continues paths already swept through ``ring0`` rows below (by calls
    with ``rows`` 0, whose ring buffers this call's are): the rows below need not be held
    at once.

    Args:
        cost: (R, W, D) uint8 cost of rows y0 .. y0 + R - 1.
        image: (H, W) float32 left image (adaptive P2).
        partial: (rows, W, D) uint16 sum of the downward paths (``aggregate.sweep_down``).
        y0: The band's first image row.
        rows: The band's number of rows.
        dxs, dys: The downward directions, as given to ``sweep_down`` (mirrored here).
        p1, p2, p2_table: Penalties, as in ``aggregate.sweep_down``.
        lb0, lb1, lb2, mbuf: Ring buffers, as in ``aggregate.sweep_down`` (this call's own).
        min_disparity: Disparity of index 0.
        uniqueness: OpenCV-style uniqueness ratio in percent (0 disables).
        subpixel: 0 none, 1 parabola, 2 equiangular.
        total: (W, D) uint16 row scratch.
        left_to_right, right_to_left: (2, W, D) uint16 scratch: the horizontal paths of
            two rows.
        keys: (W,) uint32 scratch for the right view, used as 2 W uint16: each right
            pixel's best cost, then its disparity index (mirrored: W - 1 - xr).
        disparity: (H, W) float32 out: left disparity, NaN where invalid.
        disparity_right: (H, W) float32 out: right-view disparity, NaN where invalid.
        ratio: (H, W) float32 out: best / second-best aggregated cost of the left winner.
        total_out: (H, W, D) uint16 out when ``store_total``: the full sum (tests).
        store_total: Write the full sum into ``total_out``.
        upward: Run the upward directions (False for the
            :data:`~depth_nodes.core.sgm.aggregate.SINGLE_PASS` path counts).
        ring0: Rows the upward paths already went through (see above).
        extrapolate: Select the left disparity over every disparity, also those whose
            right pixel is outside the image (their cells then hold a neutral cost, see
            ``border.fill_outside``): the left border strip takes the disparity its
            neighbours' paths carry in. Otherwise only in-image disparities are candidates.
            The right view always uses in-image cells only.
        lines: (4, D + 2) uint16 scratch with SENTINEL at both ends of each line (this
            kernel allocates nothing: ``jit.NO_NRT``).
    """
    for _ in prange(1):  # one iteration: see aggregate.ONE_THREAD_GUFUNC
        r_all, w, n = cost.shape
        ndir = dxs.shape[0] if upward else 0
        cost_m = keys.view(np.uint16)[:w]  # the right view's candidates (uint16 pairs)
        k_m = keys.view(np.uint16)[w:]
        for i in range(r_all if upward else rows):
            b = (r_all if upward else rows) - 1 - i  # band-relative row, bottom up
            y = y0 + b
            ring = (ring0 + i) % 3
            cur_ring = ring_slot(lb0, lb1, lb2, ring)
            in_band = b < rows
            # (1) upward paths + downward sum; without upward paths (1) has nothing to do
            # and (3) adds the downward sum itself
            for x in range(w if ndir else 0):
                out = total[x]
                if in_band:
                    part = partial[b, x]
                    for d in range(n):
                        out[d] = part[d]
                for j in range(ndir):
                    step = dys[j]
                    xp = x + dxs[j]
                    cur = cur_ring[j, x]
                    if ring0 + i - step < 0 or xp < 0 or xp >= w:
                        best = path_start(cost[b, x], cur)
                    else:
                        pring = (ring0 + i - step) % 3
                        p2e = table_p2(p2, p2_table, image[y, x], image[y + step, xp])
                        best = path_step(cost[b, x], ring_slot(lb0, lb1, lb2, pring)[j, xp],
                                         int(mbuf[j, pring, xp]), p1, p2e, cur)
                    mbuf[j, ring, x] = best
                    if in_band:
                        store_path(cur, out, True)
            if not in_band:
                continue
            pair = (rows - 1 - b) % 2
            if pair == 0:  # (2) horizontal paths of this row and the next, both directions
                b_next = max(b - 1, 0)
                _horizontal_pair(cost, image, p1, p2, p2_table, b, b_next, y0, True,
                                 left_to_right, lines)
                _horizontal_pair(cost, image, p1, p2, p2_table, b, b_next, y0, False,
                                 right_to_left, lines)
            for xr in range(w):  # (3) totals, left selection, right-view candidates
                cost_m[xr] = np.uint16(65535)
                k_m[xr] = np.uint16(65535)
            for x in range(w):
                tot = total[x]
                ltr = left_to_right[pair, x]
                rtl = right_to_left[pair, x]
                k_lo = max(0, x - min_disparity - (w - 1))
                k_hi = min(n - 1, x - min_disparity)
                sel_lo, sel_hi = (0, n - 1) if extrapolate else (k_lo, k_hi)
                # without upward paths here the total is the partial sum plus the
                # horizontal paths, formed in the same pass (no copy of the partial first)
                part = partial[b, x]
                if sel_lo == 0 and sel_hi == n - 1:  # every disparity a candidate: one pass
                    key = (_add_rows_keyed_min(tot, ltr, rtl) if ndir else
                           _sum_rows_keyed_min(tot, part, ltr, rtl))
                else:
                    if ndir:
                        for d in range(n):
                            tot[d] += ltr[d] + rtl[d]
                    else:
                        for d in range(n):
                            tot[d] = part[d] + ltr[d] + rtl[d]
                    key = keyed_min(tot, sel_lo, sel_hi) if sel_lo <= sel_hi else 0
                if store_total:
                    part = total_out[y, x]
                    for d in range(n):
                        part[d] = tot[d]
                k, r = select_pixel(tot, key, sel_lo, sel_hi, subpixel, uniqueness)
                disparity[y, x] = min_disparity + k
                ratio[y, x] = r
                if k_lo <= k_hi:
                    _right_candidates(tot, w - 1 - (x - min_disparity), k_lo, k_hi, cost_m, k_m)
            for xr in range(w):  # (4) right view: refine the winners
                kbest = int(k_m[w - 1 - xr])
                if kbest == 65535:  # no candidate (k < D <= 4096 otherwise)
                    disparity_right[y, xr] = math.nan
                    continue
                xl = xr + min_disparity + kbest
                offset = 0.0
                if 0 < kbest < n - 1 and 0 < xl < w - 1:
                    offset = subpixel_offset(subpixel, float(total[xl - 1, kbest - 1]),
                                             float(cost_m[w - 1 - xr]),
                                             float(total[xl + 1, kbest + 1]))
                disparity_right[y, xr] = min_disparity + kbest + offset
