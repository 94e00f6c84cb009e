"""`eval --previews` on any bag: a sheet a frame, the left image and the colour-mapped maps
side by side, a row per kind over one range with one colour bar, for a user's own
recording without ground truth too (depth_nodes.tools.evaluation.previews)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import run_cli
from std_msgs.msg import Header

from depth_nodes.errors import BagError, ConfigError
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image
from depth_nodes.tools.bags.io import BagWriter
from depth_nodes.tools.evaluation.previews import (
    BAR_WIDTH,
    TITLE_HEIGHT,
    MapView,
    bag_previews,
    colour,
    colour_bar,
    sheet_rows,
)

H, W = 40, 60


def _bag(path: Path, frames: int = 3) -> np.ndarray:
    """Disparity, depth (16UC1 mm) and confidence under /cam, no ground truth."""
    disparity = np.tile(np.linspace(5, 30, W, dtype=np.float32), (H, 1))
    disparity[:5, :5] = np.nan
    with BagWriter(path) as writer:
        for i in range(frames):
            header = Header()
            header.stamp.sec = 10 + i
            t = (10 + i) * 1_000_000_000
            writer.write('/cam/left/image_rect', array_to_image(
                np.full((H, W), 90 + i, np.uint8), 'mono8', header), t)
            writer.write('/cam/disparity', build_disparity(
                disparity, header, focal=100.0, baseline=0.1, min_disparity=0,
                max_disparity=63, delta_d=1 / 16), t)
            depth = np.where(np.isfinite(disparity), 10_000 / np.nan_to_num(disparity, nan=1),
                             0).astype(np.uint16)
            writer.write('/cam/depth', array_to_image(depth, '16UC1', header), t)
            writer.write('/cam/confidence', array_to_image(
                np.full((H, W), 0.5, np.float32), '32FC1', header), t)
    return disparity


def test_colour_maps_the_range_and_blacks_out_missing_values() -> None:
    values = np.array([[0.0, 10.0, np.nan]], np.float32)
    img = colour(values, 0.0, 10.0, cv2.COLORMAP_TURBO)
    ramp = cv2.applyColorMap(np.array([[0, 255]], np.uint8), cv2.COLORMAP_TURBO)
    np.testing.assert_array_equal(img[0, :2], ramp[0])
    np.testing.assert_array_equal(img[0, 2], [0, 0, 0])
    bar = colour_bar(50, MapView('d', values, 0.0, 10.0))
    assert bar.shape == (50, BAR_WIDTH, 3)
    np.testing.assert_array_equal(bar[0, 10], ramp[0, 1])  # high at the top
    np.testing.assert_array_equal(bar[-1, 10], ramp[0, 0])


def test_previews_of_a_bag_without_ground_truth(tmp_path: Path) -> None:
    """One sheet a frame: rows disparity, depth, confidence; the left image first on the
    top row, each map under its title, a colour bar at each row's end."""
    disparity = _bag(tmp_path / 'bag')
    written = bag_previews(tmp_path / 'bag', tmp_path / 'png', max_frames=2)
    assert sorted(p.name for p in written) == ['10000000000_sheet.png', '11000000000_sheet.png']
    img = cv2.imread(str(tmp_path / 'png' / '10000000000_sheet.png'))
    row = H + TITLE_HEIGHT
    assert img.shape == (3 * row, 2 * W + BAR_WIDTH, 3)  # image | map | bar, three rows
    body = img[TITLE_HEIGHT:row]
    np.testing.assert_array_equal(body[:, :W], np.full((H, W, 3), 90, np.uint8))
    finite = disparity[np.isfinite(disparity)]
    low, high = np.percentile(finite, [1, 99])
    expected = colour(disparity, float(low), float(high), cv2.COLORMAP_TURBO)
    np.testing.assert_array_equal(body[:, W:2 * W], expected)
    assert not body[:5, W:W + 5].any()  # no disparity: black
    # the rows below start with white space where the left image is on the first
    assert (img[row + TITLE_HEIGHT:2 * row, :W] == 255).all()


def test_a_row_shares_one_range() -> None:
    a = MapView('a', np.zeros((2, 2)), 0.0, 10.0, kind='disparity')
    b = MapView('b', np.zeros((2, 2)), 2.0, 30.0, kind='disparity')
    c = MapView('c', np.zeros((2, 2)), 0.0, 1.0, kind='confidence')
    e = MapView('e', np.zeros((2, 2)), 0.0, 4.0, kind='error')
    rows = sheet_rows([c, b, e, a])
    assert [[v.name for v in row] for row in rows] == [['b', 'a'], ['e'], ['c']]
    assert {(v.low, v.high) for v in rows[0]} == {(0.0, 30.0)}


def test_eval_draws_a_bag_without_ground_truth_and_says_so(tmp_path: Path) -> None:
    _bag(tmp_path / 'bag', frames=1)
    refused = run_cli(['eval', str(tmp_path / 'bag')])
    assert refused.returncode == 1
    assert refused.stderr.count('\n') == 1
    assert 'has no ground truth' in refused.stderr
    assert '--previews DIR draws its disparity' in refused.stderr
    drawn = run_cli(['eval', str(tmp_path / 'bag'), '--previews', str(tmp_path / 'png')])
    assert drawn.returncode == 0, drawn.stderr
    assert 'no ground truth, nothing scored; 1 previews written' in drawn.stdout
    assert len(list((tmp_path / 'png').glob('*.png'))) == 1


def test_bad_requests_are_one_line_errors(tmp_path: Path) -> None:
    _bag(tmp_path / 'bag', frames=1)
    with pytest.raises(ConfigError, match='--preview-frames must be at least 1'):
        bag_previews(tmp_path / 'bag', tmp_path / 'png', max_frames=0)
    (tmp_path / 'file').write_text('')
    with pytest.raises(ConfigError, match='is a file'):
        bag_previews(tmp_path / 'bag', tmp_path / 'file' / 'png')
    with BagWriter(tmp_path / 'empty') as writer:
        writer.write('/x/left/image_rect', array_to_image(np.zeros((2, 2), np.uint8), 'mono8'),
                     1)
    with pytest.raises(BagError, match='holds no disparity, depth or confidence topic'):
        bag_previews(tmp_path / 'empty', tmp_path / 'png')


def test_a_colour_left_image_keeps_its_colours_and_the_maps_their_values(
        tmp_path: Path) -> None:
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[:, :, 0] = 200  # red: would turn blue if the channels were swapped
    depth = np.full((H, W), 2000, np.uint16)  # 2 m in millimetres
    with BagWriter(tmp_path / 'bag') as writer:
        header = Header()
        header.stamp.sec = 3
        writer.write('/cam/left/image_rect_color', array_to_image(rgb, 'rgb8', header), 1)
        writer.write('/cam/depth', array_to_image(depth, '16UC1', header), 1)
        writer.write('/cam/confidence', array_to_image(
            np.full((H, W), 0.25, np.float32), '32FC1', header), 1)
    bag_previews(tmp_path / 'bag', tmp_path / 'png')
    img = cv2.imread(str(tmp_path / 'png' / '3000000000_sheet.png'))
    row = H + TITLE_HEIGHT
    depth_row = img[TITLE_HEIGHT:row]  # rows: depth, confidence
    np.testing.assert_array_equal(depth_row[0, 0], [0, 0, 200])  # BGR on disk: red
    expected = colour(np.full((1, 1), 2.0, np.float32), 0.0, 2.0, cv2.COLORMAP_TURBO)
    np.testing.assert_array_equal(depth_row[H // 2, W + W // 2], expected[0, 0])  # 2 m: top
    conf = img[row + TITLE_HEIGHT:2 * row]
    expected = colour(np.full((1, 1), 0.25, np.float32), 0.0, 1.0, cv2.COLORMAP_VIRIDIS)
    np.testing.assert_array_equal(conf[H // 2, W + W // 2], expected[0, 0])
