"""`depth-nodes eval`: exact scores on hand-made estimates, the OpenCV reference, errors."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import run_cli
from ros_helpers import header
from std_msgs.msg import Header

from depth_nodes.errors import BagError
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image
from depth_nodes.tools.bags.io import BagWriter
from depth_nodes.tools.evaluation.evaluate import evaluate_bag
from depth_nodes.tools.evaluation.previews import BAR_WIDTH, TITLE_HEIGHT

H, W, D = 60, 96, 8.0
N_FRAMES = 2


def _left(i: int) -> Header:
    """The header of frame ``i``: left camera, 10 + i seconds."""
    return header((10 + i) * 10**9, 'left')


def _scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A fronto-parallel textured plane at disparity D: right(x) = left(x + D)."""
    wide = cv2.GaussianBlur(rng.integers(0, 256, (H, W + 16)).astype(np.float32), (3, 3), 0)
    left = wide[:, 8:8 + W]
    right = wide[:, 8 + int(D):8 + int(D) + W]
    return left.astype(np.uint8), right.astype(np.uint8)


def _bag(path: Path, with_estimate: bool = True) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(1)
    bad = rng.random((H, W)) < 0.1
    invalid = ~bad & (rng.random((H, W)) < 0.1)
    gt = np.full((H, W), D, np.float32)
    est = gt.copy()
    est[bad] += 5.0
    est[invalid] = np.nan
    occlusion = np.zeros((H, W), np.uint8)
    occlusion[:, :4] = 255
    with BagWriter(path) as writer:
        for i in range(N_FRAMES):
            h, t = _left(i), (10 + i) * 10**9
            left, right = _scene(rng)
            writer.write('/stereo/left/image_rect', array_to_image(left, 'mono8', h), t)
            writer.write('/stereo/right/image_rect', array_to_image(right, 'mono8', h), t)
            writer.write('/stereo/left/disparity_gt', build_disparity(
                gt, h, focal=100.0, baseline=0.1, min_disparity=0.0, max_disparity=D,
                delta_d=0.0), t)
            writer.write('/stereo/left/occlusion_gt', array_to_image(occlusion, 'mono8', h), t)
            if with_estimate:
                writer.write('/stereo/disparity', build_disparity(
                    est, h, focal=100.0, baseline=0.1, min_disparity=0.0, max_disparity=15.0,
                    delta_d=1 / 16), t)
                conf = np.where(bad, 0.1, np.where(invalid, 0.0, 0.9)).astype(np.float32)
                writer.write('/stereo/confidence', array_to_image(conf, '32FC1', h), t)
                depth = np.full((H, W), 1.25 * 1.01, np.float32)  # truth: f B / d = 1.25 m
                depth[invalid] = np.nan
                writer.write('/stereo/depth', array_to_image(depth, '32FC1', h), t)
            writer.write('/stereo/left/depth_gt',
                         array_to_image(np.full((H, W), 1.25, np.float32), '32FC1', h), t)
    return bad, invalid


def test_scores_match_hand_computed_values(tmp_path: Path) -> None:
    bad, invalid = _bag(tmp_path / 'bag')
    report = evaluate_bag(tmp_path / 'bag', previews=tmp_path / 'png')
    drawn = sorted((tmp_path / 'png').glob('*.png'))
    assert [p.name.split('_', 1)[1] for p in drawn] == ['sheet.png'] * N_FRAMES
    sheet = cv2.imread(str(drawn[0]))
    # rows: disparities (the truth, ours, stereo_image_proc's), their errors, the depths,
    # the confidence; each row the left image's width more, and a colour bar
    assert sheet.shape[0] == 4 * (H + TITLE_HEIGHT)
    assert sheet.shape[1] == 4 * W + BAR_WIDTH
    rows = {r.method: r for r in report.rows}
    ours = rows['/stereo/disparity']
    n = bad.size
    assert ours.frames == N_FRAMES
    assert ours.missing_frames == 0
    assert ours.bad_dense == pytest.approx((bad.sum() + invalid.sum()) / n)
    assert ours.bad_sparse == pytest.approx(bad.sum() / (n - invalid.sum()))
    assert ours.density == pytest.approx(1 - invalid.sum() / n)
    assert ours.avgerr == pytest.approx(5.0 * bad.sum() / (n - invalid.sum()))
    visible = np.ones((H, W), bool)
    visible[:, :4] = False
    assert ours.bad_dense_nonocc == pytest.approx(
        ((bad | invalid) & visible).sum() / visible.sum())
    # every bad or invalid pixel has a lower confidence than every good one: optimal ranking
    assert ours.auc_ratio == pytest.approx(1.0, abs=0.01)
    assert report.gt_range == (D, D)
    depth = report.depth['/stereo/depth']
    assert depth.mae == pytest.approx(0.0125, rel=1e-4)
    assert depth.rel == pytest.approx(0.01, rel=1e-4)
    assert depth.density == pytest.approx(1 - invalid.sum() / n)
    assert 'depth /stereo/depth vs ground truth: mean |dZ| 12.5 mm' in report.format()
    assert report.size == (W, H)
    # bad-1: the bad pixels are off by 5 px, the others exact
    assert ours.bad1_dense == pytest.approx(ours.bad_dense)
    assert ours.bad1_dense_nonocc == pytest.approx(ours.bad_dense_nonocc)
    assert ours.bad1_sparse_nonocc == pytest.approx(
        (bad & visible & ~invalid).sum() / (visible & ~invalid).sum())
    assert ours.density_nonocc == pytest.approx((visible & ~invalid).sum() / visible.sum())
    assert report.nonocc_source == '/stereo/left/occlusion_gt'
    assert report.nonocc_fraction == pytest.approx(visible.mean())
    # the OpenCV reference ran on the same rectified pair and does well on this easy plane:
    # stereo_image_proc's defaults, every setting of the grid, and the grid's best
    assert len(report.grid) == 18
    for row in [rows['opencv SGBM MODE_SGBM, stereo_image_proc defaults'], *report.grid]:
        assert row.bad_sparse_nonocc < 0.05, row.method
        assert row.density > 0.5, row.method
    best = report.opencv_best('bad_dense')
    assert best.bad_dense == min(r.bad_dense for r in report.grid)
    assert rows[f'opencv best of 18 by bad-2: {best.method.removeprefix("opencv ")}'] == \
        dataclasses.replace(best, method=f'opencv best of 18 by bad-2: '
                                         f'{best.method.removeprefix("opencv ")}')
    text = report.format()
    assert 'opencv SGBM MODE_SGBM, stereo_image_proc defaults' in text
    assert 'opencv best of 18 by nonocc bad-1:' in text
    assert best.method not in text  # grid rows only with grid=True
    assert best.method in report.format(grid=True)
    pngs = sorted(p.name for p in (tmp_path / 'png').iterdir())
    assert len(pngs) == N_FRAMES  # one sheet a frame


def test_missing_estimate_frames_are_counted_as_invalid(tmp_path: Path) -> None:
    _bag(tmp_path / 'bag', with_estimate=False)
    with BagWriter(tmp_path / 'partial') as writer:
        h = _left(0)
        writer.write('/stereo/left/disparity_gt', build_disparity(
            np.full((H, W), D, np.float32), h, focal=1.0, baseline=1.0, min_disparity=0.0,
            max_disparity=D, delta_d=0.0), 10**10)
        writer.write('/stereo/left/disparity_gt', build_disparity(
            np.full((H, W), D, np.float32), _left(1), focal=1.0, baseline=1.0,
            min_disparity=0.0, max_disparity=D, delta_d=0.0), 11 * 10**9)
        writer.write('/stereo/disparity', build_disparity(
            np.full((H, W), D, np.float32), h, focal=1.0, baseline=1.0, min_disparity=0.0,
            max_disparity=D, delta_d=0.0), 10**10)
    report = evaluate_bag(tmp_path / 'partial', baselines=False)
    (row,) = report.rows
    assert row.missing_frames == 1
    assert row.bad_dense == pytest.approx(0.5)
    assert row.bad_sparse == 0.0
    assert '1 frames missing' in report.format()


def test_bag_without_ground_truth(tmp_path: Path) -> None:
    with BagWriter(tmp_path / 'bag') as writer:
        writer.write('/x', array_to_image(np.zeros((2, 2), np.uint8), 'mono8'), 1)
    with pytest.raises(BagError, match='has no ground-truth topic'):
        evaluate_bag(tmp_path / 'bag')
    result = run_cli(['eval', str(tmp_path / 'bag')])
    assert result.returncode == 1
    assert len(result.stderr.strip().splitlines()) == 1
    assert 'depth-nodes eval: error:' in result.stderr


def test_baseline_needs_images(tmp_path: Path) -> None:
    with BagWriter(tmp_path / 'bag') as writer:
        writer.write('/stereo/left/disparity_gt', build_disparity(
            np.full((H, W), D, np.float32), _left(0), focal=1.0, baseline=1.0,
            min_disparity=0.0, max_disparity=D, delta_d=0.0), 1)
    with pytest.raises(BagError, match='cannot run the OpenCV baseline'):
        evaluate_bag(tmp_path / 'bag')
    assert evaluate_bag(tmp_path / 'bag', baselines=False).rows == []


def test_confidence_is_scored_over_the_raw_pixels_and_its_own(tmp_path: Path) -> None:
    """A raw disparity with holes and 10 % wrong pixels, its checked version dense: the
    confidence's first AUC ranks the raw errors over the raw pixels only (a dropped pixel
    is not an error ranked last), the second the checked output's errors over its pixels."""
    rng = np.random.default_rng(5)
    gt = np.full((H, W), D, np.float32)
    raw = gt.copy()
    wrong = rng.random((H, W)) < 0.1
    raw[wrong] += 4.0
    holes = ~wrong & (rng.random((H, W)) < 0.2)
    raw[holes] = np.nan
    checked = gt.copy()
    filled_wrong = holes & (rng.random((H, W)) < 0.5)  # half the filled pixels are wrong
    checked[filled_wrong] += 3.0
    checked[wrong] += 4.0
    # confident where the raw pixel is right; the wrong raw pixels least confident
    conf = np.where(wrong, 0.05, np.where(holes, 0.1, 0.9)).astype(np.float32)
    with BagWriter(tmp_path / 'bag') as writer:
        h = _left(0)
        common = {'focal': 1.0, 'baseline': 1.0, 'min_disparity': 0.0, 'max_disparity': 15.0,
                  'delta_d': 1 / 32}
        writer.write('/stereo/left/disparity_gt', build_disparity(gt, h, **common), 1)
        writer.write('/stereo/disparity', build_disparity(raw, h, **common), 1)
        writer.write('/stereo/disparity_checked', build_disparity(checked, h, **common), 1)
        writer.write('/stereo/confidence', array_to_image(conf, '32FC1', h), 1)
    report = evaluate_bag(tmp_path / 'bag', baselines=False)
    row = report.row('/stereo/disparity_checked')
    assert report.row('/stereo/disparity').auc_ratio is None
    assert report.nonocc_source is None
    assert report.nonocc_fraction == 1.0
    # over the raw pixels the wrong ones are ranked last: optimal
    assert row.auc_ratio == pytest.approx(1.0, abs=0.01)
    # over its own pixels (all of them) half the filled ones are wrong at confidence 0.1,
    # ranked among right ones: no longer optimal
    assert row.auc_ratio_own is not None
    assert row.auc_ratio_own > 1.05
    with pytest.raises(KeyError):
        report.row('/stereo/nothing')
    with pytest.raises(ValueError, match='grid did not run'):
        report.opencv_best()
