"""Left-right consistency, speckle removal, hole filling and a confidence map (no ROS).

The inputs are what the SGM matcher produces (:mod:`depth_nodes.core.sgm`): the left
disparity, the right-view disparity (``x_left = x_right + d``) and the cost ratio
(best / second-best aggregated cost of the left winner, in [0, 1], low = distinct).

Decisions:
    * Left-right check (stereo_image_proc's ``disp12_max_diff``): a left pixel ``x`` with
      disparity ``d`` is consistent when ``|d - d_right(round(x - d))| <= max_diff``.
      An inconsistent pixel is an *occlusion* when the right view at ``x - d`` sees
      something nearer (``d_right > d + max_diff``: the standard rule), else a
      *mismatch*; a pixel whose partner is outside the right image or has no right
      disparity is an occlusion too (the right camera cannot see it).
    * Speckles: connected regions (4-neighbours differing by at most ``speckle_range`` px)
      of at most ``speckle_size`` pixels are removed, with OpenCV's ``filterSpeckles`` on
      an int16 copy in 1/16 px steps (coarser only when the range would not fit).
    * Hole filling (optional): an occlusion takes the background's disparity, the smaller
      of the nearest valid disparities to its left and right on the row; a mismatch
      takes the median of the nearest valid disparities in the 8 directions
      (Hirschmueller 2008). Filled pixels keep a low confidence.
    * Confidence = cost term x agreement term, in [0, 1]: the cost term is
      ``1 - cost_ratio`` averaged over a ``window`` x ``window`` box; the agreement term
      is ``1 / (1 + (diff / max_diff)^2)`` of the left-right difference. It is 0 where the
      output is invalid, and ``filled_confidence`` x the cost term where a hole was filled.

Labels (uint8): :data:`VALID`, :data:`INVALID` (no input disparity), :data:`OCCLUDED`,
:data:`MISMATCH`, :data:`SPECKLE`. Misuse (shapes, dtypes, ranges) raises ``ValueError``
naming the argument.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

__all__ = [
    'INVALID', 'MISMATCH', 'OCCLUDED', 'SPECKLE', 'VALID',
    'CrossCheckResult', 'LeftRightCheck', 'confidence_map', 'cross_check', 'fill_holes',
    'left_right_check', 'remove_speckles',
]

F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]
Bool = NDArray[np.bool_]

VALID, INVALID, OCCLUDED, MISMATCH, SPECKLE = 0, 1, 2, 3, 4
#: int16 steps per pixel of the speckle filter's copy (OpenCV's fixed point).
SPECKLE_SCALE = 16


@dataclass(frozen=True)
class LeftRightCheck:
    """What :func:`left_right_check` returns.

    Attributes:
        difference: (H, W) float32 ``|d - d_right(round(x - d))|``, NaN where ``d`` is
            invalid or its partner is outside the right image or invalid.
        labels: (H, W) uint8 VALID, INVALID, OCCLUDED or MISMATCH.
    """

    difference: F32
    labels: U8


@dataclass(frozen=True)
class CrossCheckResult:
    """What :func:`cross_check` returns.

    Attributes:
        disparity: (H, W) float32 checked (and optionally filled) disparity, NaN invalid.
        confidence: (H, W) float32 in [0, 1], 0 where ``disparity`` is NaN.
        labels: (H, W) uint8 label of every pixel before filling.
        filled: (H, W) bool, True where a hole was filled.
        difference: (H, W) float32 left-right difference (see :class:`LeftRightCheck`).
    """

    disparity: F32
    confidence: F32
    labels: U8
    filled: Bool
    difference: F32


# -- validation ---------------------------------------------------------------------------


def _float_map(name: str, value: Any, shape: tuple[int, ...] | None = None) -> F32:
    arr = np.asarray(value)
    if arr.ndim != 2:
        raise ValueError(f'{name} must be a (H, W) array, got shape {arr.shape}')
    if shape is not None and arr.shape != shape:
        raise ValueError(f'{name} must have the disparity shape {shape}, got {arr.shape}')
    if not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(f'{name} must be a float array, got dtype {arr.dtype}')
    return np.ascontiguousarray(arr, dtype=np.float32)


def _non_negative(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and value >= 0):
        raise ValueError(f'{name} must be a finite number >= 0, got {value!r}')
    return float(value)


# -- left-right check ---------------------------------------------------------------------


@njit(parallel=True, cache=True, nogil=True)
def _lr_kernel(disp: F32, disp_right: F32, max_diff: float, diff: F32, labels: U8) -> None:
    h, w = disp.shape
    for y in prange(h):
        for x in range(w):
            d = disp[y, x]
            if not math.isfinite(d):
                diff[y, x] = math.nan
                labels[y, x] = INVALID
                continue
            xr = math.floor(x - d + 0.5)
            dr = disp_right[y, xr] if 0 <= xr < w else math.nan
            if not math.isfinite(dr):
                diff[y, x] = math.nan
                labels[y, x] = OCCLUDED
                continue
            e = abs(d - dr)
            diff[y, x] = e
            if e <= max_diff:
                labels[y, x] = VALID
            elif dr > d + max_diff:
                labels[y, x] = OCCLUDED
            else:
                labels[y, x] = MISMATCH


def left_right_check_reference(disparity: F32, disparity_right: F32,
                               max_diff: float) -> tuple[F32, U8]:
    """Plain numpy version of the left-right check kernel (tests compare against it)."""
    h, w = disparity.shape
    finite = np.isfinite(disparity)
    xs = np.arange(w)[None, :]
    with np.errstate(invalid='ignore'):
        xr = np.floor(xs - np.where(finite, disparity, 0) + 0.5).astype(np.int64)
    inside = finite & (xr >= 0) & (xr < w)
    dr = np.full((h, w), np.nan, np.float32)
    ys = np.nonzero(inside)[0]
    dr[inside] = disparity_right[ys, xr[inside]]
    has = inside & np.isfinite(dr)
    diff = np.where(has, np.abs(disparity - dr), np.nan).astype(np.float32)
    labels = np.full((h, w), INVALID, np.uint8)
    labels[finite & ~has] = OCCLUDED
    with np.errstate(invalid='ignore'):
        labels[has & (diff <= max_diff)] = VALID
        labels[has & (diff > max_diff) & (dr > disparity + max_diff)] = OCCLUDED
        labels[has & (diff > max_diff) & ~(dr > disparity + max_diff)] = MISMATCH
    return diff, labels


def left_right_check(disparity: Any, disparity_right: Any, *,
                     max_diff: float = 1.0) -> LeftRightCheck:
    """Compare the left disparity with the right view's at ``x - d``.

    Args:
        disparity: (H, W) float left disparity, NaN where invalid.
        disparity_right: (H, W) float right-view disparity (``x_left = x_right + d``).
        max_diff: Largest consistent ``|d - d_right|`` in px (``disp12_max_diff``).

    Returns:
        The difference and the label of every pixel.

    Raises:
        ValueError: Not 2-D float arrays of one shape, or ``max_diff`` negative.
    """
    left = _float_map('disparity', disparity)
    right = _float_map('disparity_right', disparity_right, left.shape)
    limit = _non_negative('max_diff', max_diff)
    diff = np.empty(left.shape, np.float32)
    labels = np.empty(left.shape, np.uint8)
    _lr_kernel(left, right, limit, diff, labels)
    return LeftRightCheck(diff, labels)


# -- speckles -----------------------------------------------------------------------------


def remove_speckles(disparity: Any, *, max_size: int, max_diff: float) -> Bool:
    """The pixels of small disparity regions (speckles), as OpenCV's filterSpeckles sees
    them on a fixed-point copy.

    Args:
        disparity: (H, W) float disparity, NaN where invalid (invalid pixels separate
            regions). Not modified.
        max_size: Largest speckle area in pixels (0: none removed).
        max_diff: Largest difference in px between 4-neighbours of one region.

    Returns:
        (H, W) bool, True on the pixels of removed speckles.

    Raises:
        ValueError: Bad shapes or negative sizes.
    """
    disp = _float_map('disparity', disparity)
    if isinstance(max_size, bool) or not isinstance(max_size, (int, np.integer)) or max_size < 0:
        raise ValueError(f'max_size must be an int >= 0, got {max_size!r}')
    diff = _non_negative('max_diff', max_diff)
    finite = np.isfinite(disp)
    if max_size == 0 or not finite.any():
        return np.zeros(disp.shape, np.bool_)
    lo = float(disp[finite].min())
    span = float(disp[finite].max()) - lo + 1.0
    scale = min(SPECKLE_SCALE, max(1, int(32000 // span)))
    fixed = np.full(disp.shape, -1, np.int16)
    fixed[finite] = np.rint((disp[finite] - lo) * scale).astype(np.int16)
    before = fixed.copy()
    cv2.filterSpeckles(fixed, -1, int(max_size), round(diff * scale))
    removed: Bool = (fixed == -1) & (before != -1)
    return removed


# -- hole filling -------------------------------------------------------------------------

_DIRECTIONS = np.array([(0, -1), (0, 1), (-1, 0), (1, 0), (-1, -1), (-1, 1), (1, -1), (1, 1)],
                       np.int64)


@njit(cache=True, nogil=True)
def _nearest(disp: F32, valid: Bool, y: int, x: int, dy: int, dx: int) -> float:
    h, w = disp.shape
    y, x = y + dy, x + dx
    while 0 <= y < h and 0 <= x < w:
        if valid[y, x]:
            return float(disp[y, x])
        y, x = y + dy, x + dx
    return math.nan


@njit(parallel=True, cache=True, nogil=True)
def _fill_kernel(disp: F32, valid: Bool, labels: U8, dirs: NDArray[np.int64], out: F32) -> None:
    h, w = disp.shape
    for y in prange(h):
        found = np.empty(8, np.float64)
        for x in range(w):
            out[y, x] = disp[y, x] if valid[y, x] else math.nan
            if valid[y, x]:
                continue
            label = labels[y, x]
            if label == OCCLUDED:
                a = _nearest(disp, valid, y, x, 0, -1)
                b = _nearest(disp, valid, y, x, 0, 1)
                if math.isfinite(a) and math.isfinite(b):
                    out[y, x] = min(a, b)
                elif math.isfinite(a):
                    out[y, x] = a
                elif math.isfinite(b):
                    out[y, x] = b
            elif label >= MISMATCH:  # MISMATCH or SPECKLE
                n = 0
                for j in range(8):
                    v = _nearest(disp, valid, y, x, dirs[j, 0], dirs[j, 1])
                    if math.isfinite(v):
                        found[n] = v
                        n += 1
                if n:
                    out[y, x] = np.median(found[:n])


def fill_holes_reference(disparity: F32, valid: Bool, labels: U8) -> F32:
    """Plain Python version of the hole-filling kernel (tests compare against it)."""
    h, w = disparity.shape
    out = np.where(valid, disparity, np.nan).astype(np.float32)

    def nearest(y: int, x: int, dy: int, dx: int) -> float:
        y, x = y + dy, x + dx
        while 0 <= y < h and 0 <= x < w:
            if valid[y, x]:
                return float(disparity[y, x])
            y, x = y + dy, x + dx
        return math.nan

    for y in range(h):
        for x in range(w):
            if valid[y, x]:
                continue
            if labels[y, x] == OCCLUDED:
                side = [v for v in (nearest(y, x, 0, -1), nearest(y, x, 0, 1))
                        if math.isfinite(v)]
                if side:
                    out[y, x] = min(side)
            elif labels[y, x] in (MISMATCH, SPECKLE):
                around = [v for v in (nearest(y, x, int(dy), int(dx)) for dy, dx in _DIRECTIONS)
                          if math.isfinite(v)]
                if around:
                    out[y, x] = float(np.median(around))
    return out


def fill_holes(disparity: Any, labels: Any) -> tuple[F32, Bool]:
    """Fill occlusions from the background and mismatches / speckles from around them.

    Args:
        disparity: (H, W) float disparity; pixels labelled other than VALID are holes.
        labels: (H, W) uint8 labels (:func:`left_right_check`, SPECKLE added). INVALID
            pixels (no input disparity) stay unfilled.

    Returns:
        ``(filled_disparity, filled_mask)``; NaN where a hole has no valid neighbour.

    Raises:
        ValueError: Bad shapes or dtypes.
    """
    disp = _float_map('disparity', disparity)
    lab = np.asarray(labels)
    if lab.shape != disp.shape or lab.dtype != np.uint8:
        raise ValueError(f'labels must be a uint8 array of shape {disp.shape}, got '
                         f'{lab.dtype} {lab.shape}')
    valid = np.ascontiguousarray((lab == VALID) & np.isfinite(disp))
    out = np.empty(disp.shape, np.float32)
    _fill_kernel(disp, valid, np.ascontiguousarray(lab), _DIRECTIONS, out)
    filled: Bool = ~valid & np.isfinite(out)
    return out, filled


# -- confidence ---------------------------------------------------------------------------


def confidence_map(cost_ratio: Any, difference: Any, valid: Any, *, window: int = 5,
                   max_diff: float = 1.0, filled: Any = None,
                   filled_confidence: float = 0.1) -> F32:
    """Confidence in [0, 1]: pooled cost distinctiveness x left-right agreement.

    Args:
        cost_ratio: (H, W) float best / second-best cost in [0, 1] (NaN counts as 1).
        difference: (H, W) float left-right difference in px (NaN counts as no agreement).
        valid: (H, W) bool, the pixels whose disparity is kept (others get 0).
        window: Odd side of the box the cost term is averaged over (1: no pooling).
        max_diff: The difference scale in px: agreement 1/2 at ``max_diff`` (> 0).
        filled: Optional (H, W) bool of filled pixels: they get ``filled_confidence`` x the
            cost term (their own left-right difference is not used).
        filled_confidence: Factor in [0, 1] for filled pixels.

    Returns:
        (H, W) float32 confidence, 0 where neither valid nor filled.

    Raises:
        ValueError: Bad shapes or dtypes, even ``window``, non-positive ``max_diff``.
    """
    ratio = _float_map('cost_ratio', cost_ratio)
    diff = _float_map('difference', difference, ratio.shape)
    keep = np.asarray(valid)
    if keep.dtype != np.bool_ or keep.shape != ratio.shape:
        raise ValueError(f'valid must be a bool array of shape {ratio.shape}')
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or (
            window < 1 or window % 2 == 0):
        raise ValueError(f'window must be an odd int >= 1, got {window!r}')
    scale = _non_negative('max_diff', max_diff)
    if scale == 0:
        raise ValueError('max_diff must be > 0 for the confidence')
    factor = _non_negative('filled_confidence', filled_confidence)
    if factor > 1:
        raise ValueError(f'filled_confidence must be in [0, 1], got {filled_confidence!r}')
    distinct: F32 = (1.0 - np.clip(np.nan_to_num(ratio, nan=1.0), 0.0, 1.0)).astype(np.float32)
    if window > 1:
        distinct = np.asarray(cv2.blur(distinct, (int(window), int(window)),
                                       borderType=cv2.BORDER_REFLECT), dtype=np.float32)
    with np.errstate(invalid='ignore'):
        agree = 1.0 / (1.0 + np.square(np.nan_to_num(diff, nan=np.inf) / scale))
    conf = np.where(keep, distinct * agree, 0.0)
    if filled is not None:
        fill = np.asarray(filled, dtype=np.bool_)
        conf = np.where(fill & ~keep, factor * distinct, conf)
    out: F32 = np.clip(conf, 0.0, 1.0).astype(np.float32)
    return out


# -- the whole step -----------------------------------------------------------------------


def cross_check(disparity: Any, disparity_right: Any, cost_ratio: Any, *,
                disp12_max_diff: float = 1.0, speckle_size: int = 100,
                speckle_range: float = 2.0, fill: bool = False, confidence_window: int = 9,
                filled_confidence: float = 0.1) -> CrossCheckResult:
    """Left-right check, speckle removal, optional hole filling and confidence.

    Args:
        disparity: (H, W) float left disparity, NaN invalid.
        disparity_right: (H, W) float right-view disparity, NaN invalid.
        cost_ratio: (H, W) float best / second-best cost of the left winner, in [0, 1].
        disp12_max_diff: Left-right threshold in px (> 0).
        speckle_size: Largest speckle area in px (0: no speckle removal).
        speckle_range: Largest step within one region, px.
        fill: Fill holes (:func:`fill_holes`).
        confidence_window: Odd pooling window of the cost term.
        filled_confidence: Confidence factor of filled pixels, in [0, 1].

    Returns:
        The checked disparity, its confidence and the per-pixel labels.

    Raises:
        ValueError: Bad shapes, dtypes or settings (the message names the argument).
    """
    left = _float_map('disparity', disparity)
    _float_map('cost_ratio', cost_ratio, left.shape)
    check = left_right_check(left, disparity_right, max_diff=disp12_max_diff)
    labels = check.labels.copy()
    kept = np.where(labels == VALID, left, np.float32(np.nan))
    speckles = remove_speckles(kept, max_size=speckle_size, max_diff=speckle_range)
    labels[speckles] = SPECKLE
    valid = labels == VALID
    filled = np.zeros(left.shape, np.bool_)
    out = np.where(valid, left, np.float32(np.nan)).astype(np.float32)
    if fill:
        out, filled = fill_holes(left, labels)
    confidence = confidence_map(cost_ratio, check.difference, valid,
                                window=confidence_window, max_diff=disp12_max_diff,
                                filled=filled, filled_confidence=filled_confidence)
    return CrossCheckResult(out, confidence, labels, filled, check.difference)
