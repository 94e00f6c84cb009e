"""Every SGM numba kernel against its plain numpy reference, on small random inputs."""

from __future__ import annotations

import numpy as np
import pytest

from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.core.sgm.aggregate import aggregate_reference
from depth_nodes.core.sgm.cost import (
    census_dtype,
    census_transform,
    census_transform_reference,
    cost_volume,
    cost_volume_reference,
)
from depth_nodes.core.sgm.select import select_reference


def _pair(h: int = 23, w: int = 37, shift: int = 5, seed: int = 0) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    wide = rng.integers(0, 256, (h, w + shift)).astype(np.uint8)
    left = wide[:, shift:]
    right = np.clip(wide[:, :w].astype(int) + rng.integers(-3, 4, (h, w)), 0, 255)
    return left, right.astype(np.uint8)


@pytest.mark.parametrize('window', [(3, 3), (5, 5), (7, 9), (9, 7)])
def test_census_matches_reference(window: tuple[int, int]) -> None:
    left, _ = _pair()
    np.testing.assert_array_equal(census_transform(left, window),
                                  census_transform_reference(left, window))


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


@pytest.mark.parametrize('window', [(5, 5), (7, 9)])
def test_mirrored_census_is_the_census_flipped(window: tuple[int, int]) -> None:
    left, _ = _pair()
    np.testing.assert_array_equal(census_transform(left, window, mirrored=True)[:, ::-1],
                                  census_transform_reference(left, window))


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
@pytest.mark.parametrize(('window', 'disparities'), [((5, 7), 11), ((5, 5), 35)])
def test_cost_volume_matches_reference(settings: dict[str, object], min_disparity: int,
                                       image_type: str, window: tuple[int, int],
                                       disparities: int) -> None:
    """(5, 7) has 34 neighbours: a 64-bit census; (5, 5) a 32-bit one, and 35 disparities
    run the kernel's vector loop body as well as its remainder. uint8 pairs with the 32-bit
    census take the 16-bit kernel, every other case the float one."""
    left, right = _pair()
    if image_type == 'float32':  # fractional intensities
        left, right = left + np.float32(0.25), right * np.float32(0.97)
    kwargs = {'min_disparity': min_disparity, 'disparity_range': disparities,
              'census_window': window, **settings}
    np.testing.assert_array_equal(cost_volume(left, right, **kwargs),
                                  cost_volume_reference(left, right, **kwargs))


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
    left = (rng.integers(0, 2, (9, 40)) * 255).astype(np.uint8)
    right = np.roll(left, -3, axis=1)
    kwargs = {'min_disparity': 0, 'disparity_range': 36, 'census_window': (5, 5), **settings}
    expected = cost_volume_reference(left, right, **kwargs)
    np.testing.assert_array_equal(cost_volume(left, right, **kwargs), expected)
    np.testing.assert_array_equal(
        cost_volume(left.astype(np.float32), right.astype(np.float32), **kwargs), expected)
    assert expected[expected < 255].max() == 254  # the clip was reached


@pytest.mark.parametrize(('paths', 'scale', 'intensity'), [
    (4, 0.0, 0), (5, 0.0, 0), (5, 20.0, 1), (8, 0.0, 0), (8, 12.0, 0), (8, 20.0, 1),
    (16, 0.0, 0), (16, 7.5, 2)])
def test_aggregation_matches_reference(paths: int, scale: float, intensity: int) -> None:
    left, right = _pair(h=17, w=29)
    params = SgmParams(min_disparity=-2, disparity_range=9, census_width=5, census_height=5,
                       intensity_weight=intensity, P1=5, P2=60, p2_adaptive_scale=scale,
                       paths=paths, median_filter=False)
    matcher = SgmMatcher(params)
    matcher.match(left, right, keep_total=True)
    cost = cost_volume_reference(left, right, min_disparity=-2, disparity_range=9,
                                 census_window=(5, 5), intensity_weight=intensity)
    expected = aggregate_reference(cost, left.astype(np.float32), paths, 5, 60, scale)
    np.testing.assert_array_equal(matcher.total.astype(np.int64), expected)
    matcher.match(left, right)  # without keep_total the volume holds no total
    with pytest.raises(RuntimeError, match='kept no total'):
        _ = matcher.total


@pytest.mark.parametrize('subpixel', ['none', 'parabola', 'equiangular'])
@pytest.mark.parametrize(('min_disparity', 'uniqueness'), [(0, 0), (-3, 15), (2, 5)])
@pytest.mark.parametrize('paths', [8, 5])
def test_selection_matches_reference(subpixel: str, min_disparity: int, uniqueness: int,
                                     paths: int) -> None:
    left, right = _pair(h=19, w=31, seed=3)
    params = SgmParams(min_disparity=min_disparity, disparity_range=10, census_width=5,
                       census_height=5, P1=4, P2=40, uniqueness_ratio=uniqueness,
                       subpixel=subpixel, median_filter=False, paths=paths)
    matcher = SgmMatcher(params)
    result = matcher.match(left, right, keep_total=True)
    want_left, want_right, want_ratio = select_reference(
        matcher.total, min_disparity=min_disparity, uniqueness=uniqueness, subpixel=subpixel)
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
