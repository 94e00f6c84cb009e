"""Ground-truth disparity files in the formats stereo benchmarks publish, and the
non-occlusion mask derived from a left and a right ground truth.

Formats (``fmt`` of :func:`read_disparity_file`):

* ``scaled``: an 8- or 16-bit PNG / PGM whose value is ``scale`` x the disparity, 0
  unknown (Middlebury 2001 and 2003: ``scale`` 8 or 4, depending on the image size).
* ``kitti``: a 16-bit PNG, disparity = value / 256, 0 unknown (KITTI 2012 / 2015).
* ``pfm``: Portable Float Map, float32 disparity, ``inf`` (or NaN) unknown (Middlebury
  2014, SceneFlow, ETH3D). Rows are stored bottom to top.

``auto`` picks ``pfm`` by the extension, ``kitti`` for a 16-bit PNG without a ``scale``,
``scaled`` otherwise (which then needs ``scale``). Unknown pixels are NaN in every array
returned here. A file that cannot be used raises :class:`~depth_nodes.errors.InputFileError`
naming the file.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import ArgumentError, InputFileError

__all__ = ['GT_FORMATS', 'nonoccluded_from_right', 'read_disparity_file', 'read_image',
           'read_pfm', 'write_pfm']

F32 = NDArray[np.float32]
GT_FORMATS = ('auto', 'scaled', 'kitti', 'pfm')
#: KITTI's fixed point: disparity = value / 256.
KITTI_SCALE = 256.0
#: Occlusion codes of an occlusion image (the simulator's convention).
VISIBLE, OCCLUDED, OUTSIDE = 0, 255, 128


def read_image(path: str | Path) -> NDArray[np.generic]:
    """An image file as it is stored: (H, W) grey or (H, W, 3) RGB, 8 or 16 bit.

    Raises:
        InputFileError: Missing or not an image OpenCV can read.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f'{path}: no such file')
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputFileError(f'{path}: not an image file OpenCV can read')
    if image.ndim == 3:
        if image.shape[2] == 4:
            image = image[:, :, :3]
        image = np.ascontiguousarray(image[:, :, ::-1])  # OpenCV's BGR to RGB
    return np.asarray(image)


def read_pfm(path: str | Path) -> F32:
    """A one-channel PFM file as float32 (top row first); a three-channel one's first
    channel.

    Raises:
        InputFileError: Missing, or not a PFM file.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputFileError(f'{path}: cannot read: {exc.strerror}') from None
    match = re.match(rb'(P[Ff])\s+(\d+)\s+(\d+)\s+(\S+)\s', data)
    if match is None:
        raise InputFileError(f'{path}: not a PFM file (no "Pf"/"PF" header)')
    channels = 3 if match.group(1) == b'PF' else 1
    width, height = int(match.group(2)), int(match.group(3))
    try:
        scale = float(match.group(4))
    except ValueError:
        raise InputFileError(f'{path}: PFM scale {match.group(4)!r} is not a number') from None
    dtype = np.dtype('<f4' if scale < 0 else '>f4')
    count = width * height * channels
    body = data[match.end():]
    if len(body) < count * 4:
        raise InputFileError(f'{path}: PFM of {width}x{height}x{channels} needs {count * 4} '
                             f'bytes of data, the file has {len(body)}')
    values = np.frombuffer(body, dtype, count).reshape(height, width, channels)
    return np.ascontiguousarray(values[::-1, :, 0], dtype=np.float32)


def write_pfm(path: str | Path, disparity: F32) -> None:
    """Write a (H, W) float map as a little-endian one-channel PFM."""
    arr = np.asarray(disparity, np.float32)
    if arr.ndim != 2:
        raise ArgumentError(f'disparity must be (H, W), got shape {arr.shape}')
    header = f'Pf\n{arr.shape[1]} {arr.shape[0]}\n-1.0\n'.encode('ascii')
    Path(path).write_bytes(header + arr[::-1].astype('<f4').tobytes())


def read_disparity_file(path: str | Path, *, fmt: str = 'auto',
                        scale: float | None = None) -> F32:
    """A ground-truth disparity map in px, NaN where unknown (see the module notes).

    Args:
        path: The file.
        fmt: ``auto``, ``scaled``, ``kitti`` or ``pfm``.
        scale: Stored value per px of disparity (``scaled``; overrides KITTI's 256).

    Raises:
        InputFileError: The file cannot be read, or does not fit the format.
        ArgumentError: Unknown ``fmt`` or a non-positive ``scale``.
    """
    if fmt not in GT_FORMATS:
        raise ArgumentError(f'fmt must be one of {", ".join(GT_FORMATS)}, got {fmt!r}')
    if scale is not None and not scale > 0:
        raise ArgumentError(f'scale must be > 0, got {scale!r}')
    path = Path(path)
    if fmt == 'pfm' or (fmt == 'auto' and path.suffix.lower() == '.pfm'):
        disparity = read_pfm(path)
        disparity[~np.isfinite(disparity)] = np.nan
        return disparity
    raw = read_image(path)
    if raw.ndim != 2:
        raise InputFileError(f'{path}: a disparity image must have one channel, this one has '
                             f'{raw.shape[2]}')
    if fmt == 'auto':
        fmt = 'kitti' if raw.dtype == np.uint16 and scale is None else 'scaled'
    if fmt == 'kitti':
        if raw.dtype != np.uint16:
            raise InputFileError(f'{path}: a KITTI disparity is a 16-bit PNG, this one is '
                                 f'{raw.dtype}')
        scale = scale or KITTI_SCALE
    elif scale is None:
        raise InputFileError(f'{path}: a {raw.dtype} disparity image needs its scale (stored '
                             'value per px; Middlebury 2003 quarter size: 4, 2001: 8)')
    disparity = raw.astype(np.float32) / np.float32(scale)
    disparity[raw == 0] = np.nan
    return disparity


def nonoccluded_from_right(left_gt: F32, right_gt: F32, *, tolerance: float = 1.0
                           ) -> NDArray[np.uint8]:
    """The occlusion image of the left view from both views' ground truth.

    A left pixel ``x`` with disparity ``d`` is visible in the right view when the right
    ground truth at ``round(x - d)`` agrees with ``d`` within ``tolerance`` px (the rule of
    the Middlebury 2003 README). Codes: :data:`VISIBLE` (0), :data:`OCCLUDED` (255),
    :data:`OUTSIDE` (128: ``x - d`` is outside the right image); pixels without left
    ground truth are OCCLUDED (nothing is known of them).

    Raises:
        ArgumentError: The maps differ in shape or are not 2-D.
    """
    left = np.asarray(left_gt, np.float32)
    right = np.asarray(right_gt, np.float32)
    if left.ndim != 2 or left.shape != right.shape:
        raise ArgumentError(f'left and right ground truth must be equal 2-D shapes, got '
                            f'{left.shape} and {right.shape}')
    h, w = left.shape
    known = np.isfinite(left)
    xs = np.broadcast_to(np.arange(w), (h, w))
    xr = np.rint(xs - np.where(known, left, 0.0)).astype(np.int64)
    inside = known & (xr >= 0) & (xr < w)
    partner = np.full((h, w), np.nan, np.float32)
    ys, xi = np.nonzero(inside)
    partner[ys, xi] = right[ys, xr[ys, xi]]
    with np.errstate(invalid='ignore'):
        agree = inside & (np.abs(partner - left) <= tolerance)
    out = np.full((h, w), OCCLUDED, np.uint8)
    out[known & ~inside] = OUTSIDE
    out[agree] = VISIBLE
    return out
