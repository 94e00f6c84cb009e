"""`depth-nodes generate`: the bag's topics, read back with the rosbags deserialiser, agree
with each other and with the simulator's geometry."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import run_cli
from rosbags.typesys import Stores, get_typestore

from depth_nodes.sim import StereoSimConfig
from depth_nodes.tools.bags.generate import config_from_metadata, write_stereo_bag
from depth_nodes.tools.bags.io import BagReader

pytestmark = pytest.mark.slow

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
CONFIG = StereoSimConfig(width=160, height=120, n_frames=2, seed=5, colour=True,
                         distortion_model='rational_polynomial', right_cx_offset=2.5)
TOPICS = {
    '/stereo/left/image_raw': 'sensor_msgs/msg/Image',
    '/stereo/left/camera_info': 'sensor_msgs/msg/CameraInfo',
    '/stereo/right/image_raw': 'sensor_msgs/msg/Image',
    '/stereo/right/camera_info': 'sensor_msgs/msg/CameraInfo',
    '/stereo/left/image_rect_gt': 'sensor_msgs/msg/Image',
    '/stereo/right/image_rect_gt': 'sensor_msgs/msg/Image',
    '/stereo/left/disparity_gt': 'stereo_msgs/msg/DisparityImage',
    '/stereo/left/depth_gt': 'sensor_msgs/msg/Image',
    '/stereo/left/occlusion_gt': 'sensor_msgs/msg/Image',
}


def _pixels(msg: object) -> np.ndarray:
    """Decode an Image by hand from the rosbags message (independent of depth_nodes.ros)."""
    dtype = {'mono8': np.uint8, 'rgb8': np.uint8, '32FC1': np.float32}[msg.encoding]
    channels = 3 if msg.encoding == 'rgb8' else 1
    rows = np.asarray(msg.data).reshape(msg.height, msg.step)
    flat = rows[:, : msg.width * channels * np.dtype(dtype).itemsize].copy().view(dtype)
    return flat.reshape(msg.height, msg.width, channels).squeeze()


@pytest.fixture(scope='module')
def frames(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, object]]]:
    path = tmp_path_factory.mktemp('gen') / 'bag'
    assert write_stereo_bag(path, CONFIG) == len(TOPICS) * CONFIG.n_frames
    by_stamp: dict[int, dict[str, object]] = {}
    with BagReader(path) as reader:
        assert reader.topics == TOPICS
        assert config_from_metadata(reader.custom_data, path) == CONFIG
        for m in reader.messages():
            msg = TYPESTORE.deserialize_cdr(m.data, m.msgtype)
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            assert stamp == m.timestamp, m.topic
            by_stamp.setdefault(stamp, {})[m.topic] = msg
    assert len(by_stamp) == CONFIG.n_frames
    period = np.diff(sorted(by_stamp))
    assert (period == 10**9 / CONFIG.frame_rate_hz).all()
    return path, [by_stamp[s] for s in sorted(by_stamp)]


def test_every_frame_has_every_topic(frames: tuple[Path, list[dict[str, object]]]) -> None:
    for frame in frames[1]:
        assert set(frame) == set(TOPICS)
        assert frame['/stereo/left/image_raw'].encoding == 'rgb8'
        assert frame['/stereo/left/depth_gt'].encoding == '32FC1'
        assert frame['/stereo/left/camera_info'].distortion_model == 'rational_polynomial'
        assert len(frame['/stereo/left/camera_info'].d) == 8
        assert frame['/stereo/left/image_raw'].header.frame_id == 'left_camera_optical_frame'
        assert frame['/stereo/right/image_raw'].header.frame_id == 'right_camera_optical_frame'


def test_disparity_depth_and_calibration_agree(frames: tuple[Path, list[dict[str, object]]]
                                               ) -> None:
    for frame in frames[1]:
        left_p = np.asarray(frame['/stereo/left/camera_info'].p).reshape(3, 4)
        right_p = np.asarray(frame['/stereo/right/camera_info'].p).reshape(3, 4)
        f, baseline = left_p[0, 0], -right_p[0, 3] / right_p[0, 0]
        assert baseline == pytest.approx(CONFIG.baseline_m)
        assert right_p[0, 2] - left_p[0, 2] == pytest.approx(CONFIG.right_cx_offset)
        gt_msg = frame['/stereo/left/disparity_gt']
        assert gt_msg.f == pytest.approx(f)
        assert gt_msg.t == pytest.approx(baseline)
        disparity = _pixels(gt_msg.image)
        depth = _pixels(frame['/stereo/left/depth_gt'])
        assert np.isfinite(disparity).all()
        assert gt_msg.min_disparity <= disparity.min()
        assert disparity.max() <= gt_msg.max_disparity
        # Z = f B / (d - (cx_left - cx_right))
        expected = f * baseline / (disparity + CONFIG.right_cx_offset)
        np.testing.assert_allclose(depth, expected, rtol=1e-5)
        occlusion = _pixels(frame['/stereo/left/occlusion_gt'])
        assert set(np.unique(occlusion)) <= {0, 128, 255}
        assert 0.005 < (occlusion == 255).mean() < 0.3


def test_ground_truth_disparity_maps_left_onto_right(frames: tuple[Path, list[dict[str, object]]]
                                                     ) -> None:
    """Photometric check on non-occluded pixels of the noise-free rectified renders."""
    for frame in frames[1]:
        left = cv2.cvtColor(_pixels(frame['/stereo/left/image_rect_gt']), cv2.COLOR_RGB2GRAY)
        right = cv2.cvtColor(_pixels(frame['/stereo/right/image_rect_gt']), cv2.COLOR_RGB2GRAY)
        disparity = _pixels(frame['/stereo/left/disparity_gt'].image)
        visible = _pixels(frame['/stereo/left/occlusion_gt']) == 0
        # keep away from depth edges, where anti-aliasing mixes surfaces
        edges = cv2.dilate((np.abs(cv2.Laplacian(disparity, cv2.CV_32F)) > 0.25).astype(np.uint8),
                           np.ones((5, 5), np.uint8)) > 0
        keep = visible & ~edges

        assert _residual(left, right, disparity, keep, 0.0) < 1.5
        assert _residual(left, right, disparity, keep, 1.0) > 2 * _residual(
            left, right, disparity, keep, 0.0)


def _residual(left: np.ndarray, right: np.ndarray, disparity: np.ndarray, keep: np.ndarray,
              shift: float) -> float:
    """Median |left - right sampled at x - d - shift|, the right gain/offset undone."""
    ys, xs = np.mgrid[0:left.shape[0], 0:left.shape[1]].astype(np.float32)
    warped = cv2.remap(right.astype(np.float32), xs - disparity - shift, ys, cv2.INTER_LINEAR)
    undone = (warped - CONFIG.right_offset) / CONFIG.right_gain
    return float(np.median(np.abs(undone - left)[keep]))


def test_generate_cli_errors(tmp_path: Path) -> None:
    result = run_cli(['generate', str(tmp_path / 'x'), '--preset', 'nope'])
    assert result.returncode == 1
    assert result.stderr.strip() == (
        "depth-nodes generate: error: unknown preset 'nope' (presets: stereo_vga, "
        'stereo_qvga_color, stereo_qvga_fisheye, structured_light_vga, tof_vga, mvs_sideways, '
        'mvs_forward, mvs_orbit, mvs_rig, depth_static, depth_moving_camera, '
        'depth_moving_object, depth_tof_static, depth_orbit, depth_object_leaves, depth_long, '
        'stereo_orbit, bad_inputs, all)')
    for preset in ('stereo_qvga_color', 'tof_vga'):
        result = run_cli(['generate', str(tmp_path / 'x'), '--preset', preset,
                          '--frames', '0'])
        assert result.returncode == 1
        assert 'n_frames' in result.stderr
        assert 'Traceback' not in result.stderr
        assert not (tmp_path / 'x').exists()


def test_generate_cli_writes_a_readable_bag(tmp_path: Path) -> None:
    result = run_cli(['generate', str(tmp_path / 'bag'), '--preset', 'stereo_qvga_fisheye',
                      '--frames', '1', '--seed', '99'])
    assert result.returncode == 0, result.stderr
    with BagReader(tmp_path / 'bag') as reader:
        config = config_from_metadata(reader.custom_data, tmp_path / 'bag')
        assert reader.counts['/stereo/left/image_raw'] == 1
    assert config.seed == 99
    assert config.distortion_model == 'equidistant'
    assert dataclasses.replace(config, seed=13, n_frames=3).width == 320
