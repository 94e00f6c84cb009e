"""librealsense's filters through a software device (pyrealsense2, the `realsense` extra):
the harness is exact with every filter off, and each filter does on a crafted frame what
librealsense 2.59.1 was measured to do (depth_nodes/tools/evaluation/librealsense.py)."""

from __future__ import annotations

import builtins
import sys
from typing import Any

import numpy as np
import pytest

from depth_nodes.errors import ArgumentError, CalibrationError, ConfigError
from depth_nodes.tools.evaluation.librealsense import (
    Camera,
    RealsenseChain,
    RealsenseSettings,
    load_pyrealsense,
)

CAMERA = Camera(width=16, height=8, fx=20.0, fy=22.0, cx=7.5, cy=3.5)
#: Half a depth unit (1 mm): the quantisation of the Z16 frames, plus float32 rounding.
QUANTUM = 0.0005 + 1e-6


def run(settings: RealsenseSettings, *frames: np.ndarray, camera: Camera = CAMERA) -> list:
    """The chain's outputs for ``frames`` in order, through one chain."""
    with RealsenseChain(settings, camera) as chain:
        return [chain.process(frame) for frame in frames]


def test_all_filters_off_round_trips_the_frame() -> None:
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.3, 5.0, (CAMERA.height, CAMERA.width)).astype(np.float32)
    depth[1, 2] = np.nan
    depth[3, 4] = 0.0
    depth[5, 6] = np.inf
    (out,) = run(RealsenseSettings(), depth)
    unknown = ~np.isfinite(depth) | (depth == 0)
    assert out.depth.dtype == np.float32
    assert out.depth.shape == depth.shape
    np.testing.assert_array_equal(np.isnan(out.depth), unknown)
    assert np.abs(out.depth[~unknown] - depth[~unknown]).max() <= QUANTUM
    assert out.seconds == {}
    assert out.camera == CAMERA


def test_decimation_by_two_takes_the_lower_median_of_the_known_pixels() -> None:
    depth = np.full((CAMERA.height, CAMERA.width), 2.0, np.float32)
    depth[0:2, 0:2] = [[1.0, 1.1], [1.2, 1.3]]  # four known: the second smallest
    depth[0:2, 2:4] = [[1.0, np.nan], [1.4, 1.2]]  # three known: the middle one
    depth[0:2, 4:6] = [[np.nan, 1.5], [1.1, np.nan]]  # two known: the smaller
    depth[0:2, 6:8] = np.nan  # none known: unknown
    (out,) = run(RealsenseSettings(decimation=2), depth)
    assert out.depth.shape == (4, 8)
    np.testing.assert_allclose(out.depth[0, :4], [1.1, 1.2, 1.1, np.nan], atol=QUANTUM)
    np.testing.assert_allclose(out.depth[1:], 2.0, atol=QUANTUM)
    assert out.seconds.keys() == {'decimation'}
    # intrinsics divided by the magnitude, the principal point included (not (c + 0.5) / 2)
    assert out.camera == Camera(8, 4, 10.0, 11.0, 3.75, 1.75, CAMERA.baseline)


def test_decimation_pads_to_a_multiple_of_four_with_unknown_pixels() -> None:
    camera = Camera(width=13, height=9, fx=20.0, fy=20.0, cx=6.0, cy=4.0)
    depth = np.full((9, 13), 1.0, np.float32)
    (out,) = run(RealsenseSettings(decimation=3), depth, camera=camera)
    # floor(13 / 3) = 4 columns and floor(9 / 3) = 3 rows of blocks, padded to 4 x 4
    assert out.depth.shape == (4, 4)
    np.testing.assert_allclose(out.depth[:3], 1.0, atol=QUANTUM)
    assert np.isnan(out.depth[3]).all()


def test_hole_filling_mode_0_copies_the_left_neighbour_along_the_row() -> None:
    depth = np.full((CAMERA.height, CAMERA.width), 1.0, np.float32)
    depth[2, 3:7] = [1.25, np.nan, np.nan, 1.5]
    depth[4, 0:2] = [np.nan, 1.75]  # first column: nothing on its left
    depth[5:7, 9] = np.nan  # a vertical hole, filled from the left too
    depth[5, 8] = 1.125
    (out,) = run(RealsenseSettings(hole_filling=0), depth)
    np.testing.assert_allclose(out.depth[2, 3:7], [1.25, 1.25, 1.25, 1.5], atol=QUANTUM)
    assert np.isnan(out.depth[4, 0])
    np.testing.assert_allclose(out.depth[5:7, 9], [1.125, 1.0], atol=QUANTUM)
    assert np.isnan(out.depth).sum() == 1


def test_temporal_filter_halves_the_noise_of_a_still_scene() -> None:
    rng = np.random.default_rng(3)
    shape = (CAMERA.height, CAMERA.width)
    frames = [(1.0 + rng.normal(0.0, 0.003, shape)).astype(np.float32) for _ in range(10)]
    outputs = run(RealsenseSettings(temporal=True, temporal_alpha=0.4), *frames)
    noisy = np.median(np.std(frames, axis=0))
    smoothed = np.median(np.std([out.depth for out in outputs], axis=0))
    # an exponential average with alpha 0.4 keeps sqrt(0.4 / 1.6) = 0.5 of the noise
    assert 0.35 * noisy < smoothed < 0.65 * noisy
    # librealsense truncates to whole units: a bias below one unit
    assert abs(np.mean([out.depth for out in outputs]) - 1.0) < 0.001
    assert all(out.seconds.keys() == {'temporal'} for out in outputs)


def test_temporal_filter_takes_a_step_beyond_delta_at_once() -> None:
    near = np.full((CAMERA.height, CAMERA.width), 1.0, np.float32)
    far = near + np.float32(0.05)
    outputs = run(RealsenseSettings(temporal=True, temporal_delta=20), near, near, far)
    np.testing.assert_allclose(outputs[-1].depth, 1.05, atol=QUANTUM)


def test_the_disparity_domain_sets_the_scale_of_delta() -> None:
    """2.000 m beside 2.004 m: 4 depth units apart, but under one disparity unit (1/32 px at
    32 * 20 px * 50 mm / 2000 mm = 16): a delta of 2 keeps the step in depth and smooths it
    in disparity, so the transform really runs on the software device."""
    depth = np.full((CAMERA.height, CAMERA.width), 2.0, np.float32)
    depth[:, 8:] = 2.004
    spatial = {'spatial': True, 'spatial_alpha': 0.5, 'spatial_delta': 2}
    (in_depth,) = run(RealsenseSettings(**spatial), depth)
    (in_disparity,) = run(RealsenseSettings(disparity=True, **spatial), depth)
    np.testing.assert_allclose(in_depth.depth, depth, atol=QUANTUM)
    assert np.abs(in_disparity.depth[:, 7] - 2.002).max() <= 0.0015
    assert list(in_disparity.seconds) == ['depth_to_disparity', 'spatial', 'disparity_to_depth']


def test_two_hundred_frames_do_not_leak() -> None:
    camera = Camera(width=320, height=240, fx=300.0, fy=300.0, cx=159.5, cy=119.5)
    depth = np.full((240, 320), 1.5, np.float32)
    depth[::7, ::5] = np.nan
    settings = RealsenseSettings(decimation=2, spatial=True, temporal=True, disparity=True,
                                 hole_filling=1)
    with RealsenseChain(settings, camera) as chain:
        for _ in range(20):
            chain.process(depth)
        before = resident_bytes()
        for _ in range(200):
            chain.process(depth)
        grown = resident_bytes() - before
    # one leaked input frame per call would be 200 * 150 KB = 30 MB
    assert grown < 5_000_000


def resident_bytes() -> int:
    """This process's resident set size (Linux)."""
    with open('/proc/self/statm') as statm:
        return int(statm.read().split()[1]) * 4096


@pytest.mark.parametrize(('depth', 'message'), [
    (np.ones((8, 16), np.float64), 'depth_m must be a float32 array, got float64'),
    (np.ones((16, 8), np.float32), r'depth_m must have the camera shape \(8, 16\), got \(16, 8\)'),
    (np.full((8, 16), -1.0, np.float32), 'depth_m must not be negative'),
    (np.full((8, 16), 70.0, np.float32),
     r'depth_m exceeds what Z16 holds .* \(65.535 m\): maximum 70.0'),
])
def test_bad_depth_frames_are_refused(depth: np.ndarray, message: str) -> None:
    with RealsenseChain(RealsenseSettings(), CAMERA) as chain, \
            pytest.raises(ArgumentError, match=message):
        chain.process(depth)


@pytest.mark.parametrize(('options', 'message'), [
    ({'decimation': 9}, r'decimation must be in \[1, 8\], got 9'),
    ({'spatial_alpha': 0.1}, r'spatial_alpha must be in \[0.25, 1.0\], got 0.1'),
    ({'temporal_persistence': -1}, r'temporal_persistence must be in \[0, 8\], got -1'),
    ({'hole_filling': 3}, 'hole_filling must be None, 0, 1 or 2, got 3'),
    ({'depth_units': 0.0}, r'depth_units must be in \(0, 0.01\] metres, got 0.0'),
])
def test_bad_settings_are_refused(options: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        RealsenseSettings(**options)


def test_bad_cameras_are_refused() -> None:
    with pytest.raises(CalibrationError, match='camera size must be positive, got 0x8'):
        Camera(0, 8, 20.0, 20.0, 0.0, 4.0)
    with pytest.raises(CalibrationError, match='camera fx, fy and baseline must be positive'):
        Camera(16, 8, 20.0, 20.0, 7.5, 3.5, baseline=0.0)
    with pytest.raises(CalibrationError, match='camera cx must be finite, got nan'):
        Camera(16, 8, 20.0, 20.0, float('nan'), 3.5)


def test_a_closed_chain_is_refused() -> None:
    chain = RealsenseChain(RealsenseSettings(), CAMERA)
    chain.close()
    chain.close()
    with pytest.raises(ConfigError, match='was closed'):
        chain.process(np.ones((8, 16), np.float32))


def test_missing_pyrealsense2_says_how_to_install_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, 'pyrealsense2', None)
    with pytest.raises(ConfigError, match=r'pip install \.\[realsense\]'):
        load_pyrealsense()
    with pytest.raises(ConfigError, match='not installed'):
        RealsenseChain(RealsenseSettings(), CAMERA)


def test_pyrealsense2_loads_with_the_libusb_of_the_extra() -> None:
    """pyrealsense2's native library needs libusb-1.0, which the realsense extra brings
    (libusb-package): the module loads and filters a frame without a system libusb."""
    assert load_pyrealsense().decimation_filter is not None
    with RealsenseChain(RealsenseSettings(decimation=2), CAMERA) as chain:
        out = chain.process(np.full((CAMERA.height, CAMERA.width), 1.5, np.float32))
    assert np.nanmedian(out.depth) == pytest.approx(1.5)


def test_a_pyrealsense2_that_cannot_load_names_the_library(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The PyPI wheel links libusb-1.0; where neither libusb-package nor the system has
    it the import fails, and the message says where to get it."""
    real_import = builtins.__import__

    def failing_import(name: str, *args: Any, **kwargs: Any) -> Any:
        if name == 'pyrealsense2':
            raise ImportError('libusb-1.0.so.0: cannot open shared object file')
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, 'pyrealsense2', raising=False)
    monkeypatch.setattr(builtins, '__import__', failing_import)
    with pytest.raises(ConfigError, match=r'cannot be loaded \(libusb-1.0.so.0: .*\); it '
                                          r'needs libusb-1.0: pip install .\[realsense\]'):
        load_pyrealsense()
