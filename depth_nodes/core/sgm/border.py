"""The cells whose match lies outside the right image, and the cost they may be given.

The cost volume gives a disparity whose right pixel ``x - d`` falls outside the image
:data:`~depth_nodes.core.sgm.cost.OUT_OF_RANGE_COST`, the largest cost, so it is never
preferred. The matcher may replace it with a neutral cost (:func:`fill_outside`), a
multiple of how much a match usually costs in the frame (:func:`mean_best_cost`), so that
the left border strip takes its disparity from its neighbours instead of being forced to
one inside the image.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from depth_nodes.core.sgm.cost import StereoCostRows
from depth_nodes.errors import ArgumentError

U8 = NDArray[np.uint8]


@njit(cache=True, nogil=True)
def best_cost_sum(cost: U8, x_lo: int, x_hi: int, row_step: int) -> float:
    """Sum over every ``row_step``-th row of an (R, W, D) volume and over its columns
    [x_lo, x_hi) of the smallest cost over d (the sum behind :func:`mean_best_cost`)."""
    total = 0.0
    for y in range(0, cost.shape[0], row_step):
        row = 0.0
        for x in range(x_lo, x_hi):
            best = np.uint8(255)
            cell = cost[y, x]
            for k in range(cell.shape[0]):
                best = min(best, cell[k])
            row += best
        total += row
    return total


def full_range_columns(w: int, n: int, min_disparity: int) -> tuple[int, int]:
    """[x_lo, x_hi): the columns of a width-``w`` image where each of the ``n`` disparities
    from ``min_disparity`` on matches inside the image (every column when none does)."""
    x_lo = max(0, min_disparity + n - 1)
    x_hi = min(w, w + min_disparity)
    return (x_lo, x_hi) if x_lo < x_hi else (0, w)


def mean_best_cost(cost: U8, min_disparity: int, *, row_step: int = 4) -> float:
    """Mean over pixels of the smallest cost over d: how much a match usually costs in
    this frame (its noise and texture), from every ``row_step``-th row and the columns
    where every disparity stays inside the image. Falls back to every column when no
    column has the full range (the mean then includes out-of-image cells)."""
    h, w, n = cost.shape
    x_lo, x_hi = full_range_columns(w, n, min_disparity)
    step = max(1, row_step)
    rows = (h + step - 1) // step
    total = float(best_cost_sum(cost, x_lo, x_hi, step))
    return float(total / max(1, rows * (x_hi - x_lo)))


def sampled_best_cost_sum(inputs: StereoCostRows, ys: range, buffer: U8) -> float:
    """:func:`mean_best_cost`'s sum over the rows ``ys`` (before dividing), their costs
    computed ``len(buffer)`` rows at a time into ``buffer``: the whole volume is never
    needed. Exact (integer sums in float64), so the mean equals mean_best_cost's."""
    w, n = buffer.shape[1:]
    x_lo, x_hi = full_range_columns(w, n, inputs.min_disparity)
    total = 0.0
    for y in ys:
        inputs.rows(y, buffer[:1])
        total += float(best_cost_sum(buffer[:1], x_lo, x_hi, 1))
    return total


def mean_best_count(h: int, w: int, n: int, min_disparity: int, row_step: int) -> int:
    """How many pixels :func:`mean_best_cost` averages over."""
    x_lo, x_hi = full_range_columns(w, n, min_disparity)
    return max(1, (h + row_step - 1) // row_step * (x_hi - x_lo))


@njit(cache=True, nogil=True)
def _fill_outside(cost: U8, min_disparity: int, value: np.uint8) -> None:
    h, w, n = cost.shape
    # only the columns near the borders have cells outside: [0, lo) and [hi, w)
    lo = min(w, max(0, min_disparity + n - 1))
    hi = max(lo, min(w, w + min_disparity))
    for y in range(h):
        for i in range(lo + w - hi):
            x = i if i < lo else hi + i - lo
            xr0 = x - min_disparity
            k_lo = max(0, xr0 - (w - 1))
            k_hi = min(n - 1, xr0)
            cell = cost[y, x]
            for k in range(0, min(k_lo, n)):
                cell[k] = value
            for k in range(max(k_hi + 1, 0), n):
                cell[k] = value


def fill_outside(cost: U8, min_disparity: int, value: int) -> None:
    """Set every cell whose right pixel ``x - min_disparity - k`` lies outside the image
    to ``value`` (0..255), in place (any band of rows of the volume).

    Raises:
        ArgumentError: ``value`` is outside 0..255.
    """
    if not 0 <= value <= 255:
        raise ArgumentError(f'value must be in 0..255, got {value}')
    _fill_outside(cost, int(min_disparity), np.uint8(value))
