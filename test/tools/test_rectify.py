"""Rectification: cached maps, R without distortion, binning/ROI, and accuracy of the node
on the bundled bags against the simulator's rectified renders and row alignment."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import REPO

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.rectify import Rectifier, interpolation_flag, rectify_image
from depth_nodes.errors import CalibrationError
from depth_nodes.graph.description import load_graph_config
from depth_nodes.ros.camera_info import camera_info_to_model
from depth_nodes.ros.image import image_to_array, to_gray
from depth_nodes.sim import StereoSimConfig, simulate_stereo
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bags.process import process_bag
from depth_nodes.tools.bench.rectify import bench_rectify
from depth_nodes.tools.evaluation.evaluate import evaluate_bag

pytestmark = pytest.mark.slow

BAGS = REPO / 'bags'
MARGIN = 16  # px left out at the image border, where a remap samples near the raw edge


def _frame(**overrides: object):
    config = StereoSimConfig(width=240, height=180, n_frames=1, seed=4, noise_sigma=0.0,
                             **overrides)
    return config, next(simulate_stereo(config))


def _mad(a: np.ndarray, b: np.ndarray) -> float:
    diff = np.abs(a.astype(np.float32) - b.astype(np.float32))
    return float(diff[MARGIN:-MARGIN, MARGIN:-MARGIN].mean())


def vertical_misalignment(left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                          keep: np.ndarray, tiles: tuple[int, int] = (3, 4)) -> np.ndarray:
    """Per tile, the vertical offset dy (px) with left(x, y) ~ a * right(x - d, y + dy) + b.

    Lucas-Kanade in y with a gain/offset, two iterations, over the ``keep`` pixels.
    """
    h, w = left.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    L, R = left.astype(np.float32), right.astype(np.float32)
    out = np.full(tiles, np.nan)
    for ty in range(tiles[0]):
        for tx in range(tiles[1]):
            tile = np.zeros((h, w), bool)
            tile[ty * h // tiles[0]:(ty + 1) * h // tiles[0],
                 tx * w // tiles[1]:(tx + 1) * w // tiles[1]] = True
            mask = tile & keep
            dy = 0.0
            for _ in range(3):
                warped = cv2.remap(R, xs - disparity, (ys + dy).astype(np.float32),
                                   cv2.INTER_CUBIC)
                grad = cv2.Sobel(warped, cv2.CV_32F, 0, 1, ksize=3) / 8.0
                a_mat = np.column_stack([warped[mask], grad[mask], np.ones(mask.sum())])
                (gain, c, _), *_ = np.linalg.lstsq(a_mat, L[mask], rcond=None)
                dy += c / gain
            out[ty, tx] = dy
    return out


def test_interpolation_names_and_codes() -> None:
    assert interpolation_flag('nearest') == cv2.INTER_NEAREST
    assert interpolation_flag('Lanczos4') == cv2.INTER_LANCZOS4
    assert interpolation_flag(2) == cv2.INTER_CUBIC
    for bad in ('bilinear', 7, True, 1.0):
        with pytest.raises(ValueError, match='interpolation must be one of nearest'):
            interpolation_flag(bad)  # type: ignore[arg-type]


def test_maps_are_built_once_and_rebuilt_only_on_change() -> None:
    _, frame = _frame()
    rectifier = Rectifier()
    for _ in range(5):
        rectifier.rectify(frame.left_raw, frame.left_camera)
    assert rectifier.rebuilds == 1
    same = dataclasses.replace(frame.left_camera, K=frame.left_camera.K.copy())
    rectifier.rectify(frame.left_raw, same)
    assert rectifier.rebuilds == 1
    changed = dataclasses.replace(frame.left_camera, D=frame.left_camera.D * 0.5)
    rectifier.rectify(frame.left_raw, changed)
    assert rectifier.rebuilds == 2
    with pytest.raises(CalibrationError, match='K is all zero'):
        rectifier.rectify(frame.left_raw, dataclasses.replace(changed, K=np.zeros((3, 3))))
    rectifier.rectify(frame.left_raw, changed)
    assert rectifier.rebuilds == 2, 'a bad calibration must not evict the cached maps'
    with pytest.raises(ValueError, match='image is 120x90 but the camera_info describes'):
        rectifier.rectify(frame.left_raw[::2, ::2], changed)


def test_rotation_is_applied_without_distortion() -> None:
    """Pure rotation, zero distortion: image_proc would skip this; we must not."""
    _, frame = _frame(distortion_scale=0.0, rotation_deg=2.0)
    for raw, truth, camera in ((frame.left_raw, frame.left_rect_gt, frame.left_camera),
                               (frame.right_raw, frame.right_rect_gt, frame.right_camera)):
        assert not camera.D.any()
        assert _mad(rectify_image(raw, camera), truth) < 1.5
        unrotated = dataclasses.replace(camera, R=np.eye(3))
        assert _mad(rectify_image(raw, unrotated), truth) > 5.0


@pytest.mark.parametrize('model', ['plumb_bob', 'rational_polynomial', 'equidistant'])
def test_roi_and_binning_match_the_full_image(model: str) -> None:
    _, frame = _frame(distortion_model=model)
    camera: CameraModel = frame.left_camera
    full = rectify_image(frame.left_raw, camera).astype(np.float32)
    x0, y0, rw, rh = 40, 30, 160, 120
    roi_cam = dataclasses.replace(camera, roi=(x0, y0, rw, rh, True))
    crop = rectify_image(np.ascontiguousarray(frame.left_raw[y0:y0 + rh, x0:x0 + rw]), roi_cam)
    # inside, both sample the same raw pixels: equal up to fixed-point map rounding
    inner = np.abs(crop.astype(np.float32) - full[y0:y0 + rh, x0:x0 + rw])[12:-12, 12:-12]
    assert inner.mean() < 0.5
    binned_raw = cv2.resize(frame.left_raw, (120, 90), interpolation=cv2.INTER_AREA)
    binned_cam = dataclasses.replace(camera, binning_x=2, binning_y=2)
    binned = rectify_image(binned_raw, binned_cam)
    assert binned.shape == (90, 120)
    reference = cv2.resize(full, (120, 90), interpolation=cv2.INTER_AREA)
    assert np.abs(binned - reference)[6:-6, 6:-6].mean() < 4.0


@pytest.fixture(scope='module')
def processed(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Every bundled bag replayed through the default pipeline's rectifiers."""
    out = {}
    config = load_graph_config(REPO / 'config' / 'stereo_pipeline.yaml')
    for bag in sorted(BAGS.iterdir()):
        target = tmp_path_factory.mktemp('rect') / bag.name
        report = process_bag(bag, target, config=config)
        assert sum(sum(c.values()) for c in report.drops.values()) == 0
        out[bag.name] = target
    return out


def _topics(bag: Path, topics: list[str]) -> dict[str, list[object]]:
    found: dict[str, list[object]] = {}
    with BagReader(bag) as reader:
        for m in reader.messages(topics):
            found.setdefault(m.topic, []).append(m.deserialize())
    return found


@pytest.mark.parametrize('bag', ['stereo_vga', 'stereo_qvga_color', 'stereo_qvga_fisheye'])
def test_node_output_matches_ground_truth_renders(processed: dict[str, Path], bag: str) -> None:
    """Mean |image_rect - image_rect_gt| under 2.5 grey levels inside the margin (the raw
    images carry noise of sigma 2, so about 1.5 is the floor), every frame, both sides."""
    for side in ('left', 'right'):
        msgs = _topics(processed[bag], [f'/stereo/{side}/image_rect',
                                        f'/stereo/{side}/image_rect_gt'])
        rect, truth = msgs[f'/stereo/{side}/image_rect'], msgs[f'/stereo/{side}/image_rect_gt']
        assert len(rect) == len(truth) > 0
        for out_msg, gt_msg in zip(rect, truth, strict=True):
            assert out_msg.header.stamp == gt_msg.header.stamp
            assert out_msg.encoding == 'mono8'
            expected = to_gray(image_to_array(gt_msg), gt_msg.encoding)
            assert _mad(image_to_array(out_msg), expected) < 2.5, (bag, side)


def test_colour_input_gives_colour_and_mono(processed: dict[str, Path]) -> None:
    msgs = _topics(processed['stereo_qvga_color'], ['/stereo/left/image_rect_color',
                                                    '/stereo/left/image_rect_gt'])
    (color, *_), (truth, *_) = msgs['/stereo/left/image_rect_color'], msgs[
        '/stereo/left/image_rect_gt']
    assert color.encoding == 'rgb8'
    assert _mad(image_to_array(color), image_to_array(truth)) < 2.5
    with BagReader(processed['stereo_vga']) as reader:
        assert '/stereo/left/image_rect_color' not in reader.topics


def _project_raw(camera: CameraModel, points_rect: np.ndarray) -> np.ndarray:
    """Exact raw pixel of 3-D points given in the camera's rectified frame (OpenCV's forward
    distortion model, independent of the undistortion the maps are built with)."""
    rvec, _ = cv2.Rodrigues(np.asarray(camera.R).T)
    pts = points_rect.reshape(-1, 1, 3).astype(np.float64)
    if camera.distortion_model == 'equidistant':
        raw, _ = cv2.fisheye.projectPoints(pts, rvec, np.zeros(3), camera.K, camera.D)
    else:
        raw, _ = cv2.projectPoints(pts, rvec, np.zeros(3), camera.K, camera.D)
    return raw.reshape(-1, 2)


def _rectified_position(rectifier: Rectifier, camera: CameraModel, raw: np.ndarray,
                        guess: np.ndarray) -> np.ndarray:
    """Where the node's maps put raw points: solve map(p) = raw by Newton iteration on the
    bilinearly interpolated maps the node itself remaps with."""
    map1, map2 = rectifier.maps(camera)
    mx, my = cv2.convertMaps(map1, map2, cv2.CV_32FC1)
    p = guess.astype(np.float32).copy()

    def sample(q: np.ndarray) -> np.ndarray:
        qx, qy = q[:, 0].reshape(1, -1), q[:, 1].reshape(1, -1)
        return np.column_stack([cv2.remap(m, qx, qy, cv2.INTER_LINEAR).ravel()
                                for m in (mx, my)])

    dx, dy = np.array([0.5, 0], np.float32), np.array([0, 0.5], np.float32)
    for _ in range(8):
        here = sample(p)
        jx = sample(p + dx) - sample(p - dx)  # per px: divided by 2 * 0.5
        jy = sample(p + dy) - sample(p - dy)
        jac = np.stack([jx, jy], axis=2)  # d map / d (x, y)
        p -= np.linalg.solve(jac, (here - raw)[:, :, None])[:, :, 0].astype(np.float32)
    return p


@pytest.mark.parametrize('bag', ['stereo_vga', 'stereo_qvga_color', 'stereo_qvga_fisheye'])
def test_corresponding_points_share_a_row(bag: str) -> None:
    """A scene point lands on the same row in the node's left and right rectified images
    to well under 0.1 px.

    For a grid of left pixels, the ground-truth depth gives the 3-D point; its exact raw
    pixel in each camera comes from OpenCV's forward distortion model with the bag's
    CameraInfo; the point's position in each rectified image is where the rectifier's maps
    (the ones it remaps with, fixed-point included) send it.
    """
    names = ['/stereo/left/camera_info', '/stereo/right/camera_info', '/stereo/left/depth_gt']
    msgs = _topics(BAGS / bag, names)
    left, right = (camera_info_to_model(msgs[n][0]) for n in names[:2])
    depth = image_to_array(msgs[names[2]][0])
    h, w = depth.shape
    v, u = (g.ravel().astype(np.float64) for g in np.mgrid[MARGIN:h - MARGIN:8,
                                                         MARGIN:w - MARGIN:8])
    P = left.projection
    z = depth[v.astype(int), u.astype(int)]
    points = np.column_stack([(u - P[0, 2]) / P[0, 0] * z, (v - P[1, 2]) / P[1, 1] * z, z])
    baseline = -right.projection[0, 3] / right.projection[0, 0]
    u_right = right.projection[0, 0] * (points[:, 0] - baseline) / z + right.projection[0, 2]
    inside = (u_right > MARGIN) & (u_right < w - MARGIN)
    rect_left = _rectified_position(Rectifier(), left, _project_raw(left, points[inside]),
                                    np.column_stack([u, v])[inside])
    offset = points[inside] - [baseline, 0.0, 0.0]
    rect_right = _rectified_position(Rectifier(), right, _project_raw(right, offset),
                                     np.column_stack([u_right, v])[inside])
    assert inside.sum() > 500
    np.testing.assert_allclose(rect_left, np.column_stack([u, v])[inside], atol=0.05)
    row_error = np.abs(rect_left[:, 1] - rect_right[:, 1])
    assert row_error.max() < 0.05, (bag, row_error.max())


def test_eval_reports_rectification_accuracy(processed: dict[str, Path]) -> None:
    report = evaluate_bag(processed['stereo_qvga_fisheye'], baselines=False)
    assert set(report.rectification_mad) == {'left', 'right'}
    assert all(0.5 < mad < 2.5 for mad in report.rectification_mad.values())
    assert 'rectified left vs ground-truth render: mean |diff|' in report.format()


def test_bench_command_prints_its_figures() -> None:
    cv2.setNumThreads(2)  # as `depth-nodes bench rectify --threads 2` does (restored by conftest)
    result = bench_rectify(width=160, height=120, repeats=3)
    # the node's own `threads` parameter follows the caller's setting instead of
    # resetting OpenCV to its default of 1 thread for the baselines timed after it
    assert result.threads == cv2.getNumThreads() == 2
    assert min(result.node_ms, result.remap_ms, result.undistort_ms) > 0
    text = result.format()
    assert 'node / remap' in text
    assert 'node / undistort' in text
