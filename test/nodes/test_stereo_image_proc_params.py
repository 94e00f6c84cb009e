"""stereo_image_proc's (Jazzy) disparity-node parameters: a parameter file written for it
runs unchanged through the shipped graph and gives OpenCV the settings it gets upstream
(block matching or SGBM), addressed by its node name or by `/**`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import REPO
from rclpy.context import Context
from rclpy.parameter import Parameter

from depth_nodes.core.opencv_stereo import BmSettings, SgbmSettings, opencv_bm, opencv_sgbm
from depth_nodes.nodes.sgm_stereo import SgmStereoNode
from depth_nodes.ros.disparity import read_disparity
from depth_nodes.ros.image import image_to_array
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bags.process import process_bag

#: A stereo_image_proc parameter file as its users keep one (every disparity-node
#: parameter, upstream's types).
SIP_PARAMETERS = """\
{key}:
  ros__parameters:
    stereo_algorithm: {algorithm}
    sgbm_mode: 1
    full_dp: false
    prefilter_size: 11
    prefilter_cap: 31
    correlation_window_size: {window}
    min_disparity: 0
    disparity_range: 64
    texture_threshold: 12
    speckle_size: 100
    speckle_range: 4
    disp12_max_diff: 0
    uniqueness_ratio: 12.0
    P1: 200.0
    P2: 800.0
    approximate_sync: false
    queue_size: 5
    use_system_default_qos: false
"""


def _rectified_and_disparity(bag: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    with BagReader(bag) as reader:
        first: dict[str, Any] = {}
        for m in reader.messages(['/stereo/left/image_rect', '/stereo/right/image_rect',
                                  '/stereo/disparity']):
            first.setdefault(m.topic, m.deserialize())
    return (image_to_array(first['/stereo/left/image_rect']),
            image_to_array(first['/stereo/right/image_rect']),
            read_disparity(first['/stereo/disparity']).disparity)


@pytest.mark.parametrize('key', ['disparity_node', '/**'])
@pytest.mark.parametrize(('algorithm', 'window'), [(0, 15), (1, 5)])
def test_a_stereo_image_proc_file_runs_unchanged(tmp_path: Path, key: str, algorithm: int,
                                                 window: int) -> None:
    params = tmp_path / 'sip.yaml'
    params.write_text(SIP_PARAMETERS.format(key=f'"{key}"', algorithm=algorithm,
                                            window=window))
    report = process_bag(REPO / 'bags' / 'stereo_qvga_color', tmp_path / 'out',
                         params_file=params)
    assert report.unmatched_params == []
    assert sum(sum(c.values()) for c in report.drops.values()) == 0, report.format()
    left, right, disparity = _rectified_and_disparity(tmp_path / 'out')
    if algorithm == 0:
        expected = opencv_bm(left, right, BmSettings(
            correlation_window_size=window, prefilter_size=11, prefilter_cap=31,
            texture_threshold=12, uniqueness_ratio=12, speckle_size=100, speckle_range=4),
            disparity_range=64)
    else:
        import cv2

        expected = opencv_sgbm(left, right, SgbmSettings(
            'sip', mode=cv2.STEREO_SGBM_MODE_HH, correlation_window_size=window, P1=200,
            P2=800, uniqueness_ratio=12, speckle_size=100, speckle_range=4,
            disp12_max_diff=0, prefilter_cap=31), disparity_range=64)
    np.testing.assert_array_equal(disparity, expected)
    assert np.isfinite(disparity).mean() > 0.3  # a real disparity, not an empty one


@pytest.mark.parametrize(('algorithm', 'p1', 'uniqueness', 'speckle_range', 'lr'), [
    (0, 200.0, 15.0, 4, 0), (1, 200.0, 15.0, 4, 0), (2, 18.0, 10.0, 2, 2)])
def test_defaults_follow_the_algorithm_chosen_at_start_up(
        context: Context, algorithm: int, p1: float, uniqueness: float, speckle_range: int,
        lr: int) -> None:
    """A node started with stereo_image_proc's algorithms takes its defaults for the
    parameters whose units or defaults differ; the census matcher its own."""
    node = SgmStereoNode(context=context,
                         parameter_overrides=[Parameter('stereo_algorithm', value=algorithm)])
    try:
        values = node.params.values
        assert (values['P1'], values['uniqueness_ratio'], values['speckle_range'],
                values['disp12_max_diff']) == (p1, uniqueness, speckle_range, lr)
        assert values['disparity_range'] == (128 if algorithm == 2 else 64)
        assert (values['correlation_window_size'], values['prefilter_cap'],
                values['sgbm_mode'], values['full_dp']) == (15, 31, 0, False)
    finally:
        node.destroy_node()


@pytest.mark.parametrize(('overrides', 'reason'), [
    ({'stereo_algorithm': 0, 'correlation_window_size': 3},
     'correlation_window_size (3) must be at least 5 with block matching'),
    ({'stereo_algorithm': 1, 'disparity_range': 50},
     'disparity_range (50) must be a multiple of 16 with OpenCV StereoSGBM'),
    ({'stereo_algorithm': 1, 'P1': 500.0, 'P2': 400.0}, 'P2 (400.0) must be >= P1 (500.0)'),
    ({'stereo_algorithm': 2, 'paths': 8, 'P2': 8000.0},
     'SGM parameter P2=8000: must be <= 7936 with 8 paths'),
])
def test_settings_the_chosen_matcher_refuses_say_why(context: Context,
                                                     overrides: dict[str, Any],
                                                     reason: str) -> None:
    from depth_nodes.errors import ConfigError

    with pytest.raises(ConfigError, match=reason.replace('(', r'\(').replace(')', r'\)')):
        SgmStereoNode(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in overrides.items()])


def test_p2_up_to_the_four_path_limit_is_accepted(context: Context) -> None:
    """P2's declared range is the loosest (4 paths); the path count decides."""
    node = SgmStereoNode(context=context, parameter_overrides=[
        Parameter('paths', value=4), Parameter('P2', value=16000.0)])
    try:
        assert node.params.values['P2'] == 16000.0
    finally:
        node.destroy_node()


def test_a_file_that_only_picks_opencv_gets_stereo_image_procs_defaults(
        tmp_path: Path) -> None:
    """`stereo_algorithm: 1` alone, through the shipped graph: StereoSGBM with
    stereo_image_proc's defaults (built here with cv2 directly, not through the package's
    wrapper): window 15, P1 200, P2 400, uniqueness 15, speckles 100 / 4, disp12 0,
    prefilter cap 31, MODE_SGBM, 64 disparities."""
    import cv2

    params = tmp_path / 'sip.yaml'
    params.write_text('disparity_node:\n  ros__parameters: {stereo_algorithm: 1}\n')
    report = process_bag(REPO / 'bags' / 'stereo_qvga_color', tmp_path / 'out',
                         params_file=params)
    assert sum(sum(c.values()) for c in report.drops.values()) == 0, report.format()
    left, right, disparity = _rectified_and_disparity(tmp_path / 'out')
    sgbm = cv2.StereoSGBM.create(minDisparity=0, numDisparities=64, blockSize=15, P1=200,
                                 P2=400, disp12MaxDiff=0, preFilterCap=31, uniquenessRatio=15,
                                 speckleWindowSize=100, speckleRange=4,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM)
    raw = sgbm.compute(left, right)
    expected = np.where(raw >= 0, raw.astype(np.float32) / 16, np.nan)
    np.testing.assert_array_equal(disparity, expected)
