"""sensor_msgs/Image <-> numpy, the package's small cv_bridge.

Reading works on rclpy messages (``data`` is ``array.array`` or ``bytes``) and on rosbags
messages (``data`` is a uint8 numpy array): only ``height``, ``width``, ``encoding``,
``step``, ``is_bigendian`` and ``data`` are read.

Decisions:
    * ``len(data)`` must be at least ``step * height`` (even the last row must be complete);
      extra trailing bytes are ignored.
    * An image with zero width or height reads as an empty array of the right shape and
      dtype, whatever ``data`` holds.
    * ``8UC3`` is treated as BGR (as cv_bridge does) by :func:`to_gray` / :func:`to_rgb8`.
    * Camera-native encodings (:data:`CAMERA_ENCODINGS`: Bayer mosaics in the four orders,
      8 and 16 bit; ``yuv422`` (UYVY), ``yuv422_yuy2`` (YUYV), ``nv21``) read as they are
      stored; :func:`decode_camera_image` turns them into ``bgr8`` / ``bgr16`` (as
      image_proc's debayer node does), and every consumer of pixels calls it first
      (through ``ros.transport.image_pixels`` / ``gray_image``), so demosaicing happens
      before rectification, never after. A Bayer or NV21 image must
      have an even width and height, a YUV 4:2:2 image an even width.
"""

from __future__ import annotations

import array
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import Image

from depth_nodes.errors import EncodingError, MessageError

#: Supported encodings: name -> (dtype of one channel, channels).
ENCODINGS: dict[str, tuple[np.dtype[Any], int]] = {
    'mono8': (np.dtype(np.uint8), 1),
    'mono16': (np.dtype(np.uint16), 1),
    'rgb8': (np.dtype(np.uint8), 3),
    'bgr8': (np.dtype(np.uint8), 3),
    'rgba8': (np.dtype(np.uint8), 4),
    'bgra8': (np.dtype(np.uint8), 4),
    '8UC1': (np.dtype(np.uint8), 1),
    '8UC3': (np.dtype(np.uint8), 3),
    '16UC1': (np.dtype(np.uint16), 1),
    '32FC1': (np.dtype(np.float32), 1),
    'rgb16': (np.dtype(np.uint16), 3),
    'bgr16': (np.dtype(np.uint16), 3),
    'rgba16': (np.dtype(np.uint16), 4),
    'bgra16': (np.dtype(np.uint16), 4),
}

#: Bayer orders: ROS names the 2x2 tile from the top-left pixel, and so do OpenCV's
#: ``COLOR_Bayer<TILE>2...`` codes (its older names, ``BayerBG`` for RGGB, differ).
_BAYER_ORDERS = {
    'rggb': 'RGGB', 'bggr': 'BGGR', 'gbrg': 'GBRG', 'grbg': 'GRBG',
}
#: Debayering methods, image_proc's debayer node's codes: 0 bilinear, 1 edge-aware,
#: 2 edge-aware weighted (OpenCV has one edge-aware method: the same), 3 VNG (8 bit only;
#: 16-bit images fall back to edge-aware).
DEBAYER_METHODS = {0: '', 1: '_EA', 2: '_EA', 3: '_VNG'}


def _bayer(tile: str, bits: int) -> tuple[str, np.dtype[Any]]:
    return f'bayer_{tile}{bits}', np.dtype(np.uint8 if bits == 8 else np.uint16)


#: Camera-native encodings: stored as ``(dtype, channels)`` like :data:`ENCODINGS`, turned
#: into bgr8 / bgr16 by :func:`decode_camera_image`.
CAMERA_ENCODINGS: dict[str, tuple[np.dtype[Any], int]] = {
    **{name: (dtype, 1) for tile in _BAYER_ORDERS for name, dtype in
       (_bayer(tile, 8), _bayer(tile, 16))},
    'yuv422': (np.dtype(np.uint8), 2),
    'yuv422_yuy2': (np.dtype(np.uint8), 2),
    'nv21': (np.dtype(np.uint8), 1),
}
#: Every encoding :func:`image_to_array` reads.
READABLE_ENCODINGS = {**ENCODINGS, **CAMERA_ENCODINGS}

_TO_GRAY = {
    'rgb8': cv2.COLOR_RGB2GRAY,
    'bgr8': cv2.COLOR_BGR2GRAY,
    '8UC3': cv2.COLOR_BGR2GRAY,
    'rgba8': cv2.COLOR_RGBA2GRAY,
    'bgra8': cv2.COLOR_BGRA2GRAY,
    'rgb16': cv2.COLOR_RGB2GRAY,
    'bgr16': cv2.COLOR_BGR2GRAY,
    'rgba16': cv2.COLOR_RGBA2GRAY,
    'bgra16': cv2.COLOR_BGRA2GRAY,
}
_TO_RGB = {
    'bgr8': cv2.COLOR_BGR2RGB,
    '8UC3': cv2.COLOR_BGR2RGB,
    'rgba8': cv2.COLOR_RGBA2RGB,
    'bgra8': cv2.COLOR_BGRA2RGB,
    'bgr16': cv2.COLOR_BGR2RGB,
    'rgba16': cv2.COLOR_RGBA2RGB,
    'bgra16': cv2.COLOR_BGRA2RGB,
}


def encoding_info(encoding: str) -> tuple[np.dtype[Any], int]:
    """Return (channel dtype, channels) of ``encoding`` as stored in a message.

    Raises:
        EncodingError: The encoding is not in :data:`READABLE_ENCODINGS`.
    """
    try:
        return READABLE_ENCODINGS[encoding]
    except KeyError:
        raise EncodingError(
            f'unsupported image encoding {encoding!r}; supported: '
            f'{", ".join(READABLE_ENCODINGS)}') from None


def set_message_bytes(msg: Any, data: array.array[int]) -> None:
    """``msg.data = data`` for an ``array('B')``, without the copy the generated setter makes.

    rosidl_generator_py's setter of a ``uint8[]`` field keeps an ``array('B')`` as given only
    when the message checks its fields (``ROS_PYTHON_CHECK_FIELDS=1``); otherwise it copies
    it into a new one (9.8 MB for a padded 640x480 colour cloud, 0.7 - 3 ms). Its classes
    keep the field in the slot ``_data``, which takes the array as it is.
    """
    if data.typecode == 'B' and '_data' in getattr(type(msg), '__slots__', ()):
        msg._data = data
    else:
        msg.data = data


def array_bytes(arr: NDArray[Any]) -> array.array[int]:
    """A C-contiguous array's bytes as a new ``array('B')``, in one copy."""
    data = array.array('B')
    contiguous: Any = np.ascontiguousarray(arr).reshape(-1)  # 1-D: empty arrays cast too
    data.frombytes(memoryview(contiguous).cast('B'))
    return data


def buffer_as_uint8(data: Any) -> NDArray[np.uint8]:
    """View a message's ``data`` (bytes, array.array, numpy array, list) as flat uint8."""
    if isinstance(data, np.ndarray):
        return data.reshape(-1).view(np.uint8) if data.dtype.itemsize == 1 else (
            np.ascontiguousarray(data).reshape(-1).view(np.uint8))
    try:
        return np.frombuffer(data, dtype=np.uint8)
    except (TypeError, ValueError):
        return np.asarray(data, dtype=np.uint8).reshape(-1)


def image_to_array(msg: Any) -> NDArray[Any]:
    """Convert a sensor_msgs/Image to a numpy array, without copying when possible.

    Args:
        msg: An rclpy or rosbags sensor_msgs/Image.

    Returns:
        (H, W) for one channel, (H, W, C) otherwise, of the encoding's dtype in native byte
        order (``nv21``: (H * 3 / 2, W), the Y plane above the V/U rows; convert camera
        encodings with :func:`decode_camera_image`). For little-endian data this is a
        strided view of ``msg.data`` (row padding skipped; read-only when ``data`` is
        ``bytes``); big-endian multi-byte data is byte-swapped into a new array.

    Raises:
        EncodingError: Unknown encoding.
        MessageError: ``step`` shorter than a row, or ``data`` shorter than
            ``step * height``.
    """
    dtype, channels = encoding_info(msg.encoding)
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if msg.encoding == 'nv21':  # a full-size Y plane, then interleaved V/U at half size
        height += height // 2
    shape = (height, width) if channels == 1 else (height, width, channels)
    if height <= 0 or width <= 0:
        return np.empty((max(height, 0), max(width, 0), channels)[: len(shape)], dtype=dtype)
    row_bytes = width * channels * dtype.itemsize
    if step < row_bytes:
        raise MessageError(
            f'Image step {step} is smaller than a row: width {width} x {channels} channel(s) '
            f'x {dtype.itemsize} byte(s) ({msg.encoding}) = {row_bytes}'
        )
    buf = buffer_as_uint8(msg.data)
    if buf.size < step * height:
        raise MessageError(
            f'Image data has {buf.size} bytes, but step {step} x height {height} needs '
            f'{step * height}'
        )
    rows = buf[: step * height].reshape(height, step)[:, :row_bytes]
    big = bool(msg.is_bigendian) and dtype.itemsize > 1
    arr = rows.view(dtype.newbyteorder('>' if big else '<'))
    if big or not arr.dtype.isnative:
        arr = arr.astype(dtype)  # byte-swap to native (copies)
    return arr.reshape(shape)


def array_to_image(arr: NDArray[Any], encoding: str, header: Any = None) -> Image:
    """Build an rclpy sensor_msgs/Image from an array (data copied once, as bytes).

    Args:
        arr: (H, W) or (H, W, 1) for one-channel encodings, (H, W, C) otherwise, of exactly
            the encoding's dtype (any byte order, any strides).
        encoding: A key of :data:`ENCODINGS`.
        header: A std_msgs/Header to copy into the message; default an empty header.

    Returns:
        The message, with ``step = width * bytes_per_pixel`` and ``is_bigendian = 0``.

    Raises:
        EncodingError: Unknown encoding, or dtype / channel count not those of the encoding.
        MessageError: ``arr`` is not 2-D or 3-D.
    """
    dtype, channels = check_array(arr, encoding)
    height, width = arr.shape[:2]
    if encoding == 'nv21':  # the stored rows are the Y plane and the V/U rows below it
        height = height * 2 // 3
    msg = Image()
    if header is not None:
        msg.header = header
    msg.height, msg.width, msg.encoding = height, width, encoding
    msg.is_bigendian = 0
    msg.step = width * channels * dtype.itemsize
    set_message_bytes(msg, array_bytes(np.asarray(arr, dtype=dtype.newbyteorder('<'))))
    return msg


def check_array(arr: NDArray[Any], encoding: str) -> tuple[np.dtype[Any], int]:
    """Check that ``arr`` fits ``encoding``; return (channel dtype, channels).

    Raises:
        EncodingError: Unknown encoding, wrong dtype or wrong channel count.
        MessageError: ``arr`` is not a 2-D or 3-D numpy array.
    """
    dtype, channels = encoding_info(encoding)
    if not isinstance(arr, np.ndarray) or arr.ndim not in (2, 3):
        shape = getattr(arr, 'shape', type(arr).__name__)
        raise MessageError(f'image array must be 2-D or 3-D, got shape {shape}')
    got = 1 if arr.ndim == 2 else arr.shape[2]
    if got != channels:
        raise EncodingError(
            f'encoding {encoding} needs {channels} channel(s), array shape {arr.shape} has {got}'
        )
    if arr.dtype.newbyteorder('=') != dtype.newbyteorder('='):
        raise EncodingError(f'encoding {encoding} needs dtype {dtype}, got {arr.dtype}')
    return dtype, channels


def _plain(encoding: str) -> None:
    if encoding in CAMERA_ENCODINGS:
        raise EncodingError(f'{encoding} pixels must be decoded first (decode_camera_image)')


def to_gray(arr: NDArray[Any], encoding: str) -> NDArray[Any]:
    """Return a 2-D single-channel image: colour -> luminance (cv2), mono passed through.

    Args:
        arr: An image of ``encoding`` (as :func:`image_to_array` returns it).
        encoding: A key of :data:`ENCODINGS`.

    Returns:
        (H, W) array of the input's dtype.

    Raises:
        EncodingError / MessageError: As :func:`check_array`.
    """
    _, channels = check_array(arr, encoding)
    _plain(encoding)
    if channels == 1:
        return arr.reshape(arr.shape[:2])
    return np.asarray(cv2.cvtColor(np.ascontiguousarray(arr), _TO_GRAY[encoding]))


def to_rgb8(arr: NDArray[Any], encoding: str) -> NDArray[np.uint8]:
    """Return an (H, W, 3) uint8 RGB image (mono replicated into the three channels).

    16-bit mono is scaled to 8 bits (``round(v / 257)``, so 65535 -> 255).

    Args:
        arr: An image of ``encoding``.
        encoding: A key of :data:`ENCODINGS`; 32FC1 has no colour scale and is refused.

    Returns:
        (H, W, 3) uint8; ``arr`` itself when it already is rgb8.

    Raises:
        EncodingError: 32FC1, or as :func:`check_array`.
    """
    dtype, channels = check_array(arr, encoding)
    _plain(encoding)
    if encoding == 'rgb8':
        return arr
    if channels > 1:
        rgb = arr if encoding == 'rgb16' else cv2.cvtColor(np.ascontiguousarray(arr),
                                                           _TO_RGB[encoding])
        if dtype == np.uint16:
            rgb = np.rint(np.asarray(rgb) / 257.0).astype(np.uint8)
        return np.asarray(rgb)
    if dtype == np.float32:
        raise EncodingError(f'cannot convert {encoding} to rgb8: no defined colour scale')
    mono = arr.reshape(arr.shape[:2])
    if dtype == np.uint16:
        mono = np.rint(mono / 257.0).astype(np.uint8)
    return np.repeat(mono[:, :, None], 3, axis=2)


def _even_mosaic(arr: NDArray[Any], encoding: str) -> None:
    h, w = arr.shape[:2]
    if h % 2 or w % 2:
        raise MessageError(f'{encoding} image is {w}x{h}: a Bayer mosaic needs an even '
                           'width and height')


def bayer_to_gray(arr: NDArray[Any], encoding: str) -> NDArray[Any]:
    """A Bayer mosaic (``bayer_<tile><bits>``) interpolated straight to grey.

    Raises:
        MessageError: An odd width or height.
    """
    _even_mosaic(arr, encoding)
    code = getattr(cv2, f'COLOR_Bayer{_BAYER_ORDERS[encoding[6:10]]}2GRAY')
    return np.asarray(cv2.cvtColor(np.ascontiguousarray(arr), code))


def to_uint8(grey: NDArray[Any]) -> NDArray[np.uint8]:
    """A grey image as 8 bits: 16-bit samples by their top byte (cv_bridge's mono8 of a
    mono16 image scales the same way), 8-bit ones as they are."""
    if grey.dtype == np.uint16:
        return np.ascontiguousarray(grey >> 8, dtype=np.uint8)
    return np.ascontiguousarray(grey, dtype=np.uint8)


def decode_camera_image(arr: NDArray[Any], encoding: str, *,
                        debayer: int = 3) -> tuple[NDArray[Any], str]:
    """Turn a camera-native image (:data:`CAMERA_ENCODINGS`) into ``bgr8`` (``bgr16`` for a
    16-bit Bayer mosaic); any other encoding is returned as it is.

    Args:
        arr: The stored pixels, as :func:`image_to_array` returns them.
        encoding: The message's encoding.
        debayer: A key of :data:`DEBAYER_METHODS` (image_proc's debayer codes).

    Returns:
        ``(pixels, encoding)``.

    Raises:
        MessageError: A Bayer or NV21 image with an odd width or height, a YUV 4:2:2 image
            with an odd width (no real sensor delivers those; the sample layout is broken).
        EncodingError: An unknown ``debayer`` method.
    """
    if encoding not in CAMERA_ENCODINGS:
        return arr, encoding
    if encoding.startswith('bayer_'):
        _even_mosaic(arr, encoding)
        if debayer not in DEBAYER_METHODS:
            raise EncodingError(f'debayer method {debayer!r} is not one of '
                                f'{", ".join(map(str, DEBAYER_METHODS))}')
        tile = _BAYER_ORDERS[encoding[6:10]]
        sixteen = arr.dtype == np.uint16
        suffix = DEBAYER_METHODS[debayer]
        if sixteen and suffix == '_VNG':
            suffix = '_EA'  # OpenCV's VNG takes 8-bit mosaics only
        code = getattr(cv2, f'COLOR_Bayer{tile}2BGR{suffix}')
        return (np.asarray(cv2.cvtColor(np.ascontiguousarray(arr), code)),
                'bgr16' if sixteen else 'bgr8')
    if encoding == 'nv21':
        h = arr.shape[0] * 2 // 3
        w = arr.shape[1]
        if h % 2 or w % 2 or arr.shape[0] != h + h // 2:
            raise MessageError(f'nv21 image of {arr.shape[0]} stored rows ({w} wide): NV21 '
                               'needs an even width and height')
        return np.asarray(cv2.cvtColor(np.ascontiguousarray(arr), cv2.COLOR_YUV2BGR_NV21)), 'bgr8'
    if arr.shape[1] % 2:
        raise MessageError(f'{encoding} image is {arr.shape[1]}x{arr.shape[0]}: YUV 4:2:2 '
                           'needs an even width')
    code = cv2.COLOR_YUV2BGR_UYVY if encoding == 'yuv422' else cv2.COLOR_YUV2BGR_YUY2
    return np.asarray(cv2.cvtColor(np.ascontiguousarray(arr), code)), 'bgr8'
