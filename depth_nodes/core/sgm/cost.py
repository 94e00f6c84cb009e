"""Matching costs: census transform + Hamming distance, absolute difference and
Birchfield-Tomasi, and their weighted sum, as a (H, W, D) uint8 cost volume.

Layout: the disparity axis is innermost and contiguous; index ``k`` of the volume is the
disparity ``min_disparity + k``. A disparity whose right pixel ``x - d`` falls outside the
image gets :data:`OUT_OF_RANGE_COST`, the largest cost, so it is never preferred.

Every numba kernel here has a plain numpy reference (``*_reference``) that the tests
compare it with.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

#: Cost of a disparity whose right pixel lies outside the image.
OUT_OF_RANGE_COST = 255

U8 = NDArray[np.uint8]
U64 = NDArray[np.uint64]


# ----------------------------------------------------------------------------- census
@njit(cache=True, nogil=True)
def _census_row(padded: NDArray[np.float32], y: int, ry: int, rx: int, width: int,
                mirror: bool, bits: U64) -> None:
    """Census of one row of a border-padded image, accumulated neighbour by neighbour so
    the loop over x vectorises. ``mirror`` takes the neighbours in mirrored x order (for
    an image flipped left-right, see :func:`census_transform`)."""
    for x in range(width):
        bits[x] = np.uint64(0)
    centre = padded[y + ry, rx:rx + width]
    for dy in range(-ry, ry + 1):
        for dx in range(-rx, rx + 1):
            if dy == 0 and dx == 0:
                continue
            sx = -dx if mirror else dx
            # row views indexed by the loop counter alone: the loop vectorises
            neighbour = padded[y + ry + dy, rx + sx:rx + sx + width]
            for x in range(width):
                darker = neighbour[x] < centre[x]
                bits[x] = (bits[x] << np.uint64(1)) | np.uint64(darker)


@njit(parallel=True, cache=True, nogil=True)
def _census_kernel(padded: NDArray[np.float32], win_h: int, win_w: int, mirror: bool,
                   out: U64) -> None:
    h, w = out.shape
    for y in prange(h):
        _census_row(padded, y, win_h // 2, win_w // 2, w, mirror, out[y])


def census_transform(image: NDArray[np.generic], window: tuple[int, int],
                     out: U64 | None = None, *, mirrored: bool = False) -> U64:
    """Census signature of every pixel: one bit per window neighbour, set when the
    neighbour is darker than the centre (borders replicated).

    Args:
        image: (H, W) grey image (any real dtype).
        window: (height, width), odd, at most 63 neighbours (e.g. 9x7).
        out: Optional (H, W) uint64 buffer to fill.
        mirrored: Fill ``out`` with the census mirrored left-right (``out[:, ::-1]`` is
            then the plain census, same bit order); the cost kernel reads the right
            image's census this way.
    """
    img = np.asarray(image, dtype=np.float32)
    if mirrored:
        img = img[:, ::-1]
    if out is None:
        out = np.empty(img.shape, np.uint64)
    ry, rx = window[0] // 2, window[1] // 2
    padded = np.pad(img, ((ry, ry), (rx, rx)), mode='edge')
    _census_kernel(padded, window[0], window[1], mirrored, out)
    return out


def census_transform_reference(image: NDArray[np.generic], window: tuple[int, int]) -> U64:
    """Plain numpy census transform (same bit order as the kernel)."""
    img = np.asarray(image, dtype=np.float32)
    ry, rx = window[0] // 2, window[1] // 2
    padded = np.pad(img, ((ry, ry), (rx, rx)), mode='edge')
    h, w = img.shape
    out = np.zeros(img.shape, np.uint64)
    for dy in range(-ry, ry + 1):
        for dx in range(-rx, rx + 1):
            if dy == 0 and dx == 0:
                continue
            neighbour = padded[ry + dy:ry + dy + h, rx + dx:rx + dx + w]
            out = (out << np.uint64(1)) | (neighbour < img).astype(np.uint64)
    return out


# ------------------------------------------------------------------ intensity costs
@njit(cache=True, nogil=True, inline='always')
def _popcount(v: np.uint64) -> np.uint64:
    v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
    v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (v * np.uint64(0x0101010101010101)) >> np.uint64(56)


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
def _census_costs(cl: np.uint64, census_rm: U64, xm0: int, k_lo: int, k_hi: int,
                  weight: int, out: U8) -> None:
    """out[k] = weight * popcount(cl ^ census_r[xr0 - k]) for k in [k_lo, k_hi].

    ``census_rm`` is the right row mirrored (census_r[xr] = census_rm[W - 1 - xr]) and
    xm0 = W - 1 - xr0, so the loop reads forward (reading backward costs a permute per
    vector: the whole cost volume took 1.6x as long).
    """
    for k in range(k_lo, k_hi + 1):
        xm = np.uint64(xm0 + k)  # unsigned: no negative-index wraparound check
        out[np.uint64(k)] = np.uint8(min(weight * int(_popcount(cl ^ census_rm[xm])), 254))


@njit(cache=True, nogil=True, inline='always')
def _intensity_costs(il: np.float32, lo_l: np.float32, hi_l: np.float32,
                     right_m: NDArray[np.float32], lo_rm: NDArray[np.float32],
                     hi_rm: NDArray[np.float32], xm0: int, k_lo: int, k_hi: int,
                     weight: int, use_bt: bool, truncation: int, add: bool,
                     out: U8) -> None:
    """Add (or write) weight * round(min(AD or BT, truncation)) for k in [k_lo, k_hi].

    The right-image rows are mirrored and indexed as in :func:`_census_costs`.

    float32 throughout (a float64 constant would halve the vector width).
    """
    zero = np.float32(0.0)
    half = np.float32(0.5)
    cap = np.float32(truncation)
    top = np.float32(254.0)
    w = np.float32(weight)
    for k in range(k_lo, k_hi + 1):
        xm = np.uint64(xm0 + k)
        i = np.uint64(k)
        ir = right_m[xm]
        if use_bt:
            d_left = max(zero, max(il - hi_rm[xm], lo_rm[xm] - il))
            d_right = max(zero, max(ir - hi_l, lo_l - ir))
            diff = min(d_left, d_right)
        else:
            diff = abs(il - ir)
        value = w * np.floor(min(diff, cap) + half)
        if add:
            value += np.float32(out[i])
        out[i] = np.uint8(min(value, top))


@njit(parallel=True, cache=True, nogil=True)
def _cost_kernel(census_l: U64, census_rm: U64, left: NDArray[np.float32],
                 right_m: NDArray[np.float32], lo_l: NDArray[np.float32],
                 hi_l: NDArray[np.float32], lo_rm: NDArray[np.float32],
                 hi_rm: NDArray[np.float32], min_disparity: int, census_weight: int,
                 intensity_weight: int, use_bt: bool, truncation: int, out: U8) -> None:
    """The cost volume. Every right-image array (``*_rm``, ``right_m``) is mirrored
    left-right: disparity k's right pixel xr0 - k is entry W - 1 - xr0 + k."""
    h, w, n = out.shape
    for y in prange(h):
        for x in range(w):
            xr0 = x - min_disparity  # right pixel of k = 0; of k: xr0 - k
            k_lo = max(0, xr0 - (w - 1))
            k_hi = min(n - 1, xr0)
            cell = out[y, x]
            for k in range(0, min(k_lo, n)):
                cell[k] = OUT_OF_RANGE_COST
            for k in range(max(k_hi + 1, 0), n):
                cell[k] = OUT_OF_RANGE_COST
            if k_lo > k_hi:
                continue
            if census_weight:
                _census_costs(census_l[y, x], census_rm[y], w - 1 - xr0, k_lo, k_hi,
                              census_weight, cell)
            if intensity_weight:
                _intensity_costs(left[y, x], lo_l[y, x], hi_l[y, x], right_m[y], lo_rm[y],
                                 hi_rm[y], w - 1 - xr0, k_lo, k_hi, intensity_weight, use_bt,
                                 truncation, census_weight > 0, cell)


def cost_volume(left: NDArray[np.generic], right: NDArray[np.generic], *,
                min_disparity: int, disparity_range: int,
                census_window: tuple[int, int] = (9, 7), census_weight: int = 1,
                intensity_weight: int = 0, intensity_cost: str = 'bt',
                intensity_truncation: int = 30, out: U8 | None = None,
                census_buffers: tuple[U64, U64] | None = None) -> U8:
    """Matching cost of every pixel and disparity.

    cost = census_weight * hamming(census) + intensity_weight * min(AD or BT, truncation),
    clipped to 254; out-of-image disparities cost :data:`OUT_OF_RANGE_COST`.

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
        out: Optional (H, W, D) uint8 buffer.
        census_buffers: Optional two (H, W) uint64 buffers for the census images (the
            right one is filled mirrored).

    Returns:
        The (H, W, D) uint8 cost volume.
    """
    lf = np.ascontiguousarray(left, dtype=np.float32)
    rf = np.ascontiguousarray(right, dtype=np.float32)
    h, w = lf.shape
    if out is None:
        out = np.empty((h, w, disparity_range), np.uint8)
    if census_buffers is None:
        census_buffers = (np.empty((h, w), np.uint64), np.empty((h, w), np.uint64))
    cl, crm = census_buffers
    if census_weight:
        census_transform(lf, census_window, cl)
        census_transform(rf, census_window, crm, mirrored=True)
    # the right image mirrored (the half-sample range commutes with the mirror)
    rfm = np.ascontiguousarray(rf[:, ::-1])
    lo_l, hi_l = _half_sample_range(lf)
    lo_rm, hi_rm = _half_sample_range(rfm)
    _cost_kernel(cl, crm, lf, rfm, lo_l, hi_l, lo_rm, hi_rm, min_disparity, census_weight,
                 intensity_weight, intensity_cost == 'bt', intensity_truncation, out)
    return out


def cost_volume_reference(left: NDArray[np.generic], right: NDArray[np.generic], *,
                          min_disparity: int, disparity_range: int,
                          census_window: tuple[int, int] = (9, 7), census_weight: int = 1,
                          intensity_weight: int = 0, intensity_cost: str = 'bt',
                          intensity_truncation: int = 30) -> U8:
    """Plain numpy version of :func:`cost_volume`."""
    lf, rf = np.asarray(left, np.float32), np.asarray(right, np.float32)
    h, w = lf.shape
    cl = census_transform_reference(lf, census_window)
    cr = census_transform_reference(rf, census_window)

    def half_range(img: NDArray[np.float32]) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        left_n = 0.5 * (img + np.concatenate([img[:, :1], img[:, :-1]], axis=1))
        right_n = 0.5 * (img + np.concatenate([img[:, 1:], img[:, -1:]], axis=1))
        stack = np.stack([img, left_n, right_n])
        return stack.min(axis=0), stack.max(axis=0)

    lo_l, hi_l = half_range(lf)
    lo_r, hi_r = half_range(rf)
    out = np.full((h, w, disparity_range), OUT_OF_RANGE_COST, np.uint8)
    xs = np.arange(w)
    for k in range(disparity_range):
        xr = xs - (min_disparity + k)
        ok = (xr >= 0) & (xr < w)
        xl, xrr = xs[ok], xr[ok]
        cost = np.zeros((h, ok.sum()), np.int64)
        if census_weight:
            x = cl[:, xl] ^ cr[:, xrr]
            x = np.ascontiguousarray(x)
            bits = np.unpackbits(x.view(np.uint8).reshape(h, -1, 8), axis=2).sum(axis=2)
            cost += census_weight * bits.astype(np.int64)
        if intensity_weight:
            il, ir = lf[:, xl], rf[:, xrr]
            if intensity_cost == 'bt':
                d_left = np.maximum(0, np.maximum(il - hi_r[:, xrr], lo_r[:, xrr] - il))
                d_right = np.maximum(0, np.maximum(ir - hi_l[:, xl], lo_l[:, xl] - ir))
                diff = np.minimum(d_left, d_right)
            else:
                diff = np.abs(il - ir)
            cost += intensity_weight * (np.minimum(diff, intensity_truncation) + 0.5).astype(
                np.int64)
        out[:, xl, k] = np.minimum(cost, OUT_OF_RANGE_COST - 1)
    return out
