"""A confidence map for a checked disparity: how likely each pixel's value is right.

The map is the product of terms in [0, 1], each from a signal that separates right from
wrong disparities on the simulator scenes and on the Middlebury pairs (README, "Accuracy
on real pairs"):

* distinctiveness: ``1 - cost_ratio`` (best / second-best aggregated cost of the winner,
  from the matcher), averaged over a ``window`` x ``window`` box;
* left-right agreement: ``1 / (1 + (diff / max_diff)^2)`` of the left-right difference
  (no difference, a NaN, counts as no agreement; see the extrapolation term);
* support (``terms.support_window``): the fraction of kept pixels around the pixel. The
  wrong disparities a check lets through sit mostly beside the holes it makes: at
  occlusion edges, where a nearer object's disparity spills over the background;
* smoothness (``terms.smoothness``, px): ``1 / (1 + (|d - mean_5x5(d)| / s)^2)`` of the
  output disparity: outliers and depth edges;
* extrapolation (``terms.outside_scale``, px): a pixel whose partner ``x - d`` lies ``o``
  px outside the right image has no left-right difference; it gets ``1 / (1 + o /
  scale)`` instead of the agreement term (the left border strip, where the matcher
  extrapolated from the neighbours).

Filled pixels get ``filled_confidence`` times the distinctiveness and the terms that do not
need a left-right difference; pixels without a disparity get 0. Misuse raises
``ValueError`` naming the argument.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numba import njit
from numpy.typing import NDArray

from depth_nodes.core.validate import float_map, non_negative
from depth_nodes.errors import ArgumentError

__all__ = ['DEFAULT_TERMS', 'PLAIN_TERMS', 'ConfidenceTerms', 'box_mean', 'confidence_map',
           'outside_distance']

F32 = NDArray[np.float32]
#: Box of the smoothness term's local mean.
SMOOTHNESS_WINDOW = 5


@dataclass(frozen=True)
class ConfidenceTerms:
    """The optional terms of :func:`confidence_map` (see the module notes).

    Attributes:
        support_window: Odd side of the box of the support term (1: off).
        smoothness: Deviation scale in px of the smoothness term (0: off).
        outside_scale: Distance scale in px of the extrapolation term (0: off; a pixel
            with no left-right difference then gets no agreement).
    """

    support_window: int = 9
    smoothness: float = 1.0
    outside_scale: float = 4.0


#: What :func:`~depth_nodes.core.cross_check.cross_check` uses.
DEFAULT_TERMS = ConfidenceTerms()
#: Distinctiveness and agreement only.
PLAIN_TERMS = ConfidenceTerms(support_window=1, smoothness=0.0, outside_scale=0.0)


def _odd_window(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or (
            value < 1 or value % 2 == 0):
        raise ArgumentError(f'{name} must be an odd int >= 1, got {value!r}')
    return int(value)


def box_mean(values: F32, window: int) -> F32:
    """The mean over a ``window`` x ``window`` box, the border reflected (float32)."""
    return np.asarray(cv2.blur(values, (window, window), borderType=cv2.BORDER_REFLECT),
                      dtype=np.float32)


def outside_distance(disparity: F32) -> F32:
    """How far in px the partner ``x - d`` of each pixel lies outside the image (0 inside
    or where the disparity is NaN)."""
    w = disparity.shape[1]
    xs = np.arange(w, dtype=np.float32)[None, :]
    with np.errstate(invalid='ignore'):
        xr = np.floor(xs - disparity + 0.5)
        beyond = np.maximum(-xr, xr - (w - 1))
    distance: F32 = np.nan_to_num(np.maximum(beyond, 0.0), nan=0.0).astype(np.float32)
    return distance


def confidence_map(cost_ratio: Any, difference: Any, valid: Any, *, window: int = 5,
                   max_diff: float = 1.0, filled: Any = None,
                   filled_confidence: float = 0.1, disparity: Any = None,
                   terms: ConfidenceTerms = PLAIN_TERMS) -> F32:
    """Confidence in [0, 1] of every pixel (see the module notes).

    Args:
        cost_ratio: (H, W) float best / second-best cost in [0, 1] (NaN counts as 1).
        difference: (H, W) float left-right difference in px (NaN: no partner).
        valid: (H, W) bool, the pixels whose disparity is kept (others get 0).
        window: Odd side of the box the distinctiveness is averaged over (1: no pooling).
        max_diff: The difference scale in px: agreement 1/2 at ``max_diff`` (> 0).
        filled: Optional (H, W) bool of filled pixels: they get ``filled_confidence`` x
            the terms that need no left-right difference.
        filled_confidence: Factor in [0, 1] for filled pixels.
        disparity: Optional (H, W) float output disparity, needed by the smoothness and
            extrapolation terms (they are skipped without it).
        terms: Which optional terms to apply (:data:`PLAIN_TERMS`: none).

    Returns:
        (H, W) float32 confidence, 0 where neither valid nor filled.

    Raises:
        ArgumentError: Bad shapes or dtypes, even windows, non-positive ``max_diff``.
    """
    ratio = float_map('cost_ratio', cost_ratio)
    diff = float_map('difference', difference, ratio.shape)
    keep = np.asarray(valid)
    if keep.dtype != np.bool_ or keep.shape != ratio.shape:
        raise ArgumentError(f'valid must be a bool array of shape {ratio.shape}')
    window = _odd_window('window', window)
    support_window = _odd_window('support_window', terms.support_window)
    scale = non_negative('max_diff', max_diff)
    if scale == 0:
        raise ArgumentError('max_diff must be > 0 for the confidence')
    factor = non_negative('filled_confidence', filled_confidence)
    if factor > 1:
        raise ArgumentError(f'filled_confidence must be in [0, 1], got {filled_confidence!r}')
    smooth_scale = non_negative('smoothness', terms.smoothness)
    outside_scale = non_negative('outside_scale', terms.outside_scale)
    out = None if disparity is None else float_map('disparity', disparity, ratio.shape)
    fill = None if filled is None else np.asarray(filled, dtype=np.bool_)
    # float32 throughout, as the node's maps are: another float dtype is read as float32
    return _confidence_f32(ratio.astype(np.float32, copy=False),
                           diff.astype(np.float32, copy=False), keep, window, support_window,
                           scale, factor, smooth_scale, outside_scale,
                           None if out is None else out.astype(np.float32, copy=False), fill)


def _confidence_f32(ratio: F32, diff: F32, keep: NDArray[np.bool_], window: int,
                    support_window: int, scale: float, factor: float, smooth_scale: float,
                    outside_scale: float, out: F32 | None,
                    fill: NDArray[np.bool_] | None) -> F32:
    """:func:`confidence_map` on checked float32 maps: two numba passes around OpenCV's box
    filters, in float32 as numpy computes it, so the result is the plain numpy definition's
    bit for bit (``test/reference/confidence.py``). 7.8 ms at 640x480 in numpy, 3.6 ms this
    way."""
    shape = ratio.shape
    have_out = out is not None
    disparity = out if out is not None else np.zeros((1, 1), np.float32)
    smooth = have_out and smooth_scale > 0
    distinct = np.empty(shape, np.float32)
    keep_f = np.empty(shape, np.float32)
    finite = np.empty(shape if smooth else (1, 1), np.float32)
    values = np.empty(shape if smooth else (1, 1), np.float32)
    _confidence_inputs(ratio, keep, disparity, smooth, distinct, keep_f, finite, values)
    if window > 1:
        distinct = box_mean(distinct, window)
    support = box_mean(keep_f, support_window) if support_window > 1 else keep_f
    count = box_mean(finite, SMOOTHNESS_WINDOW) if smooth else finite
    sums = box_mean(values, SMOOTHNESS_WINDOW) if smooth else values
    conf = np.empty(shape, np.float32)
    _confidence_combine(distinct, diff, keep, support, support_window > 1, disparity, smooth,
                        count, sums, np.float32(smooth_scale), have_out and outside_scale > 0,
                        np.float32(outside_scale), np.float32(scale),
                        fill if fill is not None else np.zeros((1, 1), np.bool_),
                        fill is not None, np.float32(factor), conf)
    return conf


@njit(cache=True, nogil=True)
def _confidence_inputs(ratio: F32, keep: NDArray[np.bool_], disparity: F32, smooth: bool,
                       distinct: F32, keep_f: F32, finite: F32, values: F32) -> None:
    """What the box filters average: 1 - clip(ratio) (NaN counting as 1), the kept pixels,
    and for the smoothness the finite disparities and their values."""
    h, w = ratio.shape
    zero, one = np.float32(0.0), np.float32(1.0)
    for y in range(h):
        for x in range(w):
            r = ratio[y, x]
            r = one if np.isnan(r) else min(max(r, zero), one)
            distinct[y, x] = one - r
            keep_f[y, x] = one if keep[y, x] else zero
            if smooth:
                d = disparity[y, x]
                ok = np.isfinite(d)
                finite[y, x] = one if ok else zero
                values[y, x] = d if ok else zero


@njit(cache=True, nogil=True)
def _confidence_combine(distinct: F32, diff: F32, keep: NDArray[np.bool_], support: F32,
                        use_support: bool, disparity: F32, smooth: bool, count: F32,
                        sums: F32, smooth_scale: np.float32, outside: bool,
                        outside_scale: np.float32, scale: np.float32,
                        fill: NDArray[np.bool_], use_fill: bool, factor: np.float32,
                        conf: F32) -> None:
    """The terms per pixel, multiplied in the reference's order (float32 products do not
    associate)."""
    h, w = distinct.shape
    zero, one, half = np.float32(0.0), np.float32(1.0), np.float32(0.5)
    big = np.float32(np.finfo(np.float32).max)
    last = np.float32(w - 1)
    for y in range(h):
        for x in range(w):
            d = diff[y, x]  # nan_to_num(diff, nan=inf): NaN -> inf, +-inf -> +-max
            q = np.float32(np.inf) if np.isnan(d) else (
                big if d == np.inf else (-big if d == -np.inf else d))
            q = q / scale
            agree = one / (one + q * q)
            shared = distinct[y, x]
            if use_support:
                shared = shared * support[y, x]
            if smooth:
                v = disparity[y, x]
                n = count[y, x]
                deviation = zero
                if np.isfinite(v) and n > zero:
                    deviation = abs(v - sums[y, x] / n)
                t = deviation / smooth_scale
                shared = shared * (one / (one + t * t))
            if outside:
                v = disparity[y, x]
                xr = np.floor(np.float32(x) - v + half)
                beyond = max(-xr, xr - last)
                distance = zero if np.isnan(beyond) else (
                    big if beyond == np.inf else max(beyond, zero))
                if np.isnan(d) and distance > zero:
                    agree = one / (one + distance / outside_scale)
            value = shared * agree if keep[y, x] else zero
            if use_fill and fill[y, x] and not keep[y, x]:
                value = factor * shared
            conf[y, x] = min(max(value, zero), one)
