"""The learned matching cost (``matching_cost: learned | census+learned``) as rows of the
matcher's (H, W, D) uint8 volume, like :class:`~depth_nodes.core.sgm.cost.CostInputs`.

Each image's unit feature vectors (``core/learned/network.py``) are computed once per
frame and quantised to integers (:data:`QUANT` per unit, so that a unit's square is
:data:`QUANT2` = 2^12); the cost of disparity ``d`` at (y, x) is then about
``learned_weight * (1 - f_left(y, x) . f_right(y, x - d))``, in integers on 16-bit lanes
(:func:`learned_term`: the distance ``QUANT2 - dot``, over 32, times the weight, over
128, rounded). The dot product is exact: by Cauchy-Schwarz every partial sum of two
quantised unit vectors is at most about (QUANT + sqrt(C) / 2)^2, 4 356 for 16 features,
below 2^15, so the plain reference matches bit for bit. With ``census+learned`` it is
added to the census + intensity cost of the same cell: for a network of
:data:`FUSED_CHANNELS` features and the 16-bit census kernel (uint8 images, a census of
32 bits at most) in the same pass over each pixel's cell (:func:`_census_learned_rows_16`),
else in a second pass over the rows. A cell whose match lies outside the right image costs
:data:`~depth_nodes.core.sgm.cost.OUT_OF_RANGE_COST`, as with census, so the border rules
(``border.py``) apply unchanged.

Layout: both images' features are stored channel-major per row ((H, C, W)), the right
ones mirrored left-right, so the loop over disparities reads each channel's row forward and
contiguously and vectorises over disparities (no sum across lanes).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from depth_nodes.core.jit import no_nrt_kernel
from depth_nodes.core.learned.network import (
    NORM_FLOOR,
    FeatureExtractor,
)
from depth_nodes.core.sgm.cost import (
    OUT_OF_RANGE_COST,
    CostInputs,
    _disparity_span,
    pixel_costs_16,
    right_halves,
)

U8 = NDArray[np.uint8]
U16 = NDArray[np.uint16]
I16 = NDArray[np.int16]
#: Integer units of a feature vector's length (features are in [-QUANT, QUANT]).
QUANT = 64
#: A unit vector's square, QUANT^2 = 2^12: the learned term divides by shifts.
QUANT2 = QUANT * QUANT
#: The feature count of the fused census + learned kernel (its dot product unrolled): the
#: shipped network's.
FUSED_CHANNELS = 6


@njit(cache=True, nogil=True, inline='always')
def learned_term(dot: np.int16, weight: np.uint16) -> np.uint16:
    """The learned cost of two quantised unit vectors whose dot product is ``dot``:
    ``((max(0, QUANT2 - dot) + 16) >> 5) * weight + 64) >> 7``, about ``weight * (1 -
    cosine)`` rounded, on 16-bit lanes (the distance is at most about 8 400, so with a
    weight up to 127 nothing overflows), clipped to 254."""
    dist = np.uint16(max(np.int16(0), np.int16(np.int16(QUANT2) - dot)))
    value = np.uint16(np.uint16(np.uint16(np.uint16(dist + np.uint16(16)) >> np.uint16(5))
                                * weight + np.uint16(64)) >> np.uint16(7))
    return min(value, np.uint16(254))


@njit(cache=True, nogil=True, parallel=True)
def _unit_quantised(raw: NDArray[np.float32], border: int, mirrored: bool, out: I16) -> None:
    """Each pixel's (C,) vector of ``raw`` (C, H + 2 border, W + 2 border) over its norm,
    times QUANT, rounded into ``out`` (H, C, W), mirrored in x when ``mirrored``. Rows in
    parallel, each loop over x (it vectorises)."""
    c, h, w = out.shape[1], out.shape[0], out.shape[2]
    q = np.float32(QUANT)
    floor = np.float32(NORM_FLOOR)
    for y in prange(h):
        scale = np.empty(w, np.float32)
        for x in range(w):
            scale[x] = np.float32(0.0)
        for ch in range(c):
            src = raw[ch, y + border]
            for x in range(w):
                scale[x] += src[x + border] * src[x + border]
        for x in range(w):
            scale[x] = q / max(np.sqrt(scale[x]), floor)
        # |raw * scale| <= QUANT for a unit vector: no clipping needed
        for ch in range(c):
            row = out[y, ch]
            src = raw[ch, y + border]
            if mirrored:
                for x in range(w):  # unsigned: no negative-index check, so it vectorises
                    row[np.uint64(w - 1 - x)] = np.int16(np.rint(src[x + border] * scale[x]))
            else:
                for x in range(w):
                    row[x] = np.int16(np.rint(src[x + border] * scale[x]))


@no_nrt_kernel()
def _learned_rows(fl: I16, frm: I16, y0: int, min_disparity: int, weight: int, add: bool,
                  out: U8, acc: I16) -> None:
    """Rows y0 .. y0 + len(out) - 1 of the learned cost into ``out`` (added to what is
    there when ``add``: cells outside the right image already hold OUT_OF_RANGE_COST).

    ``fl`` is (H, C, W), ``frm`` the right features mirrored, (H, C, W), both quantised
    unit vectors (see the module notes: their sums fit 16 bits); ``acc`` is (D,) int16
    scratch (the kernel allocates nothing, ``jit.NO_NRT``)."""
    rows, w, n = out.shape
    c = fl.shape[1]
    wt = np.uint16(weight)
    top = np.uint16(254)
    for i in range(rows):
        y = y0 + i
        for x in range(w):
            xr0 = x - min_disparity
            k_lo = max(0, xr0 - (w - 1))
            k_hi = min(n - 1, xr0)
            if not add:
                for k in range(0, min(k_lo, n)):
                    out[i, x, k] = OUT_OF_RANGE_COST
                for k in range(max(k_hi + 1, 0), n):
                    out[i, x, k] = OUT_OF_RANGE_COST
            if k_lo > k_hi:
                continue
            xm0 = w - 1 - xr0  # mirrored index of k = 0's right pixel
            for k in range(k_lo, k_hi + 1):
                acc[k] = np.int16(0)
            for ch in range(c):
                a = fl[y, ch, x]
                for k in range(k_lo, k_hi + 1):
                    # unsigned: no negative-index wraparound check
                    acc[np.uint64(k)] = np.int16(acc[np.uint64(k)] + np.int16(
                        a * frm[y, ch, np.uint64(xm0 + k)]))
            for k in range(k_lo, k_hi + 1):
                value = learned_term(acc[k], wt)
                if add:
                    value = np.uint16(value + np.uint16(out[i, x, k]))
                out[i, x, k] = np.uint8(min(value, top))


@njit(cache=True, nogil=True, inline='always')
def _add_learned_6(f: I16, x: int, r0: I16, r1: I16, r2: I16, r3: I16, r4: I16, r5: I16,
                   xm0: int, k_lo: int, k_hi: int, weight: np.uint16, cell: U8) -> None:
    """cell[k] += the learned term of 6-feature vectors, k in [k_lo, k_hi]: ``f`` the left
    row's features (C, W) at column ``x``, ``r0 .. r5`` the right row's mirrored features by
    channel (the dot product unrolled: one 16-bit lane per disparity)."""
    f0, f1, f2, f3, f4, f5 = f[0, x], f[1, x], f[2, x], f[3, x], f[4, x], f[5, x]
    top = np.uint16(254)
    for k in range(k_lo, k_hi + 1):
        xm = np.uint64(xm0 + k)  # unsigned: no negative-index wraparound check
        dot = np.int16(np.int16(f0 * r0[xm]) + np.int16(f1 * r1[xm]) +
                       np.int16(f2 * r2[xm]) + np.int16(f3 * r3[xm]) +
                       np.int16(f4 * r4[xm]) + np.int16(f5 * r5[xm]))
        value = np.uint16(np.uint16(cell[np.uint64(k)]) + learned_term(dot, weight))
        cell[np.uint64(k)] = np.uint8(min(value, top))


@no_nrt_kernel()
def _census_learned_rows_16(census_l: NDArray[np.uint32], census_rm: NDArray[np.uint32],
                            left: NDArray[np.int16], right_m: NDArray[np.int16],
                            lo_l: NDArray[np.int16], hi_l: NDArray[np.int16],
                            lo_rm: NDArray[np.int16], hi_rm: NDArray[np.int16], y0: int,
                            min_disparity: int, census_weight: int, intensity_weight: int,
                            use_bt: bool, truncation: int, out: U8, rm_lo: U16, rm_hi: U16,
                            fl: I16, frm: I16, weight: int) -> None:
    """Rows of the census + learned volume in one pass over each pixel's cell: the census
    + intensity cost (:func:`~depth_nodes.core.sgm.cost.pixel_costs_16`), then the learned
    term of :data:`FUSED_CHANNELS` features added while the cell is in the cache."""
    rows, w = out.shape[:2]
    wt = np.uint16(weight)
    for i in range(rows):
        y = y0 + i
        for x in range(w):
            rm_lo[x] = np.uint16(census_rm[y, x] & np.uint32(0xFFFF))
            rm_hi[x] = np.uint16(census_rm[y, x] >> np.uint32(16))
        r = frm[y]
        for x in range(w):
            cell = out[i, x]
            k_lo, k_hi = _disparity_span(x, min_disparity, w, cell)
            if k_lo > k_hi:
                continue
            xm0 = w - 1 - (x - min_disparity)  # mirrored index of k = 0's right pixel
            cl = census_l[y, x]
            pixel_costs_16(np.uint16(cl & np.uint32(0xFFFF)), np.uint16(cl >> np.uint32(16)),
                           rm_lo, rm_hi, left[y, x], lo_l[y, x], hi_l[y, x], right_m[y],
                           lo_rm[y], hi_rm[y], xm0, k_lo, k_hi, census_weight,
                           intensity_weight, use_bt, truncation, cell)
            _add_learned_6(fl[y], x, r[0], r[1], r[2], r[3], r[4], r[5], xm0, k_lo, k_hi, wt,
                           cell)


@no_nrt_kernel()
def _learned_rows_6(fl: I16, frm: I16, y0: int, min_disparity: int, weight: int,
                    out: U8) -> None:
    """:func:`_learned_rows` (not added) for :data:`FUSED_CHANNELS` features, the dot
    product unrolled (:func:`_add_learned_6` on cells set to 0)."""
    rows, w = out.shape[:2]
    wt = np.uint16(weight)
    zero = np.uint8(0)
    for i in range(rows):
        y = y0 + i
        r = frm[y]
        for x in range(w):
            cell = out[i, x]
            k_lo, k_hi = _disparity_span(x, min_disparity, w, cell)
            if k_lo > k_hi:
                continue
            for k in range(k_lo, k_hi + 1):
                cell[k] = zero
            _add_learned_6(fl[y], x, r[0], r[1], r[2], r[3], r[4], r[5],
                           w - 1 - (x - min_disparity), k_lo, k_hi, wt, cell)


@dataclass(frozen=True)
class LearnedCosts:
    """A frame's learned cost, by rows (a :class:`~depth_nodes.core.sgm.cost.CostRows`).

    Attributes:
        left: (H, C, W) int16 quantised left features.
        right_mirrored: (H, C, W) int16 right features, mirrored in x.
        min_disparity: Smallest disparity.
        weight: Cost of orthogonal features (``learned_weight``); a perfect match costs 0.
        census: The census + intensity cost to add to (``census+learned``), or None.
    """

    left: I16
    right_mirrored: I16
    min_disparity: int
    weight: int
    census: CostInputs | None = None

    def rows(self, y0: int, out: U8) -> U8:
        """Rows y0 .. y0 + len(out) - 1 of the cost volume, into ``out`` (one thread)."""
        census = self.census
        if census is not None and census.sixteen_bit and \
                self.left.shape[1] == FUSED_CHANNELS:
            cl, crm, l2, r2m, lo_l, hi_l, lo_rm, hi_rm = census.arrays
            rm_lo, rm_hi = right_halves(out.shape[1])
            _census_learned_rows_16(cl, crm, l2, r2m, lo_l, hi_l, lo_rm, hi_rm, y0,
                                    census.min_disparity, census.census_weight,
                                    census.intensity_weight, census.use_bt, census.truncation,
                                    out, rm_lo, rm_hi, self.left, self.right_mirrored,
                                    self.weight)
            return out
        if census is None and self.left.shape[1] == FUSED_CHANNELS:
            _learned_rows_6(self.left, self.right_mirrored, y0, self.min_disparity,
                            self.weight, out)
            return out
        if census is not None:
            census.rows(y0, out)
        _learned_rows(self.left, self.right_mirrored, y0, self.min_disparity, self.weight,
                      self.census is not None, out, np.empty(out.shape[2], np.int16))
        return out


def learned_costs(extractor: FeatureExtractor, left: NDArray[Any], right: NDArray[Any],
                  *, min_disparity: int, weight: int, census: CostInputs | None = None,
                  buffers: tuple[I16, I16] | None = None) -> LearnedCosts:
    """The features of a rectified grey pair, ready for :meth:`LearnedCosts.rows`.

    ``buffers``: the two (H, C, W) int16 arrays of the previous frame
    (:attr:`LearnedCosts.left`, :attr:`LearnedCosts.right_mirrored`), overwritten when
    their shapes fit, so a stream allocates them once.
    """
    h, w = left.shape
    c = extractor.net.channels
    if buffers is None or buffers[0].shape != (h, c, w):
        buffers = (np.empty((h, c, w), np.int16), np.empty((h, c, w), np.int16))
    fl, frm = buffers
    _unit_quantised(extractor.padded(left), 1, False, fl)
    _unit_quantised(extractor.padded(right), 1, True, frm)
    return LearnedCosts(fl, frm, int(min_disparity), int(weight), census)


def unit_quantised(raw: NDArray[np.float32]) -> I16:
    """(H, W, C) quantised unit features of raw (C, H, W) features."""
    c, h, w = raw.shape
    out = np.empty((h, c, w), np.int16)
    _unit_quantised(np.ascontiguousarray(raw, np.float32), 0, False, out)
    return np.ascontiguousarray(out.transpose(0, 2, 1))


def learned_costs_from(left: I16, right: I16, *, min_disparity: int, weight: int,
                       census: CostInputs | None = None) -> LearnedCosts:
    """:class:`LearnedCosts` of quantised unit features (:func:`unit_quantised`) given
    as two (H, W, C) arrays."""
    frm = np.ascontiguousarray(right[:, ::-1].transpose(0, 2, 1))
    return LearnedCosts(np.ascontiguousarray(left.transpose(0, 2, 1)), frm, int(min_disparity),
                        int(weight), census)
