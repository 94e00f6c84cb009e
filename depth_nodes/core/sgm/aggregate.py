"""Semi-Global Matching path aggregation (Hirschmueller 2008), numba kernels.

For a path direction r the aggregated cost is

    L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d-1) + P1, L_r(p-r, d+1) + P1,
                              min_k L_r(p-r, k) + P2) - min_k L_r(p-r, k)

and the sum over paths S(p, d) = sum_r L_r(p, d). Every L is at most max(C) + P2, so
with ``paths * (max(C) + P2) < 65536`` the uint16 sums cannot overflow (the matcher checks).

Layout: disparity innermost. Directions with a vertical component are swept row by row
(here top to bottom; bottom to top in ``select.py``): each pixel of a row depends only on
earlier rows. The matcher sweeps bands of rows (``bands.py``): the downward paths run
through the bands in order, top to bottom, and the upward ones either bottom to top (whole
volumes) or afresh from a few rows below each band (memory-bounded bands, in
``select.py``, fused with the horizontal directions and the disparity selection). Each L
row lives in a small ring buffer padded with a large sentinel at both disparity ends, so
the inner loop over d has no branch. With a :data:`SINGLE_PASS` path count there are no
upward directions.

ONE_THREAD_GUFUNC: the band kernels run on one thread each (the matcher runs several
bands at once, ``bands.py``) but are compiled ``parallel=True`` around a ``prange`` of one
iteration. numba then compiles the loop nest as a parallel-loop body, which LLVM optimises
far better here: the downward sweep of a VGA frame with 128 disparities took 24 ms so
against 75 ms as a plain ``njit`` function (same code, one thread, measured on this
package's 2-core machine; the cause was not pinned down: not aliasing, error model or
fast-math). Run from several threads at once, this needs a thread-safe numba threading
layer (OpenMP or TBB, see ``bands.py``), and each thread set to one numba thread.

P2 may adapt to the image: P2' = max(P1, P2 / (1 + |I(p) - I(p-r)| / scale)), with the
intensity step truncated to an integer (exact for camera images), looked up in a table.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

#: Padding value at both disparity ends of every L buffer (never the minimum). Every L is
#: at most 65535 // 4 (the matcher's overflow rule with at least 4 paths), so SENTINEL
#: exceeds any L and SENTINEL + P1 still fits in 16 bits (see ``path_step``).
SENTINEL = 32768

U8 = NDArray[np.uint8]
U16 = NDArray[np.uint16]

#: Path directions (dx, dy) swept top to bottom; the bottom-to-top sweep mirrors them.
#: 4 paths = 2 horizontal + 2 of these, 8 = 2 + 6, 16 = 2 + 14. 5 paths = 2 horizontal + these
#: 3 from above, not mirrored (:data:`SINGLE_PASS`).
VERTICAL_DIRECTIONS = {
    4: ((0, 1),),
    5: ((0, 1), (1, 1), (-1, 1)),
    8: ((0, 1), (1, 1), (-1, 1)),
    16: ((0, 1), (1, 1), (-1, 1), (2, 1), (-2, 1), (1, 2), (-1, 2)),
}
#: Path counts aggregated in one top-to-bottom pass: no sum of the downward paths is
#: stored, so the (H, W, D) uint16 volume and the second pass over the cost volume are saved
#: (the directions of OpenCV's MODE_SGBM; 8 paths are its MODE_HH).
SINGLE_PASS = frozenset({5})


def p2_table(p1: int, p2: int, scale: float, levels: int = 65536) -> NDArray[np.int64]:
    """The adaptive P2 for every integer intensity step 0 .. levels - 1:
    max(P1, int(P2 / (1 + step / scale))); empty when ``scale`` is 0 (constant P2).

    A table turns a division per pixel and path into a lookup. Steps are truncated to
    integers, which is exact for the integer images cameras deliver.
    """
    if scale <= 0.0:
        return np.zeros(0, np.int64)
    steps = np.arange(levels, dtype=np.float64)
    return np.maximum(p1, (p2 / (1.0 + steps / scale)).astype(np.int64))


@njit(cache=True, nogil=True, inline='always')
def table_p2(p2: int, table: NDArray[np.int64], a: float, b: float) -> int:
    """P2 for a step between intensities ``a`` and ``b`` (constant when the table is empty)."""
    if table.shape[0] == 0:
        return p2
    step = min(int(abs(a - b)), table.shape[0] - 1)
    return int(table[step])


@njit(cache=True, nogil=True, inline='always')
def path_start(cost: U8, cur: U16) -> int:
    """L at the first pixel of a path: the cost itself. Returns min_d L."""
    for d in range(cost.shape[0]):
        cur[d + 1] = np.uint16(cost[d])
    best = np.uint16(SENTINEL)
    for d in range(cost.shape[0]):
        best = min(best, cur[d + 1])
    return int(best)


@njit(cache=True, nogil=True, inline='always')
def store_path(cur: U16, out: U16, accumulate: bool) -> None:
    """out (+)= cur[1:-1]: add a path's L into the sum over paths."""
    n = out.shape[0]
    if accumulate:
        for d in range(n):
            out[d] += cur[d + 1]
    else:
        for d in range(n):
            out[d] = cur[d + 1]


@njit(cache=True, nogil=True, inline='always')
def new_line(n: int) -> U16:
    """A path buffer of D + 2 entries with sentinels at both ends."""
    line = np.empty(n + 2, np.uint16)
    line[0] = SENTINEL
    line[n + 1] = SENTINEL
    return line


@njit(cache=True, nogil=True, inline='always')
def path_step(cost: U8, prev: U16, mprev: int, p1: int, p2: int, cur: U16) -> int:
    """One step of the recurrence; ``prev``/``cur`` are padded (D + 2). Returns min L.

    ``cur`` must be a buffer the caller allocated itself (not a view into an array that
    also holds ``prev``), or LLVM leaves the loop scalar. Every value is kept 16-bit (see
    below): then the recurrence and the running minimum vectorise as one loop on 16 lanes
    per 256-bit vector (LLVM's preferred width on this package's machine; compiled for
    512-bit vectors the sweep was no faster, docs/speed.md). (With numba's 64-bit
    arithmetic the fused minimum was slower than a second loop; in 16 bits the fused loop
    is 1.4x as fast as the two.)
    """
    n = cost.shape[0]
    mp = np.uint16(mprev)
    jump = np.uint16(mprev + p2)
    q1 = np.uint16(p1)
    best = np.uint16(SENTINEL)
    for d in range(n):
        # numba widens integer arithmetic to 64 bits; the explicit uint16 of each sum
        # (exact: at most SENTINEL + P1 < 65536, and L itself fits) keeps the loop on
        # 16-bit lanes instead of 64-bit ones
        v = min(prev[d + 1], np.uint16(min(prev[d], prev[d + 2]) + q1))
        v = min(v, jump)
        value = np.uint16(np.uint16(cost[d]) + v - mp)
        cur[d + 1] = value
        best = min(best, value)
    return int(best)


@njit(cache=True, nogil=True, inline='always')
def ring_slot(lb0: U16, lb1: U16, lb2: U16, index: int) -> U16:
    """Ring slot ``index`` (0, 1 or 2) of the three L-row arrays."""
    if index == 0:
        return lb0
    if index == 1:
        return lb1
    return lb2


@njit(parallel=True, cache=True, nogil=True)
def sweep_down(cost: U8, image: NDArray[np.float32], y0: int, rows: int,
               dxs: NDArray[np.int64], dys: NDArray[np.int64], p1: int, p2: int,
               p2_table: NDArray[np.int64], lb0: U16, lb1: U16, lb2: U16, mbuf: U16,
               partial: U16, upward: bool = False, accumulate: bool = False) -> None:
    """Aggregate the downward directions ``(dxs, dys)`` over rows y0 .. y0 + rows - 1,
    continuing the paths of the rows above (the ring buffers carry them from the call
    for the band above), on one thread; with ``upward``, the mirrored directions from
    the bottom row up, continuing the paths of the rows below.

    The previous pixel of direction (dx, dy) is (x - dx, y - dy) (upward: (x + dx, y +
    dy)); the sum over the directions is written into ``partial`` (added with
    ``accumulate``). ``select.band_select`` can also run the upward directions itself,
    from a few rows below its band.

    Args:
        cost: (R, W, D) uint8 cost of rows y0 .. y0 + R - 1 (R >= rows).
        image: (H, W) float32 image for the adaptive P2.
        y0: First row (0 starts every path afresh).
        rows: Number of rows to sweep.
        dxs: Horizontal steps of the directions.
        dys: Vertical steps (1 or 2).
        p1: Penalty of a 1-disparity change.
        p2: Penalty of a larger change.
        p2_table: Adaptive P2 by integer intensity step (:func:`p2_table`); empty for a
            constant P2.
        lb0, lb1, lb2: The ring of L rows, three separate (n_dirs, W, D + 2) uint16 arrays
            (image row y lives in ring y % 3) with SENTINEL at entries 0 and D + 1.
            Separate arrays let LLVM vectorise the recurrence in place (reading one array,
            writing another) without a scratch buffer and a copy.
        mbuf: (n_dirs, 3, W) uint16 ring of min_d L.
        partial: (rows, W, D) uint16 out: sum over these paths, row y0 + i in entry i.
        upward: Sweep the mirrored directions, bottom up.
        accumulate: Add the sum to ``partial`` instead of overwriting it.
    """
    for _ in prange(1):  # one iteration: see ONE_THREAD_GUFUNC
        h, w = image.shape
        ndir = dxs.shape[0]
        sign = -1 if upward else 1  # the previous pixel is (x, y) - sign (dx, dy)
        for r in range(rows):
            i = rows - 1 - r if upward else r
            y = y0 + i
            ring = y % 3
            cur_ring = ring_slot(lb0, lb1, lb2, ring)
            for x in range(w):
                out = partial[i, x]
                for j in range(ndir):
                    yp = y - sign * dys[j]
                    xp = x - sign * dxs[j]
                    cur = cur_ring[j, x]
                    if yp < 0 or yp >= h or xp < 0 or xp >= w:
                        best = path_start(cost[i, x], cur)
                    else:
                        pring = yp % 3
                        p2e = table_p2(p2, p2_table, image[y, x], image[yp, xp])
                        best = path_step(cost[i, x], ring_slot(lb0, lb1, lb2, pring)[j, xp],
                                         int(mbuf[j, pring, xp]), p1, p2e, cur)
                    mbuf[j, ring, x] = best
                    store_path(cur, out, accumulate or j > 0)


def new_line_buffers(n_dirs: int, width: int,
                     disparities: int) -> tuple[tuple[U16, U16, U16], U16]:
    """Ring buffers for :func:`sweep_down` (three L rows, sentinels in place; min_d L)."""
    rings = tuple(np.full((n_dirs, width, disparities + 2), SENTINEL, np.uint16)
                  for _ in range(3))
    mbuf = np.zeros((n_dirs, 3, width), np.uint16)
    return rings, mbuf  # type: ignore[return-value]
