"""Ground-truth files (scaled PNG / PGM, KITTI 16-bit PNG, PFM) against arrays written
here, the derived non-occlusion mask against a scene with known occlusions, and every
error a user can cause."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from depth_nodes.core.groundtruth import (
    OCCLUDED,
    OUTSIDE,
    VISIBLE,
    nonoccluded_from_right,
    read_disparity_file,
    read_image,
    read_pfm,
    write_pfm,
)
from depth_nodes.errors import InputFileError


def _disparity() -> np.ndarray:
    rng = np.random.default_rng(2)
    d = rng.uniform(1, 60, (13, 17)).astype(np.float32)
    d[2, 3] = np.nan
    return d


def test_scaled_8_bit(tmp_path: Path) -> None:
    d = _disparity()
    stored = np.where(np.isnan(d), 0, np.rint(d * 4)).astype(np.uint8)
    cv2.imwrite(str(tmp_path / 'disp.pgm'), stored)
    got = read_disparity_file(tmp_path / 'disp.pgm', scale=4)
    np.testing.assert_array_equal(np.isnan(got), stored == 0)
    np.testing.assert_allclose(got[stored > 0], stored[stored > 0] / 4.0)
    with pytest.raises(InputFileError, match='needs its scale'):
        read_disparity_file(tmp_path / 'disp.pgm')


def test_kitti_16_bit(tmp_path: Path) -> None:
    d = _disparity()
    stored = np.where(np.isnan(d), 0, np.rint(d * 256)).astype(np.uint16)
    cv2.imwrite(str(tmp_path / 'disp.png'), stored)
    got = read_disparity_file(tmp_path / 'disp.png')  # auto: a 16-bit PNG is KITTI's
    np.testing.assert_allclose(got[stored > 0], stored[stored > 0] / 256.0)
    assert np.isnan(got[2, 3])
    # a 16-bit PNG with a given scale is a scaled one
    np.testing.assert_allclose(read_disparity_file(tmp_path / 'disp.png', scale=64)[0, 0],
                               stored[0, 0] / 64.0)
    cv2.imwrite(str(tmp_path / 'eight.png'), np.ones((4, 4), np.uint8))
    with pytest.raises(InputFileError, match='KITTI disparity is a 16-bit PNG'):
        read_disparity_file(tmp_path / 'eight.png', fmt='kitti')


def test_pfm_round_trip_and_infinity(tmp_path: Path) -> None:
    d = _disparity()
    d[5, 5] = np.inf  # Middlebury 2014's unknown
    write_pfm(tmp_path / 'disp.pfm', d)
    raw = read_pfm(tmp_path / 'disp.pfm')
    np.testing.assert_array_equal(raw[np.isfinite(d)], d[np.isfinite(d)])
    got = read_disparity_file(tmp_path / 'disp.pfm')
    assert np.isnan(got[5, 5])
    assert np.isnan(got[2, 3])
    # big-endian, three channels: the first is taken, rows bottom to top
    rgb = np.stack([d, d + 1, d + 2], axis=-1)[::-1].astype('>f4')
    (tmp_path / 'big.pfm').write_bytes(b'PF\n17 13\n1.0\n' + rgb.tobytes())
    np.testing.assert_array_equal(read_pfm(tmp_path / 'big.pfm')[np.isfinite(d)],
                                  d[np.isfinite(d)])


@pytest.mark.parametrize(('content', 'message'), [
    (b'P5\n2 2\n255\n0000', 'not a PFM file'),
    (b'Pf\n4 4\n-1.0\n' + bytes(10), 'needs 64 bytes of data, the file has 10'),
    (b'Pf\n4 4\nx\n' + bytes(64), 'scale .* is not a number'),
])
def test_broken_pfm(tmp_path: Path, content: bytes, message: str) -> None:
    (tmp_path / 'bad.pfm').write_bytes(content)
    with pytest.raises(InputFileError, match=message):
        read_disparity_file(tmp_path / 'bad.pfm')


def test_files_that_cannot_be_read(tmp_path: Path) -> None:
    with pytest.raises(InputFileError, match='no such file'):
        read_image(tmp_path / 'missing.png')
    (tmp_path / 'text.png').write_text('not an image')
    with pytest.raises(InputFileError, match='not an image file OpenCV can read'):
        read_image(tmp_path / 'text.png')
    with pytest.raises(InputFileError, match='cannot read'):
        read_pfm(tmp_path / 'missing.pfm')
    cv2.imwrite(str(tmp_path / 'rgb.png'), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(InputFileError, match='must have one channel'):
        read_disparity_file(tmp_path / 'rgb.png', scale=4)
    with pytest.raises(ValueError, match='fmt must be one of'):
        read_disparity_file(tmp_path / 'rgb.png', fmt='jpeg')


def test_colour_images_are_rgb(tmp_path: Path) -> None:
    bgr = np.zeros((3, 4, 3), np.uint8)
    bgr[..., 0] = 255  # blue in OpenCV's order
    cv2.imwrite(str(tmp_path / 'blue.png'), bgr)
    rgb = read_image(tmp_path / 'blue.png')
    assert (rgb[..., 2] == 255).all()
    assert (rgb[..., 0] == 0).all()


def test_nonoccluded_from_right_on_a_box_before_a_wall() -> None:
    """Wall at d 8, box at d 20 over columns 50..79: the right view sees the box shifted
    12 px more, so the 12 wall columns left of the box are hidden; the first 8 columns map
    outside the right image."""
    h, w = 10, 120
    left = np.full((h, w), 8.0, np.float32)
    left[:, 50:80] = 20.0
    right = np.full((h, w), np.nan, np.float32)
    for x in range(w):  # z-buffer the left pixels into the right view
        for y in range(h):
            xr = int(x - left[y, x])
            if 0 <= xr < w and not right[y, xr] >= left[y, x]:
                right[y, xr] = left[y, x]
    left[0, 100] = np.nan
    mask = nonoccluded_from_right(left, right)
    assert (mask[:, :8] == OUTSIDE).all()
    assert (mask[1:, 38:50] == OCCLUDED).all()
    assert (mask[1:, 8:38] == VISIBLE).all()
    assert (mask[1:, 50:] == VISIBLE).all()
    assert mask[0, 100] == OCCLUDED  # no ground truth: nothing known
    with pytest.raises(ValueError, match='equal 2-D shapes'):
        nonoccluded_from_right(left, right[:, :5])
