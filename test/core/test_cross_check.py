"""The cross-check core: left-right labels against a scene with exact occlusions, the
numba kernels against their plain references, speckles, hole filling and confidence."""

from __future__ import annotations

import numpy as np
import pytest
from reference.confidence import confidence_reference
from reference.cross_check import fill_disparity_holes_reference, left_right_check_reference

from depth_nodes.core.confidence import (
    DEFAULT_TERMS,
    PLAIN_TERMS,
    ConfidenceTerms,
)
from depth_nodes.core.cross_check import (
    INVALID,
    MISMATCH,
    OCCLUDED,
    OUTSIDE,
    SPECKLE,
    VALID,
    confidence_map,
    cross_check,
    fill_disparity_holes,
    left_right_check,
    median_filter,
    remove_speckles,
)

H, W = 40, 120
BACK, FRONT = 8.0, 20.0
X0, X1 = 50, 80  # the foreground box's columns in the left image, rows 10..29


def scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact left and right disparity of a box (d 20) before a wall (d 8), and the left
    occlusion mask: what the right camera cannot see.

    The right view is rendered by z-buffering the left pixels at x - d (the nearer surface,
    the larger d, wins); the wall behind the box's left edge is hidden from the right camera.
    """
    left = np.full((H, W), BACK, np.float32)
    left[10:30, X0:X1] = FRONT
    right = np.full((H, W), np.nan, np.float32)
    for y in range(H):
        for x in range(W):
            d = left[y, x]
            xr = int(x - d)
            if 0 <= xr < W and not right[y, xr] >= d:
                right[y, xr] = d
    occluded = np.zeros((H, W), bool)
    for y in range(H):
        for x in range(W):
            xr = int(x - left[y, x])
            occluded[y, x] = not (0 <= xr < W) or right[y, xr] != left[y, x]
    return left, right, occluded


def test_scene_has_the_expected_occlusion() -> None:
    _, right, occluded = scene()
    # the box shifts 12 px more than the wall: 12 wall columns left of it are hidden
    assert occluded[10:30, X0 - 12:X0].all()
    assert not occluded[10:30, X0:].any()
    assert occluded[:, :8].all()  # the wall's left border leaves the right image
    assert np.isnan(right[:, W - 8:]).all()  # nothing of the left image lands there


def test_left_right_labels_match_the_geometry() -> None:
    left, right, occluded = scene()
    estimate = left.copy()
    estimate[0, 0] = np.nan
    estimate[35, 100:104] = BACK + 3.0  # wrong, and the right view there sees d 8: mismatch
    check = left_right_check(estimate, right, max_diff=1.0)
    assert check.labels[0, 0] == INVALID
    assert (check.labels[35, 100:104] == MISMATCH).all()
    np.testing.assert_allclose(check.difference[35, 100:104], 3.0)
    rest = np.ones((H, W), bool)
    rest[0, 0] = False
    rest[35, 100:104] = False
    beyond = (np.arange(W)[None, :] - left) < -0.5  # the partner is left of the image
    assert beyond[:, :8].all()
    assert (check.labels[rest & occluded & beyond] == OUTSIDE).all()
    assert (check.labels[rest & occluded & ~beyond] == OCCLUDED).all()
    assert (check.labels[rest & ~occluded] == VALID).all()
    assert (check.difference[rest & ~occluded] == 0).all()


def test_threshold_is_inclusive() -> None:
    left, right, _ = scene()
    estimate = left + np.float32(1.0)  # off by exactly disp12_max_diff: still consistent
    labels = left_right_check(estimate, right, max_diff=1.0).labels
    assert (labels[20:, 100:] == VALID).all()
    labels = left_right_check(estimate, right, max_diff=0.5).labels
    assert (labels[20:, 100:] == MISMATCH).all()


@pytest.mark.kernels
class TestKernelsAgainstReferences:
    """Both numba kernels against the plain implementations, on random maps with holes."""

    @pytest.mark.parametrize('seed', [0, 1, 2])
    def test_left_right(self, seed: int) -> None:
        rng = np.random.default_rng(seed)
        left = rng.uniform(0, 30, (23, 57)).astype(np.float32)
        right = rng.uniform(0, 30, (23, 57)).astype(np.float32)
        left[rng.random(left.shape) < 0.1] = np.nan
        right[rng.random(right.shape) < 0.1] = np.nan
        left[0, :3] = [0.5, 1.5, 2.5]  # rounding half-way: floor(x - d + 0.5)
        for max_diff in (0.0, 1.0, 4.5):
            got = left_right_check(left, right, max_diff=max_diff)
            diff, labels = left_right_check_reference(left, right, max_diff)
            np.testing.assert_array_equal(got.labels, labels)
            np.testing.assert_array_equal(got.difference, diff)

    @pytest.mark.parametrize('seed', [0, 1, 2])
    @pytest.mark.parametrize('mode', ['labels', 'background'])
    def test_fill(self, seed: int, mode: str) -> None:
        rng = np.random.default_rng(seed)
        disp = rng.uniform(0, 30, (19, 31)).astype(np.float32)
        labels = rng.choice(np.array([VALID, INVALID, OCCLUDED, MISMATCH, SPECKLE], np.uint8),
                            disp.shape, p=[0.5, 0.1, 0.15, 0.15, 0.1])
        labels[3, :] = OCCLUDED  # a row without any valid pixel
        got, filled = fill_disparity_holes(disp, labels, mode=mode)
        valid = labels == VALID
        expected = fill_disparity_holes_reference(disp, valid, labels, mode)
        np.testing.assert_array_equal(got, expected)
        np.testing.assert_array_equal(filled, ~valid & np.isfinite(expected))
        if mode == 'labels':
            assert np.isnan(got[labels == INVALID]).all()
        else:  # every hole of a row with a kept pixel is filled
            assert np.isfinite(got[np.arange(19) != 3]).all()
            assert np.isnan(got[3]).all()


    @pytest.mark.parametrize('seed', [0, 1])
    @pytest.mark.parametrize('terms', [DEFAULT_TERMS, PLAIN_TERMS,
                                       ConfidenceTerms(support_window=1, smoothness=0.5,
                                                       outside_scale=0.0)])
    def test_confidence(self, seed: int, terms: ConfidenceTerms) -> None:
        """The float32 confidence passes against numpy, bit for bit: NaN and infinite
        ratios, differences and disparities, extrapolated pixels, filled pixels."""
        rng = np.random.default_rng(seed)
        shape = (21, 37)
        ratio = rng.uniform(-0.2, 1.2, shape).astype(np.float32)
        diff = rng.uniform(0, 3, shape).astype(np.float32)
        disp = rng.uniform(-5, 45, shape).astype(np.float32)
        for array, values in ((ratio, [np.nan, np.inf, -np.inf]),
                              (diff, [np.nan, np.inf, -np.inf]),
                              (disp, [np.nan, np.inf, -np.inf])):
            array[rng.random(shape) < 0.08] = values[0]
            array[0, :2] = values[1:]
        keep = rng.random(shape) < 0.7
        filled = ~keep & (rng.random(shape) < 0.5)
        for window, max_diff, factor in ((9, 1.0, 0.1), (1, 2.5, 0.3)):
            kwargs = {'window': window, 'max_diff': max_diff, 'terms': terms,
                      'filled_confidence': factor}
            for extra in ({}, {'filled': filled}, {'filled': filled, 'disparity': disp}):
                got = confidence_map(ratio, diff, keep, **kwargs, **extra)  # type: ignore
                want = confidence_reference(
                    ratio, diff, keep, window, terms.support_window, max_diff, factor,
                    terms.smoothness, terms.outside_scale, extra.get('disparity'),
                    extra.get('filled'))
                np.testing.assert_array_equal(got, want)
                assert got.dtype == np.float32
                assert (got[~keep & ~filled] == 0).all()
        # float64 maps are read as float32: the same result as the float32 maps'
        got64 = confidence_map(ratio.astype(np.float64), diff, keep, terms=terms)
        np.testing.assert_array_equal(got64, confidence_map(ratio, diff, keep, terms=terms))


def test_occlusions_fill_from_the_background() -> None:
    left, right, occluded = scene()
    estimate = left.copy()
    estimate[occluded] = FRONT  # what a matcher typically guesses there: the foreground
    labels = left_right_check(estimate, right, max_diff=1.0).labels
    filled, mask = fill_disparity_holes(estimate, labels)
    band = np.zeros((H, W), bool)
    band[10:30, X0 - 12:X0] = True
    assert mask[band].all()
    np.testing.assert_array_equal(filled[band], BACK)  # the wall, not the box


def test_mismatches_fill_from_the_neighbourhood() -> None:
    left, right, _ = scene()
    estimate = left.copy()
    estimate[33:36, 100:103] = 14.0  # too far: the right view there sees 8, a mismatch
    labels = left_right_check(estimate, right, max_diff=1.0).labels
    assert (labels[33:36, 100:103] == MISMATCH).all()
    filled, mask = fill_disparity_holes(estimate, labels)
    np.testing.assert_array_equal(filled[33:36, 100:103], BACK)
    assert mask[33:36, 100:103].all()
    estimate[33:36, 100:103] = 2.0  # too near: the right view at x - 2 sees the nearer wall
    labels = left_right_check(estimate, right, max_diff=1.0).labels
    assert (labels[33:36, 100:103] == OCCLUDED).all()  # the standard rule


def test_background_mode_fills_every_hole_from_the_farther_side() -> None:
    """A matcher that already left its occlusions and mismatches empty: 'background' fills
    both with the wall's disparity, the mismatch included (its neighbours are wall too);
    'labels' leaves pixels without an input disparity (INVALID) empty."""
    left, right, occluded = scene()
    estimate = left.copy()
    estimate[occluded] = np.nan
    estimate[33:36, 100:103] = np.nan
    labels = left_right_check(estimate, right, max_diff=1.0).labels
    filled, mask = fill_disparity_holes(estimate, labels, mode='background')
    band = np.zeros((H, W), bool)
    band[10:30, X0 - 12:X0] = True
    np.testing.assert_array_equal(filled[band], BACK)
    np.testing.assert_array_equal(filled[33:36, 100:103], BACK)
    assert mask[band].all()
    unfilled, mask = fill_disparity_holes(estimate, labels, mode='labels')
    assert np.isnan(unfilled[band]).all()
    assert not mask[band].any()
    with pytest.raises(ValueError, match='mode must be one of'):
        fill_disparity_holes(estimate, labels, mode='nearest')


@pytest.mark.parametrize('size', [3, 5])
def test_median_filter_keeps_holes_and_removes_outliers(size: int) -> None:
    disp = np.full((20, 20), 10.0, np.float32)
    disp[10, 10] = 30.0  # a lone outlier
    disp[2:4, 2:4] = np.nan
    out = median_filter(disp, size)
    assert out[10, 10] == 10.0
    assert np.isnan(out[2:4, 2:4]).all()
    assert np.isfinite(out[~np.isnan(disp)]).all()
    np.testing.assert_array_equal(median_filter(np.full((4, 4), np.nan, np.float32), size),
                                  np.full((4, 4), np.nan, np.float32))
    with pytest.raises(ValueError, match='size must be 3 or 5'):
        median_filter(disp, 7)


def test_extrapolated_pixels_are_kept_and_ranked_by_distance() -> None:
    """The left border strip: pixels whose partner lies past the right image's left edge
    (the matcher extrapolated them) are kept with keep_outside, dropped without, and their
    confidence falls with the distance past the border."""
    left, right, _ = scene()
    ratio = np.full(left.shape, 0.2, np.float32)
    kept = cross_check(left, right, ratio, speckle_size=0)
    strip = np.zeros((H, W), bool)
    strip[:, :8] = True
    assert (kept.labels[strip] == OUTSIDE).all()
    assert np.isfinite(kept.disparity[strip]).all()
    conf = kept.confidence[20, :8]  # partner 8 - x px past the border
    assert (np.diff(conf) > 0).all()
    assert conf[-1] < kept.confidence[20, 30]
    dropped = cross_check(left, right, ratio, speckle_size=0, keep_outside=False)
    assert np.isnan(dropped.disparity[strip]).all()


def test_confidence_terms_lower_edges_and_holes() -> None:
    """Support: a pixel beside a hole is less confident than one in the open; smoothness:
    a pixel at a depth edge less than one on a flat surface."""
    disp = np.full((30, 30), 10.0, np.float32)
    disp[:, 15:] = 20.0
    valid = np.ones(disp.shape, bool)
    valid[5:10, 5:10] = False
    ratio = np.full(disp.shape, 0.2, np.float32)
    diff = np.zeros_like(disp)
    terms = ConfidenceTerms(support_window=5, smoothness=1.0, outside_scale=0.0)
    conf = confidence_map(ratio, diff, valid, window=1, disparity=disp, terms=terms)
    plain = confidence_map(ratio, diff, valid, window=1)
    assert conf[20, 5] == pytest.approx(plain[20, 5])  # open, flat: no term lowers it
    assert conf[7, 11] < conf[20, 5]  # beside the hole
    assert conf[20, 14] < conf[20, 5]  # at the depth edge
    assert (conf[~valid] == 0).all()


def test_speckles_are_removed_and_regions_kept() -> None:
    disp = np.full((H, W), 10.0, np.float32)
    disp[5:8, 5:8] = 30.0  # 9 px island: a speckle
    disp[15:35, 20:60] = 25.0  # 800 px region: kept
    disp[2, 100] = np.nan
    removed = remove_speckles(disp, max_size=50, max_diff=2.0)
    assert removed[5:8, 5:8].all()
    assert removed.sum() == 9
    assert not remove_speckles(disp, max_size=0, max_diff=2.0).any()
    # within speckle_range the island joins the wall
    disp[5:8, 5:8] = 11.5
    assert not remove_speckles(disp, max_size=50, max_diff=2.0).any()
    # sub-pixel steps survive the fixed-point copy: 1/16 px resolution
    disp[5:8, 5:8] = 12.25
    assert remove_speckles(disp, max_size=50, max_diff=2.0)[5:8, 5:8].all()
    assert not remove_speckles(disp, max_size=50, max_diff=2.25).any()


def test_speckles_of_a_wide_range() -> None:
    """Disparities over thousands of px do not overflow the int16 copy."""
    disp = np.full((20, 20), 3000.0, np.float32)
    disp[0, 0] = -1000.0
    disp[5:7, 5:7] = 3010.0
    removed = remove_speckles(disp, max_size=10, max_diff=2.0)
    assert removed[5:7, 5:7].all()
    assert removed[0, 0]
    assert removed.sum() == 5


def test_confidence_is_monotone_and_bounded() -> None:
    ratio = np.tile(np.linspace(0.0, 1.0, 11, dtype=np.float32), (11, 1))
    diff = np.tile(np.linspace(0.0, 3.0, 11, dtype=np.float32)[:, None], (1, 11))
    valid = np.ones(ratio.shape, bool)
    valid[0, 0] = False
    conf = confidence_map(ratio, diff, valid, window=1, max_diff=1.0)
    assert conf.dtype == np.float32
    assert conf.shape == ratio.shape
    assert conf.min() >= 0
    assert conf.max() <= 1
    assert conf[0, 0] == 0
    assert conf[0, 1] == pytest.approx(0.9)  # diff 0: the cost term alone
    assert (np.diff(conf[1:, 1:-1], axis=1) < 0).all()  # more ambiguous, less confident
    assert (np.diff(conf[1:, 1:-1], axis=0) < 0).all()  # less consistent, less confident
    assert conf[:, -1].max() == 0  # cost ratio 1: no information
    assert conf[5, 1] == pytest.approx(0.9 / (1 + 1.5**2), rel=1e-6)
    filled = np.zeros(ratio.shape, bool)
    filled[0, 0] = True
    conf = confidence_map(ratio, diff, valid & ~filled, window=1, filled=filled,
                          filled_confidence=0.1)
    assert conf[0, 0] == pytest.approx(0.1)
    nan = confidence_map(np.full((3, 3), np.nan, np.float32), np.full((3, 3), np.nan,
                                                                        np.float32),
                         np.ones((3, 3), bool), window=3)
    assert (nan == 0).all()


def test_pooling_spreads_ambiguity() -> None:
    ratio = np.zeros((9, 9), np.float32)
    ratio[4, 4] = 1.0
    diff = np.zeros_like(ratio)
    conf = confidence_map(ratio, diff, np.ones((9, 9), bool), window=3)
    assert conf[4, 4] == pytest.approx(8 / 9)
    assert conf[3, 3] == pytest.approx(8 / 9)
    assert conf[0, 0] == 1.0


def test_cross_check_on_a_noisy_estimate() -> None:
    """End to end: consistent pixels kept, occlusions and a wrong speckle dropped, and the
    confidence ranks the kept pixels above the dropped ones."""
    rng = np.random.default_rng(3)
    left, right, occluded = scene()
    estimate = left + rng.normal(0, 0.2, left.shape).astype(np.float32)
    estimate[occluded] = FRONT
    estimate[33:36, 100:103] = 14.0
    ratio = rng.uniform(0.0, 0.5, left.shape).astype(np.float32)
    # the foreground's 20 px in the wall's border strip point past the right image: an
    # extrapolation claim, dropped here as the occlusion it is
    result = cross_check(estimate, right, ratio, speckle_size=20, speckle_range=1.0,
                         keep_outside=False)
    kept = np.isfinite(result.disparity)
    assert not kept[occluded].any()
    assert not kept[33:36, 100:103].any()
    assert kept[~occluded].mean() > 0.95
    assert (np.abs(result.disparity[kept] - left[kept]) < 1.0).all()
    assert (result.confidence[~kept] == 0).all()
    assert (result.confidence[kept] > 0).all()
    assert not result.filled.any()
    filled = cross_check(estimate, right, ratio, speckle_size=20, speckle_range=1.0,
                         fill=True, keep_outside=False)
    assert np.isfinite(filled.disparity[10:30, X0 - 12:X0]).all()
    assert (filled.confidence[filled.filled] <= 0.1).all()
    assert np.abs(filled.disparity[10:30, X0 - 12:X0] - BACK).max() < 1.0


@pytest.mark.parametrize(('call', 'message'), [
    (lambda: left_right_check(np.zeros(5, np.float32), np.zeros(5, np.float32)),
     r'disparity must be a \(H, W\) array'),
    (lambda: left_right_check(np.zeros((4, 5), np.float32), np.zeros((4, 6), np.float32)),
     'disparity_right must have the disparity shape'),
    (lambda: left_right_check(np.zeros((4, 5), np.int16), np.zeros((4, 5), np.float32)),
     'disparity must be a float array'),
    (lambda: left_right_check(np.zeros((4, 5)), np.zeros((4, 5)), max_diff=-1),
     'max_diff must be a finite number >= 0'),
    (lambda: remove_speckles(np.zeros((4, 5)), max_size=-1, max_diff=1),
     'max_size must be an int >= 0'),
    (lambda: fill_disparity_holes(np.zeros((4, 5)), np.zeros((4, 5), np.int32)),
     'labels must be a uint8 array'),
    (lambda: confidence_map(np.zeros((4, 5)), np.zeros((4, 5)), np.ones((4, 5), bool),
                            window=4), 'window must be an odd int'),
    (lambda: confidence_map(np.zeros((4, 5)), np.zeros((4, 5)), np.ones((4, 5)), window=3),
     'valid must be a bool array'),
    (lambda: confidence_map(np.zeros((4, 5)), np.zeros((4, 5)), np.ones((4, 5), bool),
                            max_diff=0), 'max_diff must be > 0'),
    (lambda: confidence_map(np.zeros((4, 5)), np.zeros((4, 5)), np.ones((4, 5), bool),
                            filled_confidence=2.0), 'filled_confidence must be in'),
    (lambda: cross_check(np.zeros((4, 5)), np.zeros((4, 5)), np.zeros((3, 5))),
     'cost_ratio must have the disparity shape'),
])
def test_misuse_names_the_argument(call: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        call()  # type: ignore[operator]
