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
"""

from __future__ import annotations

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
}

_TO_GRAY = {
    'rgb8': cv2.COLOR_RGB2GRAY,
    'bgr8': cv2.COLOR_BGR2GRAY,
    '8UC3': cv2.COLOR_BGR2GRAY,
    'rgba8': cv2.COLOR_RGBA2GRAY,
    'bgra8': cv2.COLOR_BGRA2GRAY,
}
_TO_RGB = {
    'bgr8': cv2.COLOR_BGR2RGB,
    '8UC3': cv2.COLOR_BGR2RGB,
    'rgba8': cv2.COLOR_RGBA2RGB,
    'bgra8': cv2.COLOR_BGRA2RGB,
}


def encoding_info(encoding: str) -> tuple[np.dtype[Any], int]:
    """Return (channel dtype, channels) of ``encoding``.

    Raises:
        EncodingError: The encoding is not in :data:`ENCODINGS`.
    """
    try:
        return ENCODINGS[encoding]
    except KeyError:
        raise EncodingError(
            f'unsupported image encoding {encoding!r}; supported: {", ".join(ENCODINGS)}'
        ) from None


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
        order. For little-endian data this is a strided view of ``msg.data`` (row padding
        skipped; read-only when ``data`` is ``bytes``); big-endian multi-byte data is
        byte-swapped into a new array.

    Raises:
        EncodingError: Unknown encoding.
        MessageError: ``step`` shorter than a row, or ``data`` shorter than
            ``step * height``.
    """
    dtype, channels = encoding_info(msg.encoding)
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
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
    msg = Image()
    if header is not None:
        msg.header = header
    msg.height, msg.width, msg.encoding = height, width, encoding
    msg.is_bigendian = 0
    msg.step = width * channels * dtype.itemsize
    msg.data = np.ascontiguousarray(arr, dtype=dtype.newbyteorder('<')).tobytes()
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


def to_gray(arr: NDArray[Any], encoding: str) -> NDArray[Any]:
    """Return a 2-D single-channel image: colour -> luminance (cv2), mono passed through.

    Args:
        arr: An image of ``encoding`` (as :func:`image_to_array` returns it).
        encoding: A key of :data:`ENCODINGS`.

    Returns:
        (H, W) array: uint8 for colour input, the input's dtype for one-channel input.

    Raises:
        EncodingError / MessageError: As :func:`check_array`.
    """
    _, channels = check_array(arr, encoding)
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
    if encoding == 'rgb8':
        return arr
    if channels > 1:
        return np.asarray(cv2.cvtColor(np.ascontiguousarray(arr), _TO_RGB[encoding]))
    if dtype == np.float32:
        raise EncodingError(f'cannot convert {encoding} to rgb8: no defined colour scale')
    mono = arr.reshape(arr.shape[:2])
    if dtype == np.uint16:
        mono = np.rint(mono / 257.0).astype(np.uint8)
    return np.repeat(mono[:, :, None], 3, axis=2)
