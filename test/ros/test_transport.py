"""image_transport's compressed and compressedDepth formats (depth_nodes.ros.transport and
ros.rvl): what image_transport_plugins' publishers write is read back exactly (PNG, RVL) or
within JPEG's loss, and every damaged or foreign message is a one-line error of its kind."""

from __future__ import annotations

import struct

import cv2
import numpy as np
import pytest
from sensor_msgs.msg import CompressedImage

from depth_nodes.errors import DecodeError, EncodingError, MessageError, UnsupportedFormatError
from depth_nodes.ros.image import array_to_image
from depth_nodes.ros.rvl import rvl_decode, rvl_encode
from depth_nodes.ros.transport import (
    MAX_PIXELS,
    compress_depth,
    compress_image,
    decode_image,
    gray_image,
    image_pixels,
    transport_topic,
    transport_type,
)


def _texture(h: int = 40, w: int = 56, channels: int = 1, bits: int = 8) -> np.ndarray:
    rng = np.random.default_rng(3)
    smooth = cv2.GaussianBlur(rng.random((h, w, channels)).astype(np.float32), (0, 0), 2)
    smooth = smooth.reshape(h, w, channels)  # OpenCV drops a single channel axis
    smooth = (smooth - smooth.min()) / (smooth.max() - smooth.min())
    top = 255 if bits == 8 else 65535
    out = np.rint(smooth * top).astype(np.uint8 if bits == 8 else np.uint16)
    return out[:, :, 0] if channels == 1 else out


def _as_bgr(pixels: np.ndarray, encoding: str) -> np.ndarray:
    """What image_transport's publisher compresses a colour image as: BGR, no alpha."""
    code = {'rgb8': cv2.COLOR_RGB2BGR, 'rgba8': cv2.COLOR_RGBA2BGR, 'bgra8': cv2.COLOR_BGRA2BGR,
            'rgb16': cv2.COLOR_RGB2BGR}.get(encoding)
    return pixels if code is None else cv2.cvtColor(pixels, code)


@pytest.mark.parametrize(('encoding', 'channels', 'bits', 'stored'), [
    ('mono8', 1, 8, 'mono8'), ('mono16', 1, 16, 'mono16'), ('rgb8', 3, 8, 'bgr8'),
    ('bgr8', 3, 8, 'bgr8'), ('rgba8', 4, 8, 'bgr8'), ('bgra8', 4, 8, 'bgr8'),
    ('rgb16', 3, 16, 'bgr16'), ('bgr16', 3, 16, 'bgr16'),
])
def test_png_round_trips_exactly_as_image_transport_stores_it(
        encoding: str, channels: int, bits: int, stored: str) -> None:
    """Colour is stored BGR without alpha and named so after ``compressed``; the pixels
    come back exactly, in that encoding."""
    pixels = _texture(channels=channels, bits=bits)
    msg = compress_image(pixels, encoding, codec='png')
    assert msg.format == f'{encoding}; png compressed {"" if channels == 1 else stored}'
    decoded, out_encoding = decode_image(msg)
    assert out_encoding == stored
    np.testing.assert_array_equal(decoded, _as_bgr(pixels, encoding))


@pytest.mark.parametrize('encoding', ['mono8', 'rgb8', 'bgr8'])
def test_jpeg_is_close_and_keeps_the_channel_order(encoding: str) -> None:
    pixels = _texture(channels=1 if encoding == 'mono8' else 3)
    if encoding != 'mono8':  # distinct channels, so a swap would show
        pixels[:, :, 0] //= 4
    msg = compress_image(pixels, encoding, codec='jpeg', quality=95)
    assert msg.format == f'{encoding}; jpeg compressed {"" if encoding == "mono8" else "bgr8"}'
    decoded, out_encoding = decode_image(msg)
    assert out_encoding == ('mono8' if encoding == 'mono8' else 'bgr8')
    expected = _as_bgr(pixels, encoding).astype(np.float64)
    error = np.abs(decoded.astype(np.float64) - expected)
    assert error.mean() < (2.0 if encoding == 'mono8' else 5.0)  # colour: 4:2:0 chroma
    if encoding != 'mono8':
        assert np.abs(decoded[:, :, ::-1].astype(np.float64) - expected).mean() > \
            5 * error.mean()


@pytest.mark.parametrize(('fmt', 'stored', 'channels', 'bits'), [
    ('rgba8; jpeg compressed bgr8', 'bgr8', 3, 8),    # ZED-like bgra8 cameras, JPEG
    ('bgra8; png compressed bgr8', 'bgr8', 3, 8),
    ('rgb16; png compressed bgr16', 'bgr16', 3, 16),
    ('mono8; jpeg compressed ', 'mono8', 1, 8),       # mono: no stored name
    ('bayer_grbg8; png compressed ', 'bayer_grbg8', 1, 8),
])
def test_formats_as_image_transport_plugins_write_them(fmt: str, stored: str, channels: int,
                                                       bits: int) -> None:
    """Messages built the way the upstream publisher builds them (cv::imencode of the
    converted image, its format string), not with this package's encoder."""
    pixels = _texture(channels=channels, bits=bits)
    ok, data = cv2.imencode('.jpg' if 'jpeg' in fmt else '.png', pixels)
    assert ok
    decoded, encoding = decode_image(CompressedImage(format=fmt, data=data.tobytes()))
    assert encoding == stored
    assert decoded.shape == pixels.shape
    assert decoded.dtype == pixels.dtype


def test_rgb_compressed_without_the_bgr_swap_is_read_in_its_own_order() -> None:
    """A publisher that wrote ``compressed rgb8`` stored the channels as they were."""
    rgb = _texture(channels=3)
    rgb[:, :, 0] //= 4
    ok, png = cv2.imencode('.png', rgb)  # OpenCV would read these bytes as BGR
    assert ok
    msg = CompressedImage(format='rgb8; png compressed rgb8', data=png.tobytes())
    decoded, _ = decode_image(msg)
    np.testing.assert_array_equal(decoded, rgb)


@pytest.mark.parametrize(('fmt', 'channels', 'expected'), [
    ('jpeg', 1, 'mono8'), ('png', 3, 'bgr8'), ('', 1, 'mono8')])
def test_old_formats_without_an_encoding_follow_the_decoded_channels(
        fmt: str, channels: int, expected: str) -> None:
    pixels = _texture(channels=channels)
    ok, data = cv2.imencode('.png' if fmt != 'jpeg' else '.jpg', pixels)
    assert ok
    decoded, encoding = decode_image(CompressedImage(format=fmt, data=data.tobytes()))
    assert encoding == expected
    assert decoded.shape == pixels.shape


def test_a_compressed_bayer_mosaic_is_demosaiced_after_decoding() -> None:
    bgr = np.dstack([_texture(), _texture()[::-1], _texture()[:, ::-1]])
    mosaic = np.empty(bgr.shape[:2], np.uint8)
    mosaic[0::2, 0::2] = bgr[0::2, 0::2, 2]  # R G / G B
    mosaic[0::2, 1::2] = bgr[0::2, 1::2, 1]
    mosaic[1::2, 0::2] = bgr[1::2, 0::2, 1]
    mosaic[1::2, 1::2] = bgr[1::2, 1::2, 0]
    msg = compress_image(mosaic, 'bayer_rggb8', codec='png')
    assert msg.format == 'bayer_rggb8; png compressed '
    colour, encoding = image_pixels(msg)
    raw_colour, _ = image_pixels(array_to_image(mosaic, 'bayer_rggb8'))
    assert encoding == 'bgr8'
    np.testing.assert_array_equal(colour, raw_colour)
    np.testing.assert_array_equal(gray_image(msg), gray_image(array_to_image(mosaic,
                                                                             'bayer_rggb8')))


# -- compressedDepth ----------------------------------------------------------------------


def test_rvl_stream_layout_matches_the_format() -> None:
    """[0, 0, 5]: two zeros, one non-zero, zigzag(5) = 10 in two 3-bit nibbles: the nibbles
    2, 1, A, 1 fill the top of one little-endian word."""
    stream = rvl_encode(np.array([[0, 0, 5]], np.uint16))
    assert stream == struct.pack('<I', 0x21A10000)
    np.testing.assert_array_equal(rvl_decode(stream, 3, 1), [[0, 0, 5]])


def test_rvl_round_trips_runs_jumps_and_extremes() -> None:
    rng = np.random.default_rng(5)
    depth = rng.integers(1, 65536, (37, 23)).astype(np.uint16)
    depth[rng.random(depth.shape) < 0.4] = 0
    depth[0, :5] = [65535, 1, 65535, 0, 65535]
    np.testing.assert_array_equal(rvl_decode(rvl_encode(depth), 23, 37), depth)
    zeros = np.zeros((4, 9), np.uint16)
    np.testing.assert_array_equal(rvl_decode(rvl_encode(zeros), 9, 4), zeros)


def test_damaged_rvl_is_an_error_never_an_overrun() -> None:
    depth = np.arange(1, 61, dtype=np.uint16).reshape(6, 10)
    stream = rvl_encode(depth)
    with pytest.raises(MessageError, match='the stream ends before the image does'):
        rvl_decode(stream[:8], 10, 6)
    with pytest.raises(MessageError, match='a run is longer than the image'):
        rvl_decode(rvl_encode(np.zeros((1, 100), np.uint16)), 10, 6)
    rng = np.random.default_rng(0)
    for _ in range(300):  # random bytes: an error or an image, nothing else
        noise = rng.integers(0, 256, rng.integers(0, 64)).astype(np.uint8).tobytes()
        try:
            out = rvl_decode(noise, 10, 6)
        except MessageError:
            continue
        assert out.shape == (6, 10)


@pytest.mark.parametrize('codec', ['png', 'rvl'])
def test_compressed_depth_16uc1_is_exact(codec: str) -> None:
    depth = _texture(bits=16) // 8  # millimetres up to 8 m
    depth[5:9, 5:9] = 0
    msg = compress_depth(depth, '16UC1', codec=codec)
    assert msg.format == f'16UC1; compressedDepth {codec}'
    decoded, encoding = decode_image(msg)
    assert encoding == '16UC1'
    np.testing.assert_array_equal(decoded, depth)


@pytest.mark.parametrize('codec', ['png', 'rvl'])
def test_compressed_depth_32fc1_is_within_its_quantisation(codec: str) -> None:
    depth = 0.5 + _texture().astype(np.float32) / 255 * 7.0  # 0.5 .. 7.5 m
    depth[0, :3] = [np.nan, 12.0, np.inf]  # unknown, beyond depth_max: no depth
    msg = compress_depth(depth, '32FC1', codec=codec, depth_max=10.0,
                         depth_quantization=100.0)
    decoded, encoding = decode_image(msg)
    assert encoding == '32FC1'
    assert np.isnan(decoded[0, :3]).all()
    valid = np.isfinite(depth) & (depth < 10)
    # inverse-depth steps of a / q^2: about z^2 / a, 7.5 m -> 5.6 mm; allow one step
    step = depth[valid] ** 2 / (100.0 * 101.0)
    assert (np.abs(decoded[valid] - depth[valid]) <= step + 1e-6).all()


# -- hostile messages -------------------------------------------------------------------------


def test_damaged_and_foreign_compressed_images_are_errors_of_their_kind() -> None:
    good = compress_image(_texture(), 'mono8', codec='jpeg')
    data = bytes(good.data)
    with pytest.raises(DecodeError, match='could not be decoded'):
        decode_image(CompressedImage(format=good.format, data=data[:len(data) // 3]))
    with pytest.raises(DecodeError, match='neither a PNG nor a JPEG'):
        decode_image(CompressedImage(format=good.format, data=b'\x00' * 100))
    with pytest.raises(UnsupportedFormatError, match="'mono8; h264 compressed mono8' is not"):
        decode_image(CompressedImage(format='mono8; h264 compressed mono8', data=data))
    colour = compress_image(_texture(channels=3), 'bgr8', codec='jpeg')
    with pytest.raises(DecodeError, match='says mono8 but decodes to 3 channel'):
        decode_image(CompressedImage(format='mono8; jpeg compressed mono8',
                                     data=bytes(colour.data)))
    with pytest.raises(EncodingError, match="encoding 'yuv420'"):
        decode_image(CompressedImage(format='yuv420; png compressed yuv420', data=data))
    with pytest.raises(UnsupportedFormatError, match="compressedDepth of encoding 'mono8'"):
        decode_image(CompressedImage(format='mono8; compressedDepth png', data=b'\0' * 40))
    with pytest.raises(DecodeError, match='has no image after its 12-byte header'):
        decode_image(CompressedImage(format='16UC1; compressedDepth png', data=b'\0' * 12))


def test_a_stream_claiming_a_huge_image_is_refused_before_decoding() -> None:
    ok, png = cv2.imencode('.png', np.zeros((4, 4), np.uint8))
    assert ok
    forged = bytearray(png.tobytes())
    forged[16:24] = struct.pack('>II', 100_000, 100_000)  # IHDR width, height
    with pytest.raises(DecodeError, match=f'claims a 100000x100000 image .at most {MAX_PIXELS}'):
        decode_image(CompressedImage(format='mono8; png compressed mono8', data=bytes(forged)))
    rvl = CompressedImage(format='16UC1; compressedDepth rvl',
                          data=struct.pack('<iff', 0, 0, 0) + struct.pack('<II', 1 << 20, 1 << 20))
    with pytest.raises(DecodeError, match='RVL claims a 1048576x1048576 image'):
        decode_image(rvl)


def test_transport_topics_and_types() -> None:
    assert transport_topic('/cam/left/image_raw', 'raw') == '/cam/left/image_raw'
    assert transport_topic('/cam/left/image_raw', 'compressed') == \
        '/cam/left/image_raw/compressed'
    assert transport_type('compressedDepth') is CompressedImage
    with pytest.raises(UnsupportedFormatError, match="image_transport 'theora' is not one of"):
        transport_type('theora')
