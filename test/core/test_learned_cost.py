"""The learned matching cost: the feature network (OpenCV dnn on the hand-written ONNX
model against plain numpy), its weights file, the quantised features and the cost rows
against their plain references, and SGM with the learned cost against a simulated
scene's ground truth."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import kernel_size
from reference.learned import conv3x3_reference, features_reference
from reference.sgm import cost_volume_reference, learned_cost_reference, unit_quantised_reference

from depth_nodes.core.learned.network import (
    SHIPPED,
    FeatureExtractor,
    FeatureNet,
    WeightsError,
    normalise,
)
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.core.sgm.cost import cost_inputs
from depth_nodes.core.sgm.learned_cost import (
    FUSED_CHANNELS,
    QUANT,
    learned_costs_from,
    unit_quantised,
)
from depth_nodes.errors import ArgumentError
from depth_nodes.sim.stereo import StereoSimConfig, simulate_stereo

H, W = kernel_size((21, 43), (9, 23))


def _net(channels: int = 6, layers: int = 3, seed: int = 0) -> FeatureNet:
    rng = np.random.default_rng(seed)
    kernels, biases, c_in = [], [], 1
    for _ in range(layers):
        kernels.append(rng.normal(0, 0.4, (3, 3, c_in, channels)).astype(np.float32))
        biases.append(rng.normal(0, 0.1, channels).astype(np.float32))
        c_in = channels
    return FeatureNet(tuple(kernels), tuple(biases), 5, {'made': 'test'})


def _image(seed: int = 0, h: int = H, w: int = W) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.integers(0, 256, (h, w)).astype(np.uint8), (3, 3), 0)


def test_weights_round_trip(tmp_path: Path) -> None:
    net = _net()
    net.save(tmp_path / 'w.npz')
    back = FeatureNet.load(tmp_path / 'w.npz')
    assert back.window == 5
    assert back.recipe == {'made': 'test'}
    assert back.channels == 6
    for a, b in zip(net.kernels + net.biases, back.kernels + back.biases, strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_bad_weights_file_names_the_problem(tmp_path: Path) -> None:
    with pytest.raises(WeightsError, match=r'cannot read feature weights .*missing\.npz'):
        FeatureNet.load(tmp_path / 'missing.npz')
    (tmp_path / 'junk.npz').write_bytes(b'not a zip')
    with pytest.raises(WeightsError, match='cannot read'):
        FeatureNet.load(tmp_path / 'junk.npz')
    net = _net()
    with pytest.raises(WeightsError, match='layer 1'):
        FeatureNet((net.kernels[0], net.kernels[0]), net.biases[:2], 5)
    with pytest.raises(WeightsError, match='odd'):
        FeatureNet(net.kernels, net.biases, 4)


def test_normalisation_ignores_gain_and_offset() -> None:
    img = _image().astype(np.float32)
    a = normalise(img, 5)
    # a gain and an offset change only the variance floor's share (small for texture)
    b = normalise(1.6 * img + 20.0, 5)
    assert np.abs(a - b).max() < 0.05
    with pytest.raises(ArgumentError, match='grey'):
        normalise(np.zeros((4, 4, 3)), 5)


def test_conv_reference_is_a_correlation_with_zero_padding() -> None:
    x = np.zeros((5, 6, 1), np.float32)
    x[2, 3, 0] = 1.0
    kernel = np.arange(9, dtype=np.float32).reshape(3, 3, 1, 1)
    out = conv3x3_reference(x, kernel, np.zeros(1, np.float32))[:, :, 0]
    # the output at (y, x) reads input (y + dy - 1, x + dx - 1) with weight kernel[dy, dx]
    assert out[1, 2] == kernel[2, 2, 0, 0]
    assert out[3, 4] == kernel[0, 0, 0, 0]
    assert out[2, 3] == kernel[1, 1, 0, 0]
    assert out.sum() == kernel.sum()


@pytest.mark.kernels
def test_the_numba_features_match_the_numpy_network() -> None:
    """The convolution kernel against the plain network (float32 sums in another order:
    2e-5), twice with the same buffers, and again at another size."""
    net = _net()
    img = _image(1)
    extractor = FeatureExtractor(net)
    got = extractor.features(img)
    ref = features_reference(net, img)
    assert got.shape == (H, W, 6)
    np.testing.assert_allclose(got, ref, atol=2e-5)
    np.testing.assert_allclose(np.linalg.norm(got, axis=2), 1.0, atol=1e-5)
    np.testing.assert_array_equal(extractor.features(img), got)
    small = img[: H // 2, : W // 2]
    np.testing.assert_allclose(extractor.features(small), features_reference(net, small),
                               atol=2e-5)


@pytest.mark.kernels
def test_quantised_units_match_reference() -> None:
    raw = np.random.default_rng(2).normal(0, 1, (6, H, W)).astype(np.float32)
    raw[:, 0, 0] = 0.0  # a zero vector stays zero
    got = unit_quantised(raw)
    np.testing.assert_array_equal(got, unit_quantised_reference(raw))
    assert np.abs(got).max() <= QUANT
    assert not got[0, 0].any()


@pytest.mark.kernels
@pytest.mark.parametrize('min_disparity', [0, -3, 5])
@pytest.mark.parametrize('channels', [5, FUSED_CHANNELS])
def test_learned_cost_rows_match_reference(min_disparity: int, channels: int) -> None:
    """The generic kernel (5 features) and the unrolled one (6) against the reference."""
    rng = np.random.default_rng(3)
    fl = unit_quantised_reference(rng.normal(0, 1, (channels, H, W)).astype(np.float32))
    fr = unit_quantised_reference(rng.normal(0, 1, (channels, H, W)).astype(np.float32))
    n = kernel_size(16, 7)
    costs = learned_costs_from(fl, fr, min_disparity=min_disparity, weight=40)
    out = np.empty((H, W, n), np.uint8)
    costs.rows(0, out)
    ref = learned_cost_reference(fl, fr, min_disparity=min_disparity, disparity_range=n,
                                 weight=40)
    np.testing.assert_array_equal(out, ref)
    # any band of rows is the same band of the whole volume
    y0 = H // 3
    band = np.empty((4, W, n), np.uint8)
    costs.rows(y0, band)
    np.testing.assert_array_equal(band, ref[y0:y0 + 4])
    # identical features cost 0 (1 where the quantisation's rounding shortens a vector
    # by more than 1 %); opposite ones twice the weight
    same = learned_costs_from(fl, fl, min_disparity=0, weight=40)
    row = np.empty((1, W, n), np.uint8)
    same.rows(0, row)
    assert (row[0, np.arange(n, W), 0] <= 1).all()
    assert (row[0, np.arange(n, W), 0] == 0).mean() > 0.8
    opposite = learned_costs_from(fl, -fl, min_disparity=0, weight=40)
    opposite.rows(0, row)
    nonzero = np.abs(fl[0, n:]).sum(axis=1) > 0
    assert (np.abs(row[0, n:, 0][nonzero].astype(int) - 80) <= 2).all()


@pytest.mark.kernels
@pytest.mark.parametrize('channels', [5, FUSED_CHANNELS])
def test_census_plus_learned_is_the_sum_of_both_clipped(channels: int) -> None:
    """Both ways of adding the two: census's rows then the learned pass (5 features), and
    the fused pass over each pixel's cell (6 features, 16-bit census)."""
    rng = np.random.default_rng(4)
    left, right = _image(5), _image(6)
    fl = unit_quantised_reference(rng.normal(0, 1, (channels, H, W)).astype(np.float32))
    fr = unit_quantised_reference(rng.normal(0, 1, (channels, H, W)).astype(np.float32))
    n = kernel_size(12, 6)
    census = cost_inputs(left, right, min_disparity=1, disparity_range=n,
                         census_window=(5, 5), intensity_weight=1)
    assert census.sixteen_bit
    costs = learned_costs_from(fl, fr, min_disparity=1, weight=90, census=census)
    out = np.empty((H, W, n), np.uint8)
    costs.rows(0, out)
    both = cost_volume_reference(left, right, min_disparity=1, disparity_range=n,
                                 census_window=(5, 5), intensity_weight=1).astype(int)
    learned = learned_cost_reference(fl, fr, min_disparity=1, disparity_range=n, weight=90)
    expected = np.where(both == 255, 255, np.minimum(both + learned, 254))
    np.testing.assert_array_equal(out, expected)


def test_learned_settings_are_checked() -> None:
    with pytest.raises(ArgumentError, match=r'disparity_search.*coarse needs matching_cost '
                       r'census'):
        SgmParams(matching_cost='learned', disparity_search='coarse').validate()
    with pytest.raises(ArgumentError, match='matching_cost'):
        SgmParams(matching_cost='mc-cnn').validate()
    with pytest.raises(ArgumentError, match='learned_weight'):
        SgmParams(learned_weight=0).validate()


def test_shipped_weights_are_small_and_say_how_they_were_made() -> None:
    net = FeatureNet.load(SHIPPED)
    assert SHIPPED.stat().st_size <= 2 * 1024 * 1024
    assert net.recipe['command'].startswith('depth-nodes train-cost')
    assert net.recipe['data']['scenes'] > 0
    assert 'seed' in net.recipe['data']
    assert net.radius == net.recipe['train']['layers']


@pytest.fixture(scope='module')
def sim_frame():  # type: ignore[no-untyped-def]
    config = StereoSimConfig(width=320, height=240, n_frames=1, seed=41)
    return next(iter(simulate_stereo(config)))


def _bad(disparity: np.ndarray, frame, threshold: float) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """Density over the visible pixels, and the share of the kept ones off by more than
    ``threshold`` px."""
    visible = (frame.occlusion_gt == 0) & np.isfinite(frame.disparity_gt)
    found = visible & np.isfinite(disparity)
    error = np.abs(disparity[found] - frame.disparity_gt[found])
    return found.sum() / visible.sum(), float(np.mean(error > threshold))


@pytest.mark.parametrize('cost', ['learned', 'census+learned'])
def test_sgm_with_the_learned_cost_finds_the_true_disparity(sim_frame, cost: str) -> None:  # type: ignore[no-untyped-def]
    f = sim_frame
    d = SgmMatcher(SgmParams(disparity_range=48, matching_cost=cost)).match(
        f.left_rect_gt, f.right_rect_gt).disparity
    density, bad1 = _bad(d, f, 1.0)
    _, bad4 = _bad(d, f, 4.0)
    # on a clean pair census alone does better (2.5 % bad-1 here): the learned cost is
    # for cameras that disagree (the next test; docs/learned.md). The shipped 6-feature
    # network alone: 9.9 % bad-1 (the 16-feature one before it: 7.4 %)
    assert density > 0.85
    assert bad1 < 0.11
    assert bad4 < 0.02


def test_census_plus_learned_beats_census_when_the_right_camera_sits_lower(sim_frame) -> None:  # type: ignore[no-untyped-def]
    f = sim_frame
    right = cv2.warpAffine(f.right_rect_gt.astype(np.float32), np.float32([[1, 0, 0],
                                                                        [0, 1, 0.6]]),
                           f.right_rect_gt.shape[::-1], borderMode=cv2.BORDER_REPLICATE)
    right = np.round(right).astype(np.uint8)
    scores = {}
    for cost in ('census', 'census+learned'):
        d = SgmMatcher(SgmParams(disparity_range=48, matching_cost=cost)).match(
            f.left_rect_gt, right).disparity
        density, bad = _bad(d, f, 1.0)
        scores[cost] = bad + (1 - density)  # dense bad-1: a dropped pixel counts as bad
    assert scores['census+learned'] < 0.9 * scores['census'], scores


def test_the_windows_of_the_coarse_search_need_census() -> None:
    left = _image(7)
    lo = np.zeros(left.shape, np.int32)
    matcher = SgmMatcher(SgmParams(disparity_range=8, matching_cost='learned'))
    with pytest.raises(ArgumentError, match='match_windows needs matching_cost census'):
        matcher.match_windows(left, left, lo, lo + 8)


def test_a_stream_keeps_its_feature_buffers_and_its_results() -> None:
    left, right = _image(8, 40, 64), _image(9, 40, 64)
    matcher = SgmMatcher(SgmParams(disparity_range=16, matching_cost='learned'))
    first = matcher.match(left, right).disparity.copy()
    buffers = matcher._features
    again = matcher.match(left, right).disparity
    assert buffers is not None
    assert matcher._features is not None
    assert matcher._features[0] is buffers[0]
    assert matcher._features[1] is buffers[1]
    np.testing.assert_array_equal(first, again)
    fresh = SgmMatcher(SgmParams(disparity_range=16, matching_cost='learned'))
    np.testing.assert_array_equal(fresh.match(left, right).disparity, again)
    # another size: new buffers of that size
    matcher.match(left[:30], right[:30])
    assert matcher._features[0].shape[::2] == (30, 64)  # (H, C, W)
