"""Every argument error the library raises on purpose is an ArgumentError (a DepthNodesError
and a ValueError) whose message names the argument (the CLI prints one as one line:
tools/test_cli.py)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from depth_nodes.core.camera import CameraModel, StereoModel
from depth_nodes.core.confidence import ConfidenceTerms, confidence_map
from depth_nodes.core.cross_check import (
    cross_check,
    fill_disparity_holes,
    left_right_check,
    median_filter,
    remove_speckles,
)
from depth_nodes.core.geometry import camera_transform
from depth_nodes.core.groundtruth import nonoccluded_from_right, read_disparity_file, write_pfm
from depth_nodes.core.metrics import disparity_errors, optimal_auc, sparsification_auc
from depth_nodes.core.opencv_stereo import BmSettings, opencv_bm, opencv_sgbm
from depth_nodes.core.rectify import Rectifier, interpolation_flag
from depth_nodes.core.reproject import depth_std, reproject_disparity
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.core.sgm.border import fill_outside
from depth_nodes.core.sgm.census import census_transform
from depth_nodes.errors import ArgumentError, DepthNodesError
from depth_nodes.sim.texture import Texture

F = np.zeros((4, 6), np.float32)
U8 = np.zeros((20, 40), np.uint8)
K = np.array([[50.0, 0, 19.5], [0, 50.0, 14.5], [0, 0, 1]])
CAMERA = CameraModel(40, 30, K)
STEREO = StereoModel(
    CameraModel(40, 30, K, P=np.array([[50.0, 0, 19.5, 0], [0, 50, 14.5, 0], [0, 0, 1, 0]])),
    CameraModel(40, 30, K, P=np.array([[50.0, 0, 19.5, -10], [0, 50, 14.5, 0], [0, 0, 1, 0]])))


def _texture(**fields: Any) -> Callable[[], Any]:
    return lambda: Texture(**{'kind': 'noise', 'period_m': 0.1, **fields})


#: (what is called, what its message must say)
CASES: list[tuple[str, Callable[[], Any], str]] = [
    ('match: colour', lambda: SgmMatcher().match(np.zeros((9, 9, 3)), np.zeros((9, 9, 3))),
     'must be grey (H, W) images'),
    ('match: sizes', lambda: SgmMatcher().match(np.zeros((9, 9)), np.zeros((9, 8))),
     'must have one size'),
    ('SgmParams', lambda: SgmParams(census_width=4).validate(),
     'SGM parameter census_width=4: must be odd'),
    ('SgmParams: P2 with 16 paths', lambda: SgmParams(paths=16, P2=5000).validate(),
     'must be <= 3840 with 16 paths'),
    ('SgmParams: width', lambda: SgmParams(disparity_range=64).validate(40),
     'is not smaller than the image width 40'),
    ('SgmParams: min_disparity', lambda: SgmParams(min_disparity=-50,
                                                   disparity_range=8).validate(40),
     'min_disparity=-50: is outside (-40, 40)'),
    ('SgmParams: census bits', lambda: SgmParams(census_width=9, census_height=9).validate(),
     'a 9x9 window has more than 63 neighbours'),
    ('SgmParams: no cost', lambda: SgmParams(census_weight=0, intensity_weight=0).validate(),
     'census_weight and intensity_weight cannot both be 0'),
    ('SgmParams: uniqueness', lambda: SgmParams(uniqueness_ratio=100).validate(),
     'uniqueness_ratio=100: must be below 100'),
    ('SgmParams: P2 below P1', lambda: SgmParams(P1=50, P2=40).validate(),
     'P2=40: must be >= P1 (50)'),
    ('census', lambda: census_transform(U8, (9, 9), np.zeros((20, 40), np.uint32)),
     'census holds fewer bits than a 9x9'),
    ('fill_outside', lambda: fill_outside(np.zeros((2, 2, 2), np.uint8), 0, 300),
     'value must be in 0..255, got 300'),
    ('sgbm: shapes', lambda: opencv_sgbm(U8, U8[:, :30]), 'must be 2-D and of one'),
    ('sgbm: dtype', lambda: opencv_sgbm(U8.astype(np.uint16), U8.astype(np.uint16)),
     'images must be uint8'),
    ('sgbm: range', lambda: opencv_sgbm(U8, U8, disparity_range=20),
     'disparity_range must be a positive multiple of 16'),
    ('bm: window', lambda: opencv_bm(U8, U8, BmSettings(correlation_window_size=4),
                                     disparity_range=16),
     'must be odd, 5..255 for block matching, got 4'),
    ('left_right_check: shape', lambda: left_right_check(F, F[:, :3], max_diff=1),
     'disparity_right must have the disparity shape (4, 6)'),
    ('left_right_check: dtype', lambda: left_right_check(F.astype(int), F, max_diff=1),
     'disparity must be a float array'),
    ('left_right_check: 3-D', lambda: left_right_check(F[None], F, max_diff=1),
     'disparity must be a (H, W) array'),
    ('left_right_check: max_diff', lambda: left_right_check(F, F, max_diff=-1),
     'max_diff must be a finite number >= 0, got -1'),
    ('remove_speckles', lambda: remove_speckles(F, max_size=-1, max_diff=1),
     'max_size must be an int >= 0, got -1'),
    ('fill_disparity_holes: labels', lambda: fill_disparity_holes(F, np.zeros((4, 6), np.int32)),
     'labels must be a uint8 array of shape (4, 6)'),
    ('fill_disparity_holes: mode',
     lambda: fill_disparity_holes(F, np.zeros((4, 6), np.uint8), mode='near'),
     "mode must be one of"),
    ('median_filter', lambda: median_filter(F, 4), 'size must be 3 or 5, got 4'),
    ('cross_check', lambda: cross_check(F, F, F, median_size=7),
     'median_size must be 0, 3 or 5, got 7'),
    ('confidence: window', lambda: confidence_map(F, F, F > 0, window=4),
     'window must be an odd int >= 1, got 4'),
    ('confidence: valid', lambda: confidence_map(F, F, F), 'valid must be a bool array'),
    ('confidence: max_diff', lambda: confidence_map(F, F, F > 0, max_diff=0),
     'max_diff must be > 0'),
    ('confidence: filled', lambda: confidence_map(F, F, F > 0, filled_confidence=2),
     'filled_confidence must be in [0, 1], got 2'),
    ('confidence: terms', lambda: confidence_map(F, F, F > 0, terms=ConfidenceTerms(
        smoothness=-1)), 'smoothness must be a finite number >= 0'),
    ('metrics: 3-D', lambda: disparity_errors(F[None], F), 'must be a 2-D (H, W) array'),
    ('metrics: dtype', lambda: disparity_errors(F.astype(complex), F),
     'must be a real numeric array'),
    ('metrics: shapes', lambda: disparity_errors(F, F[:, :3]), 'must have the same shape'),
    ('metrics: mask dtype', lambda: disparity_errors(F, F, valid_mask=F),
     'valid_mask must be a boolean array'),
    ('metrics: mask shape', lambda: disparity_errors(F, F, valid_mask=F[:, :3] > 0),
     'valid_mask must have shape (4, 6)'),
    ('metrics: n', lambda: disparity_errors(F, F, n=-1), 'n must be a finite number >= 0'),
    ('optimal_auc', lambda: optimal_auc(2), 'error_rate must be in [0, 1], got 2'),
    ('sparsification', lambda: sparsification_auc(F, F, steps=0),
     'steps must be None or an int >= 1'),
    ('transform', lambda: camera_transform(0, 0, float('nan'), 0, 0, 0, optical=True),
     'transform values must be finite'),
    ('reproject: size', lambda: reproject_disparity(F, STEREO),
     'disparity is 6x4 but the cameras are 40x30'),
    ('reproject: ranges', lambda: reproject_disparity(
        np.zeros((30, 40), np.float32), STEREO, min_range=-1),
     'point cloud parameter min_range=-1: must be in [0, 1e+06]'),
    ('reproject: order', lambda: reproject_disparity(
        np.zeros((30, 40), np.float32), STEREO, min_range=5, max_range=1),
     'max_range (1) must be >= min_range (5) or 0'),
    ('reproject: confidence', lambda: reproject_disparity(
        np.zeros((30, 40), np.float32), STEREO, confidence=F),
     'confidence must have the disparity shape (30, 40)'),
    ('depth_std: focal', lambda: depth_std(F, 0, 1, 0.1), 'focal * baseline must be positive'),
    ('depth_std: std', lambda: depth_std(F, 1, 1, -1), 'disparity_std must be >= 0'),
    ('interpolation', lambda: interpolation_flag('cubicle'), 'interpolation must be one of'),
    ('rectify: size', lambda: Rectifier().rectify(U8, CAMERA),
     'image is 40x20 but the camera_info describes 40x30'),
    ('ground truth: format', lambda: read_disparity_file('x.png', fmt='jpeg'),
     'fmt must be one of'),
    ('ground truth: scale', lambda: read_disparity_file('x.png', scale=0),
     'scale must be > 0, got 0'),
    ('nonoccluded', lambda: nonoccluded_from_right(F, F[:, :3]),
     'must be equal 2-D shapes'),
    ('texture: kind', _texture(kind='plaid'), 'texture kind must be one of'),
    ('texture: period', _texture(period_m=0), 'texture period_m must be positive'),
]


@pytest.mark.parametrize(('call', 'message'), [c[1:] for c in CASES],
                         ids=[c[0] for c in CASES])
def test_argument_errors_are_one_family_and_name_the_argument(call: Callable[[], Any],
                                                              message: str) -> None:
    with pytest.raises(ArgumentError) as info:
        call()
    assert isinstance(info.value, DepthNodesError)
    assert isinstance(info.value, ValueError)  # code that catches ValueError keeps working
    assert message in str(info.value)


def test_write_pfm_refuses_a_volume(tmp_path: Path) -> None:
    with pytest.raises(ArgumentError, match=r'disparity must be \(H, W\)'):
        write_pfm(tmp_path / 'x.pfm', np.zeros((2, 2, 2), np.float32))
    assert not (tmp_path / 'x.pfm').exists()
