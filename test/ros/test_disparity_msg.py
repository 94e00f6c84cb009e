"""Tests of depth_nodes.ros.disparity: DisparityImage building and reading."""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from ros_helpers import header
from rosbags.typesys import Stores, get_typestore
from std_msgs.msg import Header

from depth_nodes.errors import EncodingError, MessageError
from depth_nodes.ros.disparity import build_disparity, read_disparity
from depth_nodes.ros.image import array_to_image, image_to_array

PARAMS = {'focal': 400.0, 'baseline': 0.12, 'min_disparity': 2.0, 'max_disparity': 65.0,
          'delta_d': 1.0 / 16}


def _header() -> Header:
    return header(12 * 10**9 + 345, 'left_optical')


def _disparity(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d = rng.uniform(2.0, 60.0, size=(12, 16)).astype(np.float32)
    d[:, :3] = np.nan  # left border, as a matcher leaves it
    d[10:, :] = np.nan
    d[5, 7] = np.inf
    d[6, 8] = 1.0  # below min_disparity
    return d


def test_fields_and_invalid_stored_below_min() -> None:
    d = _disparity()
    msg = build_disparity(d, _header(), **PARAMS)
    assert msg.header.frame_id == 'left_optical'
    assert msg.image.header.stamp.sec == 12
    assert msg.image.encoding == '32FC1'
    assert (msg.f, msg.min_disparity, msg.max_disparity) == (400.0, 2.0, 65.0)
    assert msg.t == pytest.approx(0.12)
    assert msg.delta_d == 1.0 / 16
    stored = image_to_array(msg.image)
    invalid = ~np.isfinite(d) | (d < 2.0)
    assert np.all(stored[invalid] == 1.0)  # min_disparity - 1, strictly below
    assert np.isfinite(stored).all()
    np.testing.assert_array_equal(stored[~invalid], d[~invalid])
    assert np.isnan(d[0, 0])  # input untouched


def test_valid_window_from_known_mask() -> None:
    d = np.full((10, 20), np.nan, np.float32)
    d[3:7, 5:12] = 10.0
    d[8, 15] = 4.0
    msg = build_disparity(d, _header(), **PARAMS)
    w = msg.valid_window
    assert (w.x_offset, w.y_offset, w.width, w.height) == (5, 3, 11, 6)
    assert read_disparity(msg).valid_window == (5, 3, 16, 9)


def test_valid_window_empty_and_full() -> None:
    msg = build_disparity(np.full((4, 5), np.nan, np.float32), _header(), **PARAMS)
    w = msg.valid_window
    assert (w.x_offset, w.y_offset, w.width, w.height) == (0, 0, 0, 0)
    assert read_disparity(msg).valid_window == (0, 0, 0, 0)
    msg = build_disparity(np.full((4, 5), 3.0, np.float32), _header(), **PARAMS)
    w = msg.valid_window
    assert (w.x_offset, w.y_offset, w.width, w.height) == (0, 0, 5, 4)


def test_valid_window_given() -> None:
    msg = build_disparity(_disparity(), _header(), valid_window=(3, 0, 16, 10), **PARAMS)
    w = msg.valid_window
    assert (w.x_offset, w.y_offset, w.width, w.height) == (3, 0, 13, 10)
    with pytest.raises(MessageError, match=r'valid_window \(x0 3, y0 0, x1 17, y1 10\) must '
                                           r'satisfy 0 <= x0 <= x1 <= width 16'):
        build_disparity(_disparity(), _header(), valid_window=(3, 0, 17, 10), **PARAMS)


def test_round_trip_rclpy_and_rosbags() -> None:
    d = _disparity(1)
    msg = build_disparity(d, _header(), **PARAMS)
    store = get_typestore(Stores.ROS2_JAZZY)
    bag_msg = store.deserialize_cdr(serialize_message(msg), 'stereo_msgs/msg/DisparityImage')
    expected = np.where(np.isfinite(d) & (d >= 2.0), d, np.nan)
    for m in (msg, bag_msg):
        frame = read_disparity(m)
        assert frame.disparity.dtype == np.float32
        np.testing.assert_array_equal(frame.disparity, expected)
        assert frame.stamp_ns == 12_000_000_345
        assert frame.frame_id == 'left_optical'
        assert frame.focal == 400.0
        assert frame.baseline == pytest.approx(0.12)
        assert (frame.min_disparity, frame.max_disparity, frame.delta_d) == (2.0, 65.0, 0.0625)
        assert frame.valid_window == (3, 0, 16, 10)


def test_negative_min_disparity() -> None:
    d = np.array([[-3.0, np.nan, 0.0]], np.float32)
    msg = build_disparity(d, None, **{**PARAMS, 'min_disparity': -4.0})
    np.testing.assert_array_equal(image_to_array(msg.image), [[-3.0, -5.0, 0.0]])
    np.testing.assert_array_equal(read_disparity(msg).disparity, d)


def test_read_rejects_non_float_image() -> None:
    msg = build_disparity(_disparity(), _header(), **PARAMS)
    msg.image = array_to_image(np.zeros((2, 2), np.uint16), '16UC1')
    with pytest.raises(EncodingError, match="encoding must be 32FC1, got '16UC1'"):
        read_disparity(msg)


def test_build_rejects_bad_input() -> None:
    with pytest.raises(MessageError, match=r'disparity must be a \(H, W\) array, got shape '
                                           r'\(2, 2, 1\)'):
        build_disparity(np.zeros((2, 2, 1), np.float32), None, **PARAMS)
    with pytest.raises(MessageError, match='focal must be finite, got nan'):
        build_disparity(np.zeros((2, 2), np.float32), None, **{**PARAMS, 'focal': np.nan})
    with pytest.raises(MessageError, match=r'min_disparity 70\.0 is greater than max_disparity'):
        build_disparity(np.zeros((2, 2), np.float32), None, **{**PARAMS, 'min_disparity': 70.0})
