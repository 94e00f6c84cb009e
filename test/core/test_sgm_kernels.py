"""Every SGM numba kernel against its plain numpy reference, on small random inputs
(smaller still, and fewer cases, when the kernels run as plain Python: ``kernels``)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import kernel_size
from reference.sgm import (
    aggregate_reference,
    census_transform_reference,
    check_disparity_reference,
    cost_volume_reference,
    select_reference,
)

from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.core.sgm.border import fill_outside, mean_best_cost
from depth_nodes.core.sgm.brightness import GAIN_LIMITS, matched_brightness
from depth_nodes.core.sgm.census import census_dtype, census_transform
from depth_nodes.core.sgm.check import check_disparity
from depth_nodes.core.sgm.cost import cost_volume


def _outside(shape: tuple[int, int, int], min_disparity: int) -> np.ndarray:
    """(W, D) True where the right pixel x - min_disparity - k is outside the image."""
    _, w, n = shape
    xr = np.arange(w)[:, None] - min_disparity - np.arange(n)[None, :]
    return (xr < 0) | (xr >= w)


#: (rows, columns) of the random pair most tests match.
H, W = kernel_size((23, 37), (9, 19))


def _pair(h: int = H, w: int = W, shift: int = 5, seed: int = 0) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    wide = rng.integers(0, 256, (h, w + shift)).astype(np.uint8)
    left = wide[:, shift:]
    right = np.clip(wide[:, :w].astype(int) + rng.integers(-3, 4, (h, w)), 0, 255)
    return left, right.astype(np.uint8)


@pytest.mark.kernels
@pytest.mark.parametrize('window', [(3, 3), (5, 5), (7, 9), (9, 7)])
def test_census_matches_reference(window: tuple[int, int]) -> None:
    left, _ = _pair()
    np.testing.assert_array_equal(census_transform(left, window),
                                  census_transform_reference(left, window))


@pytest.mark.kernels
@pytest.mark.parametrize(('window', 'dtype'), [((5, 5), np.uint32), ((3, 11), np.uint32),
                                                ((5, 7), np.uint64), ((9, 7), np.uint64)])
def test_census_uses_32_bits_when_the_window_fits(window: tuple[int, int],
                                                  dtype: type) -> None:
    left, _ = _pair()
    assert census_dtype(window) is dtype
    assert census_transform(left, window).dtype == dtype


def test_census_rejects_a_buffer_too_narrow_for_the_window() -> None:
    left, _ = _pair()
    with pytest.raises(ValueError, match='fewer bits'):
        census_transform(left, (5, 7), np.empty(left.shape, np.uint32))


@pytest.mark.kernels
@pytest.mark.parametrize('window', [(5, 5), (7, 9)])
def test_mirrored_census_is_the_census_flipped(window: tuple[int, int]) -> None:
    left, _ = _pair()
    np.testing.assert_array_equal(census_transform(left, window, mirrored=True)[:, ::-1],
                                  census_transform_reference(left, window))


@pytest.mark.kernels
@pytest.mark.parametrize('settings', [
    {'census_weight': 1, 'intensity_weight': 0},
    {'census_weight': 0, 'intensity_weight': 1, 'intensity_cost': 'ad'},
    {'census_weight': 0, 'intensity_weight': 2, 'intensity_cost': 'bt'},
    {'census_weight': 2, 'intensity_weight': 1, 'intensity_cost': 'bt',
     'intensity_truncation': 12},
    # far past the 254 clip: the kernel's int32 sum must not overflow
    {'census_weight': 100_000, 'intensity_weight': 70_000, 'intensity_truncation': 10**6},
])
@pytest.mark.parametrize('min_disparity', [0, -4, 3])
@pytest.mark.parametrize('image_type', ['uint8', 'float32'])
@pytest.mark.parametrize(('window', 'disparities'), kernel_size([((5, 7), 11), ((5, 5), 35)],
                                                                [((5, 7), 7), ((5, 5), 13)]))
def test_cost_volume_matches_reference(settings: dict[str, object], min_disparity: int,
                                       image_type: str, window: tuple[int, int],
                                       disparities: int) -> None:
    """(5, 7) has 34 neighbours: a 64-bit census; (5, 5) a 32-bit one, and 35 disparities
    run the compiled kernel's vector loop body as well as its remainder. uint8 pairs with the 32-bit
    census take the 16-bit kernel, every other case the float one."""
    left, right = _pair()
    if image_type == 'float32':  # fractional intensities
        left, right = left + np.float32(0.25), right * np.float32(0.97)
    kwargs = {'min_disparity': min_disparity, 'disparity_range': disparities,
              'census_window': window, **settings}
    np.testing.assert_array_equal(cost_volume(left, right, **kwargs),
                                  cost_volume_reference(left, right, **kwargs))
    kwargs['match_brightness'] = True  # the intensity term on the brightness-matched right
    np.testing.assert_array_equal(cost_volume(left, right, **kwargs),
                                  cost_volume_reference(left, right, **kwargs))


@pytest.mark.parametrize('dtype', [np.uint8, np.uint16, np.float32])
def test_matched_brightness_undoes_a_gain_and_offset(dtype: type) -> None:
    """A right image 0.8 x + 30 of the left gets the left's mean and spread back (to the
    rounding of integer images), and keeps its dtype."""
    rng = np.random.default_rng(1)
    left = rng.uniform(20, 200, (30, 40)).astype(dtype)
    right = (left.astype(np.float64) * 0.8 + 30).astype(dtype)
    mapped = matched_brightness(left, right)
    assert mapped.dtype == dtype
    np.testing.assert_allclose(mapped.astype(np.float64), left.astype(np.float64), atol=1.01)
    flat = matched_brightness(left, np.full_like(left, 7))  # no spread: offset only
    assert np.allclose(flat.astype(np.float64), left.astype(np.float64).mean(), atol=0.5)
    dark = matched_brightness(left, (left.astype(np.float64) * 0.01).astype(dtype))
    assert dark.astype(np.float64).std() <= left.astype(np.float64).std() * GAIN_LIMITS[1] * 0.02


def test_brightness_matching_makes_the_cost_indifferent_to_a_gain() -> None:
    """Census + BT under a 20 % gain and an offset: with matching, the volume is the one
    of the undistorted pair to within a few grey levels of the intensity term; without,
    the intensity term is off by the offset nearly everywhere."""
    left, right = _pair(h=30, w=60)
    brighter = np.clip(right.astype(np.float64) * 1.2 + 12, 0, 255).astype(np.uint8)
    kwargs = {'min_disparity': 0, 'disparity_range': 8, 'census_window': (5, 5),
              'census_weight': 0, 'intensity_weight': 1, 'intensity_truncation': 255}
    clean = cost_volume(left, right, match_brightness=True, **kwargs).astype(int)
    matched = cost_volume(left, brighter, match_brightness=True, **kwargs).astype(int)
    plain = cost_volume(left, brighter, **kwargs).astype(int)
    inside = ~_outside(clean.shape, 0)[None].repeat(clean.shape[0], 0)
    assert np.median(np.abs(matched - clean)[inside]) <= 2
    assert np.median(np.abs(plain - clean)[inside]) >= 10


@pytest.mark.kernels
@pytest.mark.parametrize('min_disparity', [0, -5, 4])
def test_fill_outside_and_mean_best_cost(min_disparity: int) -> None:
    left, right = _pair()
    cost = cost_volume(left, right, min_disparity=min_disparity, disparity_range=11,
                       census_window=(5, 5), intensity_weight=1)
    outside = _outside(cost.shape, min_disparity)
    assert (cost[:, outside] == 255).all()
    inside_before = cost[:, ~outside].copy()
    full = ~outside.any(axis=1)  # columns where every disparity is inside the image
    want = cost[::4][:, full].min(axis=2).mean()
    assert mean_best_cost(cost, min_disparity) == pytest.approx(want)
    fill_outside(cost, min_disparity, 17)
    assert (cost[:, outside] == 17).all()
    np.testing.assert_array_equal(cost[:, ~outside], inside_before)
    with pytest.raises(ValueError, match=r'value must be in 0\.\.255'):
        fill_outside(cost, min_disparity, 256)


@pytest.mark.kernels
@pytest.mark.parametrize('settings', [
    {'census_weight': 1, 'intensity_weight': 1, 'intensity_truncation': 255},
    {'census_weight': 255, 'intensity_weight': 255, 'intensity_truncation': 10**6},
    {'census_weight': 0, 'intensity_weight': 300, 'intensity_cost': 'ad'},
])
def test_16_bit_kernel_at_the_extremes_of_uint8(settings: dict[str, object]) -> None:
    """Black and white stripes: intensity differences of 255 (510 doubled), the largest
    the 16-bit kernel of uint8 pairs sees; it must equal the float kernel and the
    reference."""
    rng = np.random.default_rng(3)
    left = (rng.integers(0, 2, (9, kernel_size(40, 20))) * 255).astype(np.uint8)
    right = np.roll(left, -3, axis=1)
    kwargs = {'min_disparity': 0, 'disparity_range': kernel_size(36, 16),
              'census_window': (5, 5), **settings}
    expected = cost_volume_reference(left, right, **kwargs)
    np.testing.assert_array_equal(cost_volume(left, right, **kwargs), expected)
    np.testing.assert_array_equal(
        cost_volume(left.astype(np.float32), right.astype(np.float32), **kwargs), expected)
    assert expected[expected < 255].max() == 254  # the clip was reached


@pytest.mark.kernels
@pytest.mark.parametrize(('paths', 'scale', 'intensity', 'border_cost'), [
    (4, 0.0, 0, 0.0), (5, 0.0, 0, 3.5), (5, 20.0, 1, 0.0), (8, 0.0, 0, 0.0), (8, 12.0, 0, 2.0),
    (8, 20.0, 1, 3.5), (16, 0.0, 0, 0.0), (16, 7.5, 2, 3.5)])
def test_aggregation_matches_reference(paths: int, scale: float, intensity: int,
                                       border_cost: float) -> None:
    """The aggregated volume equals the reference's over the reference cost volume, whose
    out-of-image cells hold the cost the matcher chose for them (border_cost x the mean
    best cost; the maximum when border_cost is 0)."""
    left, right = _pair(*kernel_size((17, 29), (9, 17)))
    params = SgmParams(min_disparity=-2, disparity_range=9, census_width=5, census_height=5,
                       intensity_weight=intensity, P1=5, P2=60, p2_adaptive_scale=scale,
                       paths=paths, median_filter=False, border_cost=border_cost)
    matcher = SgmMatcher(params)
    matcher.match(left, right, keep_total=True)
    cost = cost_volume_reference(left, right, min_disparity=-2, disparity_range=9,
                                 census_window=(5, 5), intensity_weight=intensity,
                                 match_brightness=True)
    outside = _outside(cost.shape, -2)
    if border_cost:
        full = ~outside.any(axis=1)
        want = round(border_cost * cost[::4][:, full].min(axis=2).mean())
        assert matcher.border_cost == want
        cost[:, outside] = want
    else:
        assert matcher.border_cost == 0
    expected = aggregate_reference(cost, left.astype(np.float32), paths, 5, 60, scale)
    np.testing.assert_array_equal(matcher.total.astype(np.int64), expected)
    matcher.match(left, right)  # without keep_total the volume holds no total
    with pytest.raises(RuntimeError, match='kept no total'):
        _ = matcher.total


@pytest.mark.kernels
@pytest.mark.parametrize('subpixel', ['none', 'parabola', 'equiangular'])
@pytest.mark.parametrize(('min_disparity', 'uniqueness'), [(0, 0), (-3, 15), (2, 5)])
@pytest.mark.parametrize('paths', [8, 5])
@pytest.mark.parametrize(('border_cost', 'max_diff'), [(0.0, 0.0), (3.5, 1.5)])
def test_selection_matches_reference(subpixel: str, min_disparity: int, uniqueness: int,
                                     paths: int, border_cost: float, max_diff: float) -> None:
    """Selection (over every disparity when the border strip extrapolates) and then the
    left-right and extrapolation rules, against the references of both."""
    left, right = _pair(*kernel_size((19, 31), (9, 17)), seed=3)
    params = SgmParams(min_disparity=min_disparity, disparity_range=10, census_width=5,
                       census_height=5, P1=4, P2=40, uniqueness_ratio=uniqueness,
                       subpixel=subpixel, median_filter=False, paths=paths,
                       border_cost=border_cost, border_extrapolation=0.3,
                       disp12_max_diff=max_diff, speckle_size=0)
    matcher = SgmMatcher(params)
    result = matcher.match(left, right, keep_total=True)
    want_left, want_right, want_ratio = select_reference(
        matcher.total, min_disparity=min_disparity, uniqueness=uniqueness, subpixel=subpixel,
        extrapolate=border_cost > 0)
    want_left = check_disparity_reference(want_left, want_right, max_diff=max_diff,
                                          max_outside=3.0)
    np.testing.assert_allclose(result.disparity, want_left, rtol=0, atol=1e-5)
    np.testing.assert_allclose(result.disparity_right, want_right, rtol=0, atol=1e-5)
    np.testing.assert_allclose(result.cost_ratio, want_ratio, rtol=0, atol=1e-6)
    assert np.isnan(result.disparity).any() == np.isnan(want_left).any()


def test_buffers_are_reused_across_frames() -> None:
    left, right = _pair()
    matcher = SgmMatcher(SgmParams(disparity_range=8, census_width=5, census_height=5))
    first = matcher.match(left, right).disparity
    again = matcher.match(left, right).disparity
    assert first is again  # same buffer, refilled
    assert matcher.allocations == 1
    matcher.set_params(SgmParams(disparity_range=12, census_width=5, census_height=5))
    matcher.match(left, right)
    assert matcher.allocations == 2


@pytest.mark.kernels
@pytest.mark.parametrize(('max_diff', 'max_outside'), [(0.0, 0.0), (1.0, 2.5), (2.0, 100.0)])
def test_check_matches_reference(max_diff: float, max_outside: float) -> None:
    """Random disparities (some NaN, some pointing outside the image) against a random
    right view: the kernel and the reference invalidate the same pixels."""
    rng = np.random.default_rng(7)
    disparity = rng.uniform(-6, 14, (15, 23)).astype(np.float32)
    disparity[rng.random(disparity.shape) < 0.1] = np.nan
    right = (disparity + rng.normal(0, 1.5, disparity.shape)).astype(np.float32)
    right[rng.random(right.shape) < 0.1] = np.nan
    want = check_disparity_reference(disparity, right, max_diff=max_diff,
                                     max_outside=max_outside)
    got = disparity.copy()
    check_disparity(got, right, max_diff=max_diff, max_outside=max_outside)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_array_equal(got[~np.isnan(got)], want[~np.isnan(want)])
    assert np.isnan(want).sum() > np.isnan(disparity).sum() or max_diff == 0
