"""Radiometry: the right image given the left's brightness before the intensity cost.

The census compares a pixel with its own neighbours, so a gain or offset between the
cameras does not change it; the intensity term does. ``match_brightness`` maps the right
image's mean and standard deviation onto the left's before that term
(:func:`matched_brightness`): a 20% gain difference otherwise made census + BT wrong on
most pixels of the Middlebury pairs.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

#: Bounds of the gain :func:`matched_brightness` applies (a flat or nearly black image
#: would otherwise be stretched without limit).
GAIN_LIMITS = (0.25, 4.0)


def matched_brightness(left: NDArray[np.generic], right: NDArray[np.generic]) -> NDArray[Any]:
    """``right`` with the mean and standard deviation of ``left`` (a global gain and offset).

    Integer images stay of their dtype (rounded and clipped to its range, through a lookup
    table); others become float32. The gain is bounded by :data:`GAIN_LIMITS`.
    """
    left, right = np.asarray(left), np.asarray(right)
    (ml, sl), (mr, sr) = (_mean_std(img) for img in (left, right))
    gain = 1.0 if sr <= 1e-6 or sl <= 1e-6 else min(max(sl / sr, GAIN_LIMITS[0]),
                                                      GAIN_LIMITS[1])
    if right.dtype in (np.uint8, np.uint16):
        top = 255 if right.dtype == np.uint8 else 65535
        levels = np.arange(top + 1, dtype=np.float64)
        table = np.clip(np.rint((levels - mr) * gain + ml), 0, top).astype(right.dtype)
        mapped_levels: NDArray[Any] = table[right]
        return mapped_levels
    mapped = (right.astype(np.float64) - mr) * gain + ml
    if np.issubdtype(right.dtype, np.integer):
        info = np.iinfo(right.dtype.name)
        return np.clip(np.rint(mapped), info.min, info.max).astype(right.dtype)
    return mapped.astype(np.float32)


def _mean_std(image: NDArray[Any]) -> tuple[float, float]:
    """Mean and standard deviation of an image (OpenCV's single pass where it can)."""
    if image.dtype in (np.uint8, np.uint16, np.float32) and image.ndim == 2:
        mean, std = cv2.meanStdDev(np.ascontiguousarray(image))
        return float(mean[0, 0]), float(std[0, 0])
    values = image.astype(np.float64)
    return float(values.mean()), float(values.std())
