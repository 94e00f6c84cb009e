"""Tests of depth_nodes.core.metrics against hand-computed values and closed forms."""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np
import pytest

from depth_nodes.core.metrics import (
    ConfidenceScores,
    depth_errors,
    disparity_errors,
    optimal_auc,
    sparsification_auc,
    sparsification_curve,
)

nan = np.nan


# -- disparity_errors ---------------------------------------------------------------------


def test_ten_pixels_three_bad() -> None:
    truth = np.arange(10, dtype=np.float64).reshape(2, 5) + 5
    offsets = np.array([0, 0.5, -1, 0, 2, 0, 0, 3, -3, 2.5]).reshape(2, 5)
    s = disparity_errors(truth + offsets, truth)
    assert (s.n_gt, s.n_est, s.threshold) == (10, 10, 2.0)
    assert s.bad_dense == pytest.approx(0.3)  # 3, -3 and 2.5; exactly 2 is not bad
    assert s.bad_sparse == pytest.approx(0.3)
    assert s.density == 1.0
    assert s.avgerr == pytest.approx(12.0 / 10)
    assert s.rmse == pytest.approx(math.sqrt((0.25 + 1 + 4 + 9 + 9 + 6.25) / 10))
    assert disparity_errors(truth + offsets, truth, n=0.75).bad_dense == pytest.approx(0.5)


def test_nan_estimates_and_missing_truth() -> None:
    truth = np.array([[1.0, 2, 3, 4, nan], [6, 7, 8, 9, nan]])
    estimate = np.array([[1.0, nan, 3, 7, 5], [np.inf, 7, 8, 9, nan]])
    s = disparity_errors(estimate, truth)
    assert (s.n_gt, s.n_est) == (8, 6)
    assert s.bad_dense == pytest.approx(3 / 8)  # two unestimated + one off by 3
    assert s.bad_sparse == pytest.approx(1 / 6)
    assert s.density == pytest.approx(6 / 8)
    assert s.avgerr == pytest.approx(3 / 6)
    assert s.rmse == pytest.approx(math.sqrt(9 / 6))


def test_valid_mask_restricts_pixels() -> None:
    truth = np.full((2, 3), 10.0)
    estimate = truth + np.array([[0.0, 5, 0], [0, 0, 5]])
    mask = np.array([[True, False, True], [True, True, False]])
    s = disparity_errors(estimate, truth, valid_mask=mask)
    assert (s.n_gt, s.bad_dense, s.avgerr) == (4, 0.0, 0.0)


def test_integer_inputs_accepted() -> None:
    s = disparity_errors(np.array([[1, 2], [3, 9]]), np.array([[1, 2], [3, 4]]))
    assert s.bad_dense == pytest.approx(0.25)


def test_no_ground_truth_gives_nan_without_warnings() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        s = disparity_errors(np.ones((3, 3)), np.full((3, 3), nan))
        scores = [s.bad_dense, s.bad_sparse, s.density, s.avgerr, s.rmse]
        assert all(math.isnan(v) for v in scores)
        assert (s.n_gt, s.n_est) == (0, 0)
        s = disparity_errors(np.full((3, 3), nan), np.ones((3, 3)))
        assert (s.bad_dense, s.density, s.n_gt, s.n_est) == (1.0, 0.0, 9, 0)
        assert math.isnan(s.bad_sparse)
        assert math.isnan(s.avgerr)


@pytest.mark.parametrize(
    ('args', 'kwargs', 'match'),
    [
        (
            (np.zeros((2, 3)), np.zeros((3, 2))),
            {},
            r'estimate and truth must have the same shape, got \(2, 3\) and \(3, 2\)',
        ),
        (
            (np.zeros(4), np.zeros(4)),
            {},
            r'estimate must be a 2-D \(H, W\) array, got shape \(4,\)',
        ),
        ((np.zeros((2, 2)), np.zeros((1, 2, 2))), {}, r'truth must be a 2-D .* \(1, 2, 2\)'),
        ((np.zeros((2, 2), complex), np.zeros((2, 2))), {}, 'estimate must be a real numeric'),
        (
            (np.zeros((2, 2)), np.zeros((2, 2))),
            {'valid_mask': np.ones((2, 2))},
            'valid_mask must be a boolean array, got dtype float64',
        ),
        (
            (np.zeros((2, 2)), np.zeros((2, 2))),
            {'valid_mask': np.ones((2, 3), bool)},
            r'valid_mask must have shape \(2, 2\), got \(2, 3\)',
        ),
        ((np.zeros((2, 2)), np.zeros((2, 2))), {'n': -1.0}, r'n must be .* >= 0 \(px\), got -1.0'),
        ((np.zeros((2, 2)), np.zeros((2, 2))), {'n': nan}, 'n must be a finite number'),
    ],
)
def test_disparity_errors_rejects(args: Any, kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        disparity_errors(*args, **kwargs)


# -- depth_errors -------------------------------------------------------------------------


def test_depth_errors_known_values() -> None:
    truth = np.array([[1.0, 2.0, 4.0], [0.0, nan, 5.0]])  # 0 and NaN: no ground truth
    estimate = np.array([[1.1, 2.0, 3.0], [1.0, 1.0, -1.0]])  # -1: no estimate
    s = depth_errors(estimate, truth)
    assert (s.n_gt, s.n_est) == (4, 3)
    assert s.density == pytest.approx(0.75)
    assert s.mae == pytest.approx((0.1 + 0 + 1) / 3)
    assert s.rel == pytest.approx((0.1 / 1 + 0 + 1 / 4) / 3)
    assert s.rmse == pytest.approx(math.sqrt((0.01 + 1) / 3))
    masked = depth_errors(estimate, truth, np.array([[True, True, False], [True] * 3]))
    assert masked.mae == pytest.approx(0.05)


def test_depth_errors_empty_and_shape() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        s = depth_errors(np.full((2, 2), nan), np.ones((2, 2)))
    assert (s.density, s.n_gt, s.n_est) == (0.0, 4, 0)
    assert math.isnan(s.mae)
    assert math.isnan(s.rel)
    assert math.isnan(s.rmse)
    with pytest.raises(ValueError, match=r'estimate_m and truth_m must have the same shape'):
        depth_errors(np.ones((2, 2)), np.ones((2, 1)))


# -- confidence ---------------------------------------------------------------------------


def test_optimal_auc_closed_form() -> None:
    assert optimal_auc(0.0) == 0.0
    assert optimal_auc(1.0) == 1.0
    assert optimal_auc(0.3) == pytest.approx(0.3 + 0.7 * math.log(0.7))
    with pytest.raises(ValueError, match=r'error_rate must be in \[0, 1\], got 1.5'):
        optimal_auc(1.5)


def test_auc_hand_computed() -> None:
    conf = np.array([[4.0, 3.0, 2.0, 1.0]])
    error = np.array([[0.0, 5.0, 1.0, nan]])  # bad: pixels 2 and 4 (NaN = no estimate)
    s = sparsification_auc(conf, error)
    assert s.auc == pytest.approx((0 + 1 / 2 + 1 / 3 + 2 / 4) / 4)
    assert s.error_rate == 0.5
    assert s.optimal_auc == pytest.approx(0.5 + 0.5 * math.log(0.5))
    assert s.ratio == pytest.approx(s.auc / s.optimal_auc)
    assert (s.n_pixels, s.threshold) == (4, 2.0)
    density, rate = sparsification_curve(conf, error)
    np.testing.assert_allclose(density, [0.25, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(rate, [0, 1 / 2, 1 / 3, 2 / 4])


def test_ties_use_the_expected_value() -> None:
    # A tie of one good and one bad pixel contributes 0.5 bad at k=1 whichever comes first.
    error_a = np.array([[9.0, 0.0, 0.0]])
    error_b = np.array([[0.0, 9.0, 0.0]])
    conf = np.array([[1.0, 1.0, 0.0]])
    a = sparsification_auc(conf, error_a)
    b = sparsification_auc(conf, error_b)
    assert a.auc == b.auc == pytest.approx((0.5 + 0.5 + 1 / 3) / 3)
    # NaN confidence ranks last, tied with other NaNs.
    nan_conf = sparsification_auc(np.array([[nan, 1.0, nan]]), np.array([[0.0, 0.0, 9.0]]))
    assert nan_conf.auc == pytest.approx((0 + 0.25 + 1 / 3) / 3)


def test_constant_confidence_gives_error_rate() -> None:
    rng = np.random.default_rng(3)
    error = rng.exponential(1.5, size=(100, 123))
    s = sparsification_auc(np.full(error.shape, 0.7), error)
    e = np.count_nonzero(error > 2.0) / error.size
    assert s.error_rate == e
    assert s.auc == pytest.approx(e, rel=1e-12, abs=0)
    assert s.ratio > 1.5


@pytest.mark.parametrize('size', [10, 97, 1000, 20_000])
@pytest.mark.parametrize('e_target', [0.05, 0.3, 0.8])
def test_oracle_auc_matches_closed_form_within_one_over_n(size: int, e_target: float) -> None:
    rng = np.random.default_rng(size)
    n_bad = max(1, round(e_target * size))
    error = np.r_[rng.uniform(0, 2, size - n_bad), rng.uniform(2.5, 9, n_bad)]
    error = rng.permutation(error).reshape(1, size)
    s = sparsification_auc(-error, error)
    assert s.error_rate == n_bad / size
    assert abs(s.auc - s.optimal_auc) <= 1.0 / size
    assert s.auc >= s.optimal_auc  # the discrete sum never beats the continuous optimum


def test_oracle_ratio_random_ratio() -> None:
    rng = np.random.default_rng(0)
    error = rng.exponential(1.0, size=(200, 500))  # 10^5 pixels, e ~ exp(-2)
    error[rng.random(error.shape) < 0.05] = nan  # unestimated pixels count as bad
    oracle_conf = -np.nan_to_num(error, nan=np.inf)
    oracle = sparsification_auc(oracle_conf, error)
    assert oracle.ratio == pytest.approx(1.0, abs=1e-3)
    random_conf = sparsification_auc(rng.random(error.shape), error)
    assert random_conf.error_rate == oracle.error_rate
    assert random_conf.auc == pytest.approx(oracle.error_rate, abs=0.01)
    assert random_conf.ratio > 2.0


def test_steps_sampling() -> None:
    rng = np.random.default_rng(5)
    error = rng.exponential(1.5, size=(30, 40))
    conf = -error + rng.normal(0, 1.0, size=error.shape)
    exact = sparsification_auc(conf, error)
    assert sparsification_auc(conf, error, steps=error.size).auc == pytest.approx(exact.auc)
    assert sparsification_auc(conf, error, steps=20).auc == pytest.approx(exact.auc, abs=0.02)
    assert sparsification_auc(conf, error, steps=1).auc == pytest.approx(exact.error_rate)


def test_auc_mask_and_edge_cases() -> None:
    conf = np.array([[3.0, 2.0, 1.0]])
    error = np.array([[0.0, 9.0, nan]])
    masked = sparsification_auc(conf, error, valid_mask=np.array([[True, True, False]]))
    assert masked.n_pixels == 2
    assert masked.auc == pytest.approx((0 + 0.5) / 2)
    perfect = sparsification_auc(conf, np.zeros((1, 3)))
    assert (perfect.auc, perfect.optimal_auc, perfect.ratio, perfect.error_rate) == (0, 0, 1, 0)
    all_bad = sparsification_auc(conf, np.full((1, 3), 5.0))
    assert (all_bad.auc, all_bad.optimal_auc, all_bad.ratio) == (1.0, 1.0, 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        empty = sparsification_auc(conf, error, valid_mask=np.zeros((1, 3), bool))
    assert isinstance(empty, ConfidenceScores)
    assert empty.n_pixels == 0
    assert all(math.isnan(v) for v in (empty.auc, empty.optimal_auc, empty.ratio))


@pytest.mark.parametrize(
    ('kwargs', 'match'),
    [
        (
            {'error': np.zeros((3, 2))},
            r'confidence and error must have the same shape, got \(2, 3\)',
        ),
        ({'steps': 0}, 'steps must be None or an int >= 1, got 0'),
        ({'steps': 2.5}, 'steps must be None or an int >= 1, got 2.5'),
        ({'n': -0.5}, 'n must be a finite number >= 0'),
        ({'valid_mask': np.ones((2, 3), np.uint8)}, 'valid_mask must be a boolean array'),
    ],
)
def test_sparsification_auc_rejects(kwargs: dict[str, Any], match: str) -> None:
    args: dict[str, Any] = {'confidence': np.zeros((2, 3)), 'error': np.zeros((2, 3))}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        sparsification_auc(**args)
