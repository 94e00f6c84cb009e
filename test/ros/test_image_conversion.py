"""Tests of depth_nodes.ros.image: sensor_msgs/Image <-> numpy."""

from __future__ import annotations

import array

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from depth_nodes.errors import EncodingError, MessageError
from depth_nodes.ros.image import (
    ENCODINGS,
    array_to_image,
    image_to_array,
    to_gray,
    to_rgb8,
)


def _random(encoding: str, height: int = 5, width: int = 7, seed: int = 0) -> np.ndarray:
    dtype, channels = ENCODINGS[encoding]
    rng = np.random.default_rng(seed)
    shape = (height, width) if channels == 1 else (height, width, channels)
    if dtype == np.float32:
        return rng.normal(size=shape).astype(np.float32)
    return rng.integers(0, np.iinfo(dtype).max, size=shape, endpoint=True, dtype=dtype)


def _raw(encoding: str, height: int, width: int, step: int, data: bytes, big: int = 0) -> Image:
    msg = Image(height=height, width=width, encoding=encoding, step=step, is_bigendian=big)
    msg.data = data
    return msg


@pytest.mark.parametrize('encoding', list(ENCODINGS))
def test_every_encoding_round_trips(encoding: str) -> None:
    arr = _random(encoding)
    header = Header(frame_id='cam')
    msg = array_to_image(arr, encoding, header)
    dtype, channels = ENCODINGS[encoding]
    assert (msg.height, msg.width, msg.encoding) == (5, 7, encoding)
    assert msg.step == 7 * channels * dtype.itemsize
    assert msg.is_bigendian == 0
    assert msg.header.frame_id == 'cam'
    back = image_to_array(msg)
    assert back.dtype == dtype
    np.testing.assert_array_equal(back, arr)


@pytest.mark.parametrize('encoding', list(ENCODINGS))
def test_rosbags_message_reads_the_same(encoding: str) -> None:
    arr = _random(encoding, seed=1)
    store = get_typestore(Stores.ROS2_JAZZY)
    raw = serialize_message(array_to_image(arr, encoding))
    msg = store.deserialize_cdr(raw, 'sensor_msgs/msg/Image')
    assert isinstance(msg.data, np.ndarray)
    np.testing.assert_array_equal(image_to_array(msg), arr)


def test_one_channel_array_with_trailing_axis_accepted() -> None:
    arr = _random('mono16')
    np.testing.assert_array_equal(image_to_array(array_to_image(arr[..., None], 'mono16')), arr)


def test_non_contiguous_and_byteswapped_input_written_little_endian() -> None:
    arr = _random('16UC1', 6, 8)
    msg = array_to_image(arr[::2, ::2].astype('>u2'), '16UC1')
    assert msg.step == 8
    np.testing.assert_array_equal(np.frombuffer(bytes(msg.data), '<u2').reshape(3, 4),
                                  arr[::2, ::2])


def test_padded_mono8_rows_are_a_view() -> None:
    arr = _random('mono8', 4, 5)
    padded = np.full((4, 8), 0xEE, np.uint8)
    padded[:, :5] = arr
    msg = _raw('mono8', 4, 5, 8, padded.tobytes())
    out = image_to_array(msg)
    np.testing.assert_array_equal(out, arr)
    assert np.shares_memory(out, np.frombuffer(msg.data, np.uint8))


def test_padded_rgb8_and_32fc1_rows() -> None:
    rgb = _random('rgb8', 3, 4)
    buf = np.zeros((3, 16), np.uint8)
    buf[:, :12] = rgb.reshape(3, 12)
    np.testing.assert_array_equal(image_to_array(_raw('rgb8', 3, 4, 16, buf.tobytes())), rgb)
    f = _random('32FC1', 3, 4)
    buf = np.zeros((3, 20), np.uint8)
    buf[:, :16] = f.view(np.uint8).reshape(3, 16)
    np.testing.assert_array_equal(image_to_array(_raw('32FC1', 3, 4, 20, buf.tobytes())), f)


def test_rosbags_uint8_array_data_is_a_view() -> None:
    arr = _random('mono8', 4, 6)

    class Msg:  # duck-typed like a rosbags message
        height, width, encoding, step, is_bigendian = 4, 6, 'mono8', 6, 0
        data = arr.reshape(-1).copy()

    out = image_to_array(Msg)
    np.testing.assert_array_equal(out, arr)
    assert np.shares_memory(out, Msg.data)


@pytest.mark.parametrize(('encoding', 'big_dtype'), [('mono16', '>u2'), ('32FC1', '>f4'),
                                                    ('16UC1', '>u2')])
def test_big_endian_is_swapped_to_native(encoding: str, big_dtype: str) -> None:
    arr = _random(encoding, 3, 5)
    width_bytes = 5 * np.dtype(big_dtype).itemsize
    buf = np.zeros((3, width_bytes + 2), np.uint8)
    buf[:, :width_bytes] = arr.astype(big_dtype).view(np.uint8).reshape(3, -1)
    out = image_to_array(_raw(encoding, 3, 5, width_bytes + 2, buf.tobytes(), big=1))
    assert out.dtype.isnative
    np.testing.assert_array_equal(out, arr)


def test_big_endian_flag_ignored_for_bytes() -> None:
    arr = _random('bgr8', 2, 3)
    np.testing.assert_array_equal(image_to_array(_raw('bgr8', 2, 3, 9, arr.tobytes(), 1)), arr)


def test_array_array_data() -> None:
    msg = _raw('mono8', 2, 2, 2, b'')
    msg.data = array.array('B', [1, 2, 3, 4])
    np.testing.assert_array_equal(image_to_array(msg), [[1, 2], [3, 4]])


@pytest.mark.parametrize(('height', 'width'), [(0, 4), (3, 0), (0, 0)])
def test_zero_size_reads_as_empty(height: int, width: int) -> None:
    out = image_to_array(_raw('rgb8', height, width, 12, b'\x01' * 50))
    assert out.shape == (height, width, 3)
    assert out.dtype == np.uint8


def test_data_shorter_than_step_times_height() -> None:
    msg = _raw('mono8', 480, 640, 640, bytes(100))
    with pytest.raises(MessageError, match=r'Image data has 100 bytes, but step 640 x height '
                                           r'480 needs 307200'):
        image_to_array(msg)


def test_last_row_must_be_complete() -> None:
    with pytest.raises(MessageError, match='Image data has 11 bytes, but step 4 x height 3'):
        image_to_array(_raw('mono8', 3, 3, 4, bytes(11)))


def test_unknown_encoding_lists_supported() -> None:
    with pytest.raises(EncodingError, match=r"unsupported image encoding 'yuv420'.*mono8.*32FC1"
                                            r".*bayer_rggb8.*nv21"):
        image_to_array(_raw('yuv420', 2, 2, 4, bytes(8)))



def test_step_smaller_than_row() -> None:
    with pytest.raises(MessageError, match=r'Image step 19 is smaller than a row: width 10 '
                                           r'x 1 channel\(s\) x 2 byte\(s\) \(mono16\) = 20'):
        image_to_array(_raw('mono16', 2, 10, 19, bytes(100)))


def test_huge_declared_size_with_small_data_is_a_message_error() -> None:
    msg = _raw('32FC1', 2**31 - 1, 2**31 - 1, 4 * (2**31 - 1), bytes(64))
    with pytest.raises(MessageError, match='Image data has 64 bytes, but step 8589934588'):
        image_to_array(msg)


def test_array_to_image_checks_dtype_channels_and_ndim() -> None:
    with pytest.raises(EncodingError, match='encoding mono16 needs dtype uint16, got uint8'):
        array_to_image(np.zeros((2, 2), np.uint8), 'mono16')
    with pytest.raises(EncodingError, match=r'encoding rgb8 needs 3 channel\(s\), array shape'):
        array_to_image(np.zeros((2, 2), np.uint8), 'rgb8')
    with pytest.raises(MessageError, match=r'must be 2-D or 3-D, got shape \(4,\)'):
        array_to_image(np.zeros(4, np.uint8), 'mono8')
    with pytest.raises(EncodingError, match="unsupported image encoding 'bayer_rgbg8'"):
        array_to_image(np.zeros((2, 2), np.uint8), 'bayer_rgbg8')


def test_to_gray() -> None:
    rgb = _random('rgb8', 4, 4)
    gray = to_gray(rgb, 'rgb8')
    expected = np.rint(rgb @ np.array([0.299, 0.587, 0.114]))
    assert gray.shape == (4, 4)
    assert np.max(np.abs(gray - expected)) <= 1
    np.testing.assert_array_equal(to_gray(rgb[..., ::-1], 'bgr8'), gray)
    bgra = np.dstack([rgb[..., ::-1], np.full((4, 4), 7, np.uint8)])
    np.testing.assert_array_equal(to_gray(bgra, 'bgra8'), gray)
    mono = _random('32FC1')
    np.testing.assert_array_equal(to_gray(mono, '32FC1'), mono)


def test_to_rgb8() -> None:
    rgb = _random('rgb8', 4, 4)
    assert to_rgb8(rgb, 'rgb8') is rgb
    np.testing.assert_array_equal(to_rgb8(np.ascontiguousarray(rgb[..., ::-1]), 'bgr8'), rgb)
    rgba = np.dstack([rgb, np.zeros((4, 4), np.uint8)])
    np.testing.assert_array_equal(to_rgb8(rgba, 'rgba8'), rgb)
    mono = _random('mono8', 4, 4)
    np.testing.assert_array_equal(to_rgb8(mono, 'mono8'), np.dstack([mono] * 3))
    m16 = np.array([[0, 257, 65535]], np.uint16)
    np.testing.assert_array_equal(to_rgb8(m16, 'mono16')[..., 1], [[0, 1, 255]])
    with pytest.raises(EncodingError, match='cannot convert 32FC1 to rgb8'):
        to_rgb8(np.zeros((2, 2), np.float32), '32FC1')
