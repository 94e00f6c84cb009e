"""Speckle matching: the box-filter ZNCC equals the direct definition; known shifts and
depths are recovered; bad inputs raise with a message."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from depth_nodes.core.structured_light import (
    match_rows,
    match_rows_reference,
    shift_range,
    shift_to_depth,
    speckle_depth,
    speckle_pattern,
)
from depth_nodes.errors import ConfigError


def _dots(h: int, w: int, seed: int = 0) -> np.ndarray:
    pattern = speckle_pattern(w, h, seed=seed, density=0.2)
    return cv2.GaussianBlur(pattern * 200 + 20, (0, 0), 0.8)


def _shifted(ref: np.ndarray, shift: float) -> np.ndarray:
    h, w = ref.shape
    mx = (np.arange(w, dtype=np.float32) - shift)[None].repeat(h, 0)
    my = np.arange(h, dtype=np.float32)[:, None].repeat(w, 1)
    return cv2.remap(ref, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


class TestAgainstReference:
    """The fast matcher and the per-pixel definition agree (scores and shifts)."""

    def test_same_scores_and_shifts(self) -> None:
        rng = np.random.default_rng(1)
        ref = _dots(14, 30)
        img = _shifted(ref, 2.3) + rng.normal(0, 2, ref.shape).astype(np.float32)
        img[2:6, 3:9] = 50.0  # a flat patch: no texture, invalid in both
        kwargs = {'shift_min': -2, 'shift_max': 5, 'window': 5, 'min_score': 0.3}
        fast = match_rows(img, ref, **kwargs)
        slow = match_rows_reference(img, ref, **kwargs)
        np.testing.assert_allclose(fast[1], slow[1], atol=2e-4, equal_nan=True)
        np.testing.assert_array_equal(np.isnan(fast[0]), np.isnan(slow[0]))
        np.testing.assert_allclose(fast[0], slow[0], atol=2e-3, equal_nan=True)


def test_known_subpixel_shift() -> None:
    ref = _dots(40, 80)
    img = _shifted(ref, 3.4)
    shift, score = match_rows(img, ref, shift_min=-2, shift_max=8, window=9)
    inner = shift[5:-5, 12:-12]
    assert np.isfinite(inner).all()
    assert np.abs(np.median(inner) - 3.4) < 0.05
    assert np.nanmin(score[5:-5, 12:-12]) > 0.8  # sub-pixel interpolation blurs a little


def test_shift_depth_round_trip() -> None:
    lo, hi = shift_range(500.0, 0.1, 1.0, 0.5, 2.0)
    assert (lo, hi) == (-26, 51)
    depth = shift_to_depth(np.array([0.0, 50.0, -25.0], np.float32), 500.0, 0.1, 1.0)
    np.testing.assert_allclose(depth, [1.0, 0.5, 2.0], rtol=1e-6)


def test_speckle_depth_of_a_plane() -> None:
    ref = _dots(40, 90)
    focal, baseline = 500.0, 0.1
    shift = focal * baseline * (1 / 0.8 - 1 / 1.0)  # a plane at 0.8 m: 12.5 px
    depth, conf = speckle_depth(_shifted(ref, shift), ref, focal=focal, baseline=baseline,
                                reference_depth=1.0, depth_min=0.5, depth_max=2.0, window=9)
    inner = depth[5:-5, 30:-5]
    assert np.abs(np.median(inner) - 0.8) < 1e-3
    assert (conf[np.isnan(depth)] == 0).all()


@pytest.mark.parametrize(('call', 'message'), [
    (lambda: match_rows(np.zeros((4, 8)), np.zeros((4, 9)), shift_min=0, shift_max=2),
     r'image and reference must be 2-D of one size, got \(4, 8\) and \(4, 9\)'),
    (lambda: match_rows(np.zeros((4, 8)), np.zeros((4, 8)), shift_min=0, shift_max=2,
                        window=4), 'window must be odd and >= 3, got 4'),
    (lambda: match_rows(np.zeros((4, 8)), np.zeros((4, 8)), shift_min=3, shift_max=2),
     'empty shift range 3..2'),
    (lambda: shift_range(500.0, 0.0, 1.0, 0.5, 2.0), 'nonzero baseline'),
    (lambda: shift_range(500.0, 0.1, 1.0, 2.0, 0.5), '0 < depth_min < depth_max'),
])
def test_errors(call: object, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        call()  # type: ignore[operator]
