"""Matching costs: the census Hamming distance, absolute difference and Birchfield-Tomasi,
and their weighted sum, as a (H, W, D) uint8 cost volume, or any band of its rows.

Layout: the disparity axis is innermost and contiguous; index ``k`` of the volume is the
disparity ``min_disparity + k``. A disparity whose right pixel ``x - d`` falls outside the
image gets :data:`OUT_OF_RANGE_COST`, the largest cost, so it is never preferred (the
matcher may give those cells a neutral cost instead: ``border.py``).

The census is :mod:`~depth_nodes.core.sgm.census`'s; the intensity term may be taken on a
brightness-matched right image (:mod:`~depth_nodes.core.sgm.brightness`). Every numba
kernel here has a plain numpy reference that the tests compare it with
(``cost_volume_reference`` in ``test/reference/sgm.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numba import njit
from numpy.typing import NDArray

from depth_nodes.core.jit import no_nrt_kernel
from depth_nodes.core.sgm.brightness import matched_brightness
from depth_nodes.core.sgm.census import (
    Census,
    census_dtype,
    census_transform,
    popcount,
)

#: Cost of a disparity whose right pixel lies outside the image.
OUT_OF_RANGE_COST = 255

U8 = NDArray[np.uint8]
U16 = NDArray[np.uint16]


@njit(cache=True, nogil=True)
def _half_sample_range(img: NDArray[np.float32]) -> tuple[NDArray[np.float32],
                                                           NDArray[np.float32]]:
    """Per pixel, min and max of the pixel and its two half-way interpolations in x."""
    h, w = img.shape
    lo = np.empty_like(img)
    hi = np.empty_like(img)
    for y in range(h):
        for x in range(w):
            c = img[y, x]
            left = 0.5 * (c + img[y, max(x - 1, 0)])
            right = 0.5 * (c + img[y, min(x + 1, w - 1)])
            lo[y, x] = min(c, min(left, right))
            hi[y, x] = max(c, max(left, right))
    return lo, hi


@njit(cache=True, nogil=True, inline='always')
def pixel_costs(cl: np.unsignedinteger[Any], census_rm: NDArray[np.unsignedinteger[Any]],
                il: np.float32, lo_l: np.float32, hi_l: np.float32,
                right_m: NDArray[np.float32], lo_rm: NDArray[np.float32],
                hi_rm: NDArray[np.float32], xm0: int, k_lo: int, k_hi: int,
                census_weight: int, intensity_weight: int, use_bt: bool, truncation: int,
                out: U8) -> None:
    """out[k] = min(census_weight * hamming + intensity_weight * round(min(AD or BT,
    truncation)), 254) for k in [k_lo, k_hi], the right pixel of k being xr0 - k.

    Every right-image row is mirrored (right[xr] = right_m[W - 1 - xr]) and xm0 = W - 1 -
    xr0, so the loop reads forward (reading backward costs a permute per vector: the
    volume took 1.6x as long). Both terms in one loop on 32-bit lanes: the sum in int32,
    the intensity term in float32 (a float64 constant would halve the vector width). A
    zero weight skips its term. Weights and truncation are clamped to 255, which changes
    no result (any term reaching 255 is clipped to 254 anyway) and keeps the int32 sum
    far from overflow. (The coarse search's window kernels call it too: ``ranged.py``.)
    """
    zero = np.float32(0.0)
    half = np.float32(0.5)
    cap = np.float32(min(truncation, 255))
    cw = np.int32(min(census_weight, 255))
    iw = np.int32(min(intensity_weight, 255))
    top = np.int32(254)
    for k in range(k_lo, k_hi + 1):
        xm = np.uint64(xm0 + k)  # unsigned: no negative-index wraparound check
        value = np.int32(0)
        if census_weight:
            value = np.int32(cw * np.int32(popcount(cl ^ census_rm[xm])))
        if intensity_weight:
            ir = right_m[xm]
            if use_bt:
                d_left = max(zero, max(il - hi_rm[xm], lo_rm[xm] - il))
                d_right = max(zero, max(ir - hi_l, lo_l - ir))
                diff = min(d_left, d_right)
            else:
                diff = abs(il - ir)
            value = np.int32(value + iw * np.int32(min(diff, cap) + half))
        out[np.uint64(k)] = np.uint8(min(value, top))


@njit(cache=True, nogil=True, inline='always')
def _disparity_span(x: int, min_disparity: int, w: int, cell: U8) -> tuple[int, int]:
    """The indices [k_lo, k_hi] of pixel x whose right pixel x - min_disparity - k lies in
    the image (empty when k_lo > k_hi); every other entry of ``cell`` gets
    :data:`OUT_OF_RANGE_COST`."""
    n = cell.shape[0]
    xr0 = x - min_disparity  # right pixel of k = 0; of k: xr0 - k
    k_lo = max(0, xr0 - (w - 1))
    k_hi = min(n - 1, xr0)
    for k in range(0, min(k_lo, n)):
        cell[k] = OUT_OF_RANGE_COST
    for k in range(max(k_hi + 1, 0), n):
        cell[k] = OUT_OF_RANGE_COST
    return k_lo, k_hi


@njit(cache=True, nogil=True)
def _cost_rows(census_l: NDArray[np.unsignedinteger[Any]],
               census_rm: NDArray[np.unsignedinteger[Any]], left: NDArray[np.float32],
               right_m: NDArray[np.float32], lo_l: NDArray[np.float32],
               hi_l: NDArray[np.float32], lo_rm: NDArray[np.float32],
               hi_rm: NDArray[np.float32], y0: int, min_disparity: int, census_weight: int,
               intensity_weight: int, use_bt: bool, truncation: int, out: U8) -> None:
    """Rows y0 .. y0 + len(out) - 1 of the cost volume, into ``out``. Every right-image
    array (``*_rm``, ``right_m``) is mirrored left-right: disparity k's right pixel xr0 - k
    is entry W - 1 - xr0 + k. One thread: the matcher runs bands of rows in parallel."""
    rows, w = out.shape[:2]
    for i in range(rows):
        y = y0 + i
        for x in range(w):
            cell = out[i, x]
            k_lo, k_hi = _disparity_span(x, min_disparity, w, cell)
            if k_lo > k_hi:
                continue
            xm0 = w - 1 - (x - min_disparity)  # mirrored index of k = 0's right pixel
            pixel_costs(census_l[y, x], census_rm[y], left[y, x], lo_l[y, x], hi_l[y, x],
                        right_m[y], lo_rm[y], hi_rm[y], xm0, k_lo, k_hi,
                        census_weight, intensity_weight, use_bt, truncation, cell)


@njit(cache=True, nogil=True)
def _doubled_half_sample_range(img: U8, twice: NDArray[np.int16], lo: NDArray[np.int16],
                               hi: NDArray[np.int16]) -> None:
    """For a uint8 image: 2 x the pixel, and 2 x the min and max of the pixel and its two
    half-way interpolations in x (:func:`_half_sample_range` in integers: exact)."""
    h, w = img.shape
    for y in range(h):
        row = img[y]
        for x in range(w):
            c = np.int16(row[x])
            left = c + np.int16(row[max(x - 1, 0)])
            right = c + np.int16(row[min(x + 1, w - 1)])
            twice[y, x] = 2 * c
            lo[y, x] = min(2 * c, min(left, right))
            hi[y, x] = max(2 * c, max(left, right))


@njit(cache=True, nogil=True, inline='always')
def pixel_costs_16(cl_lo: np.uint16, cl_hi: np.uint16, rm_lo: NDArray[np.uint16],
                   rm_hi: NDArray[np.uint16], il: np.int16, lo_l: np.int16, hi_l: np.int16,
                   right_m: NDArray[np.int16], lo_rm: NDArray[np.int16],
                   hi_rm: NDArray[np.int16], xm0: int, k_lo: int, k_hi: int,
                   census_weight: int, intensity_weight: int, use_bt: bool, truncation: int,
                   out: U8) -> None:
    """:func:`pixel_costs` for uint8 images, on 16-bit lanes (twice as many per vector).

    Intensities come doubled (2 I and 2 x the half-sample range), so BT and AD are integers
    and ``(min(2 diff, 2 cap) + 1) >> 1`` is exactly the float path's ``int(min(diff, cap)
    + 0.5)``. The census is split into its low and high 16 bits. Each term is clipped to
    254 before the sum, which keeps it within 16 bits and changes no result.
    """
    zero = np.int16(0)
    cap = np.int16(2 * min(truncation, 255))
    cw = np.uint16(min(census_weight, 255))
    iw = np.uint16(min(intensity_weight, 255))
    top = np.uint16(254)
    one = np.int16(1)
    # one loop per combination of terms, with no branch inside: LLVM left the conditions
    # in the loop (as masks on every load) when they were tested per k
    if census_weight and intensity_weight and use_bt:
        for k in range(k_lo, k_hi + 1):
            xm = np.uint64(xm0 + k)  # unsigned: no negative-index wraparound check
            bits = np.uint16(popcount(np.uint16(cl_lo ^ rm_lo[xm]))
                             + popcount(np.uint16(cl_hi ^ rm_hi[xm])))
            ir = right_m[xm]
            d_left = max(zero, np.int16(max(np.int16(il - hi_rm[xm]),
                                            np.int16(lo_rm[xm] - il))))
            d_right = max(zero, np.int16(max(np.int16(ir - hi_l), np.int16(lo_l - ir))))
            term = np.uint16(np.uint16(min(min(d_left, d_right), cap) + one) >> np.uint16(1))
            value = np.uint16(min(np.uint16(cw * bits), top) + min(np.uint16(iw * term), top))
            out[np.uint64(k)] = np.uint8(min(value, top))
        return
    for k in range(k_lo, k_hi + 1):
        xm = np.uint64(xm0 + k)  # unsigned: no negative-index wraparound check
        value = np.uint16(0)
        if census_weight:
            bits = np.uint16(popcount(np.uint16(cl_lo ^ rm_lo[xm]))
                             + popcount(np.uint16(cl_hi ^ rm_hi[xm])))
            value = min(np.uint16(cw * bits), top)
        if intensity_weight:
            ir = right_m[xm]
            if use_bt:
                d_left = max(zero, np.int16(max(np.int16(il - hi_rm[xm]),
                                                np.int16(lo_rm[xm] - il))))
                d_right = max(zero, np.int16(max(np.int16(ir - hi_l), np.int16(lo_l - ir))))
                diff = min(d_left, d_right)
            else:
                diff = np.int16(abs(np.int16(il - ir)))
            term = np.uint16(np.uint16(min(diff, cap) + one) >> np.uint16(1))
            value = np.uint16(value + min(np.uint16(iw * term), top))
        out[np.uint64(k)] = np.uint8(min(value, top))


@no_nrt_kernel()
def _cost_rows_16(census_l: NDArray[np.uint32], census_rm: NDArray[np.uint32],
                  left: NDArray[np.int16], right_m: NDArray[np.int16],
                  lo_l: NDArray[np.int16], hi_l: NDArray[np.int16],
                  lo_rm: NDArray[np.int16], hi_rm: NDArray[np.int16], y0: int,
                  min_disparity: int, census_weight: int, intensity_weight: int,
                  use_bt: bool, truncation: int, out: U8, rm_lo: U16, rm_hi: U16) -> None:
    """:func:`_cost_rows` for uint8 images and a census of at most 32 bits (doubled
    intensities, see :func:`pixel_costs_16`); ``rm_lo`` and ``rm_hi`` are (W,) uint16
    scratch for the right census row's halves (:func:`right_halves`)."""
    rows, w = out.shape[:2]
    for i in range(rows):
        y = y0 + i
        # the right census row as two 16-bit halves (mirrored like every right array)
        for x in range(w):
            rm_lo[x] = np.uint16(census_rm[y, x] & np.uint32(0xFFFF))
            rm_hi[x] = np.uint16(census_rm[y, x] >> np.uint32(16))
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


class CostRows(Protocol):
    """What the matcher's schedule needs of a frame's costs: any band of rows of the
    (H, W, D) uint8 volume, on demand (one thread per call). :class:`CostInputs` is one;
    the plane sweep's (``depth_nodes.core.mvs.cost``) is another."""

    def rows(self, y0: int, out: U8) -> U8:
        """Rows y0 .. y0 + len(out) - 1 of the cost volume, into ``out``."""
        ...  # pragma: no cover (a protocol)


class StereoCostRows(CostRows, Protocol):
    """A stereo pair's costs (census or learned): rows whose disparity index ``k`` is
    ``min_disparity + k``, so the border statistic knows which cells are inside."""

    @property
    def min_disparity(self) -> int:
        """The disparity of index 0."""
        ...  # pragma: no cover (a protocol)


@dataclass(frozen=True)
class CostInputs:
    """Everything the cost of any row needs, prepared once per frame (census images,
    intensities, half-sample ranges): :meth:`rows` then fills any band of rows, so the
    matcher never holds the whole (H, W, D) volume."""

    arrays: tuple[NDArray[Any], ...]
    sixteen_bit: bool
    min_disparity: int
    disparity_range: int
    census_weight: int
    intensity_weight: int
    use_bt: bool
    truncation: int

    def rows(self, y0: int, out: U8) -> U8:
        """Rows y0 .. y0 + len(out) - 1 of the cost volume, into ``out`` (one thread)."""
        common = (y0, self.min_disparity, self.census_weight, self.intensity_weight,
                  self.use_bt, self.truncation, out)
        kernel: Any = _cost_rows_16 if self.sixteen_bit else _cost_rows
        kernel(*self.arrays, *common, *(right_halves(out.shape[1]) if self.sixteen_bit else ()))
        return out


def right_halves(width: int) -> tuple[U16, U16]:
    """Scratch of the 16-bit cost kernels: the right census row as two 16-bit halves (they
    allocate nothing themselves, ``jit.NO_NRT``)."""
    return np.empty(width, np.uint16), np.empty(width, np.uint16)


def cost_inputs(left: NDArray[np.generic], right: NDArray[np.generic], *,
                min_disparity: int, disparity_range: int,
                census_window: tuple[int, int] = (9, 7), census_weight: int = 1,
                intensity_weight: int = 0, intensity_cost: str = 'bt',
                intensity_truncation: int = 30, match_brightness: bool = False,
                census_buffers: tuple[Census, Census] | None = None) -> CostInputs:
    """The per-frame inputs of :func:`cost_volume` (same arguments), for costs by rows."""
    left, right = np.asarray(left), np.asarray(right)
    h, w = left.shape
    if census_buffers is None:
        dtype = census_dtype(census_window)
        census_buffers = (np.empty((h, w), dtype), np.empty((h, w), dtype))
    cl, crm = census_buffers
    if census_weight:
        census_transform(left, census_window, cl)
        census_transform(right, census_window, crm, mirrored=True)
    if intensity_weight and match_brightness:
        right = matched_brightness(left, right)
    common = (int(min_disparity), int(disparity_range), int(census_weight),
              int(intensity_weight), intensity_cost == 'bt', int(intensity_truncation))
    if left.dtype == np.uint8 and right.dtype == np.uint8 and cl.dtype == np.uint32:
        doubled = [np.empty((h, w), np.int16) for _ in range(6)]
        l2, lo_l2, hi_l2, r2m, lo_rm2, hi_rm2 = doubled
        _doubled_half_sample_range(np.ascontiguousarray(left), l2, lo_l2, hi_l2)
        _doubled_half_sample_range(np.ascontiguousarray(right[:, ::-1]), r2m, lo_rm2, hi_rm2)
        return CostInputs((cl, crm, l2, r2m, lo_l2, hi_l2, lo_rm2, hi_rm2), True, *common)
    lf = np.ascontiguousarray(left, dtype=np.float32)
    # the right image mirrored (the half-sample range commutes with the mirror)
    rfm = np.ascontiguousarray(right[:, ::-1], dtype=np.float32)
    lo_l, hi_l = _half_sample_range(lf)
    lo_rm, hi_rm = _half_sample_range(rfm)
    return CostInputs((cl, crm, lf, rfm, lo_l, hi_l, lo_rm, hi_rm), False, *common)


def cost_volume(left: NDArray[np.generic], right: NDArray[np.generic], *,
                min_disparity: int, disparity_range: int,
                census_window: tuple[int, int] = (9, 7), census_weight: int = 1,
                intensity_weight: int = 0, intensity_cost: str = 'bt',
                intensity_truncation: int = 30, match_brightness: bool = False,
                out: U8 | None = None,
                census_buffers: tuple[Census, Census] | None = None) -> U8:
    """Matching cost of every pixel and disparity.

    cost = census_weight * hamming(census) + intensity_weight * min(AD or BT, truncation),
    clipped to 254; out-of-image disparities cost :data:`OUT_OF_RANGE_COST`.

    A uint8 pair with a census of at most 32 bits runs on 16-bit lanes (doubled integer
    intensities, :func:`pixel_costs_16`): 0.8x the time of the float kernel, same volume.

    Args:
        left: (H, W) rectified left grey image.
        right: (H, W) rectified right grey image.
        min_disparity: Smallest disparity (may be negative).
        disparity_range: Number of disparities D.
        census_window: (height, width) of the census window.
        census_weight: Weight of the Hamming distance (0 disables census).
        intensity_weight: Weight of the intensity term (0 disables it).
        intensity_cost: ``'bt'`` (Birchfield-Tomasi) or ``'ad'`` (absolute difference).
        intensity_truncation: Cap of the intensity term, grey levels.
        match_brightness: Give the right image the left's mean and standard deviation
            for the intensity term (:func:`matched_brightness`); the census is unaffected.
        out: Optional (H, W, D) uint8 buffer.
        census_buffers: Optional two (H, W) buffers of :func:`census_dtype` for the census
            images (the right one is filled mirrored).

    Returns:
        The (H, W, D) uint8 cost volume.
    """
    inputs = cost_inputs(left, right, min_disparity=min_disparity,
                         disparity_range=disparity_range, census_window=census_window,
                         census_weight=census_weight, intensity_weight=intensity_weight,
                         intensity_cost=intensity_cost,
                         intensity_truncation=intensity_truncation,
                         match_brightness=match_brightness, census_buffers=census_buffers)
    h, w = np.shape(left)
    if out is None:
        out = np.empty((h, w, disparity_range), np.uint8)
    return inputs.rows(0, out)
