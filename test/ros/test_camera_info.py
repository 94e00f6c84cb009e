"""Tests of depth_nodes.ros.camera_info: CameraInfo <-> CameraModel / StereoModel."""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from depth_nodes.core.camera import CameraModel
from depth_nodes.errors import CalibrationError, UncalibratedError
from depth_nodes.ros.camera_info import (
    StereoInfoCache,
    camera_info_to_model,
    model_to_camera_info,
    stereo_model_from_infos,
)

F, B = 410.0, 0.09


def _model(tx: float = 0.0, **kw: object) -> CameraModel:
    P = np.array([[F, 0.0, 321.0, tx], [0.0, F, 241.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    K = np.array([[405.0, 0.0, 318.0], [0.0, 406.0, 244.0], [0.0, 0.0, 1.0]])
    args: dict[str, object] = {'width': 640, 'height': 480, 'K': K,
                               'D': np.array([0.1, -0.2, 0.001, 0.002, 0.03]), 'P': P,
                               'frame_id': 'cam_optical'}
    args.update(kw)
    return CameraModel(**args)  # type: ignore[arg-type]


def test_round_trip_rclpy() -> None:
    model = _model(binning_x=2, binning_y=2, roi=(10, 20, 300, 200, True))
    msg = model_to_camera_info(model)
    assert msg.header.frame_id == 'cam_optical'
    assert list(msg.d) == model.D.tolist()
    back = camera_info_to_model(msg)
    for attr in ('K', 'D', 'R', 'P'):
        np.testing.assert_array_equal(getattr(back, attr), getattr(model, attr))
    assert (back.binning_x, back.binning_y, back.roi) == (2, 2, (10, 20, 300, 200, True))
    assert back.frame_id == 'cam_optical'
    assert back.distortion_model == 'plumb_bob'


def test_header_given_is_copied() -> None:
    msg = model_to_camera_info(_model(), Header(frame_id='other'))
    assert msg.header.frame_id == 'other'


def test_rosbags_message() -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    model = _model(distortion_model='equidistant', D=np.array([0.1, 0.2, 0.3, 0.4]))
    raw = serialize_message(model_to_camera_info(model))
    msg = store.deserialize_cdr(raw, 'sensor_msgs/msg/CameraInfo')
    back = camera_info_to_model(msg)
    np.testing.assert_array_equal(back.D, [0.1, 0.2, 0.3, 0.4])
    np.testing.assert_array_equal(back.P, model.P)
    assert back.distortion_model == 'equidistant'


@pytest.mark.parametrize(
    ('field', 'value', 'pattern'),
    [
        ('k', np.zeros(9), r"CameraInfo \(frame 'cam_optical'\): K is all zero"),
        ('k', [np.nan, 0, 320, 0, 400, 240, 0, 0, 1], 'K has non-finite values'),
        ('d', [0.1, 0.2], 'distortion_model plumb_bob needs 5 coefficients in D, got 2'),
        ('distortion_model', 'unknown', "unknown distortion_model 'unknown'"),
        ('r', [1.0, 0, 0, 0, 1, 0, 0, 0, 2], 'R is not a rotation'),
    ],
)
def test_invalid_camera_info(field: str, value: object, pattern: str) -> None:
    msg = model_to_camera_info(_model())
    setattr(msg, field, value)
    with pytest.raises(CalibrationError, match=pattern):
        camera_info_to_model(msg)


def test_stereo_from_infos_applies_binning() -> None:
    left = model_to_camera_info(_model(binning_x=2, binning_y=2))
    right = model_to_camera_info(_model(tx=-F * B, binning_x=2, binning_y=2))
    st = stereo_model_from_infos(left, right)
    assert st.baseline == pytest.approx(B)
    assert st.focal == F / 2
    assert (st.left.width, st.left.height) == (320, 240)
    np.testing.assert_allclose(st.disparity_to_depth(F / 2 * B / 1.5), 1.5)


def test_stereo_from_infos_rejects_mismatch() -> None:
    left = model_to_camera_info(_model())
    with pytest.raises(CalibrationError, match='stereo baseline must be positive'):
        stereo_model_from_infos(left, left)
    right = model_to_camera_info(_model(tx=-F * B, binning_x=2, binning_y=2))
    with pytest.raises(CalibrationError, match='stereo image sizes differ'):
        stereo_model_from_infos(left, right)


def test_empty_message_is_uncalibrated() -> None:
    with pytest.raises(CalibrationError, match='image size must be positive, got 0x0'):
        camera_info_to_model(CameraInfo())


def test_stereo_cache_converts_only_on_change() -> None:
    cache = StereoInfoCache()
    left = model_to_camera_info(_model())
    right = model_to_camera_info(_model(tx=-F * B))
    first = cache.model(left, right)
    assert first.baseline == pytest.approx(B)
    assert cache.model(model_to_camera_info(_model()), right) is first  # same content
    right.p[3] = -F * 2 * B
    second = cache.model(left, right)
    assert second is not first
    assert second.baseline == pytest.approx(2 * B)
    uncalibrated = model_to_camera_info(_model(K=np.zeros((3, 3))))
    with pytest.raises(UncalibratedError, match='K all zero'):
        cache.model(uncalibrated, right)
    right.p[3] = -F * B  # the next good pair is used again
    assert cache.model(left, right).baseline == pytest.approx(B)
