"""The coarse-to-fine search (``disparity_search: coarse``): its windows, its kernels
against the plain references on a volume whose cells outside the windows cost
"infinity", bit-for-bit equality with the full search when every window is the full
range, and its accuracy against ground truth on the real pairs."""

from __future__ import annotations

from typing import Any

import cv2
import numba
import numpy as np
import pytest
from helpers import REAL_DATA, REAL_PAIRS, kernel_size
from reference.sgm import aggregate_reference, cost_volume_reference, select_reference, window_mask

from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.core.sgm.coarse import ALIGN, NEAR_RADIUS, coarse_window, search_ranges
from depth_nodes.core.sgm.ranged import flat_offsets
from depth_nodes.errors import ArgumentError

#: A cost no path through a window can reach (the reference's "outside the window").
FAR = 1 << 24


def _pair(h: int = 23, w: int = 37, shift: int = 4,
          seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    wide = rng.integers(0, 256, (h, w + shift)).astype(np.uint8)
    right = np.clip(wide[:, shift:].astype(int) + rng.integers(-3, 4, (h, w)), 0, 255)
    return np.ascontiguousarray(wide[:, :w]), right.astype(np.uint8)


def _windows(h: int, w: int, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random windows inside [0, n): any start, any width from 1 to the end."""
    rng = np.random.default_rng(seed)
    lo = rng.integers(0, n, (h, w)).astype(np.int32)
    wid = (rng.integers(0, n, (h, w)) % (n - lo) + 1).astype(np.int32)
    return lo, wid


@pytest.mark.kernels
@pytest.mark.parametrize('paths', [8, 5, 16])
@pytest.mark.parametrize('border_cost', [0.0, 3.5])
@pytest.mark.parametrize('dtype', [np.uint8, np.float32])
@pytest.mark.parametrize('threads', [1, 2])
def test_full_windows_are_the_full_search_bit_for_bit(paths: int, border_cost: float,
                                                     dtype: type, threads: int) -> None:
    """A margin wider than the range gives every pixel the full range: the coarse search
    is then the full one, every output identical (NaNs included)."""
    h, w = kernel_size((41, 67), (9, 29))
    left, right = (a.astype(dtype) for a in _pair(h=h, w=w, seed=1))
    common: dict[str, Any] = {'disparity_range': 12, 'min_disparity': -2,
                              'census_width': 5, 'census_height': 5, 'paths': paths,
                              'border_cost': border_cost}
    own = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        full = SgmMatcher(SgmParams(**common)).match(left, right)
        coarse_matcher = SgmMatcher(SgmParams(**common, disparity_search='coarse',
                                              search_margin=100.0))
        coarse = coarse_matcher.match(left, right)
    finally:
        numba.set_num_threads(own)
    assert coarse_matcher.search_cells == 1.0
    assert coarse_matcher.fallbacks == 0
    for got, want in ((coarse.disparity, full.disparity),
                      (coarse.disparity_right, full.disparity_right),
                      (coarse.cost_ratio, full.cost_ratio)):
        np.testing.assert_array_equal(got, want)


@pytest.mark.kernels
@pytest.mark.parametrize('paths', [8, 5])
@pytest.mark.parametrize('border_cost', [0.0, 3.5])
@pytest.mark.parametrize('subpixel', ['parabola', 'equiangular'])
@pytest.mark.parametrize('seed', [0, 1])
def test_random_windows_match_the_reference(paths: int, border_cost: float, subpixel: str,
                                            seed: int) -> None:
    """Costs, border statistic, aggregation and both views' selection over random windows
    against the plain references run on the full volume with every cell outside the
    windows at a cost no path can afford."""
    left, right = _pair(*kernel_size((23, 37), (9, 19)), seed=seed)
    h, w = left.shape
    n, dmin = 10, -1
    lo, wid = _windows(h, w, n, seed)
    params = SgmParams(min_disparity=dmin, disparity_range=n, census_width=5,
                       census_height=5, P1=4, P2=40, paths=paths, subpixel=subpixel,
                       uniqueness_ratio=5, border_cost=border_cost,
                       border_extrapolation=1.0, disp12_max_diff=0, speckle_size=0,
                       median_filter=False)
    matcher = SgmMatcher(params)
    result = matcher.match_windows(left, right, lo, wid)
    assert result is not None
    mask = window_mask(lo, wid, n)
    cost = cost_volume_reference(left, right, min_disparity=dmin, disparity_range=n,
                                 census_window=(5, 5), intensity_weight=1,
                                 match_brightness=True).astype(np.int64)
    xs = np.arange(w)[:, None] - dmin - np.arange(n)[None, :]
    outside = (xs < 0) | (xs >= w)  # (W, D) cells whose right pixel is off the image
    if border_cost:
        full_columns = ~outside.any(axis=1)
        sampled = np.where(mask, cost, 255)[::4][:, full_columns].min(axis=2)
        want_border = round(border_cost * sampled.mean())
        assert matcher.border_cost == want_border
        cost[:, outside] = want_border
    cost[~mask] = FAR
    total = aggregate_reference(cost, left.astype(np.float32), paths, 4, 40, 8.0)
    want_left, want_right, want_ratio = select_reference(
        total, min_disparity=dmin, uniqueness=5, subpixel=subpixel,
        extrapolate=border_cost > 0, window=mask)
    np.testing.assert_allclose(result.disparity, want_left, rtol=0, atol=1e-5)
    np.testing.assert_allclose(result.disparity_right, want_right, rtol=0, atol=1e-5)
    np.testing.assert_allclose(result.cost_ratio, want_ratio, rtol=0, atol=1e-6)
    # every left disparity lies inside its own window
    k = np.floor(result.disparity + 0.5) - dmin
    finite = np.isfinite(k)
    assert ((k[finite] >= lo[finite]) & (k[finite] < (lo + wid)[finite])).all()


def test_windows_from_the_coarse_disparity() -> None:
    """Twice the coarse neighbourhood's span plus the margin; the wide radius where the
    near one holds nothing valid; the full range where nothing is valid; clipped to the
    range; the left border strip from index 0 up to what may be published there."""
    coarse = np.full((20, 60), 10.0, np.float32)
    coarse[:, 45:] = 20.0  # a depth edge at coarse column 45 (fine column 90)
    coarse[8:13, 30:35] = np.nan  # a hole as wide as the near square
    lo, wid = search_ranges(coarse, (40, 120), min_disparity=4, disparity_range=40,
                            margin=3.0, outside=5.0, align=ALIGN)
    # 2 * 10 +- 3 is disparities 17 .. 23, indices 13 .. 19, aligned: 8 .. 23
    assert ALIGN == 8
    assert (lo[0, 50], wid[0, 50]) == (8, 16)
    # near the edge the window spans both sides: up to 2 * 20 + 3 = 43, index 39
    edge = 2 * (45 - NEAR_RADIUS)
    assert (lo[0, edge], wid[0, edge]) == (8, 32)
    assert (lo[0, edge - 2], wid[0, edge - 2]) == (8, 16)  # one coarse pixel further
    assert (lo[0, 119], wid[0, 119]) == (32, 8)  # indices 33 .. 39, aligned 32 .. 39
    assert (lo[20, 64], wid[20, 64]) == (8, 16)  # inside the hole: from the wide radius
    # the border strip: x - d < 0 for some d in 4 .. 43, so x < 43; its windows start at
    # index 0 and reach at least disparity x + 5 (index x + 1), else the coarse window's end
    assert (lo[:, :43] == 0).all()
    xs = np.arange(43)
    assert (wid[0, :43] == np.maximum(np.minimum(40, xs + 2), 24)).all()
    nothing = np.full((20, 60), np.nan, np.float32)
    lo, wid = search_ranges(nothing, (39, 119), min_disparity=0, disparity_range=40,
                            margin=3.0)
    assert lo.shape == (39, 119)
    assert (lo == 0).all()
    assert (wid == 40).all()
    assert flat_offsets(wid)[-1] == 39 * 119 * 40


def test_the_coarse_window_holds_every_halved_disparity() -> None:
    for dmin, n in [(0, 128), (-3, 17), (5, 1), (-8, 64)]:
        c_min, c_n = coarse_window(dmin, n)
        halves = np.arange(dmin, dmin + n) / 2
        assert c_min <= halves.min()
        assert halves.max() <= c_min + c_n - 1


def test_windows_beyond_the_memory_budget_fall_back_to_the_full_search() -> None:
    """A frame whose windows do not fit memory_mb is matched by the full search (and
    counted), so memory stays bounded; the result is the full search's."""
    left, right = _pair(h=41, w=67, seed=2)
    common: dict[str, Any] = {'disparity_range': 12, 'census_width': 5,
                              'census_height': 5, 'memory_mb': 0.001}
    full = SgmMatcher(SgmParams(**common)).match(left, right)
    matcher = SgmMatcher(SgmParams(**common, disparity_search='coarse'))
    got = matcher.match(left, right)
    assert matcher.fallbacks == 1
    assert matcher.search_cells == 1.0
    np.testing.assert_array_equal(got.disparity, full.disparity)


def test_the_flat_volumes_grow_but_never_past_memory_mb() -> None:
    """They grow by a quarter more than a frame needs, so that they seldom grow again,
    but not past the budget that frame fits in."""
    left, right = _pair(h=41, w=67, seed=2)
    cells = 41 * 67 * 12  # a margin wider than the range: full windows
    for memory_mb, grown in ((1.0, cells + cells // 4), (cells * 3.3e-6, cells * 11 // 10)):
        matcher = SgmMatcher(SgmParams(disparity_range=12, census_width=5, census_height=5,
                                       disparity_search='coarse', search_margin=100.0,
                                       memory_mb=memory_mb))
        matcher.match(left, right)
        assert matcher.fallbacks == 0
        flat = matcher.workspaces.ranged  # the sizes are the point here
        assert flat is not None
        assert flat.cost.size == flat.partial.size == grown


def test_tight_windows_when_the_aligned_ones_do_not_fit() -> None:
    """Windows aligned to ALIGN when they fit memory_mb, else the tight ones, before
    falling back to the full search."""
    left, right = _pair(h=61, w=97, seed=4)
    common: dict[str, Any] = {'disparity_range': 40, 'census_width': 5, 'census_height': 5,
                              'disparity_search': 'coarse', 'search_margin': 1.0}
    roomy = SgmMatcher(SgmParams(**common))
    roomy.match(left, right)
    coarse = roomy.coarse.half_disparity  # the half-resolution pass's output
    assert coarse is not None
    tight = search_ranges(coarse, left.shape, min_disparity=0, disparity_range=40, margin=1.0,
                          outside=0.25 * 40)[1].sum()
    aligned = roomy.search_cells * left.size * 40
    assert tight < aligned
    squeezed = SgmMatcher(SgmParams(**common, memory_mb=3 * (tight + 1) / 1e6))
    squeezed.match(left, right)
    assert squeezed.fallbacks == 0
    assert squeezed.search_cells * left.size * 40 == pytest.approx(tight)


def test_a_range_the_half_width_cannot_hold_falls_back_to_the_full_search() -> None:
    """min_disparity -11 fits a 12 px wide image but its half, -6, not a 6 px one."""
    left, right = _pair(h=20, w=12, seed=3)
    common: dict[str, Any] = {'disparity_range': 5, 'min_disparity': -11,
                              'census_width': 3, 'census_height': 3}
    full = SgmMatcher(SgmParams(**common)).match(left, right)
    matcher = SgmMatcher(SgmParams(**common, disparity_search='coarse'))
    got = matcher.match(left, right)
    assert matcher.fallbacks == 1
    np.testing.assert_array_equal(got.disparity, full.disparity)


def test_bad_windows_are_refused() -> None:
    left, right = _pair()
    matcher = SgmMatcher(SgmParams(disparity_range=10, census_width=5, census_height=5))
    lo = np.zeros(left.shape, np.int32)
    with pytest.raises(ArgumentError, match='inside the range'):
        matcher.match_windows(left, right, lo, np.full(left.shape, 11, np.int32))
    with pytest.raises(ArgumentError, match='non-empty'):
        matcher.match_windows(left, right, lo, np.zeros(left.shape, np.int32))


@pytest.mark.parametrize('pair', REAL_PAIRS)
def test_accuracy_on_the_real_pairs(pair: str) -> None:
    """Teddy and Cones against their ground truth (raw matcher output, 8 paths, 64
    disparities, dense bad-2: invalid pixels count as errors). Measured when this was
    written: full search 0.1275 / 0.1186, coarse (margin 8) 0.1293 / 0.1219 with 48 - 49 %
    of the cells (the border strip, 63 px of these 450, searches more, and the windows are
    aligned to 8). The coarse search stays within 5 % of the full one and searches under
    55 % of the cells."""
    folder = REAL_DATA / pair
    left = cv2.imread(str(folder / 'im2.png'), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(folder / 'im6.png'), cv2.IMREAD_GRAYSCALE)
    truth = cv2.imread(str(folder / 'disp2.pgm'), cv2.IMREAD_GRAYSCALE) / 4.0  # its scale
    known = truth > 0
    bad = {}
    for mode in ('full', 'coarse'):
        matcher = SgmMatcher(SgmParams(disparity_range=64, disparity_search=mode))
        disparity = matcher.match(left, right).disparity
        bad[mode] = float((~(np.abs(disparity - truth) <= 2))[known].mean())
    assert bad['full'] < 0.13
    assert bad['coarse'] <= 1.05 * bad['full']
    assert matcher.search_cells < 0.55
