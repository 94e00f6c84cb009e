"""`depth-nodes import-pair` as a user runs it: a pair of files in, a bag out that
`process` and `eval` take; every input a user can get wrong ends in one line and status 1."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import REAL_DATA, run_cli

from depth_nodes.core.camera import CameraModel, write_camera_yaml
from depth_nodes.ros.camera_info import camera_info_to_model
from depth_nodes.ros.disparity import read_disparity
from depth_nodes.ros.image import image_to_array
from depth_nodes.tools.bags.io import BagReader

pytestmark = pytest.mark.slow

TEDDY = REAL_DATA / 'teddy'


def _plane(tmp_path: Path, d: int = 6) -> tuple[Path, Path, Path]:
    """A textured fronto-parallel plane at disparity ``d``: files left, right, KITTI GT."""
    rng = np.random.default_rng(0)
    wide = cv2.GaussianBlur(rng.integers(0, 256, (60, 100 + d)).astype(np.float32), (3, 3), 0)
    # left(x) = right(x - d)
    left, right = wide[:, :100].astype(np.uint8), wide[:, d:].astype(np.uint8)
    gt = np.full((60, 100), d * 256, np.uint16)
    paths = tmp_path / 'l.png', tmp_path / 'r.png', tmp_path / 'gt.png'
    for path, img in zip(paths, (left, right, gt), strict=True):
        cv2.imwrite(str(path), img)
    return paths


def _messages(bag: Path) -> dict[str, object]:
    with BagReader(bag) as reader:
        return {m.topic: m.deserialize() for m in reader.messages()}


def test_a_middlebury_pair_from_the_shell(tmp_path: Path) -> None:
    result = run_cli(['import-pair', str(TEDDY / 'im2.png'), str(TEDDY / 'im6.png'),
                      str(tmp_path / 'bag'), '--gt', str(TEDDY / 'disp2.pgm'), '--gt-scale',
                      '4', '--gt-right', str(TEDDY / 'disp6.pgm'), '--mono', '--frames', '2'])
    assert result.returncode == 0, result.stderr
    assert 'ground truth 12.50..52.75 px: search at least 0..53 (e.g. disparity_range 64)' \
        in result.stdout
    assert 'non-occluded pixels (derived from the right ground truth): 89.1%' in result.stdout
    msgs = _messages(tmp_path / 'bag')
    assert msgs['/stereo/left/image_raw'].encoding == 'mono8'  # type: ignore[attr-defined]
    with BagReader(tmp_path / 'bag') as reader:
        stamps = [m.timestamp for m in reader.messages(['/stereo/left/image_raw'])]
    assert np.diff(stamps).tolist() == [100_000_000]


def test_import_process_eval_chain(tmp_path: Path) -> None:
    """A KITTI-format ground truth (auto-detected), another namespace, then the shipped graph
    told where the cameras are, and eval scoring it."""
    left, right, gt = _plane(tmp_path)
    result = run_cli(['import-pair', str(left), str(right), str(tmp_path / 'bag'), '--gt',
                      str(gt), '--namespace', '/stereo', '--focal', '80', '--baseline', '0.2'])
    assert result.returncode == 0, result.stderr
    assert 'non-occluded' not in result.stdout  # no right ground truth, no mask
    msgs = _messages(tmp_path / 'bag')
    truth = read_disparity(msgs['/stereo/left/disparity_gt'])
    assert (truth.disparity == 6.0).all()
    assert (truth.focal, truth.baseline) == pytest.approx((80.0, 0.2))
    params = tmp_path / 'p.yaml'
    params.write_text('/stereo/sgm_stereo:\n  ros__parameters: {disparity_range: 16}\n')
    processed = run_cli(['process', str(tmp_path / 'bag'), str(tmp_path / 'out'), '--params',
                         str(params)])
    assert processed.returncode == 0, processed.stderr
    evaluated = run_cli(['eval', str(tmp_path / 'out')])
    assert evaluated.returncode == 0, evaluated.stderr
    rows = {line.split()[0]: line.split() for line in evaluated.stdout.splitlines()
            if line.startswith('/stereo/')}
    assert float(rows['/stereo/disparity_checked'][4]) < 0.05  # bad-2 dense on a plane
    assert 'no occlusion topic' in evaluated.stdout


def test_a_raw_pair_with_its_calibration(tmp_path: Path) -> None:
    left, right, _ = _plane(tmp_path)
    K = np.array([[90.0, 0, 49.5], [0, 90.0, 29.5], [0, 0, 1]])
    cams = []
    for side, tx in (('left', 0.0), ('right', -9.0)):
        P = np.hstack([K, [[tx], [0], [0]]])
        model = CameraModel(100, 60, K, np.array([0.01, 0, 0, 0, 0]), np.eye(3), P)
        write_camera_yaml(tmp_path / f'{side}.yaml', model, side)
        cams.append(tmp_path / f'{side}.yaml')
    result = run_cli(['import-pair', str(left), str(right), str(tmp_path / 'bag'),
                      '--calibration', *map(str, cams)])
    assert result.returncode == 0, result.stderr
    assert 'no ground truth' in result.stdout
    msgs = _messages(tmp_path / 'bag')
    model = camera_info_to_model(msgs['/stereo/right/camera_info'])
    assert model.D[0] == pytest.approx(0.01)
    assert model.P[0, 3] == pytest.approx(-9.0)
    assert (image_to_array(msgs['/stereo/left/image_raw']) == cv2.imread(str(left), 0)).all()


def test_a_mask_gives_the_non_occluded_pixels(tmp_path: Path) -> None:
    left, right, gt = _plane(tmp_path)
    mask = np.full((60, 100), 255, np.uint8)
    mask[:, :10] = 0
    cv2.imwrite(str(tmp_path / 'nonocc.png'), mask)
    result = run_cli(['import-pair', str(left), str(right), str(tmp_path / 'bag'), '--gt',
                      str(gt), '--nonocc', str(tmp_path / 'nonocc.png')])
    assert result.returncode == 0, result.stderr
    assert 'non-occluded pixels (mask nonocc.png): 90.0%' in result.stdout
    occlusion = image_to_array(_messages(tmp_path / 'bag')['/stereo/left/occlusion_gt'])
    assert (occlusion[:, :10] == 255).all()
    assert (occlusion[:, 10:] == 0).all()


def _mistakes(tmp_path: Path) -> list[tuple[list[str], str]]:
    left, right, gt = _plane(tmp_path)
    small = tmp_path / 'small.png'
    cv2.imwrite(str(small), np.zeros((30, 50), np.uint8))
    colour = tmp_path / 'colour.png'
    cv2.imwrite(str(colour), np.zeros((60, 100, 3), np.uint8))
    empty = tmp_path / 'empty.png'
    cv2.imwrite(str(empty), np.zeros((60, 100), np.uint16))
    cal = tmp_path / 'cal.yaml'
    write_camera_yaml(cal, CameraModel(640, 480, np.array([[500.0, 0, 320], [0, 500, 240],
                                                          [0, 0, 1]])))
    out = str(tmp_path / 'out')
    return [
        ([str(tmp_path / 'nope.png'), str(right), out], 'nope.png: no such file'),
        ([str(left), str(small), out], 'small.png: 50x30 mono8, but the left image is 100x60'),
        ([str(left), str(colour), out], 'colour.png: 100x60 rgb8, but the left image is'),
        ([str(left), str(right), out, '--gt', str(small), '--gt-scale', '4'],
         'small.png: 50x30, the images are 100x60'),
        ([str(left), str(right), out, '--gt', str(left)], 'needs its scale'),
        ([str(left), str(right), out, '--gt', str(empty)], 'no pixel has a ground truth'),
        ([str(left), str(right), out, '--gt-right', str(gt)], 'needs the left ground truth'),
        ([str(left), str(right), out, '--gt', str(gt), '--nonocc', str(colour)],
         'a non-occlusion mask must be one channel'),
        ([str(left), str(right), out, '--calibration', str(cal), str(cal)],
         'calibrated for 640x480, but the images are 100x60'),
        ([str(left), str(right), out, '--frames', '0'], 'frames must be at least 1'),
        ([str(left), str(right), out, '--namespace', 'stereo'], 'namespace must start with /'),
        ([str(left), str(right), str(left)], 'l.png: it is a file, not a folder'),
        ([str(left), str(right), str(left), '--force'], 'l.png: it is a file, not a folder'),
        ([str(left), str(right), str(tmp_path), '--force'], f'{tmp_path}: not a bag folder'),
        ([str(left), str(right), str(left / 'bag')], 'l.png is a file, not a folder'),
    ]


def test_every_mistake_is_one_line(tmp_path: Path) -> None:
    for args, message in _mistakes(tmp_path):
        result = run_cli(['import-pair', *args])
        assert result.returncode == 1, (args, result.stdout, result.stderr)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1, result.stderr
        assert lines[0].startswith('depth-nodes import-pair: error: '), lines
        assert message in lines[0], (message, lines[0])
    (tmp_path / 'taken').mkdir()
    (tmp_path / 'taken' / 'metadata.yaml').write_text('x')
    left, right, _ = _plane(tmp_path)
    exists = run_cli(['import-pair', str(left), str(right), str(tmp_path / 'taken')])
    assert exists.returncode == 1
    assert 'exists already' in exists.stderr
