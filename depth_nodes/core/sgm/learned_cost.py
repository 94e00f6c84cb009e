"""The learned matching cost (``matching_cost: learned | census+learned``) as rows of the
matcher's (H, W, D) uint8 volume, like :class:`~depth_nodes.core.sgm.cost.CostInputs`.

Each image's unit feature vectors (``core/learned/network.py``) are computed once per
frame and quantised to integers (:data:`QUANT` per unit); the cost of disparity ``d`` at
(y, x) is then ``round(learned_weight * (1 - f_left(y, x) . f_right(y, x - d)))``, the
dot product summed on 16-bit integer lanes: by Cauchy-Schwarz every partial sum of two
quantised unit vectors is at most about (QUANT + sqrt(C) / 2)^2, 16 641 for 16 features,
below 2^15, so the sum is exact and the plain reference matches bit for bit. With
``census+learned`` it is added to the census + intensity cost of the same cell. A cell
whose match lies outside the right image costs
:data:`~depth_nodes.core.sgm.cost.OUT_OF_RANGE_COST`, as with census, so the border rules
(``border.py``) apply unchanged.

Layout: the right features are stored mirrored left-right and channel-major per row
((H, C, W)), so the loop over disparities reads each channel's row forward and
contiguously and vectorises over disparities (no sum across lanes).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from depth_nodes.core.jit import no_nrt_kernel
from depth_nodes.core.learned.network import (
    NORM_FLOOR,
    FeatureExtractor,
)
from depth_nodes.core.sgm.cost import OUT_OF_RANGE_COST, CostInputs

U8 = NDArray[np.uint8]
I16 = NDArray[np.int16]
#: Integer units of a feature vector's length (features are in [-QUANT, QUANT]).
QUANT = 127


@njit(cache=True, nogil=True)
def _unit_quantised(raw: NDArray[np.float32], channel_major: bool, out: I16) -> None:
    """Each pixel's (C,) vector of ``raw`` (C, H, W) over its norm, times QUANT, rounded
    into ``out``: (H, W, C), or (H, C, W) mirrored in x when ``channel_major``."""
    c, h, w = raw.shape
    q = np.float32(QUANT)
    for y in range(h):
        for x in range(w):
            total = np.float32(0.0)
            for ch in range(c):
                total += raw[ch, y, x] * raw[ch, y, x]
            scale = q / max(np.sqrt(total), np.float32(NORM_FLOOR))
            for ch in range(c):
                value = np.int16(min(max(np.rint(raw[ch, y, x] * scale), -q), q))
                if channel_major:
                    out[y, ch, w - 1 - x] = value
                else:
                    out[y, x, ch] = value


@no_nrt_kernel()
def _learned_rows(fl: I16, frm: I16, y0: int, min_disparity: int, weight: int, add: bool,
                  out: U8, acc: I16) -> None:
    """Rows y0 .. y0 + len(out) - 1 of the learned cost into ``out`` (added to what is
    there when ``add``: cells outside the right image already hold OUT_OF_RANGE_COST).

    ``fl`` is (H, W, C), ``frm`` the right features mirrored, (H, C, W), both quantised
    unit vectors (see the module notes: their sums fit 16 bits); ``acc`` is (D,) int16
    scratch (the kernel allocates nothing, ``jit.NO_NRT``)."""
    rows, w, n = out.shape
    c = fl.shape[2]
    q2 = np.int32(QUANT * QUANT)
    half = np.int32(QUANT * QUANT // 2)
    wt = np.int32(weight)
    zero = np.int32(0)
    top = np.int32(254)
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
                a = fl[y, x, ch]
                for k in range(k_lo, k_hi + 1):
                    # unsigned: no negative-index wraparound check
                    acc[np.uint64(k)] = np.int16(acc[np.uint64(k)] + np.int16(
                        a * frm[y, ch, np.uint64(xm0 + k)]))
            for k in range(k_lo, k_hi + 1):
                value = (wt * max(zero, q2 - np.int32(acc[k])) + half) // q2
                if add:
                    value += np.int32(out[i, x, k])
                out[i, x, k] = np.uint8(min(value, top))


@dataclass(frozen=True)
class LearnedCosts:
    """A frame's learned cost, by rows (a :class:`~depth_nodes.core.sgm.cost.CostRows`).

    Attributes:
        left: (H, W, C) int16 quantised left features.
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
        if self.census is not None:
            self.census.rows(y0, out)
        _learned_rows(self.left, self.right_mirrored, y0, self.min_disparity, self.weight,
                      self.census is not None, out, np.empty(out.shape[2], np.int16))
        return out


def learned_costs(extractor: FeatureExtractor, left: NDArray[Any], right: NDArray[Any],
                  *, min_disparity: int, weight: int, census: CostInputs | None = None,
                  buffers: tuple[I16, I16] | None = None) -> LearnedCosts:
    """The features of a rectified grey pair, ready for :meth:`LearnedCosts.rows`.

    ``buffers``: the (H, W, C) and (H, C, W) int16 arrays of the previous frame
    (:attr:`LearnedCosts.left`, :attr:`LearnedCosts.right_mirrored`), overwritten when
    their shapes fit, so a stream allocates them once.
    """
    h, w = left.shape
    c = extractor.net.channels
    if buffers is None or buffers[0].shape != (h, w, c):
        buffers = (np.empty((h, w, c), np.int16), np.empty((h, c, w), np.int16))
    fl, frm = buffers
    _unit_quantised(extractor.raw(left), False, fl)
    _unit_quantised(extractor.raw(right), True, frm)
    return LearnedCosts(fl, frm, int(min_disparity), int(weight), census)


def unit_quantised(raw: NDArray[np.float32]) -> I16:
    """(H, W, C) quantised unit features of raw (C, H, W) features
    (:func:`_unit_quantised`'s layout for the left image)."""
    out = np.empty(raw.shape[1:] + raw.shape[:1], np.int16)
    _unit_quantised(np.ascontiguousarray(raw, np.float32), False, out)
    return out


def learned_costs_from(left: I16, right: I16, *, min_disparity: int, weight: int,
                       census: CostInputs | None = None) -> LearnedCosts:
    """:class:`LearnedCosts` of quantised unit features (:func:`unit_quantised`) given
    as two (H, W, C) arrays."""
    frm = np.ascontiguousarray(right[:, ::-1].transpose(0, 2, 1))
    return LearnedCosts(np.ascontiguousarray(left), frm, int(min_disparity), int(weight),
                        census)
