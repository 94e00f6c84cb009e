"""Tests of depth_nodes.core.camera: validation, binning/ROI, stereo geometry, YAML."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from depth_nodes.core.camera import (
    CameraModel,
    StereoModel,
    read_camera_yaml,
    validate_camera,
    write_camera_yaml,
)
from depth_nodes.errors import CalibrationError

K = np.array([[500.0, 0.0, 320.5], [0.0, 502.0, 240.25], [0.0, 0.0, 1.0]])


def _camera(**changes: object) -> CameraModel:
    model = CameraModel(
        width=640, height=480, K=K.copy(), D=np.array([-0.1, 0.01, 0.001, -0.002, 0.0]),
        R=np.eye(3), P=np.hstack([K, np.zeros((3, 1))]),
    )
    return replace(model, **changes)


def _stereo(f: float = 400.0, b: float = 0.12, cx_l: float = 320.0, cx_r: float = 320.0
            ) -> StereoModel:
    def cam(cx: float, tx: float) -> CameraModel:
        P = np.array([[f, 0.0, cx, tx], [0.0, f, 240.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
        return CameraModel(width=640, height=480, K=P[:, :3].copy(), P=P)
    return StereoModel(cam(cx_l, 0.0), cam(cx_r, -f * b))


def test_valid_camera_passes_and_properties() -> None:
    cam = _camera().validate()
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.Tx) == (500.0, 502.0, 320.5, 240.25, 0.0)
    assert cam.is_distorted
    assert not _camera(D=np.zeros(5)).is_distorted


def test_zero_p_means_k() -> None:
    cam = _camera(P=np.zeros((3, 4))).validate()
    np.testing.assert_array_equal(cam.projection, np.hstack([K, np.zeros((3, 1))]))
    assert cam.fx == 500.0


@pytest.mark.parametrize(
    ('changes', 'pattern'),
    [
        ({'K': np.zeros((3, 3))}, 'K is all zero: the camera is not calibrated'),
        ({'K': np.where(np.eye(3) == 1, np.nan, K)}, r'K has non-finite values: \[nan'),
        ({'D': np.array([0.1, np.inf, 0, 0, 0])}, 'D has non-finite values'),
        ({'P': np.full((3, 4), np.nan)}, 'P has non-finite values'),
        ({'K': K * [[-1], [1], [1]]}, 'K must have fx > 0 and fy > 0, got fx -500.0, fy 502.0'),
        ({'K': K * [[1], [0], [1]]}, 'K must have fx > 0 and fy > 0, got fx 500.0, fy 0.0'),
        ({'P': np.hstack([K * [[0], [1], [1]], np.zeros((3, 1))])},
         'P must have fx > 0 and fy > 0, got fx 0.0'),
        ({'width': 0}, 'image size must be positive, got 0x480'),
        ({'height': -3}, 'image size must be positive, got 640x-3'),
        ({'distortion_model': 'fisheye'},
         "unknown distortion_model 'fisheye'; supported: plumb_bob, rational_polynomial, "
         'equidistant'),
        ({'K': np.eye(4)}, 'K has 16 values, expected 9'),
        ({'R': np.diag([1.0, 1.0, -1.0])}, r'R is not a rotation: .*det\(R\) = -1'),
        ({'R': np.eye(3) * 1.01}, r'R is not a rotation: \|R R\^T - I\| = 0.0201'),
    ],
)
def test_invalid_camera(changes: dict[str, object], pattern: str) -> None:
    with pytest.raises(CalibrationError, match=pattern):
        validate_camera(_camera(**changes))


@pytest.mark.parametrize(
    ('model', 'good', 'bad'),
    [('plumb_bob', 5, (4, 8)), ('rational_polynomial', 8, (5, 12, 14)),
     ('equidistant', 4, (5, 3))],
)
def test_distortion_sizes(model: str, good: int, bad: tuple[int, ...]) -> None:
    _camera(distortion_model=model, D=np.zeros(good)).validate()
    _camera(distortion_model=model, D=np.zeros(0)).validate()  # empty means no distortion
    for n in bad:
        with pytest.raises(CalibrationError,
                           match=f'distortion_model {model} needs {good} coefficients in D, '
                                 f'got {n}'):
            _camera(distortion_model=model, D=np.zeros(n)).validate()


def test_rotation_accepted() -> None:
    R, _ = cv2.Rodrigues(np.array([0.01, -0.02, 0.03]))
    _camera(R=R).validate()


def test_binned_and_roi_like_image_geometry() -> None:
    P = np.hstack([K, [[-50.0], [0.0], [0.0]]])
    cam = _camera(P=P, binning_x=2, binning_y=4, roi=(100, 40, 400, 320, True))
    eff = cam.binned()
    assert (eff.width, eff.height, eff.binning_x, eff.binning_y) == (200, 80, 0, 0)
    assert eff.roi == (0, 0, 0, 0, True)
    np.testing.assert_allclose(eff.K, [[250.0, 0.0, 110.25], [0.0, 125.5, 50.0625],
                                       [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(eff.P[0], [250.0, 0.0, 110.25, -25.0])
    np.testing.assert_allclose(eff.P[1], [0.0, 125.5, 50.0625, 0.0])
    # Baseline-defining ratio Tx / fx is invariant under binning.
    assert eff.Tx / eff.fx == cam.Tx / cam.fx
    # Explicit arguments override the fields; zero ROI means the full image.
    plain = cam.binned(binning_x=0, binning_y=1, roi=(0, 0, 0, 0, False))
    assert (plain.width, plain.height) == (640, 480)
    np.testing.assert_array_equal(plain.K, K)
    # A zero P stays zero (still meaning [K | 0]).
    eff0 = _camera(P=np.zeros((3, 4)), binning_x=2).binned()
    assert not eff0.P.any()
    assert eff0.fx == 250.0
    with pytest.raises(CalibrationError, match=r'roi \(x_offset 600, y_offset 0, width 100, '
                                               r'height 10\) is outside the 640x480 image'):
        cam.binned(roi=(600, 0, 100, 10, False))


def test_stereo_depth_hand_computed() -> None:
    st = _stereo(f=400.0, b=0.12)
    assert st.baseline == pytest.approx(0.12)
    assert st.focal == 400.0
    assert st.delta_cx == 0.0
    z = st.disparity_to_depth(np.array([48.0, 24.0, 0.0, -3.0, np.nan], np.float32))
    assert z.dtype == np.float32
    np.testing.assert_allclose(z[:2], [1.0, 2.0], rtol=1e-6)
    assert np.isnan(z[2:]).all()
    d = st.depth_to_disparity([1.0, 4.0, 0.0, -1.0])
    np.testing.assert_allclose(d[:2], [48.0, 12.0])
    assert np.isnan(d[2:]).all()
    assert float(st.disparity_to_depth(96.0)) == pytest.approx(0.5)


def test_stereo_cx_offset() -> None:
    # Right principal point 10 px right of the left one: d = fB/Z - 10.
    st = _stereo(f=400.0, b=0.1, cx_l=300.0, cx_r=310.0)
    assert st.delta_cx == 10.0
    # Point at X = 0.2, Z = 2: x_l = 300 + 40 = 340, x_r = 310 + 400 * 0.1 / 2 = 330.
    np.testing.assert_allclose(st.depth_to_disparity(2.0), 10.0)
    np.testing.assert_allclose(st.disparity_to_depth(10.0), 2.0)
    assert np.isnan(st.disparity_to_depth(-10.0))  # zero denominator


def test_q_matches_stereo_rectify_and_reproject() -> None:
    K1 = np.array([[420.0, 0, 310.0], [0, 420.0, 235.0], [0, 0, 1]])
    K2 = np.array([[415.0, 0, 330.0], [0, 418.0, 245.0], [0, 0, 1]])
    R, _ = cv2.Rodrigues(np.array([0.002, -0.01, 0.003]))
    T = np.array([[-0.1], [0.002], [0.001]])
    size = (640, 480)
    R1, R2, P1, P2, Q_cv, _, _ = cv2.stereoRectify(K1, np.zeros(5), K2, np.zeros(5), size, R,
                                                   T, flags=0, alpha=-1)
    left = CameraModel(width=640, height=480, K=K1, R=R1, P=P1)
    right = CameraModel(width=640, height=480, K=K2, R=R2, P=P2)
    st = StereoModel(left, right)
    assert st.delta_cx != 0.0
    assert st.baseline == pytest.approx(np.linalg.norm(T))
    np.testing.assert_allclose(st.Q, Q_cv, rtol=1e-9, atol=1e-9)

    rng = np.random.default_rng(3)
    disp = rng.uniform(5.0, 60.0, size=(6, 8)).astype(np.float32)
    disp[0, 0] = -st.delta_cx - 1.0  # behind the camera: NaN depth
    xyz = cv2.reprojectImageTo3D(disp, st.Q)
    z = st.disparity_to_depth(disp)
    np.testing.assert_allclose(xyz[1:, :, 2], z[1:], rtol=1e-5)
    assert np.isnan(z[0, 0])
    xs = np.arange(8, dtype=np.float64)
    np.testing.assert_allclose(xyz[3, :, 0], (xs - st.left.cx) * z[3] / st.focal, rtol=1e-4)


@pytest.mark.parametrize(
    ('which', 'pattern'),
    [('fx', 'rectified fx differ: left P fx 400.0, right P fx 401.0'),
     ('baseline', r'stereo baseline must be positive and finite, got -0.12 m'),
     ('size', 'stereo image sizes differ: left 640x480, right 320x480')],
)
def test_invalid_stereo(which: str, pattern: str) -> None:
    st = _stereo()
    right = st.right
    if which == 'fx':
        P = right.P.copy()
        P[0, 0] = 401.0
        right = replace(right, P=P)
    elif which == 'baseline':
        right = replace(right, P=right.P * [[1, 1, 1, -1], [1, 1, 1, 1], [1, 1, 1, 1]])
    else:
        right = replace(right, width=320)
    with pytest.raises(CalibrationError, match=pattern):
        StereoModel(st.left, right)


def test_stereo_validates_cameras() -> None:
    st = _stereo()
    with pytest.raises(CalibrationError, match='K is all zero'):
        StereoModel(replace(st.left, K=np.zeros((3, 3))), st.right)


def test_yaml_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    R, _ = cv2.Rodrigues(rng.normal(scale=0.01, size=3))
    P = np.hstack([K * 1.01, [[-37.123456789], [0.0], [0.0]]])
    cam = _camera(D=rng.normal(scale=0.1, size=8), distortion_model='rational_polynomial',
                  R=R, P=P)
    path = tmp_path / 'left.yaml'
    write_camera_yaml(path, cam, 'narrow_stereo/left')
    text = path.read_text()
    assert 'image_width: 640' in text
    assert 'distortion_model: rational_polynomial' in text
    assert 'cols: 8' in text
    back, name = read_camera_yaml(path)
    assert name == 'narrow_stereo/left'
    assert (back.width, back.height, back.distortion_model) == (640, 480, 'rational_polynomial')
    for attr in ('K', 'D', 'R', 'P'):
        np.testing.assert_array_equal(getattr(back, attr), getattr(cam, attr))


def test_yaml_written_by_camera_calibration(tmp_path: Path) -> None:
    path = tmp_path / 'ost.yaml'
    path.write_text(
        'image_width: 640\nimage_height: 480\ncamera_name: narrow_stereo\n'
        'camera_matrix:\n  rows: 3\n  cols: 3\n'
        '  data: [430.15, 0.0, 306.0, 0.0, 430.3, 236.3, 0.0, 0.0, 1.0]\n'
        'distortion_coefficients:\n  rows: 1\n  cols: 5\n'
        '  data: [-0.33, 0.11, 0.0005, -0.0002, 0.0]\n'
    )
    cam, name = read_camera_yaml(path)
    assert name == 'narrow_stereo'
    assert cam.distortion_model == 'plumb_bob'
    np.testing.assert_array_equal(cam.R, np.eye(3))
    assert cam.fx == 430.15  # zero P -> K


_GOOD = {
    'image_width': '640',
    'image_height': '480',
    'camera_matrix': '{rows: 3, cols: 3, data: [400, 0, 320, 0, 400, 240, 0, 0, 1]}',
    'distortion_model': 'plumb_bob',
    'distortion_coefficients': '{rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}',
    'projection_matrix': '{rows: 3, cols: 4, data: [400, 0, 320, 0, 0, 400, 240, 0, 0, 0, 1, 0]}',
}


@pytest.mark.parametrize(
    ('key', 'value', 'pattern'),
    [
        ('image_width', None, 'image_width must be an integer, got None'),
        ('image_height', 'abc', "image_height must be an integer, got 'abc'"),
        ('camera_matrix', None, 'camera_matrix must be a mapping with rows, cols and data'),
        ('camera_matrix', '{rows: 3, cols: 3, data: [1, 2]}',
         'camera_matrix has 2 values, but rows 3 x cols 3'),
        ('projection_matrix', '{rows: 3, cols: 3, data: [1, 2, 3, 4, 5, 6, 7, 8, 9]}',
         'projection_matrix must be 3x4, got 3x3'),
        ('camera_matrix', '{rows: 3, cols: 3, data: [a, b, c, d, e, f, g, h, i]}',
         'camera_matrix.data is not numeric'),
        ('distortion_coefficients', '{rows: 1, cols: 4, data: [0, 0, 0, 0]}',
         'distortion_model plumb_bob needs 5 coefficients in D, got 4'),
        ('distortion_model', 'kannala', "unknown distortion_model 'kannala'"),
        ('camera_matrix', '{rows: 3, cols: 3, data: [0, 0, 0, 0, 0, 0, 0, 0, 0]}',
         'K is all zero'),
    ],
)
def test_broken_yaml_fields(tmp_path: Path, key: str, value: str | None, pattern: str) -> None:
    doc = dict(_GOOD)
    if value is None:
        del doc[key]
    else:
        doc[key] = value
    path = tmp_path / 'cam.yaml'
    path.write_text(''.join(f'{k}: {v}\n' for k, v in doc.items()))
    with pytest.raises(CalibrationError, match=f'{path}: {pattern}'):
        read_camera_yaml(path)


def test_broken_yaml_files(tmp_path: Path) -> None:
    missing = tmp_path / 'missing.yaml'
    with pytest.raises(CalibrationError, match=f'{missing}: cannot read camera calibration'):
        read_camera_yaml(missing)
    bad = tmp_path / 'bad.yaml'
    bad.write_text('image_width: [640\n')
    with pytest.raises(CalibrationError, match=f'{bad}: invalid YAML'):
        read_camera_yaml(bad)
    bad.write_text('- 1\n- 2\n')
    with pytest.raises(CalibrationError, match=f'{bad}: expected a YAML mapping, got list'):
        read_camera_yaml(bad)


def test_write_refuses_invalid_model(tmp_path: Path) -> None:
    with pytest.raises(CalibrationError, match='K is all zero'):
        write_camera_yaml(tmp_path / 'x.yaml', _camera(K=np.zeros((3, 3))))
    assert not (tmp_path / 'x.yaml').exists()
