"""The time-of-flight simulator (depth_nodes.sim.tof): its ground truth is consistent, its
raw frames carry what the scene was built for (saturation, dark areas, mixed pixels,
multipath at the concave corner), and its configuration is checked."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import Lazy

from depth_nodes.core.tof import LOW_AMPLITUDE, SATURATED, ToFParams, decode_tof
from depth_nodes.errors import ConfigError
from depth_nodes.sim.tof import ToFSimConfig, simulate_tof

BASE = ToFSimConfig(width=128, height=96, focal_px=100.0, supersample=2, emitter_step=8,
                    n_frames=1, noise=False)
WITH_BOUNCES = Lazy(lambda: next(simulate_tof(BASE)))
WITHOUT = Lazy(lambda: next(simulate_tof(dataclasses.replace(BASE, multipath=False))))


def test_range_and_depth_agree_where_the_lens_does_not_bend() -> None:
    frame = WITHOUT
    y, x = 48, 64  # the principal point is (63.5, 47.5): the raw and rectified rays agree
    ray = np.linalg.norm(frame.points_gt[y, x]) / frame.depth_gt[y, x]
    assert frame.range_gt[y, x] == pytest.approx(frame.depth_gt[y, x] * ray, rel=1e-3)
    np.testing.assert_allclose(frame.points_gt[..., 2], frame.depth_gt, rtol=1e-6)


def test_the_scene_saturates_the_bright_board_and_loses_the_black_patch() -> None:
    frame = WITHOUT
    names = frame.label_names
    board = frame.labels == names.index('bright_board')
    patch = frame.labels == names.index('black_patch')
    assert ((frame.flags_gt[board] & SATURATED) > 0).mean() > 0.9
    assert ((frame.flags_gt[patch] & LOW_AMPLITUDE) > 0).mean() > 0.9
    assert (frame.flags_gt[~(board | patch)] == 0).mean() > 0.97
    assert frame.samples.max() == BASE.full_well


def test_mixed_pixels_are_at_depth_edges() -> None:
    frame = WITHOUT
    near, far = frame.mixed_gt
    mixed = np.isfinite(near) & np.isfinite(far)
    assert mixed.any()
    assert (far[mixed] - near[mixed] > 0.04).all()
    # a mixed pixel's 3x3 ground truth spans a depth edge
    depth = np.pad(frame.depth_gt, 1, mode='edge')
    stack = np.stack([depth[1 + dy:97 + dy, 1 + dx:129 + dx] for dy in (-1, 0, 1)
                      for dx in (-1, 0, 1)])
    spread = stack.max(axis=0) - stack.min(axis=0)
    assert (spread[mixed] > 0.03).mean() > 0.95


def test_multipath_lengthens_the_ranges_of_the_corner() -> None:
    """Noise-free frames decoded with and without the bounced light: the walls near the
    concave corner, lit by each other, come out farther; elsewhere little changes."""
    params = ToFParams(min_confidence=0.0)
    bias = {}
    for name, frame in (('with', WITH_BOUNCES), ('without', WITHOUT)):
        depth = decode_tof(frame.samples, frame.camera, BASE.frequencies_mhz, params).depth
        corner = frame.corner_gt & np.isfinite(depth)
        assert corner.sum() > 50
        bias[name] = float(np.median((depth - frame.depth_gt)[corner]))
    assert abs(bias['without']) < 0.002
    assert bias['with'] > 0.01


def test_noise_differs_between_frames_and_the_scene_does_not() -> None:
    frames = list(simulate_tof(dataclasses.replace(BASE, noise=True, multipath=False,
                                                   n_frames=2)))
    assert not np.array_equal(frames[0].samples, frames[1].samples)
    np.testing.assert_array_equal(frames[0].depth_gt, frames[1].depth_gt)
    assert frames[1].stamp_ns - frames[0].stamp_ns == round(1e9 / BASE.frame_rate_hz)


@pytest.mark.parametrize(('change', 'message'), [
    ({'width': 8}, 'width and height must be >= 16'),
    ({'phase_steps': 2}, 'phase_steps must be >= 3'),
    ({'contrast': 0.0}, 'contrast must be in'),
    ({'frequencies_mhz': (80.0, 80.0)}, 'must differ'),
    ({'distortion': (0.1,)}, 'distortion needs the 5 plumb_bob'),
    ({'n_frames': 0}, 'n_frames must be >= 1, got 0'),
])
def test_bad_configurations_are_refused(change: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        dataclasses.replace(BASE, **change).validate()  # type: ignore[arg-type]
