"""Time-of-flight decoding (depth_nodes.core.tof) against exact ground truth: phasors and
flying pixels against their plain references, unwrapping on exact phases, and whole
frames of the simulator (depth_nodes.sim.tof) with and without noise and multipath.

Tolerances: unwrapped ranges of exact phases within 1e-4 m (float32 phases); the depth of
a noise-free frame without multipath within 0.1 % of Z at the median and 1 % at the 99th
percentile away from edges (a pixel sums 2 x 2 rays of slightly different range); a noisy
frame with multipath within 1 % at the median (the target).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import Lazy, kernel_size
from reference.tof import flying_reference, phasors_reference

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.tof import (
    FLYING,
    LOW_AMPLITUDE,
    SATURATED,
    SPEED_OF_LIGHT,
    ToFDecoder,
    ToFParams,
    check_frequencies,
    decode_tof,
    phase_of,
    phasors,
    remove_flying_pixels,
    unambiguous_range,
    unwrap,
)
from depth_nodes.errors import ArgumentError
from depth_nodes.sim.tof import ToFSimConfig, simulate_tof

SMALL = ToFSimConfig(width=160, height=120, focal_px=125.0, supersample=2, emitter_step=8,
                     n_frames=1)
CLEAN = dataclasses.replace(SMALL, noise=False, multipath=False)
NOISY = Lazy(lambda: next(simulate_tof(SMALL)))
EXACT = Lazy(lambda: next(simulate_tof(CLEAN)))


def _phases(ranges: np.ndarray, freqs: tuple[float, ...]) -> np.ndarray:
    return np.stack([np.mod(4 * np.pi * f * 1e6 * ranges / SPEED_OF_LIGHT, 2 * np.pi)
                     for f in freqs]).astype(np.float32)


# ------------------------------------------------------------- frequencies


@pytest.mark.parametrize(('freqs', 'expected'), [
    ((80.0, 100.0), SPEED_OF_LIGHT / (2 * 20e6)),
    ((16.0, 80.0, 120.0), SPEED_OF_LIGHT / (2 * 8e6)),  # Kinect v2's three
    ((100.0,), SPEED_OF_LIGHT / (2 * 100e6)),
    ((60.5, 100.0), SPEED_OF_LIGHT / (2 * 0.5e6)),
])
def test_unambiguous_range_is_that_of_the_common_divisor(freqs: tuple[float, ...],
                                                         expected: float) -> None:
    assert unambiguous_range(freqs) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize(('freqs', 'message'), [
    ([], 'one to three'),
    ([10.0, 20.0, 30.0, 40.0], 'one to three'),
    ([80.0, 80.0], 'must differ'),
    ([0.0, 80.0], 'in \\[0.001, 10000\\] MHz'),
    ([float('nan')], 'in \\[0.001, 10000\\] MHz'),
    ([80.0001], 'taken to 1 kHz'),
    (['x'], 'must be numbers'),
])
def test_bad_frequencies_are_refused(freqs: list[object], message: str) -> None:
    with pytest.raises(ArgumentError, match=message):
        check_frequencies(freqs)


# ------------------------------------------------------------------ kernels


@pytest.mark.kernels
def test_phasors_match_the_plain_reference() -> None:
    rng = np.random.default_rng(1)
    samples = rng.uniform(0, 4200, (8, 30, 40)).astype(np.float32)
    ours = phasors(samples, 2, 4, 4095.0)
    ref = phasors_reference(samples, 2, 4, 4095.0)
    for a, b in zip(ours[:3], ref[:3], strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=2e-3)
    np.testing.assert_array_equal(ours[3], ref[3])
    assert ours[3].any()
    assert not ours[3].all()


def test_phasors_recover_phase_amplitude_and_offset() -> None:
    steps = 5
    phi, amp, off = 2.1, 300.0, 900.0
    theta = 2 * np.pi * np.arange(steps) / steps
    samples = (off + amp * np.cos(phi - theta)).astype(np.float32)[:, None, None]
    phase, amplitude, offset, saturated = phasors(samples, 1, steps, 4095.0)
    assert phase[0, 0, 0] == pytest.approx(phi, abs=1e-5)
    assert amplitude[0, 0, 0] == pytest.approx(amp, rel=1e-5)
    assert offset[0, 0, 0] == pytest.approx(off, rel=1e-6)
    assert not saturated[0, 0]


@pytest.mark.parametrize('freqs', [(80.0, 100.0), (60.0, 80.0, 100.0), (16.0, 80.0, 120.0)])
def test_unwrap_recovers_ranges_beyond_each_frequency_alone(freqs: tuple[float, ...]) -> None:
    limit = unambiguous_range(freqs)
    ranges = np.linspace(0.05, limit * 0.999, 2000).reshape(40, 50)
    phase = _phases(ranges, freqs)
    ones = np.full(phase.shape, 200.0, np.float32)
    found, sigma, chi2 = unwrap(phase, ones, ones * 2, freqs, 4)
    assert np.abs(found - ranges).max() < 1e-4 * max(1.0, limit / 7.5)
    assert ranges.max() > 1.99 * max(SPEED_OF_LIGHT / (2 * f * 1e6) for f in freqs)
    assert np.isfinite(sigma).all()
    assert chi2.max() < 1e-3


def test_one_frequency_wraps_at_its_own_range() -> None:
    wrap = SPEED_OF_LIGHT / (2 * 100e6)
    ranges = np.array([[0.5, wrap + 0.5]])
    found, _, _ = unwrap(_phases(ranges, (100.0,)), np.ones((1, 1, 2), np.float32) * 100,
                         np.ones((1, 1, 2), np.float32) * 200, (100.0,), 4)
    np.testing.assert_allclose(found, [[0.5, 0.5]], atol=1e-5)


def test_noisy_phases_unwrap_to_the_right_wrap_count() -> None:
    """Phase noise of 0.05 rad (a few cm): never a wrong wrap count (0.37 m off)."""
    rng = np.random.default_rng(4)
    freqs = (80.0, 100.0)
    ranges = rng.uniform(0.1, 7.4, (100, 100))
    phase = np.mod(_phases(ranges, freqs) + rng.normal(0, 0.05, (2, 100, 100)), 2 * np.pi)
    amplitude = np.full(phase.shape, 200.0, np.float32)
    found, _, _ = unwrap(phase.astype(np.float32), amplitude, amplitude, freqs, 4)
    err = np.abs(found - ranges)
    near_wrap = np.minimum(ranges, 7.4948 - ranges) < 0.1  # wraps to 0 there
    assert err[~near_wrap].max() < 0.1


def _scene_range() -> np.ndarray:
    return EXACT.range_gt.copy()


def _steps_range() -> np.ndarray:
    """A small range image with depth edges: two slanted planes, a box in front, a column
    of mixed pixels between the planes (for the plain-Python run of the kernels)."""
    y, x = np.mgrid[0:24, 0:32].astype(np.float32)
    r = np.where(x < 12, 1.0 + 0.01 * y, 2.5 - 0.02 * x).astype(np.float32)
    r[8:16, 18:26] = 0.8
    r[:, 12] = 1.7
    return r


@pytest.mark.kernels
def test_flying_pixels_match_the_plain_reference() -> None:
    rng = np.random.default_rng(2)
    scene = kernel_size(_scene_range, _steps_range)()
    r = scene + rng.normal(0, 0.01, scene.shape).astype(np.float32)
    r[rng.random(r.shape) < 0.03] = np.nan
    sigma = rng.uniform(0.0, 0.02, r.shape).astype(np.float32)
    for args in ((0.01, 0.02), (0.03, 0.0), (0.0, 0.05), (0.001, 0.01)):
        found = remove_flying_pixels(r, *args, sigma=sigma)
        np.testing.assert_array_equal(found, flying_reference(r, *args, sigma=sigma))
        assert found.any()
    for margin, spikes in ((0.1, True), (0.3, False), (0.0, True)):  # the depth filter's
        found = remove_flying_pixels(r, 0.01, sigma=sigma, margin=margin, spikes=spikes)
        np.testing.assert_array_equal(found, flying_reference(
            r, 0.01, sigma=sigma, margin=margin, spikes=spikes))
        assert found.any()


def _rows(values: list[float]) -> np.ndarray:
    return np.tile(np.asarray(values, np.float32), (5, 1))


def test_a_mixed_pixel_in_a_small_gap_is_flying_wherever_in_it_it_lies() -> None:
    """A 9 cm gap with a pixel 3 cm from one side: off that side by less than the noise
    allowance of a one-sided test, but the gap is not explained by the flat surfaces
    beyond it."""
    near_side = _rows([2.69, 2.69, 2.69, 2.75, 2.78, 2.78, 2.78])
    sigma = np.full(near_side.shape, 0.01, np.float32)
    flying = remove_flying_pixels(near_side, 0.01, sigma=sigma)
    np.testing.assert_array_equal(flying.any(axis=0), [0, 0, 0, 1, 0, 0, 0])
    # the same steps on a steady slope are a surface
    slope = _rows([2.60, 2.645, 2.69, 2.735, 2.78, 2.825, 2.87])
    assert not remove_flying_pixels(slope, 0.01, sigma=sigma).any()


def test_a_mixed_pixel_is_flying_a_slope_and_a_pole_are_not() -> None:
    mixed = _rows([2.0, 2.0, 2.0, 2.5, 3.0, 3.0, 3.0])  # 2.5: two surfaces mixed
    flying = remove_flying_pixels(mixed, 0.01)
    np.testing.assert_array_equal(flying.any(axis=0), [0, 0, 0, 1, 0, 0, 0])
    # a plane at 60 degrees, 2 m away, 500 px focal length: 7 mm a pixel
    slope = _rows([2.0 + 0.007 * i for i in range(7)])
    assert not remove_flying_pixels(slope, 0.01).any()
    pole = _rows([3.0, 3.0, 3.0, 1.0, 3.0, 3.0, 3.0])  # 1 px wide, in front: not between
    assert not remove_flying_pixels(pole, 0.01).any()
    # the jump test takes both sides of every edge, and the pole with its neighbours
    np.testing.assert_array_equal(remove_flying_pixels(mixed, 0.0, jump=0.05).any(axis=0),
                                  [0, 0, 1, 1, 1, 0, 0])
    np.testing.assert_array_equal(remove_flying_pixels(pole, 0.0, jump=0.05).any(axis=0),
                                  [0, 0, 1, 1, 1, 0, 0])
    assert not remove_flying_pixels(slope, 0.0, jump=0.05).any()


def test_noise_alone_is_not_flying() -> None:
    rng = np.random.default_rng(7)
    plane = np.float32(3.0) + rng.normal(0, 0.02, (200, 200)).astype(np.float32)
    sigma = np.full(plane.shape, 0.02, np.float32)
    assert remove_flying_pixels(plane, 0.01, 0.02, sigma=sigma).mean() < 1e-3
    assert remove_flying_pixels(plane, 0.01, 0.02).mean() > 0.1  # without the noise model


# ------------------------------------------------------------------- frames


def _edges(depth: np.ndarray) -> np.ndarray:
    padded = np.pad(depth, 1, mode='edge')
    h, w = depth.shape
    stack = np.stack([padded[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                      for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    with np.errstate(invalid='ignore'):
        return ~((stack.max(axis=0) - stack.min(axis=0)) < 0.02 * depth)


def test_a_noise_free_frame_gives_the_exact_depth() -> None:
    result = decode_tof(EXACT.samples, EXACT.camera, CLEAN.frequencies_mhz,
                        ToFParams(min_confidence=0.0))
    truth = EXACT.depth_gt
    est = np.isfinite(result.depth)
    smooth = est & ~_edges(truth) & (EXACT.flags_gt == 0)
    rel = np.abs(result.depth - truth)[smooth] / truth[smooth]
    assert smooth.mean() > 0.7
    assert np.median(rel) < 1e-3
    assert np.quantile(rel, 0.99) < 1e-2


def test_depth_is_z_not_the_ray_length() -> None:
    """Away from the image centre the ray is longer than Z: the range the camera measures
    is converted, through the lens's distortion."""
    result = decode_tof(EXACT.samples, EXACT.camera, CLEAN.frequencies_mhz)
    corner = (slice(5, 25), slice(5, 35))
    truth = EXACT.depth_gt[corner]
    ok = np.isfinite(result.depth[corner])
    assert ok.mean() > 0.5
    ray = np.linalg.norm(EXACT.points_gt[corner], axis=-1) / truth
    assert ray.min() > 1.1  # the range is at least 10 % longer than Z there
    assert np.median(np.abs(result.depth[corner][ok] - truth[ok]) / truth[ok]) < 2e-3


def test_a_noisy_frame_with_multipath_meets_the_targets() -> None:
    result = decode_tof(NOISY.samples, NOISY.camera, SMALL.frequencies_mhz)
    truth = NOISY.depth_gt
    est = np.isfinite(result.depth)
    rel = np.abs(result.depth - truth)[est] / truth[est]
    assert np.median(rel) < 0.01
    judged = (NOISY.flags_gt == 0) & np.isfinite(truth)
    assert est[judged].mean() > 0.85  # 160 px wide: edges are a larger share than at VGA


def test_saturated_and_dark_pixels_are_flagged_and_get_no_depth() -> None:
    result = decode_tof(NOISY.samples, NOISY.camera, SMALL.frequencies_mhz)
    saturated = (NOISY.flags_gt & SATURATED) > 0
    dark = (NOISY.flags_gt & LOW_AMPLITUDE) > 0
    assert saturated.sum() > 20
    assert dark.sum() > 20
    assert ((result.flags[saturated] & SATURATED) > 0).mean() > 0.95
    assert not np.isfinite(result.depth[saturated]).any()
    assert np.isfinite(result.depth[dark]).mean() < 0.05
    assert ((result.flags & FLYING) > 0).any()


def test_confidence_is_in_range_and_higher_where_the_depth_is_right() -> None:
    result = decode_tof(NOISY.samples, NOISY.camera, SMALL.frequencies_mhz,
                        ToFParams(min_confidence=0.0))
    conf = result.confidence
    assert conf.min() >= 0.0
    assert conf.max() <= 1.0
    truth = NOISY.depth_gt
    est = np.isfinite(result.depth) & np.isfinite(truth)
    err = np.abs(result.depth - truth) / truth
    high, low = est & (conf >= 0.8), est & (conf < 0.3)
    assert high.sum() > 100
    assert low.sum() > 20
    assert np.median(err[high]) < np.median(err[low])


def test_decoder_refuses_what_does_not_fit() -> None:
    camera = EXACT.camera
    with pytest.raises(ArgumentError, match='samples must be \\(8, H, W\\)'):
        decode_tof(EXACT.samples[:6], camera, (80.0, 100.0))
    small = CameraModel(80, 60, camera.K, D=camera.D, P=camera.P)
    with pytest.raises(ArgumentError, match='samples are 160x120 but the camera is 80x60'):
        decode_tof(EXACT.samples, small, (80.0, 100.0))
    with pytest.raises(ArgumentError, match='depth_max \\(1\\) must be greater than'):
        decode_tof(EXACT.samples, camera, (80.0, 100.0), ToFParams(depth_min=2.0,
                                                                    depth_max=1.0))
    with pytest.raises(ArgumentError, match='phase_steps'):
        ToFParams(phase_steps=2).validate()


def test_the_decoder_keeps_its_maps_between_frames() -> None:
    decoder = ToFDecoder()
    first = decoder.decode(EXACT.samples, EXACT.camera, CLEAN.frequencies_mhz, ToFParams())
    maps = decoder._maps
    again = decoder.decode(EXACT.samples, EXACT.camera, CLEAN.frequencies_mhz, ToFParams())
    assert decoder._maps is maps
    np.testing.assert_array_equal(first.depth, again.depth)


@pytest.mark.kernels
def test_the_polynomial_phase_matches_arctan2() -> None:
    rng = np.random.default_rng(8)
    re, im = rng.normal(size=(2, 20000)) * rng.uniform(0.001, 1000, (2, 20000))
    special = [(0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (-1.0, 0.0), (1.0, 1.0), (-1e-30, -1.0)]
    re = np.concatenate([re, [s[0] for s in special]])
    im = np.concatenate([im, [s[1] for s in special]])
    ours = np.array([phase_of(float(i), float(r)) for i, r in zip(im, re, strict=True)])
    expected = np.mod(np.arctan2(im, re), 2 * np.pi)
    diff = np.abs(np.angle(np.exp(1j * (ours - expected))))
    assert diff.max() < 1e-6
    assert ours.min() >= 0.0
    assert ours.max() < 2 * np.pi
    assert phase_of(0.0, 0.0) == 0.0
