"""stereo_msgs/DisparityImage building and reading, with the conventions of docs/design.md
("Messages").

Decisions:
    * Invalid pixels (NaN, inf, or below ``min_disparity``) are stored as
      ``min_disparity - 1.0``: strictly below ``min_disparity`` as the message spec asks,
      and finite so that viewers which take min/max do not break.
    * ``valid_window`` as a tuple is ``(x0, y0, x1, y1)`` with exclusive ends
      (``width = x1 - x0``); an empty window is the all-zero RegionOfInterest.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import RegionOfInterest
from stereo_msgs.msg import DisparityImage

from depth_nodes.core.stamps import stamp_ns
from depth_nodes.errors import EncodingError, MessageError
from depth_nodes.ros.image import array_to_image, image_to_array

#: Offset below ``min_disparity`` at which invalid pixels are stored.
INVALID_OFFSET = 1.0

Window = tuple[int, int, int, int]


@dataclass
class DisparityFrame:
    """A decoded DisparityImage.

    Attributes:
        disparity: (H, W) float32, NaN where invalid.
        focal: Rectified focal length ``f`` in pixels.
        baseline: Baseline ``t`` in metres.
        min_disparity: Smallest disparity the matcher searched.
        max_disparity: Largest disparity it can represent.
        delta_d: Smallest disparity increment.
        valid_window: (x0, y0, x1, y1), exclusive ends; all zero when empty.
        stamp_ns: Header stamp in integer nanoseconds.
        frame_id: Header frame.
    """

    disparity: NDArray[np.float32]
    focal: float
    baseline: float
    min_disparity: float
    max_disparity: float
    delta_d: float
    valid_window: Window
    stamp_ns: int
    frame_id: str


def valid_bbox(valid: NDArray[np.bool_]) -> Window:
    """Bounding box (x0, y0, x1, y1), exclusive ends, of the True pixels; zeros if none."""
    cols = np.flatnonzero(valid.any(axis=0))
    rows = np.flatnonzero(valid.any(axis=1))
    if cols.size == 0:
        return (0, 0, 0, 0)
    return (int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1)


def _roi(window: Window, width: int, height: int) -> RegionOfInterest:
    x0, y0, x1, y1 = (int(v) for v in window)
    if not (0 <= x0 <= x1 <= width and 0 <= y0 <= y1 <= height):
        raise MessageError(
            f'valid_window (x0 {x0}, y0 {y0}, x1 {x1}, y1 {y1}) must satisfy '
            f'0 <= x0 <= x1 <= width {width} and 0 <= y0 <= y1 <= height {height}'
        )
    if x1 == x0 or y1 == y0:
        return RegionOfInterest()
    return RegionOfInterest(x_offset=x0, y_offset=y0, width=x1 - x0, height=y1 - y0)


def build_disparity(
    disparity: NDArray[np.floating[Any]],
    header: Any,
    *,
    focal: float,
    baseline: float,
    min_disparity: float,
    max_disparity: float,
    delta_d: float,
    valid_window: Window | None = None,
) -> DisparityImage:
    """Build a stereo_msgs/DisparityImage.

    Args:
        disparity: (H, W) float disparities in pixels, NaN (or anything non-finite or below
            ``min_disparity``) where invalid. Not modified.
        header: std_msgs/Header of the left image, copied into the message and its image
            (``None``: an empty header).
        focal: Rectified focal length in pixels (``f``).
        baseline: Baseline in metres (``t``).
        min_disparity: Smallest searched disparity.
        max_disparity: Largest representable disparity.
        delta_d: Real sub-pixel step (e.g. 1/16 for OpenCV's fixed point).
        valid_window: (x0, y0, x1, y1) with exclusive ends; ``None`` computes the bounding
            box of the valid pixels.

    Returns:
        The message, image 32FC1, invalid pixels stored as ``min_disparity - 1``.

    Raises:
        MessageError: ``disparity`` not 2-D, a non-finite parameter, ``min_disparity >
            max_disparity``, or ``valid_window`` outside the image.
    """
    disparity = np.asarray(disparity)
    if disparity.ndim != 2:
        raise MessageError(f'disparity must be a (H, W) array, got shape {disparity.shape}')
    params = {'focal': focal, 'baseline': baseline, 'min_disparity': min_disparity,
              'max_disparity': max_disparity, 'delta_d': delta_d}
    for name, value in params.items():
        if not np.isfinite(value):
            raise MessageError(f'{name} must be finite, got {value}')
    if min_disparity > max_disparity:
        raise MessageError(
            f'min_disparity {min_disparity} is greater than max_disparity {max_disparity}'
        )
    with np.errstate(invalid='ignore'):
        valid = np.isfinite(disparity) & (disparity >= min_disparity)
    stored = np.where(valid, disparity, np.float32(min_disparity - INVALID_OFFSET))
    height, width = disparity.shape
    window = valid_bbox(valid) if valid_window is None else valid_window
    msg = DisparityImage()
    if header is not None:
        msg.header = header
    msg.image = array_to_image(stored.astype(np.float32), '32FC1', header)
    msg.f, msg.t = float(focal), float(baseline)
    msg.min_disparity, msg.max_disparity = float(min_disparity), float(max_disparity)
    msg.delta_d = float(delta_d)
    msg.valid_window = _roi(window, width, height)
    return msg


def read_disparity(msg: Any) -> DisparityFrame:
    """Decode a DisparityImage (rclpy or rosbags) into a :class:`DisparityFrame`.

    Args:
        msg: The message.

    Returns:
        The frame; the disparity is a fresh array with NaN where the stored value is
        non-finite or below ``min_disparity``.

    Raises:
        EncodingError: The image is not 32FC1.
        MessageError: The image is malformed (see
            :func:`~depth_nodes.ros.image.image_to_array`) or empty, a field is not finite,
            ``min_disparity > max_disparity``, ``delta_d`` is negative, or ``valid_window``
            is not inside the image.
    """
    if msg.image.encoding != '32FC1':
        raise EncodingError(
            f'DisparityImage image encoding must be 32FC1, got {msg.image.encoding!r}'
        )
    if msg.image.width == 0 or msg.image.height == 0:
        raise MessageError(f'DisparityImage image is empty ({msg.image.width}x'
                           f'{msg.image.height})')
    fields = {'f': msg.f, 't': msg.t, 'min_disparity': msg.min_disparity,
              'max_disparity': msg.max_disparity, 'delta_d': msg.delta_d}
    for name, value in fields.items():
        if not np.isfinite(value):
            raise MessageError(f'DisparityImage {name} is {value}, not a finite number')
    if msg.min_disparity > msg.max_disparity:
        raise MessageError(f'DisparityImage min_disparity {msg.min_disparity} is greater '
                           f'than max_disparity {msg.max_disparity}')
    if msg.delta_d < 0:
        raise MessageError(f'DisparityImage delta_d {msg.delta_d} is negative')
    disparity = np.array(image_to_array(msg.image), dtype=np.float32)
    min_d = float(msg.min_disparity)
    with np.errstate(invalid='ignore'):
        disparity[~(disparity >= min_d)] = np.nan
    roi = msg.valid_window
    x0, y0, w, h = int(roi.x_offset), int(roi.y_offset), int(roi.width), int(roi.height)
    if w and h and (x0 + w > disparity.shape[1] or y0 + h > disparity.shape[0]):
        raise MessageError(f'DisparityImage valid_window (x {x0}, y {y0}, {w}x{h}) is not '
                           f'inside the {disparity.shape[1]}x{disparity.shape[0]} image')
    window = (x0, y0, x0 + w, y0 + h) if w and h else (0, 0, 0, 0)
    stamp = msg.header.stamp
    return DisparityFrame(
        disparity=disparity,
        focal=float(msg.f),
        baseline=float(msg.t),
        min_disparity=min_d,
        max_disparity=float(msg.max_disparity),
        delta_d=float(msg.delta_d),
        valid_window=window,
        stamp_ns=stamp_ns(stamp),
        frame_id=str(msg.header.frame_id),
    )
