"""Camera-native encodings (Bayer in four orders and two depths, YUV 4:2:2, NV21) decoded
to BGR by depth_nodes.ros.image, checked against the colour image they were made from.

The mosaics and YUV layouts are built here from a known smooth colour image by plain numpy
(which sample of which colour sits where), so a decoder that mixed up an order or swapped
red and blue would be far off."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from depth_nodes.errors import EncodingError, MessageError
from depth_nodes.ros.image import (
    CAMERA_ENCODINGS,
    DEBAYER_METHODS,
    array_to_image,
    decode_camera_image,
    image_to_array,
    to_gray,
    to_rgb8,
)
from depth_nodes.ros.transport import gray_image as gray_pixels
from depth_nodes.ros.transport import image_pixels as message_pixels

#: Mean |decoded - original| allowed (grey levels of 255) away from a 4 px border: a smooth
#: image loses little to interpolation; a wrong order swaps red and blue by ~100 levels.
TOLERANCE = 3.0


def _scene(h: int = 48, w: int = 64, bits: int = 8) -> np.ndarray:
    """A smooth BGR image with distinct channels (gradients in different directions)."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    b = 40 + 150 * x / w
    g = 60 + 120 * y / h
    r = 200 - 120 * (x + y) / (w + h)
    img = np.stack([b, g, r], axis=2)
    if bits == 16:
        return np.rint(img * 257).astype(np.uint16)
    return np.rint(img).astype(np.uint8)


def _mosaic(bgr: np.ndarray, order: str) -> np.ndarray:
    """Sample ``bgr`` on a Bayer tile named top-left first (ROS's naming: 'rggb' is R G / G B)."""
    channel = {'b': 0, 'g': 1, 'r': 2}
    out = np.empty(bgr.shape[:2], bgr.dtype)
    for i, c in enumerate(order):
        dy, dx = divmod(i, 2)
        out[dy::2, dx::2] = bgr[dy::2, dx::2, channel[c]]
    return out


def _mean_error(a: np.ndarray, b: np.ndarray, scale: float = 1.0) -> float:
    inner = (slice(4, -4), slice(4, -4))
    return float(np.mean(np.abs(a[inner].astype(np.float64) - b[inner])) / scale)


@pytest.mark.parametrize('order', ['rggb', 'bggr', 'gbrg', 'grbg'])
@pytest.mark.parametrize('bits', [8, 16])
@pytest.mark.parametrize('method', sorted(DEBAYER_METHODS))
def test_bayer_mosaics_decode_to_the_colour_they_sampled(order: str, bits: int,
                                                         method: int) -> None:
    bgr = _scene(bits=bits)
    encoding = f'bayer_{order}{bits}'
    msg = array_to_image(_mosaic(bgr, order), encoding)
    pixels, out_encoding = message_pixels(msg, debayer=method)
    assert out_encoding == ('bgr8' if bits == 8 else 'bgr16')
    assert pixels.dtype == bgr.dtype
    assert pixels.shape == bgr.shape
    assert _mean_error(pixels, bgr, 257.0 if bits == 16 else 1.0) < TOLERANCE
    # the same mosaic read as another order is far off: the test can tell orders apart
    wrong = {'rggb': 'bggr', 'bggr': 'rggb', 'gbrg': 'grbg', 'grbg': 'gbrg'}[order]
    swapped, _ = decode_camera_image(image_to_array(msg), f'bayer_{wrong}{bits}',
                                     debayer=method)
    assert _mean_error(swapped, bgr, 257.0 if bits == 16 else 1.0) > 10 * TOLERANCE


@pytest.mark.parametrize('order', ['rggb', 'gbrg'])
def test_bayer_to_grey_matches_the_grey_of_the_colour_image(order: str) -> None:
    bgr = _scene()
    grey = gray_pixels(array_to_image(_mosaic(bgr, order), f'bayer_{order}8'))
    assert grey.dtype == np.uint8
    assert _mean_error(grey, cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)) < TOLERANCE


def _bt601(bgr: np.ndarray) -> np.ndarray:
    """Y, U (Cb), V (Cr) of ITU-R BT.601 in the limited range cameras use (Y 16..235)."""
    b, g, r = (bgr[:, :, i].astype(np.float64) / 255 for i in range(3))
    y = 16 + 65.481 * r + 128.553 * g + 24.966 * b
    u = 128 - 37.797 * r - 74.203 * g + 112.0 * b
    v = 128 + 112.0 * r - 93.786 * g - 18.214 * b
    return np.stack([y, u, v], axis=2)


def _uyvy(bgr: np.ndarray, yuy2: bool) -> np.ndarray:
    """YUV 4:2:2 by hand: per pixel pair U Y0 V Y1 (UYVY, ROS's yuv422) or Y0 U Y1 V (YUY2)."""
    yuv = _bt601(bgr)
    y = yuv[:, :, 0]
    u = (yuv[:, 0::2, 1] + yuv[:, 1::2, 1]) / 2
    v = (yuv[:, 0::2, 2] + yuv[:, 1::2, 2]) / 2
    out = np.empty((*bgr.shape[:2], 2), np.float64)
    chroma, luma = (1, 0) if yuy2 else (0, 1)
    out[:, 0::2, chroma], out[:, 1::2, chroma] = u, v
    out[:, :, luma] = y
    return np.rint(out).astype(np.uint8)


@pytest.mark.parametrize('encoding', ['yuv422', 'yuv422_yuy2'])
def test_yuv422_decodes_to_the_colour_it_encoded(encoding: str) -> None:
    bgr = _scene()
    msg = array_to_image(_uyvy(bgr, encoding == 'yuv422_yuy2'), encoding)
    assert msg.step == 2 * bgr.shape[1]
    pixels, out_encoding = message_pixels(msg)
    assert out_encoding == 'bgr8'
    assert _mean_error(pixels, bgr) < TOLERANCE
    assert _mean_error(gray_pixels(msg), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)) < TOLERANCE


def _nv21(bgr: np.ndarray) -> np.ndarray:
    """NV21 by hand: the Y plane, then V and U interleaved at half resolution."""
    yuv = _bt601(bgr)
    h, w = bgr.shape[:2]
    half = yuv.reshape(h // 2, 2, w // 2, 2, 3).mean(axis=(1, 3))
    vu = np.stack([half[:, :, 2], half[:, :, 1]], axis=2).reshape(h // 2, w)
    return np.rint(np.vstack([yuv[:, :, 0], vu])).astype(np.uint8)


def test_nv21_decodes_to_the_colour_it_encoded() -> None:
    bgr = _scene()
    msg = array_to_image(_nv21(bgr), 'nv21')
    assert (msg.height, msg.width, msg.step) == (48, 64, 64)
    assert len(msg.data) == 64 * 72
    assert image_to_array(msg).shape == (72, 64)
    pixels, out_encoding = message_pixels(msg)
    assert out_encoding == 'bgr8'
    assert _mean_error(pixels, bgr) < TOLERANCE


def test_sixteen_bit_colour_to_grey_and_rgb8() -> None:
    bgr16 = _scene(bits=16)
    bgr8 = _scene(bits=8)
    assert _mean_error(to_rgb8(bgr16, 'bgr16'), bgr8[:, :, ::-1]) < 1.0
    assert _mean_error(to_gray(bgr16, 'bgr16') / 257.0,
                       cv2.cvtColor(bgr8, cv2.COLOR_BGR2GRAY)) < 1.0


@pytest.mark.parametrize(('encoding', 'shape', 'match'), [
    ('bayer_rggb8', (47, 64), r'bayer_rggb8 image is 64x47: a Bayer mosaic needs an even'),
    ('bayer_gbrg16', (48, 63), r'bayer_gbrg16 image is 63x48'),
    ('yuv422', (48, 63, 2), r'yuv422 image is 63x48: YUV 4:2:2 needs an even width'),
])
def test_odd_sizes_are_malformed(encoding: str, shape: tuple[int, ...], match: str) -> None:
    dtype = CAMERA_ENCODINGS[encoding][0]
    msg = array_to_image(np.zeros(shape, dtype), encoding)
    with pytest.raises(MessageError, match=match):
        message_pixels(msg)
    with pytest.raises(MessageError, match=match):
        gray_pixels(msg)


def test_odd_nv21_is_malformed() -> None:
    msg = array_to_image(np.zeros((72, 63), np.uint8), 'nv21')
    with pytest.raises(MessageError,
                       match=r'nv21 image of 72 stored rows \(63 wide\): NV21 needs an even'):
        message_pixels(msg)


def test_misuse_is_refused_with_the_reason() -> None:
    mosaic = _mosaic(_scene(), 'rggb')
    with pytest.raises(EncodingError, match='debayer method 7 is not one of 0, 1, 2, 3'):
        decode_camera_image(mosaic, 'bayer_rggb8', debayer=7)
    with pytest.raises(EncodingError, match='bayer_rggb8 pixels must be decoded first'):
        to_gray(mosaic, 'bayer_rggb8')
    with pytest.raises(EncodingError, match='a 32FC1 image is not a camera image'):
        gray_pixels(array_to_image(np.zeros((2, 2), np.float32), '32FC1'))
