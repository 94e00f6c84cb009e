"""Accuracy metrics for stereo disparity, depth and confidence maps (numpy only).

Definitions (docs/design.md, "Metrics"):

- bad-N: fraction of ground-truth pixels with ``|d - d_gt| > N`` px, reported dense (an
  invalid estimate counts as bad) and sparse (over estimated pixels only, with the density).
- avgerr: mean ``|d - d_gt|`` over estimated pixels with ground truth.
- Confidence AUC: sort pixels by confidence (highest first), take the bad-N rate of the kept
  fraction as the density grows, integrate over density; the optimal AUC for an error rate
  ``e`` is ``e + (1 - e) ln(1 - e)``.

Conventions: maps are ``(H, W)`` float arrays where NaN (or any non-finite value) means
"no value" (no estimate, or no ground truth). An optional boolean ``valid_mask`` restricts
the evaluated pixels further (e.g. to non-occluded ones). Empty evaluations give NaN
scores without printing warnings.

Misuse of the API (mismatched shapes, a non-boolean mask, a negative threshold) raises
:class:`~depth_nodes.errors.ArgumentError`, the package's error family's ``ValueError``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from numpy.typing import NDArray

from depth_nodes.errors import ArgumentError

__all__ = [
    'ConfidenceScores',
    'DepthScores',
    'DisparityScores',
    'depth_errors',
    'disparity_errors',
    'optimal_auc',
    'sparsification_auc',
    'sparsification_curve',
]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class DisparityScores:
    """Disparity accuracy against ground truth (see :func:`disparity_errors`).

    Attributes:
        bad_dense: Fraction of ground-truth pixels that are unestimated or off by more than
            ``threshold`` px.
        bad_sparse: Fraction of estimated ground-truth pixels off by more than ``threshold``.
        density: Fraction of ground-truth pixels that have an estimate.
        avgerr: Mean absolute error in px over estimated ground-truth pixels.
        rmse: Root-mean-square error in px over estimated ground-truth pixels.
        n_gt: Number of evaluated pixels with ground truth.
        n_est: Number of those that also have an estimate.
        threshold: The N of bad-N, in px.
    """

    bad_dense: float
    bad_sparse: float
    density: float
    avgerr: float
    rmse: float
    n_gt: int
    n_est: int
    threshold: float


@dataclass(frozen=True)
class DepthScores:
    """Depth accuracy against ground truth (see :func:`depth_errors`).

    Attributes:
        mae: Mean absolute error in metres over estimated ground-truth pixels.
        rel: Mean relative error ``|z - z_gt| / z_gt`` over the same pixels.
        rmse: Root-mean-square error in metres over the same pixels.
        density: Fraction of ground-truth pixels that have an estimate.
        n_gt: Number of evaluated pixels with ground truth.
        n_est: Number of those that also have an estimate.
    """

    mae: float
    rel: float
    rmse: float
    density: float
    n_gt: int
    n_est: int


@dataclass(frozen=True)
class ConfidenceScores:
    """How well a confidence map ranks errors (see :func:`sparsification_auc`).

    Attributes:
        auc: Area under the sparsification curve (bad-N rate of the most confident
            fraction, integrated over that fraction in (0, 1]). Lower is better.
        optimal_auc: ``e + (1 - e) ln(1 - e)``, the AUC of a perfect ranking.
        ratio: ``auc / optimal_auc`` (>= 1 up to discretisation; 1 is perfect; 1 also
            when ``error_rate`` is 0, where any ranking is perfect).
        error_rate: ``e``, the bad-N rate over all evaluated pixels (invalid counts as bad).
        n_pixels: Number of evaluated pixels.
        threshold: The N of bad-N, in px.
    """

    auc: float
    optimal_auc: float
    ratio: float
    error_rate: float
    n_pixels: int
    threshold: float


# -- validation ---------------------------------------------------------------------------


def _as_map(name: str, value: npt.ArrayLike) -> FloatArray:
    arr = np.asarray(value)
    if arr.ndim != 2:
        raise ArgumentError(f'{name} must be a 2-D (H, W) array, got shape {arr.shape}')
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise ArgumentError(f'{name} must be a real numeric array, got dtype {arr.dtype}')
    return arr.astype(np.float64, copy=False)


def _check_same_shape(name_a: str, a: FloatArray, name_b: str, b: FloatArray) -> None:
    if a.shape != b.shape:
        raise ArgumentError(
            f'{name_a} and {name_b} must have the same shape, got {a.shape} and {b.shape}'
        )


def _as_mask(valid_mask: npt.ArrayLike | None, shape: tuple[int, ...]) -> BoolArray:
    if valid_mask is None:
        return np.ones(shape, dtype=np.bool_)
    mask = np.asarray(valid_mask)
    if mask.dtype != np.bool_:
        raise ArgumentError(f'valid_mask must be a boolean array, got dtype {mask.dtype}')
    if mask.shape != shape:
        raise ArgumentError(f'valid_mask must have shape {shape}, got {mask.shape}')
    return mask


def _check_threshold(n: float) -> float:
    if isinstance(n, bool) or not isinstance(n, (int, float)) or not math.isfinite(n) or n < 0:
        raise ArgumentError(f'n must be a finite number >= 0 (px), got {n!r}')
    return float(n)


def _ratio(num: float, den: float) -> float:
    return num / den if den > 0 else math.nan


# -- disparity and depth ------------------------------------------------------------------


def disparity_errors(
    estimate: npt.ArrayLike,
    truth: npt.ArrayLike,
    *,
    valid_mask: npt.ArrayLike | None = None,
    n: float = 2.0,
) -> DisparityScores:
    """Score a disparity map against ground truth (bad-N dense and sparse, avgerr, RMSE).

    Args:
        estimate: (H, W) estimated disparity in px; NaN/inf means no estimate.
        truth: (H, W) ground-truth disparity in px; NaN/inf means no ground truth.
        valid_mask: Optional (H, W) bool array; only True pixels are evaluated.
        n: bad-N threshold in px (>= 0): an error strictly greater than ``n`` is bad.

    Returns:
        The scores. With no ground-truth pixels every score is NaN; with ground truth but
        no estimate, ``bad_dense`` is 1, ``density`` 0 and the sparse scores are NaN.

    Raises:
        ArgumentError: If the arrays are not 2-D or their shapes differ, the mask is not
            boolean, or ``n`` is negative or not finite.
    """
    est = _as_map('estimate', estimate)
    gt = _as_map('truth', truth)
    _check_same_shape('estimate', est, 'truth', gt)
    mask = _as_mask(valid_mask, gt.shape)
    threshold = _check_threshold(n)

    has_gt = mask & np.isfinite(gt)
    has_est = has_gt & np.isfinite(est)
    n_gt = int(np.count_nonzero(has_gt))
    n_est = int(np.count_nonzero(has_est))
    err = np.abs(est[has_est] - gt[has_est])
    n_bad = int(np.count_nonzero(err > threshold))
    mean_err = float(err.mean()) if n_est else math.nan
    rmse = math.sqrt(float(np.mean(err * err))) if n_est else math.nan
    return DisparityScores(
        bad_dense=_ratio(n_gt - n_est + n_bad, n_gt),
        bad_sparse=_ratio(n_bad, n_est),
        density=_ratio(n_est, n_gt),
        avgerr=mean_err,
        rmse=rmse,
        n_gt=n_gt,
        n_est=n_est,
        threshold=threshold,
    )


def depth_errors(
    estimate_m: npt.ArrayLike,
    truth_m: npt.ArrayLike,
    valid_mask: npt.ArrayLike | None = None,
) -> DepthScores:
    """Score a depth map in metres against ground truth.

    Ground truth exists where ``truth_m`` is finite and > 0; an estimate exists where
    ``estimate_m`` is finite and > 0 (REP 118: NaN unknown, +-inf out of range, and a
    non-positive depth is never a measurement).

    Args:
        estimate_m: (H, W) estimated depth in metres.
        truth_m: (H, W) ground-truth depth in metres.
        valid_mask: Optional (H, W) bool array; only True pixels are evaluated.

    Returns:
        Mean absolute / relative / RMS error over estimated ground-truth pixels, and the
        density. NaN where a score has no pixels to average.

    Raises:
        ArgumentError: If the arrays are not 2-D, their shapes differ or the mask is not boolean.
    """
    est = _as_map('estimate_m', estimate_m)
    gt = _as_map('truth_m', truth_m)
    _check_same_shape('estimate_m', est, 'truth_m', gt)
    mask = _as_mask(valid_mask, gt.shape)

    with np.errstate(invalid='ignore'):  # comparisons against NaN
        has_gt = mask & np.isfinite(gt) & (gt > 0)
        has_est = has_gt & np.isfinite(est) & (est > 0)
    n_gt = int(np.count_nonzero(has_gt))
    n_est = int(np.count_nonzero(has_est))
    err = np.abs(est[has_est] - gt[has_est])
    if n_est:
        mae = float(err.mean())
        rel = float(np.mean(err / gt[has_est]))
        rmse = math.sqrt(float(np.mean(err * err)))
    else:
        mae = rel = rmse = math.nan
    return DepthScores(
        mae=mae, rel=rel, rmse=rmse, density=_ratio(n_est, n_gt), n_gt=n_gt, n_est=n_est
    )


# -- confidence ---------------------------------------------------------------------------


def optimal_auc(error_rate: float) -> float:
    """AUC of a perfect confidence ranking for bad-pixel rate ``e``: e + (1 - e) ln(1 - e).

    Args:
        error_rate: ``e`` in [0, 1].

    Returns:
        The optimal area (0 for e = 0, 1 for e = 1).

    Raises:
        ArgumentError: If ``error_rate`` is outside [0, 1].
    """
    e = float(error_rate)
    if not 0.0 <= e <= 1.0:
        raise ArgumentError(f'error_rate must be in [0, 1], got {error_rate!r}')
    if e == 1.0:
        return 1.0  # (1 - e) ln(1 - e) -> 0
    return e + (1.0 - e) * math.log1p(-e)


def _ranked_bad_counts(confidence: FloatArray, bad: BoolArray) -> FloatArray:
    """Expected number of bad pixels among the k most confident, for k = 1..N.

    Pixels are sorted by decreasing confidence (NaN ranks last). Within a group of equal
    confidence the order is unknown, so the count grows linearly across the group (the
    expectation over all orders of the group): ties can neither help nor hurt.
    """
    conf = np.where(np.isnan(confidence), -np.inf, confidence)
    order = np.argsort(-conf, kind='stable')
    conf_sorted = conf[order]
    bad_sorted = bad[order].astype(np.float64)
    size = conf_sorted.size
    # Group boundaries: positions where the confidence changes (-inf == -inf groups NaNs).
    starts = np.flatnonzero(np.r_[True, conf_sorted[1:] != conf_sorted[:-1]])
    ends = np.r_[starts[1:], size]
    bad_cum = np.r_[0.0, np.cumsum(bad_sorted)]
    group_bad = bad_cum[ends] - bad_cum[starts]
    group_rate = group_bad / (ends - starts)
    group_of = np.repeat(np.arange(starts.size), ends - starts)
    k = np.arange(1, size + 1, dtype=np.float64)
    counts: FloatArray = bad_cum[starts][group_of] + (k - starts[group_of]) * group_rate[group_of]
    return counts


def _evaluated(
    confidence: npt.ArrayLike,
    error: npt.ArrayLike,
    valid_mask: npt.ArrayLike | None,
    n: float,
) -> tuple[FloatArray, BoolArray, float]:
    conf = _as_map('confidence', confidence)
    err = _as_map('error', error)
    _check_same_shape('confidence', conf, 'error', err)
    mask = _as_mask(valid_mask, err.shape)
    threshold = _check_threshold(n)
    err_eval = err[mask]
    with np.errstate(invalid='ignore'):
        bad = ~(np.isfinite(err_eval) & (err_eval <= threshold))
    return conf[mask], bad, threshold


def sparsification_curve(
    confidence: npt.ArrayLike,
    error: npt.ArrayLike,
    *,
    valid_mask: npt.ArrayLike | None = None,
    n: float = 2.0,
) -> tuple[FloatArray, FloatArray]:
    """The sparsification curve: bad-N rate of the most confident fraction of pixels.

    Args:
        confidence: (H, W) confidence, higher is more confident; NaN ranks last.
        error: (H, W) absolute error ``|d - d_gt|`` in px; NaN/inf (no estimate) is bad.
        valid_mask: Optional (H, W) bool array of the pixels to evaluate. Pixels without
            ground truth must be excluded here, since a NaN error counts as bad.
        n: bad-N threshold in px (>= 0).

    Returns:
        ``(density, bad_rate)``, each of length N (the number of evaluated pixels):
        ``density[k-1] = k / N`` and ``bad_rate[k-1]`` is the bad-N rate of the k most
        confident pixels, with ties in confidence resolved by their expected value.

    Raises:
        ArgumentError: If the arrays are not 2-D or their shapes differ, the mask is not
            boolean, or ``n`` is negative or not finite.
    """
    conf, bad, _ = _evaluated(confidence, error, valid_mask, n)
    size = bad.size
    k = np.arange(1, size + 1, dtype=np.float64)
    rate: FloatArray = _ranked_bad_counts(conf, bad) / k
    density: FloatArray = k / max(size, 1)
    return density, rate


def sparsification_auc(
    confidence: npt.ArrayLike,
    error: npt.ArrayLike,
    *,
    valid_mask: npt.ArrayLike | None = None,
    n: float = 2.0,
    steps: int | None = None,
) -> ConfidenceScores:
    """Area under the sparsification curve, and its ratio to the optimal area.

    With ``steps=None`` the curve is integrated exactly as a Riemann sum over every pixel
    (each kept count k = 1..N contributes ``rate(k) / N``). With ``steps=s`` it is sampled at
    densities ``j / s`` (j = 1..s, kept count rounded to the nearest pixel) and averaged,
    as the coarser published protocols do; ``steps=N`` equals the exact sum.

    Ties in confidence never favour the method: a tie group contributes its expected bad
    count under a random order, so a constant confidence gives ``auc == error_rate``.

    Args:
        confidence: (H, W) confidence, higher is more confident; NaN ranks last.
        error: (H, W) absolute error ``|d - d_gt|`` in px; NaN/inf (no estimate) is bad.
        valid_mask: Optional (H, W) bool array of the pixels to evaluate. Pixels without
            ground truth must be excluded here, since a NaN error counts as bad.
        n: bad-N threshold in px (>= 0).
        steps: Number of density samples (>= 1), or None for the exact per-pixel sum.

    Returns:
        The scores; all NaN (and ``n_pixels`` 0) when no pixel is evaluated.

    Raises:
        ArgumentError: If the arrays are not 2-D or their shapes differ, the mask is not
            boolean, ``n`` is negative or not finite, or ``steps`` < 1.
    """
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
        raise ArgumentError(f'steps must be None or an int >= 1, got {steps!r}')
    conf, bad, threshold = _evaluated(confidence, error, valid_mask, n)
    size = bad.size
    if size == 0:
        nan = math.nan
        return ConfidenceScores(nan, nan, nan, nan, 0, threshold)
    k = np.arange(1, size + 1, dtype=np.float64)
    rate = _ranked_bad_counts(conf, bad) / k
    if steps is None:
        auc = float(np.mean(rate))
    else:
        kept = np.rint(np.arange(1, steps + 1) * (size / steps)).astype(np.intp)
        auc = float(np.mean(rate[np.clip(kept, 1, size) - 1]))
    e = float(np.count_nonzero(bad)) / size
    best = optimal_auc(e)
    ratio = auc / best if best > 0 else 1.0
    return ConfidenceScores(
        auc=auc, optimal_auc=best, ratio=ratio, error_rate=e, n_pixels=size, threshold=threshold
    )
