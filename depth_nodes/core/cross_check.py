"""Left-right consistency, speckle removal, hole filling and a confidence map (no ROS).

The inputs are what the SGM matcher produces (:mod:`depth_nodes.core.sgm`): the left
disparity, the right-view disparity (``x_left = x_right + d``) and the cost ratio
(best / second-best aggregated cost of the left winner, in [0, 1], low = distinct).

Decisions:
    * Left-right check (stereo_image_proc's ``disp12_max_diff``): a left pixel ``x`` with
      disparity ``d`` is consistent when ``|d - d_right(round(x - d))| <= max_diff``.
      An inconsistent pixel is an *occlusion* when the right view at ``x - d`` sees
      something nearer (``d_right > d + max_diff``: the standard rule), else a
      *mismatch*; a pixel whose partner has no right disparity is an occlusion too.
      A pixel whose partner lies outside the right image is labelled :data:`OUTSIDE`:
      the matcher extrapolated its disparity from its neighbours (the left border
      strip, see ``sgm.border.fill_outside``); ``keep_outside`` keeps it (its confidence
      says how far it was extrapolated), otherwise it is dropped like an occlusion.
    * Speckles: connected regions (4-neighbours differing by at most ``speckle_range`` px)
      of at most ``speckle_size`` pixels are removed, with OpenCV's ``filterSpeckles`` on
      an int16 copy in 1/16 px steps (coarser only when the range would not fit).
    * Hole filling (optional), ``fill_mode``: ``'background'`` fills every hole (also
      pixels the matcher left without a disparity) with the background's disparity, the
      smaller of the nearest valid disparities to its left and right on the row;
      ``'labels'`` does that for occlusions only and gives a mismatch the median of the
      nearest valid disparities in the 8 directions (Hirschmueller 2008), leaving pixels
      without an input disparity empty. On the Middlebury pairs and the simulator the
      background rule was the more accurate (README, "Accuracy on real pairs"): most holes
      a checked SGM leaves are occlusions beside a nearer object. Filled pixels keep a
      low confidence.
    * Optional median (``median_size`` 3 or 5) of the output: invalid pixels stay invalid.
    * Confidence: :mod:`depth_nodes.core.confidence`.

Labels (uint8): :data:`VALID`, :data:`INVALID` (no input disparity), :data:`OCCLUDED`,
:data:`MISMATCH`, :data:`SPECKLE`, :data:`OUTSIDE`. Misuse (shapes, dtypes, ranges) raises
``ValueError`` naming the argument.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from depth_nodes.core.confidence import DEFAULT_TERMS, ConfidenceTerms, confidence_map
from depth_nodes.core.disparity_filters import median_filter, remove_speckles
from depth_nodes.core.settings import Rule, check_settings, setting
from depth_nodes.core.validate import float_map, non_negative
from depth_nodes.errors import ArgumentError

__all__ = [
    'FILL_MODES', 'INVALID', 'MISMATCH', 'OCCLUDED', 'OUTSIDE', 'SPECKLE', 'VALID',
    'CrossCheckResult', 'LeftRightCheck', 'confidence_map', 'cross_check',
    'fill_disparity_holes', 'left_right_check', 'median_filter', 'remove_speckles',
]

F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]
Bool = NDArray[np.bool_]

VALID, INVALID, OCCLUDED, MISMATCH, SPECKLE, OUTSIDE = 0, 1, 2, 3, 4, 5
#: Hole-filling strategies of :func:`fill_disparity_holes`.
FILL_MODES = ('background', 'labels')


class ConfidenceScorer(Protocol):
    """What scores the pixels in place of :func:`confidence_map`: the learned confidence
    (:class:`~depth_nodes.core.learned.confidence.ConfidenceModel`)."""

    def confidence(self, raw: F32, cost_ratio: F32, difference: F32, labels: U8,
                   filled: Bool, max_diff: float) -> F32:
        """(H, W) float32 in [0, 1]: how likely the raw disparity is right."""
        ...  # pragma: no cover (a protocol)


#: Confidence models of the cross_check node: the hand-made product of terms or the
#: learned one.
CONFIDENCE_MODELS = ('handmade', 'learned')

#: disp12_max_diff of -1 (no left-right check): any difference is consistent.
NO_CHECK = 1e6

#: The speckle filter's area, the same setting in the matcher and the cross-check.
SPECKLE_SIZE = Rule('Largest area in px of a disparity region removed as a speckle '
                    '(0: off)', low=0, high=100000)


def lr_threshold(value: float) -> float:
    """``disp12_max_diff`` as OpenCV's StereoSGBM reads it: 0 means 1 px (so
    stereo_image_proc's default, 0, checks at 1 px); a negative value turns the check off
    (this package's; OpenCV cannot)."""
    if value < 0:
        return -1.0
    return float(value) if value > 0 else 1.0


@dataclass(frozen=True)
class CrossCheckParams:
    """The cross_check node's settings, named as its parameters (:func:`cross_check`'s
    arguments through :meth:`arguments`)."""

    disp12_max_diff: float = setting(
        1.0, 'Largest |d_left - d_right| in px of a consistent pixel (left-right check), up '
        "to 64; 0 counts as 1, as in OpenCV's StereoSGBM (stereo_image_proc's default 0 "
        'reaches this node through /**); -1: no check; integer or double',
        low=-1.0, high=64.0, number=True)
    speckle_size: int = setting(100, SPECKLE_SIZE)
    speckle_range: float = setting(2.0, 'Largest disparity step in px within one region of '
                                   'the speckle filter, in [0, 64]; integer or double',
                                   low=0.0, high=64.0, number=True)
    fill_holes: bool = setting(False, 'Fill the holes (filled pixels get low confidence); '
                               'see fill_mode')
    fill_mode: str = setting('background', 'background: every hole takes the farther of its '
                             'nearest kept neighbours on the row; labels: occlusions do, '
                             'mismatches take the median of 8 directions, pixels without '
                             'input stay empty', choices=FILL_MODES)
    median_size: int = setting(0, 'Median of the output: 0 (off), 3 or 5', choices=(0, 3, 5))
    keep_extrapolated: bool = setting(True, 'Keep pixels whose match lies outside the right '
                                      "image (the matcher's extrapolated border strip), at a "
                                      'confidence that falls with the distance; false drops '
                                      'them as occlusions')
    confidence_window: int = setting(9, 'Odd side of the box the cost measure is pooled '
                                     'over (1: no pooling)', low=1, high=31, odd=True)
    filled_confidence: float = setting(0.1, 'Confidence factor of filled pixels',
                                       low=0.0, high=1.0)
    confidence_model: str = setting('handmade', 'handmade: the product of the terms above; '
                                    'learned: the shipped network over the same signals '
                                    '(core/learned/confidence.py)', choices=CONFIDENCE_MODELS)
    confidence_weights: str = setting('', "confidence_model learned: an .npz that "
                                      'depth-nodes train-confidence wrote; empty: the shipped '
                                      'weights')

    def validate(self) -> CrossCheckParams:
        """Check every field; returns self.

        Raises:
            ArgumentError: A field breaks its rule.
        """
        return check_settings(self, 'cross-check parameter')

    def arguments(self) -> dict[str, Any]:
        """The keyword arguments of :func:`cross_check` (:func:`cross_check` checks what
        it is given; :meth:`validate` checks the fields as a whole), but the ``model``
        that ``confidence_model: learned`` stands for (with ``confidence_weights``), which
        the caller loads."""
        max_diff = lr_threshold(self.disp12_max_diff)
        return {'disp12_max_diff': max_diff if max_diff > 0 else NO_CHECK,
                'speckle_size': self.speckle_size, 'speckle_range': self.speckle_range,
                'fill': self.fill_holes, 'fill_mode': self.fill_mode,
                'median_size': self.median_size, 'keep_outside': self.keep_extrapolated,
                'confidence_window': self.confidence_window,
                'filled_confidence': self.filled_confidence}


@dataclass(frozen=True)
class LeftRightCheck:
    """What :func:`left_right_check` returns.

    Attributes:
        difference: (H, W) float32 ``|d - d_right(round(x - d))|``, NaN where ``d`` is
            invalid or its partner is outside the right image or invalid.
        labels: (H, W) uint8 VALID, INVALID, OCCLUDED, MISMATCH or OUTSIDE.
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
            if xr < 0 or xr >= w:
                diff[y, x] = math.nan
                labels[y, x] = OUTSIDE
                continue
            dr = disp_right[y, xr]
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
        ArgumentError: Not 2-D float arrays of one shape, or ``max_diff`` negative.
    """
    left = float_map('disparity', disparity)
    right = float_map('disparity_right', disparity_right, left.shape)
    limit = non_negative('max_diff', max_diff)
    diff = np.empty(left.shape, np.float32)
    labels = np.empty(left.shape, np.uint8)
    _lr_kernel(left, right, limit, diff, labels)
    return LeftRightCheck(diff, labels)


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
def _fill_kernel(disp: F32, valid: Bool, labels: U8, dirs: NDArray[np.int64],
                 background_only: bool, out: F32) -> None:
    h, w = disp.shape
    for y in prange(h):
        found = np.empty(8, np.float64)
        for x in range(w):
            out[y, x] = disp[y, x] if valid[y, x] else math.nan
            if valid[y, x]:
                continue
            label = labels[y, x]
            if background_only or label == OCCLUDED:
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


def fill_disparity_holes(disparity: Any, labels: Any, *, mode: str = 'labels',
               keep: Any = None) -> tuple[F32, Bool]:
    """Fill holes from the background, or by label (see the module notes).

    Args:
        disparity: (H, W) float disparity; pixels not kept are holes.
        labels: (H, W) uint8 labels (:func:`left_right_check`, SPECKLE added).
        mode: ``'background'``: every hole takes the smaller of the nearest kept
            disparities left and right on its row. ``'labels'``: occlusions do; mismatches
            and speckles take the median of the nearest kept ones in 8 directions; INVALID
            pixels (no input disparity) stay unfilled.
        keep: Optional (H, W) bool of the kept pixels (default: VALID labels).

    Returns:
        ``(filled_disparity, filled_mask)``; NaN where a hole has no kept neighbour.

    Raises:
        ArgumentError: Bad shapes, dtypes or mode.
    """
    disp = float_map('disparity', disparity)
    lab = np.asarray(labels)
    if lab.shape != disp.shape or lab.dtype != np.uint8:
        raise ArgumentError(f'labels must be a uint8 array of shape {disp.shape}, got '
                            f'{lab.dtype} {lab.shape}')
    if mode not in FILL_MODES:
        raise ArgumentError(f'mode must be one of {", ".join(FILL_MODES)}, got {mode!r}')
    kept = (lab == VALID) if keep is None else np.asarray(keep, dtype=np.bool_)
    valid = np.ascontiguousarray(kept & np.isfinite(disp))
    out = np.empty(disp.shape, np.float32)
    _fill_kernel(disp, valid, np.ascontiguousarray(lab), _DIRECTIONS, mode == 'background',
                 out)
    filled: Bool = ~valid & np.isfinite(out)
    return out, filled


# -- the whole step -----------------------------------------------------------------------


def cross_check(disparity: Any, disparity_right: Any, cost_ratio: Any, *,
                disp12_max_diff: float = 1.0, speckle_size: int = 100,
                speckle_range: float = 2.0, fill: bool = False,
                fill_mode: str = 'background', median_size: int = 0,
                keep_outside: bool = True, confidence_window: int = 9,
                filled_confidence: float = 0.1,
                terms: ConfidenceTerms = DEFAULT_TERMS,
                model: ConfidenceScorer | None = None) -> CrossCheckResult:
    """Left-right check, speckle removal, optional hole filling and median, confidence.

    Args:
        disparity: (H, W) float left disparity, NaN invalid.
        disparity_right: (H, W) float right-view disparity, NaN invalid.
        cost_ratio: (H, W) float best / second-best cost of the left winner, in [0, 1].
        disp12_max_diff: Left-right threshold in px (> 0).
        speckle_size: Largest speckle area in px (0: no speckle removal).
        speckle_range: Largest step within one region, px.
        fill: Fill holes (:func:`fill_disparity_holes`).
        fill_mode: ``'background'`` or ``'labels'`` (:func:`fill_disparity_holes`).
        median_size: 0 (none), 3 or 5: median of the output (:func:`median_filter`).
        keep_outside: Keep pixels whose partner lies outside the right image (the
            matcher's extrapolated border strip); else they are dropped as occlusions.
        confidence_window: Odd pooling window of the cost term.
        filled_confidence: Confidence factor of filled pixels, in [0, 1].
        terms: The confidence's other terms (:class:`ConfidenceTerms`).
        model: A learned confidence instead of the terms' product (0 where the output
            has no disparity; ``confidence_window``, ``filled_confidence`` and ``terms``
            are then unused).

    Returns:
        The checked disparity, its confidence and the per-pixel labels.

    Raises:
        ArgumentError: Bad shapes, dtypes or settings (the message names the argument).
    """
    left = float_map('disparity', disparity)
    float_map('cost_ratio', cost_ratio, left.shape)
    if median_size not in (0, 3, 5):
        raise ArgumentError(f'median_size must be 0, 3 or 5, got {median_size!r}')
    check = left_right_check(left, disparity_right, max_diff=disp12_max_diff)
    labels = check.labels.copy()
    keep = (labels == VALID) | ((labels == OUTSIDE) if keep_outside else False)
    kept = np.where(keep, left, np.float32(np.nan))
    speckles = remove_speckles(kept, max_size=speckle_size, max_diff=speckle_range)
    labels[speckles] = SPECKLE
    valid = keep & ~speckles
    filled = np.zeros(left.shape, np.bool_)
    out = np.where(valid, left, np.float32(np.nan)).astype(np.float32)
    if fill:
        out, filled = fill_disparity_holes(left, labels, mode=fill_mode, keep=valid)
    if median_size:
        out = median_filter(out, median_size)
    if model is not None:
        learned = model.confidence(left, np.asarray(cost_ratio, np.float32),
                                   check.difference, labels, filled, disp12_max_diff)
        confidence = np.where(np.isnan(out), np.float32(0.0), learned).astype(np.float32)
    else:
        confidence = confidence_map(cost_ratio, check.difference, valid,
                                    window=confidence_window, max_diff=disp12_max_diff,
                                    filled=filled, filled_confidence=filled_confidence,
                                    disparity=out, terms=terms)
    return CrossCheckResult(out, confidence, labels, filled, check.difference)
