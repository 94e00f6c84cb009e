"""image_transport's formats: pixels from a sensor_msgs/Image or CompressedImage.

Nodes subscribe an image input either raw (``sensor_msgs/Image`` on the topic) or, with
their ``image_transport`` parameter as image_pipeline's nodes have it, compressed
(``sensor_msgs/CompressedImage`` on ``<topic>/compressed`` or
``<topic>/compressedDepth``). Either kind of message goes through the synchronisers as it
is (they match header stamps only) and is decoded here when its frame is processed, so a
frame that cannot be decoded is counted once, under one reason.

Formats read (image_transport_plugins' conventions):

* ``compressed``: ``format`` is ``"<encoding>; <jpeg|png> compressed <stored>"``: the
  publisher converted a colour image to ``<stored>`` (``bgr8`` for JPEG, ``bgr8`` /
  ``bgr16`` for PNG; alpha dropped) before compressing it, so the pixels come back in
  that encoding; with no ``<stored>`` (mono and Bayer images) they are ``<encoding>``, and
  a Bayer mosaic is demosaiced after decoding, like a raw one. Older publishers wrote
  ``"jpeg"`` / ``"png"`` alone: the encoding then follows from the decoded channels.
* ``compressedDepth``: ``"<16UC1|32FC1>; compressedDepth <png|rvl>"``: a 12-byte header
  (int32 format, two float32 quantisation parameters) then a PNG or RVL image. 16UC1 is
  stored as it is; 32FC1 as quantised inverse depth, ``depth = a / (q - b)``, 0 meaning no
  depth (NaN).

A damaged stream, a compressed image whose size would exceed :data:`MAX_PIXELS`, or pixels
that disagree with the declared encoding raise :class:`~depth_nodes.errors.DecodeError`;
a format this module does not know raises
:class:`~depth_nodes.errors.UnsupportedFormatError`.
"""

from __future__ import annotations

import struct
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import CompressedImage, Image

from depth_nodes.errors import DecodeError, EncodingError, UnsupportedFormatError
from depth_nodes.ros.image import (
    READABLE_ENCODINGS,
    bayer_to_gray,
    decode_camera_image,
    image_to_array,
    to_gray,
    to_rgb8,
)
from depth_nodes.ros.rvl import rvl_decode, rvl_encode

__all__ = [
    'MAX_PIXELS', 'TRANSPORTS', 'compress_depth', 'compress_image', 'decode_depth',
    'decode_image', 'gray_image', 'image_pixels', 'is_compressed', 'transport_topic',
    'transport_type',
]

#: The transports a node's ``image_transport`` parameter takes.
TRANSPORTS = ('raw', 'compressed', 'compressedDepth')
#: Largest image a compressed message may decode to (16.7 Mpx: twice a 4K frame; at most
#: 128 MB of 16-bit RGBA); a header claiming more is refused before anything is allocated.
MAX_PIXELS = 1 << 24
#: compressedDepth's header: int32 format, float32 depthParam[2], little-endian.
_DEPTH_HEADER = struct.Struct('<iff')

Array = NDArray[Any]


def transport_topic(topic: str, transport: str) -> str:
    """The topic a transport uses for an image topic (image_transport's convention)."""
    return topic if transport == 'raw' else f'{topic.rstrip("/")}/{transport}'


def transport_type(transport: str) -> type:
    """The message class of a transport.

    Raises:
        UnsupportedFormatError: Not one of :data:`TRANSPORTS`.
    """
    if transport not in TRANSPORTS:
        raise UnsupportedFormatError(f'image_transport {transport!r} is not one of '
                                     f'{", ".join(TRANSPORTS)}')
    message: type = Image if transport == 'raw' else CompressedImage
    return message


def is_compressed(msg: Any) -> bool:
    """True for a CompressedImage (rclpy or rosbags), False for an Image."""
    return hasattr(msg, 'format') and not hasattr(msg, 'encoding')


# -- sizes from the headers (before any allocation) ----------------------------------------


def _png_size(data: bytes) -> tuple[int, int] | None:
    if len(data) >= 24 and data[:8] == b'\x89PNG\r\n\x1a\n' and data[12:16] == b'IHDR':
        width, height = struct.unpack('>II', data[16:24])
        return int(width), int(height)
    return None


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    """Width and height from a JPEG's start-of-frame marker (None when there is none)."""
    if data[:2] != b'\xff\xd8':
        return None
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):  # markers without a length
            i += 2
            continue
        (length,) = struct.unpack('>H', data[i + 2:i + 4])
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            if i + 9 > len(data):
                return None
            height, width = struct.unpack('>HH', data[i + 5:i + 9])
            return int(width), int(height)
        i += 2 + length
    return None


def _imdecode(data: bytes, what: str) -> Array:
    size = _png_size(data) or _jpeg_size(data)
    if size is None:
        raise DecodeError(f'{what}: the data is neither a PNG nor a JPEG stream')
    if size[0] * size[1] > MAX_PIXELS or 0 in size:
        raise DecodeError(f'{what}: the stream claims a {size[0]}x{size[1]} image (at most '
                          f'{MAX_PIXELS} pixels, none empty)')
    pixels = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if pixels is None or pixels.size == 0:
        raise DecodeError(f'{what}: the data could not be decoded (damaged or truncated)')
    return np.asarray(pixels)


# -- compressed ----------------------------------------------------------------------------


def _split_format(fmt: str) -> tuple[str | None, str]:
    """(declared encoding or None, the rest) of a CompressedImage format."""
    if ';' not in fmt:
        return None, fmt.strip().lower()
    head, _, rest = fmt.partition(';')
    return head.strip(), rest.strip()


def _compressed_pixels(msg: Any) -> tuple[Array, str]:
    encoding, rest = _split_format(str(msg.format))
    codec = rest.split()[0] if rest.split() else ''
    if codec not in ('jpeg', 'jpg', 'png', ''):  # '': an old publisher; the data says
        raise UnsupportedFormatError(f'compressed image format {msg.format!r} is not JPEG or '
                                     'PNG (image_transport\'s compressed)')
    pixels = _imdecode(bytes(msg.data), 'compressed image')
    channels = 1 if pixels.ndim == 2 else pixels.shape[2]
    if encoding is None:  # an old publisher: the decoded image says what it is
        deep = pixels.dtype == np.uint16
        encoding = {1: 'mono16' if deep else 'mono8', 3: 'bgr16' if deep else 'bgr8',
                    4: 'bgra16' if deep else 'bgra8'}.get(channels, '')
        if not encoding:
            raise DecodeError(f'compressed image decodes to {channels} channels')
        return pixels, encoding
    target = rest.split()[2] if len(rest.split()) > 2 else None
    stored = target or encoding  # what the pixels were when they were compressed
    if stored not in READABLE_ENCODINGS:
        raise EncodingError(f'compressed image of encoding {stored!r}: not a camera image '
                            'encoding this package reads')
    dtype, want = READABLE_ENCODINGS[stored]
    if channels != want or pixels.dtype != dtype:
        raise DecodeError(f'compressed image says {stored} but decodes to {channels} '
                          f'channel(s) of {pixels.dtype}')
    return np.asarray(pixels), stored


# -- compressedDepth -------------------------------------------------------------------------


def decode_depth(msg: Any) -> tuple[Array, str]:
    """A compressedDepth message's depth image: ``(uint16 mm, '16UC1')`` or
    ``(float32 m with NaN, '32FC1')``.

    Raises:
        DecodeError / UnsupportedFormatError: See the module notes.
    """
    if 'compressedDepth' not in str(msg.format):
        raise UnsupportedFormatError(f'format {msg.format!r} is not compressedDepth')
    declared, _ = _split_format(str(msg.format))
    encoding = declared or '16UC1'
    codec = 'rvl' if 'compressedDepth rvl' in str(msg.format) else 'png'
    if encoding not in ('16UC1', '32FC1'):
        raise UnsupportedFormatError(f'compressedDepth of encoding {encoding!r}: only 16UC1 '
                                     'and 32FC1 exist')
    data = bytes(msg.data)
    if len(data) <= _DEPTH_HEADER.size:
        raise DecodeError(f'compressedDepth message of {len(data)} bytes has no image after '
                          'its 12-byte header')
    _, quant_a, quant_b = _DEPTH_HEADER.unpack_from(data)
    body = data[_DEPTH_HEADER.size:]
    if codec == 'png':
        raw = _imdecode(body, 'compressedDepth PNG')
        if raw.dtype != np.uint16 or raw.ndim != 2:
            raise DecodeError(f'compressedDepth PNG decodes to {raw.dtype} with '
                              f'{1 if raw.ndim == 2 else raw.shape[2]} channel(s), not 16-bit '
                              'grey')
    else:
        if len(body) < 8:
            raise DecodeError('compressedDepth RVL data has no size')
        width, height = struct.unpack('<II', body[:8])
        if not 0 < width * height <= MAX_PIXELS:
            raise DecodeError(f'compressedDepth RVL claims a {width}x{height} image')
        raw = rvl_decode(body[8:], width, height)
    if encoding == '16UC1':
        return raw, encoding
    if not (np.isfinite(quant_a) and np.isfinite(quant_b)) or quant_a == 0:
        raise DecodeError(f'compressedDepth quantisation ({quant_a}, {quant_b}) is not usable')
    with np.errstate(divide='ignore', invalid='ignore'):
        depth = np.where(raw > 0, quant_a / (raw.astype(np.float32) - np.float32(quant_b)),
                         np.nan).astype(np.float32)
    return depth, encoding


# -- one entry point for either kind -----------------------------------------------------------


def decode_image(msg: Any) -> tuple[Array, str]:
    """The stored pixels of an Image or a CompressedImage and their encoding (camera
    encodings, such as a Bayer mosaic, not yet decoded: see :func:`image_pixels`).

    Raises:
        MessageError (DecodeError, EncodingError, UnsupportedFormatError): As the formats.
    """
    if not is_compressed(msg):
        return image_to_array(msg), str(msg.encoding)
    if 'compressedDepth' in str(msg.format):
        return decode_depth(msg)
    return _compressed_pixels(msg)


def image_pixels(msg: Any, *, debayer: int = 3) -> tuple[Array, str]:
    """The pixels of an Image or CompressedImage in a plain encoding (``ENCODINGS``):
    decompressed, then Bayer / YUV decoded (``decode_camera_image``).

    Raises:
        MessageError: As :func:`decode_image` and ``decode_camera_image``.
    """
    pixels, encoding = decode_image(msg)
    return decode_camera_image(pixels, encoding, debayer=debayer)


def gray_image(msg: Any) -> Array:
    """A camera image message (raw or compressed) as one grey channel (uint8, or uint16 for
    16-bit input); a Bayer mosaic is interpolated straight to grey.

    Raises:
        EncodingError: A float image (32FC1) or an unknown encoding.
        MessageError: As :func:`decode_image`.
    """
    pixels, encoding = decode_image(msg)
    if encoding == '32FC1':
        raise EncodingError('a 32FC1 image is not a camera image')
    if encoding.startswith('bayer_'):
        return bayer_to_gray(pixels, encoding)
    pixels, encoding = decode_camera_image(pixels, encoding)
    return to_gray(pixels, encoding)


# -- writing (tests, tools, bag conversion) ---------------------------------------------------


def compress_image(pixels: Array, encoding: str, *, codec: str = 'jpeg', quality: int = 90,
                   header: Any = None) -> CompressedImage:
    """A CompressedImage as image_transport's ``compressed`` publisher writes it: a colour
    image converted to ``bgr8`` (JPEG) or ``bgr8`` / ``bgr16`` (PNG), alpha dropped, and
    named so in the format; one channel (mono, a Bayer mosaic) stored as it is.

    Args:
        pixels: An image of ``encoding``.
        encoding: Its encoding.
        codec: ``'jpeg'`` (8-bit output) or ``'png'``.
        quality: JPEG quality 1..100.
        header: A std_msgs/Header to copy.

    Raises:
        EncodingError: 16-bit mono as JPEG, or an encoding this package cannot write.
    """
    dtype, channels = READABLE_ENCODINGS.get(encoding, (None, 0))
    if dtype is None or channels == 2 or encoding == '32FC1' or encoding == 'nv21':
        raise EncodingError(f'cannot compress {encoding} pixels')
    data = np.ascontiguousarray(pixels)
    target = ''
    if channels >= 3:
        rgb = to_rgb8(data, encoding) if codec == 'jpeg' or dtype == np.uint8 else None
        if rgb is not None:
            data, target = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), 'bgr8'
        else:  # 16-bit colour as PNG keeps its depth
            code = {'rgb16': cv2.COLOR_RGB2BGR, 'rgba16': cv2.COLOR_RGBA2BGR,
                    'bgra16': cv2.COLOR_BGRA2BGR}.get(encoding)
            data, target = (cv2.cvtColor(data, code) if code is not None else data), 'bgr16'
    elif codec == 'jpeg' and dtype != np.uint8:
        raise EncodingError(f'JPEG takes 8-bit pixels, not {encoding}')
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)] if codec == 'jpeg' else [
        cv2.IMWRITE_PNG_COMPRESSION, 3]
    ok, buf = cv2.imencode('.jpg' if codec == 'jpeg' else '.png', data, params)
    if not ok:
        raise EncodingError(f'OpenCV could not write {encoding} as {codec}')
    msg = CompressedImage()
    if header is not None:
        msg.header = header
    msg.format = f'{encoding}; {codec} compressed {target}'
    msg.data = buf.tobytes()
    return msg


def compress_depth(depth: Array, encoding: str, *, codec: str = 'png',
                   depth_max: float = 10.0, depth_quantization: float = 100.0,
                   header: Any = None) -> CompressedImage:
    """A CompressedImage as image_transport's ``compressedDepth`` publisher writes it
    (16UC1 mm, or 32FC1 m quantised as inverse depth; PNG or RVL)."""
    if encoding == '32FC1':
        quant_a = depth_quantization * (depth_quantization + 1.0)
        quant_b = 1.0 - quant_a / depth_max
        with np.errstate(divide='ignore', invalid='ignore'):
            inv = np.where(np.isfinite(depth) & (depth < depth_max) & (depth > 0),
                           quant_a / depth + quant_b, 0)
        raw = np.clip(inv, 0, 65535).astype(np.uint16)
    elif encoding == '16UC1':
        quant_a = quant_b = 0.0
        raw = np.asarray(depth, np.uint16).copy()
        raw[raw > int(depth_max * 1000)] = 0
    else:
        raise EncodingError(f'compressedDepth takes 16UC1 or 32FC1, not {encoding}')
    if codec == 'png':
        ok, buf = cv2.imencode('.png', raw, [cv2.IMWRITE_PNG_COMPRESSION, 3])
        if not ok:
            raise EncodingError('OpenCV could not write the depth PNG')
        body = buf.tobytes()
    else:
        h, w = raw.shape
        body = struct.pack('<II', w, h) + rvl_encode(raw)
    msg = CompressedImage()
    if header is not None:
        msg.header = header
    msg.format = f'{encoding}; compressedDepth {codec}'
    msg.data = _DEPTH_HEADER.pack(0, quant_a, quant_b) + body
    return msg

