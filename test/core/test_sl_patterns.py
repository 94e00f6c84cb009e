"""Pattern sets: layouts, Gray code, and OpenCV GrayCodePattern's exact sequence."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from depth_nodes.core.structured_light import (
    PatternSet,
    generate_patterns,
    gray_code,
    gray_to_binary,
)
from depth_nodes.errors import ConfigError

# cv2.structured_light.GrayCodePattern.create(12, 6).generate(), recorded with
# opencv-contrib-python-headless 5.0.0.93: first row of each column pattern, first column
# of each row pattern (the patterns are constant along the other axis).
OPENCV_COLS_12 = [
    [0, 0, 0, 0, 0, 0, 0, 0, 255, 255, 255, 255], [255] * 8 + [0] * 4,
    [0, 0, 0, 0] + [255] * 8, [255] * 4 + [0] * 8,
    [0, 0, 255, 255, 255, 255, 0, 0, 0, 0, 255, 255],
    [255, 255, 0, 0, 0, 0, 255, 255, 255, 255, 0, 0],
    [0, 255, 255, 0, 0, 255, 255, 0, 0, 255, 255, 0],
    [255, 0, 0, 255, 255, 0, 0, 255, 255, 0, 0, 255],
]
OPENCV_ROWS_6 = [[0, 0, 0, 0, 255, 255], [255, 255, 255, 255, 0, 0], [0, 0, 255, 255, 255, 255],
                 [255, 255, 0, 0, 0, 0], [0, 255, 255, 0, 0, 255], [255, 0, 0, 255, 255, 0]]


def test_gray_code_round_trip_and_one_bit_steps() -> None:
    values = np.arange(1 << 11)
    codes = gray_code(values)
    np.testing.assert_array_equal(gray_to_binary(codes, 11), values)
    steps = codes[1:] ^ codes[:-1]
    assert np.all(steps & (steps - 1) == 0)  # exactly one bit changes


@pytest.mark.parametrize(('mode', 'axes', 'count'), [
    ('gray', 'columns', 2 + 2 * 10), ('gray', 'both', 2 + 2 * 19),
    ('phase', 'columns', 2 + 2 * 10 + 5), ('phase', 'both', 2 + 2 * 19 + 10),
    ('opencv', 'columns', 2 * 19 + 2), ('speckle', 'columns', 1),
])
def test_frame_counts(mode: str, axes: str, count: int) -> None:
    ps = PatternSet(mode, 640, 480, axes, steps=5, period=16.0)
    assert ps.count == count == len(generate_patterns(ps))


def test_opencv_layout_is_graycodepattern_generate_then_black_white() -> None:
    ps = PatternSet('opencv', 12, 6)
    pats = (generate_patterns(ps) * 255).astype(np.uint8)
    assert len(pats) == len(OPENCV_COLS_12) + len(OPENCV_ROWS_6) + 2
    for img, row in zip(pats[:8], OPENCV_COLS_12, strict=True):
        np.testing.assert_array_equal(img, np.tile(row, (6, 1)))
    for img, col in zip(pats[8:14], OPENCV_ROWS_6, strict=True):
        np.testing.assert_array_equal(img, np.tile(np.array(col)[:, None], (1, 12)))
    assert pats[14].max() == 0
    assert pats[15].min() == 255


@pytest.mark.skipif(not hasattr(cv2, 'structured_light'), reason='needs opencv-contrib')
def test_opencv_layout_against_live_opencv() -> None:
    pattern = cv2.structured_light.GrayCodePattern.create(40, 20)
    _, expected = pattern.generate()
    ours = (generate_patterns(PatternSet('opencv', 40, 20)) * 255).astype(np.uint8)
    for a, b in zip(ours, expected, strict=False):
        np.testing.assert_array_equal(a, b)


def test_phase_frames_are_shifted_cosines() -> None:
    ps = PatternSet('phase', 32, 8, steps=3, period=8.0)
    pats = generate_patterns(ps)
    u = np.arange(32)
    for k in range(3):
        expected = 0.5 + 0.5 * np.cos(2 * np.pi * u / 8 - 2 * np.pi * k / 3)
        np.testing.assert_allclose(pats[-3 + k][0], expected, atol=1e-6)
    assert pats[0].min() == 1
    assert pats[1].max() == 0


@pytest.mark.parametrize(('kwargs', 'message'), [
    ({'mode': 'stripes'}, 'pattern mode must be one of gray, phase, opencv, speckle'),
    ({'axes': 'rows'}, 'axes must be one of columns, both'),
    ({'width': 1}, 'projector size must be at least 2x2, got 1x48'),
    ({'steps': 2}, 'phase steps must be >= 3, got 2'),
    ({'period': 1.0}, 'phase period must be in [2, projector size], got 1.0'),
])
def test_invalid_pattern_sets(kwargs: dict[str, object], message: str) -> None:
    args = {'mode': 'phase', 'width': 64, 'height': 48, **kwargs}
    with pytest.raises(ConfigError, match=message.replace('[', r'\[').replace(']', r'\]')):
        PatternSet(**args)  # type: ignore[arg-type]
