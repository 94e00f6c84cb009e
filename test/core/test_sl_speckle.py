"""Speckle matching: the numba census matcher equals its plain definition; known shifts
and depths are recovered; a reference wider than the images serves the pixels whose dots
lie beyond the camera's view; shadows get no depth; bad inputs raise with a message.

Tolerances: sub-pixel shifts of a smooth shift within 0.1 px at the median (the census
sums' parabola); depths of a plane within 0.2 %.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from reference.structured_light import match_speckle_reference

from depth_nodes.core.structured_light import (
    SpeckleMatcher,
    match_speckle,
    shift_range,
    shift_to_depth,
    speckle_depth,
    speckle_pattern,
)
from depth_nodes.core.structured_light.speckle import SpeckleReference
from depth_nodes.errors import ConfigError, InputFileError


def _dots(h: int, w: int, seed: int = 0) -> np.ndarray:
    pattern = speckle_pattern(w, h, seed=seed, density=0.2)
    return cv2.GaussianBlur(pattern * 200 + 20, (0, 0), 0.8).astype(np.float32)


def _shifted(ref: np.ndarray, shift: float, width: int, margin: int) -> np.ndarray:
    """The image a reference with ``margin`` extra columns each side sees shifted by
    ``shift``: image column x shows reference column x - shift + margin."""
    h = ref.shape[0]
    mx = (np.arange(width, dtype=np.float32) - shift + margin)[None].repeat(h, 0)
    my = np.arange(h, dtype=np.float32)[:, None].repeat(width, 1)
    return cv2.remap(ref, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


@pytest.mark.kernels
@pytest.mark.parametrize(('window', 'margin'), [(3, 0), (5, 4), (7, 0), (9, 6), (15, 3)])
def test_the_kernel_equals_the_plain_definition(window: int, margin: int) -> None:
    """Every path: boxes of 3 m (summed as triples) and others, with and without margins,
    shifts whose reference column falls outside, a flat patch without texture."""
    rng = np.random.default_rng(window)
    ref = _dots(26, 40 + 2 * margin, seed=window)
    img = _shifted(ref, 2.3, 40, margin) + rng.normal(0, 2, (26, 40)).astype(np.float32)
    img[3:9, 4:12] = 50.0
    kwargs = {'shift_min': -3, 'shift_max': 7, 'window': window, 'min_score': 0.2,
              'uniqueness': 0.02}
    fast = match_speckle(img, ref, **kwargs)
    slow = match_speckle_reference(img, ref, **kwargs)
    np.testing.assert_array_equal(fast[1], slow[1])
    np.testing.assert_array_equal(fast[0], slow[0])
    assert np.isfinite(fast[0]).mean() > 0.3


def test_known_subpixel_shift() -> None:
    ref = _dots(60, 140)
    img = _shifted(ref, 3.4, 120, 10)
    shift, score = match_speckle(img, ref, shift_min=-2, shift_max=8)
    inner = shift[6:-6, 10:-10]
    assert np.isfinite(inner).mean() > 0.95
    assert abs(np.nanmedian(inner) - 3.4) < 0.1
    assert np.nanmin(score[6:-6, 10:-10]) > 0.4


def test_shift_depth_round_trip() -> None:
    lo, hi = shift_range(500.0, 0.1, 1.0, 0.5, 2.0)
    assert (lo, hi) == (-26, 51)
    depth = shift_to_depth(np.array([0.0, 50.0, -25.0], np.float32), 500.0, 0.1, 1.0)
    np.testing.assert_allclose(depth, [1.0, 0.5, 2.0], rtol=1e-6)


def test_speckle_depth_of_a_plane() -> None:
    margin = 20
    ref = _dots(50, 110 + 2 * margin)
    focal, baseline = 500.0, 0.1
    shift = focal * baseline * (1 / 0.8 - 1 / 1.0)  # a plane at 0.8 m: 12.5 px
    depth, conf = speckle_depth(_shifted(ref, shift, 110, margin), ref, focal=focal,
                                baseline=baseline, reference_depth=1.0, depth_min=0.5,
                                depth_max=2.0)
    inner = depth[6:-6, 6:-6]
    assert np.isfinite(inner).mean() > 0.95
    assert abs(np.nanmedian(inner) - 0.8) < 0.8 * 2e-3
    assert (conf[np.isnan(depth)] == 0).all()
    assert (conf[np.isfinite(depth)] > 0.4).all()


def test_a_wider_reference_serves_the_image_edges() -> None:
    """A surface 12 px nearer than the reference: the leftmost image columns show dots
    that lie left of the camera's view at the reference depth."""
    margin, width = 16, 100
    ref = _dots(40, width + 2 * margin)
    img = _shifted(ref, 12.0, width, margin)
    with_margin, _ = match_speckle(img, ref, shift_min=-2, shift_max=16)
    cropped, _ = match_speckle(img, np.ascontiguousarray(ref[:, margin:-margin]),
                               shift_min=-2, shift_max=16)
    edge = (slice(6, -6), slice(0, 10))
    assert np.isfinite(with_margin[edge]).mean() > 0.9
    assert np.abs(np.nanmedian(with_margin[edge]) - 12.0) < 0.1
    assert np.isfinite(cropped[edge]).mean() < 0.1


def test_a_shadow_without_dots_gets_no_depth() -> None:
    rng = np.random.default_rng(3)
    ref = _dots(60, 120)
    img = _shifted(ref, 4.0, 120, 0)
    # the projector's shadow: only the scene's own faint texture and noise
    texture = cv2.GaussianBlur(rng.uniform(10, 40, (60, 50)).astype(np.float32), (0, 0), 2)
    img[:, 40:90] = texture + rng.normal(0, 1.5, texture.shape).astype(np.float32)
    shift, _ = match_speckle(img, ref, shift_min=-8, shift_max=16)
    inside = shift[:, 46:84]  # beyond the box's reach into the lit part
    assert np.isfinite(inside).mean() < 0.01
    assert np.isfinite(shift[6:-6, 8:32]).mean() > 0.9


def test_the_matcher_keeps_the_reference_census() -> None:
    ref = _dots(30, 60)
    img = _shifted(ref, 2.0, 60, 0)
    matcher = SpeckleMatcher()
    first = matcher.match(img, ref, shift_min=-2, shift_max=6)
    census = matcher.reference_census(ref)
    again = matcher.match(img, ref, shift_min=-2, shift_max=6)
    assert matcher.reference_census(ref) is census
    np.testing.assert_array_equal(first[0], again[0])
    other = ref.copy()
    assert matcher.reference_census(other) is not census


@pytest.mark.parametrize(('call', 'message'), [
    (lambda: match_speckle(np.zeros((4, 8)), np.zeros((4, 9)), shift_min=0, shift_max=2),
     r'the reference must have the image\'s 4 rows and its 8 columns plus as many extra on '
     r'each side, got 9x4 for 8x4'),
    (lambda: match_speckle(np.zeros((4, 8)), np.zeros((5, 8)), shift_min=0, shift_max=2),
     'must have the image\'s 4 rows'),
    (lambda: match_speckle(np.zeros((4, 8)), np.zeros((4, 8)), shift_min=0, shift_max=2,
                           window=4), 'window must be odd and >= 3, got 4'),
    (lambda: match_speckle(np.zeros((4, 8)), np.zeros((4, 8)), shift_min=3, shift_max=4),
     'the shift range 3..4 needs at least 3 shifts'),
    (lambda: match_speckle(np.zeros(8), np.zeros(8), shift_min=0, shift_max=4),
     'image and reference must be 2-D'),
    (lambda: shift_range(500.0, 0.0, 1.0, 0.5, 2.0), 'nonzero baseline'),
    (lambda: shift_range(500.0, 0.1, 1.0, 2.0, 0.5), '0 < depth_min < depth_max'),
])
def test_errors(call: object, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        call()  # type: ignore[operator]


def test_reference_files(tmp_path: Path) -> None:
    loader = SpeckleReference()
    wide = tmp_path / 'wide.png'
    cv2.imwrite(str(wide), np.zeros((10, 24), np.uint8))
    assert loader.load(str(wide), (10, 20)).shape == (10, 24)
    with pytest.raises(InputFileError, match='needs their rows and their columns plus as '
                       'many extra on each side'):
        loader.load(str(wide), (10, 21))
    with pytest.raises(InputFileError, match='is 24x10; images are 20x12'):
        loader.load(str(wide), (12, 20))
    with pytest.raises(InputFileError, match='needs the speckle_reference parameter'):
        loader.load('', (10, 20))
