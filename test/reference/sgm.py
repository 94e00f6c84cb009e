"""Plain numpy references of the census SGM's kernels (``depth_nodes/core/sgm/``): the
census transform, the cost volume, the path aggregation, the selection, the matcher's
check, the learned cost; and the windows of the coarse search (``ranged.py``) as masks of
the full volume. The same arithmetic as the kernels, written out, so the tests can hold
them equal (``test_sgm_kernels.py``, ``test_sgm_ranged.py``, ``test_sgm_bands.py``,
``test_learned_cost.py``)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.jit import python_function
from depth_nodes.core.learned.network import NORM_FLOOR
from depth_nodes.core.sgm.aggregate import SENTINEL, SINGLE_PASS, VERTICAL_DIRECTIONS
from depth_nodes.core.sgm.brightness import matched_brightness
from depth_nodes.core.sgm.cost import OUT_OF_RANGE_COST
from depth_nodes.core.sgm.learned_cost import QUANT, QUANT2
from depth_nodes.core.sgm.select import SUBPIXEL_MODES, subpixel_offset

F32 = NDArray[np.float32]
I16 = NDArray[np.int16]
I32 = NDArray[np.int32]
U8 = NDArray[np.uint8]
U64 = NDArray[np.uint64]


# -- depth_nodes.core.sgm.census ---------------------------------------------------------------
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


# -- depth_nodes.core.sgm.cost -----------------------------------------------------------------
def cost_volume_reference(left: NDArray[np.generic], right: NDArray[np.generic], *,
                          min_disparity: int, disparity_range: int,
                          census_window: tuple[int, int] = (9, 7), census_weight: int = 1,
                          intensity_weight: int = 0, intensity_cost: str = 'bt',
                          intensity_truncation: int = 30,
                          match_brightness: bool = False) -> U8:
    """Plain numpy version of :func:`cost_volume`."""
    lf, rf = np.asarray(left, np.float32), np.asarray(right, np.float32)
    h, w = lf.shape
    cl = census_transform_reference(lf, census_window)
    cr = census_transform_reference(rf, census_window)
    if match_brightness:
        rf = np.asarray(matched_brightness(left, right), np.float32)

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


# -- depth_nodes.core.sgm.aggregate ------------------------------------------------------------
def aggregate_path_reference(cost: U8, image: NDArray[np.float32], dx: int, dy: int,
                             p1: int, p2: int, p2_scale: float = 0.0) -> NDArray[np.int64]:
    """L_r for one direction (dx, dy) (the previous pixel is (x - dx, y - dy)), computed
    pixel by pixel in path order with plain numpy over d; int64, for tests."""
    h, w, n = cost.shape
    out = np.zeros((h, w, n), np.int64)
    ys = range(h) if dy >= 0 else range(h - 1, -1, -1)
    xs = list(range(w)) if dx >= 0 else list(range(w - 1, -1, -1))
    for y in ys:
        for x in xs:
            c = cost[y, x].astype(np.int64)
            yp, xp = y - dy, x - dx
            if not (0 <= yp < h and 0 <= xp < w) or (dx == 0 and dy == 0):
                out[y, x] = c
                continue
            prev = out[yp, xp]
            m = prev.min()
            if p2_scale > 0:
                step = int(abs(float(image[y, x]) - float(image[yp, xp])))
                p2e = max(p1, int(p2 / (1.0 + step / p2_scale)))
            else:
                p2e = p2
            up = np.concatenate([[SENTINEL], prev[:-1]])
            down = np.concatenate([prev[1:], [SENTINEL]])
            best = np.minimum(np.minimum(prev, np.minimum(up, down) + p1), m + p2e)
            out[y, x] = c + best - m
    return out


def all_directions(paths: int) -> list[tuple[int, int]]:
    """Every (dx, dy) direction of a 4, 5, 8 or 16 path SGM (horizontal ones included)."""
    down = VERTICAL_DIRECTIONS[paths]
    if paths in SINGLE_PASS:
        return [(1, 0), (-1, 0), *down]
    return [(1, 0), (-1, 0), *down, *((-dx, -dy) for dx, dy in down)]


def aggregate_reference(cost: U8, image: NDArray[np.float32], paths: int, p1: int, p2: int,
                        p2_scale: float = 0.0) -> NDArray[np.int64]:
    """S = sum of L_r over every direction of ``paths``; plain reference, int64."""
    return sum(  # type: ignore[return-value]
        aggregate_path_reference(cost, image, dx, dy, p1, p2, p2_scale)
        for dx, dy in all_directions(paths))


# -- depth_nodes.core.sgm.select ---------------------------------------------------------------
def select_reference(total: NDArray[np.integer], *, min_disparity: int, uniqueness: float,
                     subpixel: str, extrapolate: bool = False,
                     window: NDArray[np.bool_] | None = None) -> tuple[F32, F32, F32]:
    """Plain numpy selection from a full (H, W, D) total: (left, right, ratio). With an
    (H, W, D) ``window`` mask (the coarse search's, :func:`window_mask`) only its cells
    are candidates, of both views."""
    h, w, n = total.shape
    tot = total.astype(np.float64)
    if window is not None:
        tot = np.where(window, tot, np.inf)
    ks = np.arange(n)
    xs = np.arange(w)
    xr_of = xs[:, None] - (min_disparity + ks)[None, :]  # (W, D) right pixel of (x, k)
    inside = (xr_of >= 0) & (xr_of < w)
    valid = np.ones_like(inside) if extrapolate else inside
    valid = np.broadcast_to(valid[None], (h, w, n))
    if window is not None:
        valid = valid & window
    masked = np.where(valid, tot, np.inf)
    kbest = np.argmin(masked, axis=2)
    best = np.take_along_axis(masked, kbest[..., None], axis=2)[..., 0]
    near = np.abs(ks[None, None, :] - kbest[..., None]) <= 1
    second = np.where(near, np.inf, masked).min(axis=2)
    has_second = np.isfinite(second)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(has_second & (second > 0), best / np.where(second > 0, second, 1), 1.0)
    unique = ~has_second | (second * (100 - uniqueness) >= best * 100)
    mode = SUBPIXEL_MODES[subpixel]
    plain_offset = python_function(subpixel_offset)
    offset = np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            k = kbest[y, x]
            if 0 < k < n - 1 and valid[y, x, k - 1] and valid[y, x, k + 1]:
                offset[y, x] = plain_offset(mode, tot[y, x, k - 1], tot[y, x, k],
                                            tot[y, x, k + 1])
    any_valid = valid.any(axis=2)
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
            if not np.isfinite(diag[y, k]):  # no window holds this right pixel
                continue
            off = 0.0
            if 0 < k < n - 1 and ok[k - 1] and ok[k + 1] and np.isfinite(diag[y, k - 1]) \
                    and np.isfinite(diag[y, k + 1]):
                off = plain_offset(mode, diag[y, k - 1], diag[y, k], diag[y, k + 1])
            right[y, xr] = min_disparity + k + off
    return left.astype(np.float32), right.astype(np.float32), ratio.astype(np.float32)


# -- depth_nodes.core.sgm.check ----------------------------------------------------------------
def check_disparity_reference(disparity: F32, disparity_right: F32, *, max_diff: float,
                              max_outside: float) -> F32:
    """Plain numpy version of :func:`check_disparity` (returns a new array)."""
    h, w = disparity.shape
    out = disparity.copy()
    finite = np.isfinite(disparity)
    xs = np.broadcast_to(np.arange(w), (h, w))
    with np.errstate(invalid='ignore'):
        xr = np.floor(xs - np.where(finite, disparity, 0) + 0.5).astype(np.int64)
    outside = np.maximum(-xr, xr - (w - 1))
    beyond = finite & (outside > 0)
    out[beyond & (outside > max_outside)] = np.nan
    inside = finite & ~beyond
    if max_diff > 0:
        ys, xi = np.nonzero(inside)
        partner = disparity_right[ys, xr[ys, xi]]
        with np.errstate(invalid='ignore'):
            agree = np.abs(disparity[ys, xi] - partner) <= max_diff
        out[ys[~agree], xi[~agree]] = np.nan
    return out


# -- depth_nodes.core.sgm.learned_cost ---------------------------------------------------------
def unit_quantised_reference(raw: NDArray[np.float32]) -> I16:
    """Plain numpy version of :func:`unit_quantised`."""
    x = np.asarray(raw, np.float32).transpose(1, 2, 0)
    norm = np.sqrt((x * x).sum(axis=2, keepdims=True, dtype=np.float32))
    scale = np.float32(QUANT) / np.maximum(norm, np.float32(NORM_FLOOR))
    out: I16 = np.rint(x * scale).astype(np.int16)  # a unit vector: within +-QUANT
    return out


def learned_cost_reference(left: I16, right: I16, *, min_disparity: int,
                           disparity_range: int, weight: int) -> U8:
    """Plain numpy version of the learned-only volume (H, W, D) of quantised (H, W, C)
    features."""
    fl, fr = left.astype(np.int64), right.astype(np.int64)
    h, w = fl.shape[:2]
    out = np.full((h, w, disparity_range), OUT_OF_RANGE_COST, np.uint8)
    xs = np.arange(w)
    for k in range(disparity_range):
        xr = xs - (min_disparity + k)
        ok = (xr >= 0) & (xr < w)
        dot = (fl[:, xs[ok]] * fr[:, xr[ok]]).sum(axis=2)
        distance = np.maximum(0, QUANT2 - dot)  # about (1 - cosine) * 2^12
        value = (((distance + 16) >> 5) * weight + 64) >> 7
        out[:, xs[ok], k] = np.minimum(value, 254)
    return out


# -- depth_nodes.core.sgm.ranged ---------------------------------------------------------------
def window_mask(lo: I32, wid: I32, disparity_range: int) -> NDArray[np.bool_]:
    """(H, W, D) bool: which cells each pixel's window holds (for the references)."""
    ks = np.arange(disparity_range)
    return (ks >= lo[..., None]) & (ks < (lo + wid)[..., None])


def to_flat(volume: NDArray[Any], lo: I32, wid: I32) -> NDArray[Any]:
    """The windows' cells of an (H, W, D) volume, in the flat layout."""
    return volume[window_mask(lo, wid, volume.shape[2])]


def from_flat(flat: NDArray[Any], lo: I32, wid: I32, disparity_range: int,
              fill: int) -> NDArray[np.int64]:
    """An (H, W, D) int64 volume with the flat cells in their windows, ``fill`` elsewhere."""
    mask = window_mask(lo, wid, disparity_range)
    out = np.full(mask.shape, fill, np.int64)
    out[mask] = flat
    return out
