"""SGM over windows: every pixel searches only its own disparity window.

The coarse search (``coarse.py``, tSGM's idea) gives each pixel the window of
disparities its half-resolution neighbourhood found; only the cells of those windows get
a cost, are aggregated and are selected from: 22 - 49 % of the full volume's cells in the
frames measured (docs/speed.md).

Storage: pixel (y, x) holds its window's ``wid[y, x]`` cells, disparity indices
``lo[y, x]`` .. ``lo[y, x] + wid[y, x] - 1``, at ``base[y * W + x]`` of a flat array
(:func:`flat_offsets`); cost uint8, the sum of the vertical paths uint16.

The recurrence is the full matcher's (``aggregate.py``) with every cell outside a
window treated as infinitely expensive: the step from a neighbour whose window does not
contain d - 1 .. d + 1 takes its minimum plus P2, as tSGM does. The path buffers are
indexed by the full disparity range, with the sentinel everywhere outside the window
they hold (each kernel rubs out the window a slot held before it writes a new one), so
the full matcher's step (``aggregate.path_step``) runs unchanged on a slice of them.
With every window the full range the result is the full matcher's, bit for bit (tested).

Every kernel here has a plain reference in the tests' terms: the full matcher's plain
references on a volume whose cells outside the windows cost "infinity"
(``test/reference/sgm.py``, with ``window_mask``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from depth_nodes.core.jit import no_nrt_kernel
from depth_nodes.core.sgm.aggregate import (
    SENTINEL,
    path_start,
    path_step,
    ring_slot,
    store_path,
    table_p2,
)
from depth_nodes.core.sgm.cost import (
    OUT_OF_RANGE_COST,
    CostInputs,
    pixel_costs,
    pixel_costs_16,
    right_halves,
)
from depth_nodes.core.sgm.select import cost_key, keyed_min, select_pixel, subpixel_offset

U8 = NDArray[np.uint8]
U16 = NDArray[np.uint16]
I32 = NDArray[np.int32]
I64 = NDArray[np.int64]
F32 = NDArray[np.float32]

#: Bytes a window's cell takes: 1 of cost, 2 of the vertical paths' sum.
CELL_BYTES = 3


# --------------------------------------------------------------------- flat layout
def flat_offsets(wid: I32) -> I64:
    """(H W + 1,) int64: where each pixel's cells start in the flat arrays (row-major),
    the last entry their total."""
    base = np.zeros(wid.size + 1, np.int64)
    np.cumsum(wid.ravel(), out=base[1:])
    return base


# -------------------------------------------------------------------------- costs
@njit(cache=True, nogil=True, inline='always')
def _window_span(x: int, w: int, min_disparity: int, n_disp: int, lp: int,
                 n: int, cell: U8) -> tuple[int, int]:
    """The window entries [a, b] of pixel x whose right pixel is inside the image; the
    other entries of ``cell`` get :data:`OUT_OF_RANGE_COST`."""
    xr0 = x - min_disparity
    a = max(0, xr0 - (w - 1)) - lp
    b = min(n_disp - 1, xr0) - lp
    a = max(a, 0)
    b = min(b, n - 1)
    for t in range(0, min(a, n)):
        cell[t] = OUT_OF_RANGE_COST
    for t in range(max(b + 1, 0), n):
        cell[t] = OUT_OF_RANGE_COST
    return a, b


@njit(cache=True, nogil=True, inline='always')
def _window_cell(y: int, x: int, w: int, min_disparity: int, n_disp: int, lo: I32,
                 wid: I32, base: I64, out: U8) -> tuple[U8, int, int, int]:
    """Pixel (y, x)'s cells in ``out``, the entries [a, b] whose match is inside the
    image (:func:`_window_span`) and the mirrored right pixel of its entry 0."""
    lp, n = lo[y, x], wid[y, x]
    c0 = base[y * w + x]
    cell = out[c0:c0 + n]
    a, b = _window_span(x, w, min_disparity, n_disp, lp, n, cell)
    return cell, a, b, w - 1 - (x - min_disparity) + lp


@njit(cache=True, nogil=True)
def _ranged_cost_rows(census_l: NDArray[Any], census_rm: NDArray[Any], left: F32,
                      right_m: F32, lo_l: F32, hi_l: F32, lo_rm: F32, hi_rm: F32, y0: int,
                      rows: int, min_disparity: int, n_disp: int, census_weight: int,
                      intensity_weight: int, use_bt: bool, truncation: int, lo: I32,
                      wid: I32, base: I64, out: U8) -> None:
    """``cost._cost_rows`` over the windows of rows y0 .. y0 + rows - 1."""
    w = census_l.shape[1]
    for y in range(y0, y0 + rows):
        for x in range(w):
            cell, a, b, xm0 = _window_cell(y, x, w, min_disparity, n_disp, lo, wid, base, out)
            if a > b:
                continue
            pixel_costs(census_l[y, x], census_rm[y], left[y, x], lo_l[y, x], hi_l[y, x],
                        right_m[y], lo_rm[y], hi_rm[y], xm0, a, b, census_weight,
                        intensity_weight, use_bt, truncation, cell)


@no_nrt_kernel()
def _ranged_cost_rows_16(census_l: NDArray[np.uint32], census_rm: NDArray[np.uint32],
                         left: NDArray[np.int16], right_m: NDArray[np.int16],
                         lo_l: NDArray[np.int16], hi_l: NDArray[np.int16],
                         lo_rm: NDArray[np.int16], hi_rm: NDArray[np.int16], y0: int,
                         rows: int, min_disparity: int, n_disp: int, census_weight: int,
                         intensity_weight: int, use_bt: bool, truncation: int, lo: I32,
                         wid: I32, base: I64, out: U8, rm_lo: U16, rm_hi: U16) -> None:
    """``cost._cost_rows_16`` over the windows of rows y0 .. y0 + rows - 1."""
    w = census_l.shape[1]
    for y in range(y0, y0 + rows):
        for x in range(w):
            rm_lo[x] = np.uint16(census_rm[y, x] & np.uint32(0xFFFF))
            rm_hi[x] = np.uint16(census_rm[y, x] >> np.uint32(16))
        for x in range(w):
            cell, a, b, xm0 = _window_cell(y, x, w, min_disparity, n_disp, lo, wid, base, out)
            if a > b:
                continue
            cl = census_l[y, x]
            pixel_costs_16(np.uint16(cl & np.uint32(0xFFFF)), np.uint16(cl >> np.uint32(16)),
                           rm_lo, rm_hi, left[y, x], lo_l[y, x], hi_l[y, x], right_m[y],
                           lo_rm[y], hi_rm[y], xm0, a, b, census_weight, intensity_weight,
                           use_bt, truncation, cell)


def ranged_costs(inputs: CostInputs, y0: int, rows: int, lo: I32, wid: I32, base: I64,
                 out: U8) -> None:
    """The costs of the windows of rows y0 .. y0 + rows - 1 into the flat ``out`` (one
    thread); out-of-image cells get :data:`~depth_nodes.core.sgm.cost.OUT_OF_RANGE_COST`."""
    common = (y0, rows, inputs.min_disparity, inputs.disparity_range, inputs.census_weight,
              inputs.intensity_weight, inputs.use_bt, inputs.truncation, lo, wid, base, out)
    kernel: Any = _ranged_cost_rows_16 if inputs.sixteen_bit else _ranged_cost_rows
    kernel(*inputs.arrays, *common, *(right_halves(lo.shape[1]) if inputs.sixteen_bit else ()))


@no_nrt_kernel()
def ranged_best_cost_sum(cost: U8, lo: I32, wid: I32, base: I64, x_lo: int, x_hi: int,
                         row_step: int) -> float:
    """``border.mean_best_cost``'s sum (every ``row_step``-th row, columns [x_lo, x_hi)),
    the minimum taken over each pixel's window."""
    h, w = lo.shape
    total = 0.0
    for y in range(0, h, row_step):
        row = 0.0
        for x in range(x_lo, x_hi):
            c0 = base[y * w + x]
            best = np.uint8(255)
            for t in range(wid[y, x]):
                best = min(best, cost[c0 + t])
            row += best
        total += row
    return total


@njit(cache=True, nogil=True)
def ranged_fill_outside(cost: U8, lo: I32, wid: I32, base: I64, y0: int, rows: int,
                        min_disparity: int, n_disp: int, value: int) -> None:
    """``border.fill_outside`` on the windows of rows y0 .. y0 + rows - 1."""
    w = lo.shape[1]
    edge_lo = min(w, max(0, min_disparity + n_disp - 1))
    edge_hi = max(edge_lo, min(w, w + min_disparity))
    v = np.uint8(value)
    for y in range(y0, y0 + rows):
        for i in range(edge_lo + w - edge_hi):
            x = i if i < edge_lo else edge_hi + i - edge_lo
            lp, n = lo[y, x], wid[y, x]
            c0 = base[y * w + x]
            xr0 = x - min_disparity
            a = max(0, xr0 - (w - 1)) - lp
            b = min(n_disp - 1, xr0) - lp
            for t in range(0, min(max(a, 0), n)):
                cost[c0 + t] = v
            for t in range(max(b + 1, 0), n):
                cost[c0 + t] = v


# ---------------------------------------------------------------------- aggregation
@njit(cache=True, nogil=True, inline='always')
def _rub_out(line: U16, lp: int, n: int) -> None:
    """Put the sentinel back over the window ``lp`` .. ``lp + n - 1`` of a padded line
    (through a view indexed by the loop counter: the loop vectorises)."""
    window = line[lp + 1:lp + 1 + n]
    for t in range(n):
        window[t] = SENTINEL


@njit(parallel=True, cache=True, nogil=True)
def ranged_sweep(cost: U8, base: I64, lo: I32, wid: I32, image: F32, y0: int, rows: int,
                 dxs: I64, dys: I64, p1: int, p2: int, p2_table: I64, lb0: U16, lb1: U16,
                 lb2: U16, mbuf: U16, partial: U16, upward: bool, accumulate: bool) -> None:
    """``aggregate.sweep_down`` over the windows (flat ``cost`` and ``partial``).

    The ring lines (n_dirs, W, D + 2) are indexed by the full range; the first band of a
    chain (y0 = 0 downward, the bottom band upward) fills them with the sentinel, and
    each slot's previous window (the row three back along the chain) is rubbed out
    before the slot takes the new one.
    """
    for _ in prange(1):  # one iteration: see aggregate.ONE_THREAD_GUFUNC
        h, w = image.shape
        ndir = dxs.shape[0]
        sign = -1 if upward else 1
        if (y0 + rows == h) if upward else (y0 == 0):
            lb0[:] = SENTINEL
            lb1[:] = SENTINEL
            lb2[:] = SENTINEL
        for r in range(rows):
            y = y0 + (rows - 1 - r if upward else r)
            ring = y % 3
            cur_ring = ring_slot(lb0, lb1, lb2, ring)
            y_old = y - 3 * sign
            held = 0 <= y_old < h
            for x in range(w):
                lp, n = lo[y, x], wid[y, x]
                c0 = base[y * w + x]
                cell = cost[c0:c0 + n]
                out = partial[c0:c0 + n]
                lp_old, n_old = (lo[y_old, x], wid[y_old, x]) if held else (0, 0)
                for j in range(ndir):
                    line = cur_ring[j, x]
                    _rub_out(line, lp_old, n_old)
                    cur = line[lp:lp + n + 2]
                    yp = y - sign * dys[j]
                    xp = x - sign * dxs[j]
                    if yp < 0 or yp >= h or xp < 0 or xp >= w:
                        best = path_start(cell, cur)
                    else:
                        pring = yp % 3
                        p2e = table_p2(p2, p2_table, image[y, x], image[yp, xp])
                        prev = ring_slot(lb0, lb1, lb2, pring)[j, xp]
                        best = path_step(cell, prev[lp:lp + n + 2], int(mbuf[j, pring, xp]),
                                         p1, p2e, cur)
                    mbuf[j, ring, x] = best
                    store_path(cur, out, accumulate or j > 0)


@njit(cache=True, nogil=True, inline='always')
def _ranged_horizontal(cost: U8, base: I64, lo: I32, wid: I32, image: F32, y: int, p1: int,
                       p2: int, p2_table: I64, forward: bool, even: U16, odd: U16,
                       dst: U16) -> None:
    """One horizontal path along row y (left to right when ``forward``), each pixel's
    window into dst[x, :wid]. ``even`` and ``odd`` are (D + 2) line buffers."""
    w = image.shape[1]
    even[:] = SENTINEL
    odd[:] = SENTINEL
    best = 0
    for s in range(w):
        x = s if forward else w - 1 - s
        cur_line, prev_line = (odd, even) if s & 1 else (even, odd)
        if s >= 2:  # the line held the pixel two steps back
            x_old = x - 2 if forward else x + 2
            _rub_out(cur_line, lo[y, x_old], wid[y, x_old])
        lp, n = lo[y, x], wid[y, x]
        c0 = base[y * w + x]
        cell = cost[c0:c0 + n]
        cur = cur_line[lp:lp + n + 2]
        if s == 0:
            best = path_start(cell, cur)
        else:
            xn = x - 1 if forward else x + 1
            best = path_step(cell, prev_line[lp:lp + n + 2], best, p1,
                             table_p2(p2, p2_table, image[y, x], image[y, xn]), cur)
        out = dst[x]
        for t in range(n):
            out[t] = cur[t + 1]


@no_nrt_kernel(parallel=True)
def ranged_select(cost: U8, base: I64, lo: I32, wid: I32, image: F32, partial: U16,
                  y0: int, rows: int, p1: int, p2: int, p2_table: I64, n_disp: int,
                  min_disparity: int, uniqueness: float, subpixel: int, total: U16,
                  left_to_right: U16, right_to_left: U16, lines: U16,
                  keys: NDArray[np.uint32], disparity: F32, disparity_right: F32,
                  ratio: F32, extrapolate: bool) -> None:
    """``select.band_select`` over the windows, for rows whose ``partial`` holds every
    vertical path: the horizontal paths, the total, the left and right-view selection.

    Scratch: ``total``, ``left_to_right``, ``right_to_left`` (W, D) uint16 (a pixel's
    window in its first entries), ``lines`` (2, D + 2) uint16, ``keys`` (W,) uint32.
    Outputs as in ``band_select``; a disparity outside every window is never chosen.
    """
    for _ in prange(1):  # one iteration: see aggregate.ONE_THREAD_GUFUNC
        w = image.shape[1]
        for y in range(y0, y0 + rows):
            _ranged_horizontal(cost, base, lo, wid, image, y, p1, p2, p2_table, True,
                               lines[0], lines[1], left_to_right)
            _ranged_horizontal(cost, base, lo, wid, image, y, p1, p2, p2_table, False,
                               lines[0], lines[1], right_to_left)
            for xr in range(w):
                keys[xr] = np.uint32(0xFFFFFFFF)
            for x in range(w):
                lp, n = lo[y, x], wid[y, x]
                c0 = base[y * w + x]
                part = partial[c0:c0 + n]
                ltr = left_to_right[x]
                rtl = right_to_left[x]
                tot = total[x]
                for t in range(n):
                    tot[t] = part[t] + ltr[t] + rtl[t]
                xr0 = x - min_disparity
                i_lo = max(max(0, xr0 - (w - 1)) - lp, 0)
                i_hi = min(min(n_disp - 1, xr0) - lp, n - 1)
                sel_lo, sel_hi = (0, n - 1) if extrapolate else (i_lo, i_hi)
                key = keyed_min(tot, sel_lo, sel_hi) if sel_lo <= sel_hi else 0
                k, r = select_pixel(tot, key, sel_lo, sel_hi, subpixel, uniqueness)
                disparity[y, x] = min_disparity + lp + k
                ratio[y, x] = r
                xm0 = w - 1 - xr0 + lp  # mirrored right pixel of entry 0
                for t in range(i_lo, i_hi + 1):
                    candidate = cost_key(tot[np.uint64(t)], lp + t)
                    xm = np.uint64(xm0 + t)
                    keys[xm] = min(keys[xm], candidate)
            for xr in range(w):  # the right view: refine the winners
                right_key = keys[w - 1 - xr]
                if right_key == np.uint32(0xFFFFFFFF):
                    disparity_right[y, xr] = math.nan
                    continue
                kbest = int(right_key & np.uint32(0xFFFF))
                xl = xr + min_disparity + kbest
                offset = 0.0
                if 0 < kbest < n_disp - 1 and 0 < xl < w - 1:
                    ia = kbest - 1 - lo[y, xl - 1]
                    ib = kbest + 1 - lo[y, xl + 1]
                    if 0 <= ia < wid[y, xl - 1] and 0 <= ib < wid[y, xl + 1]:
                        offset = subpixel_offset(subpixel, float(total[xl - 1, ia]),
                                                 float(right_key >> np.uint32(16)),
                                                 float(total[xl + 1, ib]))
                disparity_right[y, xr] = min_disparity + kbest + offset
