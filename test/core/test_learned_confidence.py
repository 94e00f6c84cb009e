"""The learned confidence: its signals on hand-made maps, its weights file, its forward
pass against a plain one, and its ranking against the ground truth of a simulated pair
(better than the hand-made confidence's)."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from helpers import kernel_size
from reference.learned import confidence_signals_reference, predict_reference

from depth_nodes.core.cross_check import MISMATCH, VALID, CrossCheckParams, cross_check
from depth_nodes.core.learned.confidence import (
    SHIPPED,
    SIGNALS,
    ConfidenceModel,
    confidence_signals,
    shipped_confidence,
)
from depth_nodes.core.learned.network import WeightsError
from depth_nodes.core.metrics import sparsification_auc
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.errors import ArgumentError
from depth_nodes.sim.stereo import StereoSimConfig, simulate_stereo


def _model(seed: int = 0, hidden: int = 5) -> ConfidenceModel:
    rng = np.random.default_rng(seed)
    sizes = [len(SIGNALS), hidden, hidden, 1]
    return ConfidenceModel(
        tuple(rng.normal(0, 0.5, (a, b)).astype(np.float32)
              for a, b in itertools.pairwise(sizes)),
        tuple(rng.normal(0, 0.1, b).astype(np.float32) for b in sizes[1:]), {'made': 'test'})


def _index(name: str) -> int:
    return SIGNALS.index(name)


def test_signals_of_hand_made_maps() -> None:
    h, w = 12, 30
    raw = np.full((h, w), 10.0, np.float32)
    raw[:, 20] = 14.0  # an outlier column
    raw[0, 0] = np.nan
    ratio = np.full((h, w), 0.25, np.float32)
    diff = np.zeros((h, w), np.float32)
    diff[:, 5] = 3.0
    diff[:, 2] = np.nan
    labels = np.full((h, w), VALID, np.uint8)
    labels[:, 5] = MISMATCH
    filled = np.zeros((h, w), bool)
    filled[:, 5] = True
    s = confidence_signals(raw, ratio, diff, labels, filled, 1.0)
    assert s.shape == (h, w, len(SIGNALS))
    assert s.dtype == np.float32
    np.testing.assert_allclose(s[..., _index('distinct')], 0.75)
    assert s[3, 5, _index('lr_difference')] == pytest.approx(3.0 / 8.0)
    assert s[3, 2, _index('lr_none')] == 1.0
    assert s[3, 2, _index('lr_difference')] == 1.0
    assert s[3, 5, _index('mismatch')] == 1.0
    assert s[3, 5, _index('valid')] == 0.0
    assert s[3, 5, _index('filled')] == 1.0
    assert s[3, 6, _index('filled')] == 0.0
    # the outlier deviates from its neighbourhood; a pixel far from it does not
    assert s[5, 20, _index('deviation_5')] > 0.3
    assert s[5, 10, _index('deviation_5')] == 0.0
    # distances along the row to the mismatch column, capped at 16 px (scaled to 1)
    assert s[3, 8, _index('gap_left')] == pytest.approx(3 / 16)
    assert s[3, 2, _index('gap_right')] == pytest.approx(3 / 16)
    assert s[3, 29, _index('gap_right')] == 1.0
    # the left border strip's partner x - d lies outside the right image
    assert s[3, 4, _index('outside')] == pytest.approx(6 / 16)
    assert s[3, 15, _index('outside')] == 0.0
    assert np.isfinite(s).all()
    assert s.min() >= 0.0
    assert s.max() <= 1.0


@pytest.mark.kernels
def test_the_signal_kernels_match_the_plain_signals() -> None:
    """Random maps with NaN, infinite and huge values, every label: the planes the kernels
    assemble equal numpy's definition (float32 box means taken the same way: 1e-6)."""
    rng = np.random.default_rng(7)
    shape = kernel_size((37, 53), (12, 17))
    raw = rng.uniform(-5, 60, shape).astype(np.float32)
    raw[rng.random(shape) < 0.2] = np.nan
    raw[0, :3] = (np.inf, -np.inf, 3e38)
    ratio = rng.uniform(-0.2, 1.2, shape).astype(np.float32)
    ratio[rng.random(shape) < 0.1] = np.nan
    diff = rng.uniform(0, 12, shape).astype(np.float32)
    diff[rng.random(shape) < 0.2] = np.nan
    diff[1, :2] = (np.inf, -np.inf)
    labels = rng.choice([VALID, MISMATCH, 1, 3, 4], shape).astype(np.uint8)
    filled = rng.random(shape) < 0.1
    got = confidence_signals(raw, ratio, diff, labels, filled, 1.0)
    want = confidence_signals_reference(raw, ratio, diff, labels, filled, 1.0)
    for k, name in enumerate(SIGNALS):
        np.testing.assert_allclose(got[..., k], want[..., k], atol=1e-6, err_msg=name)


@pytest.mark.kernels
def test_the_network_kernel_matches_the_plain_network() -> None:
    model = _model(3, hidden=7)
    shape = (*kernel_size((31, 45), (9, 11)), len(SIGNALS))
    x = np.random.default_rng(2).random(shape).astype(np.float32)
    np.testing.assert_allclose(model.predict(x), predict_reference(model, x), atol=1e-6)


def test_the_forward_pass_is_the_plain_network() -> None:
    model = _model()
    x = np.random.default_rng(1).random((4, 6, len(SIGNALS))).astype(np.float32)
    hidden = np.maximum(x.reshape(24, -1) @ model.matrices[0] + model.biases[0], 0)
    hidden = np.maximum(hidden @ model.matrices[1] + model.biases[1], 0)
    logit = (hidden @ model.matrices[2] + model.biases[2])[:, 0]
    np.testing.assert_allclose(model.predict(x).ravel(), 1 / (1 + np.exp(-logit)), rtol=1e-5)
    with pytest.raises(ArgumentError, match=f'signals .* must be \\(H, W, {len(SIGNALS)}\\)'):
        model.predict(x[..., :3])


def test_weights_round_trip_and_bad_files(tmp_path: Path) -> None:
    model = _model()
    model.save(tmp_path / 'c.npz')
    back = ConfidenceModel.load(tmp_path / 'c.npz')
    assert back.recipe == {'made': 'test'}
    for a, b in zip(model.matrices, back.matrices, strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(WeightsError, match='cannot read confidence weights'):
        ConfidenceModel.load(tmp_path / 'none.npz')
    np.savez(tmp_path / 'other.npz', recipe=np.array('{}'), signals=np.array(['a', 'b']),
             matrix0=np.zeros((2, 1), np.float32), bias0=np.zeros(1, np.float32))
    with pytest.raises(WeightsError, match='trained on other signals'):
        ConfidenceModel.load(tmp_path / 'other.npz')
    with pytest.raises(WeightsError, match='one output'):
        ConfidenceModel((np.zeros((len(SIGNALS), 2), np.float32),), (np.zeros(2, np.float32),))


def test_shipped_model_says_how_it_was_made() -> None:
    model = shipped_confidence()
    assert SHIPPED.stat().st_size < 100_000
    assert model.recipe['command'] == 'depth-nodes train-confidence'
    assert model.recipe['config']['threshold'] > 0


@pytest.fixture(scope='module')
def matched():  # type: ignore[no-untyped-def]
    frame = next(iter(simulate_stereo(StereoSimConfig(width=320, height=240, n_frames=1,
                                                      seed=43))))
    rng = np.random.default_rng(0)
    left, right = (np.clip(i + rng.normal(0, 2, i.shape), 0, 255).astype(np.uint8)
                   for i in (frame.left_rect_gt, frame.right_rect_gt))
    result = SgmMatcher(SgmParams(disparity_range=48, paths=5)).match(left, right)
    return frame, result


def test_learned_confidence_ranks_the_raw_errors_better_than_the_hand_made_one(
        matched) -> None:  # type: ignore[no-untyped-def]
    frame, result = matched
    params = CrossCheckParams(fill_holes=True, median_size=5)
    raw = result.disparity
    has = np.isfinite(raw) & np.isfinite(frame.disparity_gt)
    error = np.abs(raw - frame.disparity_gt)
    ratios = {}
    for name, model in (('handmade', None), ('learned', shipped_confidence())):
        checked = cross_check(raw, result.disparity_right, result.cost_ratio,
                              **params.arguments(), model=model)
        assert checked.confidence.min() >= 0.0
        assert checked.confidence.max() <= 1.0
        # the convention of the output: no disparity, no confidence
        assert (checked.confidence[np.isnan(checked.disparity)] == 0).all()
        ratios[name] = sparsification_auc(checked.confidence, error, valid_mask=has,
                                          n=2).ratio
    # AUC / optimum of the raw matcher's errors: lower is better, 1 is a perfect ranking
    assert 1.0 <= ratios['learned'] < 0.95 * ratios['handmade'], ratios
