"""The depth filter's kernels against their plain references, and each stage's defining
behaviour on small arrays whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import kernel_size
from reference.depth_filter import (
    decimate_reference,
    domain_reference,
    fill_reference,
    spatial_reference,
    spread_reference,
    temporal_reference,
    warp_reference,
)

from depth_nodes.core.depth_filter.decimate import decimate, decimated_camera
from depth_nodes.core.depth_filter.domain import from_domain, to_domain
from depth_nodes.core.depth_filter.holes import fill_depth_holes, fill_spread
from depth_nodes.core.depth_filter.params import HOLE_FILLING, PERSISTENCE, SPATIAL_HOLES
from depth_nodes.core.depth_filter.spatial import noise_factor, smoothed, spatial_smooth
from depth_nodes.core.depth_filter.temporal import (
    TemporalState,
    fresh_state,
    temporal_step,
    warp_state,
)
from depth_nodes.core.geometry import Intrinsics
from depth_nodes.errors import ArgumentError


def _depth(seed: int, shape: tuple[int, int], holes: float = 0.15) -> np.ndarray:
    """Blocks of depth 1 - 5 m with noise and holes: edges, flats and missing pixels."""
    rng = np.random.default_rng(seed)
    h, w = shape
    blocks = rng.uniform(1.0, 5.0, (h // 6 + 1, w // 6 + 1))
    z = np.kron(blocks, np.ones((6, 6)))[:h, :w] + rng.normal(0, 0.01, shape)
    z[rng.random(shape) < holes] = np.nan
    return z.astype(np.float32)


SHAPE = kernel_size((61, 83), (19, 23))


# ------------------------------------------------------------------ decimation

@pytest.mark.kernels
@pytest.mark.parametrize('factor', [2, 3, 4, 5])
def test_decimation_kernel_matches_reference(factor: int) -> None:
    z = _depth(factor, SHAPE)
    var = np.random.default_rng(1).uniform(0, 1e-4, SHAPE).astype(np.float32)
    got, got_var = decimate(z, factor, var)
    want, want_var = decimate_reference(z, factor, var)
    assert got.shape == (SHAPE[0] // factor, SHAPE[1] // factor)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    np.testing.assert_allclose(got_var, want_var, rtol=1e-5)


def test_decimation_median_and_mean_skip_unknown_pixels() -> None:
    z = np.array([[1.0, 2.0, 9.0, np.nan],
                  [3.0, np.nan, np.nan, np.nan]], np.float32)
    out, _ = decimate(z, 2)
    # median of 1, 2, 3 (the hole is not a zero); a block of one valid pixel keeps it
    assert out.tolist() == [[2.0, 9.0]]
    z4 = np.full((4, 4), np.nan, np.float32)
    z4[0, :3] = [1.0, 2.0, 6.0]
    assert decimate(z4, 4)[0][0, 0] == pytest.approx(3.0)  # mean above 3
    assert np.isnan(decimate(np.full((4, 4), np.nan, np.float32), 2)[0]).all()


def test_decimated_camera_keeps_the_pixel_centres() -> None:
    camera = Intrinsics(500.0, 400.0, 319.5, 239.5, 641, 481)
    small = decimated_camera(camera, 2)
    assert (small.width, small.height) == (320, 240)
    assert (small.fx, small.fy) == (250.0, 200.0)
    # the centre of the image stays at the centre: (319.5 + 0.5) / 2 - 0.5
    assert (small.cx, small.cy) == (159.5, 119.5)


def test_decimation_refuses_a_factor_out_of_range() -> None:
    with pytest.raises(ArgumentError, match='decimation factor'):
        decimate(np.ones((8, 8), np.float32), 9)


# ------------------------------------------------------------------ domain

@pytest.mark.kernels
@pytest.mark.parametrize('disparity', [False, True])
def test_domain_kernels_match_reference(disparity: bool) -> None:
    z = _depth(11, SHAPE)
    # unknown depths, and one so small that its inverse overflows float32
    z[0, :5] = [0.0, -1.0, np.inf, np.nan, 1e-39]
    sigma = np.random.default_rng(2).uniform(0.0, 0.05, SHAPE).astype(np.float32)
    sigma[1, :2] = [np.nan, np.inf]
    clean, v, var = to_domain(z, sigma, disparity)
    back, sd = from_domain(v, var, disparity)
    want_v, want_var, want_back, want_sd = domain_reference(z, sigma, disparity)
    np.testing.assert_array_equal(v, want_v)
    np.testing.assert_array_equal(var, want_var)
    np.testing.assert_array_equal(back, want_back)
    np.testing.assert_allclose(sd, want_sd, rtol=1e-6)
    np.testing.assert_array_equal(np.isnan(clean), np.isnan(want_v))
    assert np.isnan(v[0, :4]).all()
    # a depth whose inverse overflows is unknown in the disparity domain only
    assert bool(np.isnan(v[0, 4])) == disparity
    assert np.isfinite(v).mean() > 0.7


# ------------------------------------------------------------------ spatial

@pytest.mark.kernels
@pytest.mark.parametrize('holes_code', [0, 2, 5])
def test_spatial_kernel_matches_reference(holes_code: int) -> None:
    v = 1.0 / _depth(7, SHAPE)
    got, got_f = spatial_smooth(v, 0.5, 0.05, 2, SPATIAL_HOLES[holes_code])
    want, want_f = spatial_reference(v, 0.5, 0.05, 2, SPATIAL_HOLES[holes_code])
    np.testing.assert_allclose(got, want, rtol=2e-6, atol=1e-7)
    np.testing.assert_array_equal(got_f, want_f)


def test_spatial_keeps_steps_larger_than_delta() -> None:
    v = np.array([[1.0] * 5 + [2.0] * 5] * 4, np.float32)
    out, _ = spatial_smooth(v, 0.5, 0.5, 3)
    np.testing.assert_array_equal(out, v)  # flat on both sides, the step untouched


def test_spatial_smooths_steps_smaller_than_delta() -> None:
    v = np.array([[1.0, 1.2, 1.0, 1.2]], np.float32)
    out, _ = spatial_smooth(v, 0.5, 0.5, 1)
    assert np.ptp(out) < 0.2 * 0.5
    assert np.array_equal(spatial_smooth(v, 1.0, 0.5, 2)[0], v)  # alpha 1: no smoothing


def test_spatial_hole_fill_takes_the_left_value_up_to_its_width() -> None:
    v = np.array([[1.0, np.nan, np.nan, np.nan, 2.0]], np.float32)
    out, filled = spatial_smooth(v, 1.0, 0.0, 1, 2)
    assert out[0, 1:3].tolist() == [1.0, 1.0]
    assert np.isnan(out[0, 3])
    assert filled.tolist() == [[False, True, True, False, False]]


def test_noise_factor_is_the_measured_reduction() -> None:
    factor = noise_factor(0.5, 2)
    assert 0.05 < factor < 0.5
    assert noise_factor(1.0, 2) == pytest.approx(1.0)
    v = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 5.0], [1.0, 1.0, 1.0]], np.float32)
    assert smoothed(v, 0.5).tolist() == [[False] * 3, [False, False, False], [False] * 3]
    assert smoothed(np.ones((3, 3), np.float32), 0.5)[1, 1]


# ------------------------------------------------------------------ temporal

@pytest.mark.kernels
@pytest.mark.parametrize('persistence', [0, 1, 3, 5, 8])
def test_temporal_kernel_matches_reference(persistence: int) -> None:
    camera = Intrinsics(50.0, 50.0, 10.0, 10.0, SHAPE[1], SHAPE[0])
    a, b = fresh_state(camera), fresh_state(camera)
    for k in range(6):
        v = 1.0 / _depth(k, SHAPE, holes=0.4)
        var = np.full(SHAPE, 1e-4, np.float32)
        got = temporal_step(v, var, a, 0.4, 0.05, persistence)
        want = temporal_reference(v, var, b, 0.4, 0.05, persistence)
        for g, w in zip(got, want, strict=True):
            np.testing.assert_allclose(g, w, rtol=1e-6)
        np.testing.assert_array_equal(a.history, b.history)


@pytest.mark.parametrize(('mode', 'frames_kept'), [(0, 0), (1, 1), (2, 2), (3, 3), (5, 2), (8, 20)])
def test_persistence_keeps_a_missing_pixel_as_long_as_its_mode_says(
        mode: int, frames_kept: int) -> None:
    """Valid for 8 frames, then missing: ``k of the last n`` before each frame."""
    camera = Intrinsics(1.0, 1.0, 0.0, 0.0, 1, 1)
    state = fresh_state(camera)
    for _ in range(8):
        temporal_step(np.ones((1, 1), np.float32), np.zeros((1, 1), np.float32), state, 0.5,
                      0.1, mode)
    kept = 0
    for _ in range(20):
        out, _, was_kept = temporal_step(np.full((1, 1), np.nan, np.float32),
                                         np.zeros((1, 1), np.float32), state, 0.5, 0.1, mode)
        if not was_kept[0, 0]:
            assert np.isnan(out[0, 0])
            break
        assert out[0, 0] == 1.0
        kept += 1
    assert kept == frames_kept, PERSISTENCE[mode]


def test_temporal_takes_a_large_change_at_once_and_smooths_a_small_one() -> None:
    camera = Intrinsics(1.0, 1.0, 0.0, 0.0, 2, 1)
    state = fresh_state(camera)
    zero = np.zeros((1, 2), np.float32)
    temporal_step(np.array([[1.0, 1.0]], np.float32), zero, state, 0.25, 0.1, 3)
    out, _, _ = temporal_step(np.array([[1.05, 3.0]], np.float32), zero, state, 0.25, 0.1, 3)
    assert out[0, 0] == pytest.approx(0.25 * 1.05 + 0.75 * 1.0)
    assert out[0, 1] == 3.0


# ------------------------------------------------------------------ hole filling

@pytest.mark.kernels
@pytest.mark.parametrize('mode', HOLE_FILLING)
def test_fill_kernel_matches_reference(mode: str) -> None:
    z = _depth(3, SHAPE, holes=0.3)
    got, got_f = fill_depth_holes(z, mode)
    want, want_f = fill_reference(z, mode)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got_f, want_f)


@pytest.mark.kernels
def test_spread_kernel_matches_reference() -> None:
    z = _depth(4, SHAPE, holes=0.3)
    filled = fill_depth_holes(z, 'fill_from_left')[1]
    np.testing.assert_array_equal(fill_spread(z, filled), spread_reference(z, filled))


def test_fill_modes_on_a_hole_between_two_depths() -> None:
    z = np.array([[2.0, 2.0, 2.0, 2.0],
                  [2.0, np.nan, np.nan, 5.0],
                  [2.0, 5.0, 5.0, 5.0]], np.float32)
    left, filled = fill_depth_holes(z, 'fill_from_left')
    assert left[1].tolist() == [2.0, 2.0, 2.0, 5.0]
    assert filled.sum() == 2
    assert filled[1, 1:3].all()
    # around: left, upper-left, upper (filled), lower-left, lower (measured)
    assert fill_depth_holes(z, 'farthest_from_around')[0][1, 1:3].tolist() == [5.0, 5.0]
    assert fill_depth_holes(z, 'nearest_from_around')[0][1, 1:3].tolist() == [2.0, 2.0]
    # never from the right: a hole at the left border with depth only on its right
    right_only = np.array([[np.nan, 3.0]], np.float32)
    for mode in ('farthest_from_around', 'nearest_from_around'):
        assert np.isnan(fill_depth_holes(right_only, mode)[0][0, 0])
    # both filled pixels span the 3 m step between the hole's ends
    assert fill_spread(z, filled)[1, 1:3].tolist() == [3.0, 3.0]


def test_fill_from_left_leaves_a_hole_at_the_left_border() -> None:
    z = np.array([[np.nan, 1.0, np.nan]], np.float32)
    out, filled = fill_depth_holes(z, 'fill_from_left')
    assert np.isnan(out[0, 0])
    assert out[0, 2] == 1.0
    assert filled.tolist() == [[False, False, True]]
    assert np.isnan(fill_spread(z, filled)[0, 2])  # no measured depth on its right


# ------------------------------------------------------------------ motion

def _state(camera: Intrinsics, seed: int) -> TemporalState:
    z = _depth(seed, (camera.height, camera.width), holes=0.2)
    rng = np.random.default_rng(seed)
    return TemporalState((1.0 / z).astype(np.float32),
                         rng.uniform(1e-6, 1e-4, z.shape).astype(np.float32),
                         rng.integers(0, 256, z.shape).astype(np.uint8), camera)


@pytest.mark.kernels
@pytest.mark.parametrize('disparity', [True, False])
def test_warp_kernel_matches_reference(disparity: bool) -> None:
    src = Intrinsics(40.0, 40.0, 9.5, 7.5, *kernel_size((48, 36), (20, 16)))
    dst = Intrinsics(30.0, 31.0, 8.0, 6.5, *kernel_size((40, 30), (16, 12)))
    state = _state(src, 2)
    if not disparity:
        state.values = (1.0 / state.values).astype(np.float32)
    angle = 0.05
    R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0,
                                                                  np.cos(angle)]])
    t = np.array([0.1, -0.05, 0.2])
    got = warp_state(state, dst, (R, t), disparity)
    want = warp_reference(state, dst, (R, t), disparity)
    np.testing.assert_allclose(got.values, want.values, rtol=1e-6)
    np.testing.assert_allclose(got.var, want.var, rtol=1e-5)
    np.testing.assert_array_equal(got.history, want.history)
    assert np.isfinite(got.values).mean() > 0.5


def test_warp_keeps_every_pixel_when_the_camera_stays() -> None:
    camera = Intrinsics(40.0, 40.0, 9.5, 7.5, 20, 16)
    state = _state(camera, 5)
    moved = warp_state(state, camera, (np.eye(3), np.zeros(3)), True)
    valid = np.isfinite(state.values)
    np.testing.assert_allclose(moved.values[valid], state.values[valid], rtol=1e-6)
    np.testing.assert_array_equal(moved.history[valid], state.history[valid])
    assert np.isnan(moved.values[~valid]).all()
    assert (moved.history[~valid] == 0).all()


def test_warp_moves_a_plane_by_its_parallax() -> None:
    camera = Intrinsics(40.0, 40.0, 9.5, 7.5, 20, 16)
    state = fresh_state(camera)
    state.values[:] = 0.5  # 2 m in the disparity domain
    state.history[:] = np.arange(20, dtype=np.uint8)[None, :]
    # the camera moves 0.1 m to the right: a point 2 m away moves 40 * 0.1 / 2 = 2 px left
    moved = warp_state(state, camera, (np.eye(3), np.array([-0.1, 0.0, 0.0])), True)
    assert (moved.history[:, :18] == np.arange(2, 20)).all()
    assert np.isnan(moved.values[:, 18:]).all()
    assert (moved.history[:, 18:] == 0).all()
    np.testing.assert_allclose(moved.values[:, :18], 0.5)
