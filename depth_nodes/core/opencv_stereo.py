"""OpenCV's StereoSGBM, run the way stereo_image_proc runs it, as the reference to beat.

The figures depth_nodes reports are always printed beside these, measured on the same
rectified images in the same run.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import ArgumentError


@dataclass(frozen=True)
class SgbmSettings:
    """StereoSGBM settings, named like stereo_image_proc's disparity node parameters."""

    label: str
    mode: int = cv2.STEREO_SGBM_MODE_SGBM
    correlation_window_size: int = 15
    P1: int = 200
    P2: int = 400
    uniqueness_ratio: int = 15
    speckle_size: int = 100
    speckle_range: int = 4
    disp12_max_diff: int = 0
    prefilter_cap: int = 31


#: stereo_image_proc's disparity node defaults (full_dp false -> MODE_SGBM).
STEREO_IMAGE_PROC_DEFAULTS = SgbmSettings('opencv SGBM MODE_SGBM, stereo_image_proc defaults')

#: The usual tuning for StereoSGBM (P1 = 8 cn w^2, P2 = 32 cn w^2, small window), full DP.
TUNED_HH = SgbmSettings(
    'opencv SGBM MODE_HH, tuned P1/P2',
    mode=cv2.STEREO_SGBM_MODE_HH,
    correlation_window_size=5,
    P1=8 * 25,
    P2=32 * 25,
    uniqueness_ratio=10,
    speckle_size=100,
    speckle_range=2,
    disp12_max_diff=1,
    prefilter_cap=63,
)

#: stereo_image_proc's defaults with full_dp true (MODE_HH).
STEREO_IMAGE_PROC_DEFAULTS_HH = SgbmSettings(
    'opencv SGBM MODE_HH, stereo_image_proc defaults', mode=cv2.STEREO_SGBM_MODE_HH)

#: The tuned settings with MODE_SGBM (5 directions, single pass).
TUNED_SGBM = replace(TUNED_HH, label='opencv SGBM MODE_SGBM, tuned P1/P2',
                     mode=cv2.STEREO_SGBM_MODE_SGBM)

BASELINES = (STEREO_IMAGE_PROC_DEFAULTS, STEREO_IMAGE_PROC_DEFAULTS_HH, TUNED_SGBM, TUNED_HH)

#: The three tunings of :data:`SGBM_GRID`: (name, uniqueness_ratio, speckle_size,
#: speckle_range, disp12_max_diff, prefilter_cap).
GRID_TUNINGS = (
    ('sip filters', 15, 100, 4, 0, 31),
    ('tuned', 10, 100, 2, 1, 63),
    ('loose', 5, 0, 0, -1, 63),
)


def _grid() -> tuple[SgbmSettings, ...]:
    settings = []
    for mode, mode_name in ((cv2.STEREO_SGBM_MODE_SGBM, 'MODE_SGBM'),
                            (cv2.STEREO_SGBM_MODE_HH, 'MODE_HH')):
        for window in (3, 5, 7):
            for name, uniqueness, size, span, lr, cap in GRID_TUNINGS:
                settings.append(SgbmSettings(
                    f'opencv {mode_name} w{window} {name}', mode=mode,
                    correlation_window_size=window, P1=8 * window * window,
                    P2=32 * window * window, uniqueness_ratio=uniqueness, speckle_size=size,
                    speckle_range=span, disp12_max_diff=lr, prefilter_cap=cap))
    return tuple(settings)


#: 18 StereoSGBM settings to take OpenCV's best from: MODE_SGBM (5 directions) and MODE_HH
#: (8) x block sizes 3, 5, 7 (P1 = 8 w^2, P2 = 32 w^2, OpenCV's documented rule for a
#: one-channel image) x three tunings of its filters (:data:`GRID_TUNINGS`):
#: stereo_image_proc's (uniqueness 15, speckles 100 / 4 px, no left-right check,
#: prefilter cap 31), the usual tuning (10, 100 / 2 px, left-right 1 px, 63) and a loose
#: one (5, no speckle filter, no left-right check, 63).
SGBM_GRID = _grid()


@dataclass(frozen=True)
class BmSettings:
    """StereoBM settings, named like stereo_image_proc's disparity node parameters (its
    defaults; stereo_algorithm 0, upstream's default algorithm)."""

    label: str = 'opencv BM, stereo_image_proc defaults'
    correlation_window_size: int = 15
    prefilter_size: int = 9
    prefilter_cap: int = 31
    texture_threshold: int = 10
    uniqueness_ratio: int = 15
    speckle_size: int = 100
    speckle_range: int = 4


def opencv_range(min_disparity: int, max_disparity: float) -> int:
    """The smallest multiple of 16 that covers [min_disparity, max_disparity]."""
    span = max(float(max_disparity) - min_disparity + 1.0, 16.0)
    return int(np.ceil(span / 16.0) * 16)


def opencv_sgbm(
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    settings: SgbmSettings = STEREO_IMAGE_PROC_DEFAULTS,
    *,
    min_disparity: int = 0,
    disparity_range: int = 64,
) -> NDArray[np.float32]:
    """Run StereoSGBM on a rectified mono8 pair.

    Args:
        left: (H, W) uint8 rectified left image.
        right: (H, W) uint8 rectified right image.
        settings: Matcher settings.
        min_disparity: Smallest disparity searched.
        disparity_range: Number of disparities; OpenCV needs a positive multiple of 16.

    Returns:
        (H, W) float32 disparity in pixels, NaN where OpenCV marks the pixel invalid.

    Raises:
        ArgumentError: Shapes or dtypes differ, or the range is not a multiple of 16.
    """
    _check_pair(left, right, disparity_range)
    matcher = cv2.StereoSGBM.create(
        minDisparity=int(min_disparity),
        numDisparities=int(disparity_range),
        blockSize=settings.correlation_window_size,
        P1=settings.P1,
        P2=settings.P2,
        disp12MaxDiff=settings.disp12_max_diff,
        preFilterCap=settings.prefilter_cap,
        uniquenessRatio=settings.uniqueness_ratio,
        speckleWindowSize=settings.speckle_size,
        speckleRange=settings.speckle_range,
        mode=settings.mode,
    )
    return _to_pixels(matcher.compute(left, right), min_disparity)


def _to_pixels(raw: NDArray[Any], min_disparity: int) -> NDArray[np.float32]:
    """OpenCV's 1/16 px fixed point to float px, NaN where it marks a pixel invalid."""
    disparity = raw.astype(np.float32) / 16.0
    disparity[raw < min_disparity * 16] = np.nan
    return disparity


def _check_pair(left: NDArray[np.uint8], right: NDArray[np.uint8], disparity_range: int) -> None:
    if left.ndim != 2 or left.shape != right.shape:
        raise ArgumentError(f'left {left.shape} and right {right.shape} must be 2-D and of one '
                            'shape')
    if left.dtype != np.uint8 or right.dtype != np.uint8:
        raise ArgumentError(f'images must be uint8, got {left.dtype} and {right.dtype}')
    if disparity_range <= 0 or disparity_range % 16:
        raise ArgumentError(f'disparity_range must be a positive multiple of 16, '
                            f'got {disparity_range}')


def opencv_bm(
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    settings: BmSettings = BmSettings(),
    *,
    min_disparity: int = 0,
    disparity_range: int = 64,
) -> NDArray[np.float32]:
    """Run StereoBM (block matching, stereo_image_proc's stereo_algorithm 0) on a rectified
    mono8 pair, set as stereo_image_proc sets it (no left-right check).

    Returns:
        (H, W) float32 disparity in pixels, NaN where OpenCV marks the pixel invalid.

    Raises:
        ArgumentError: Shapes or dtypes differ, the range is not a multiple of 16, or a window
            is even or outside 5..255.
    """
    _check_pair(left, right, disparity_range)
    for name in ('correlation_window_size', 'prefilter_size'):
        value = getattr(settings, name)
        if value % 2 == 0 or not 5 <= value <= 255:
            raise ArgumentError(f'{name} must be odd, 5..255 for block matching, got {value}')
    matcher = cv2.StereoBM.create(numDisparities=int(disparity_range),
                                  blockSize=settings.correlation_window_size)
    matcher.setMinDisparity(int(min_disparity))
    matcher.setPreFilterSize(settings.prefilter_size)
    matcher.setPreFilterCap(settings.prefilter_cap)
    matcher.setTextureThreshold(settings.texture_threshold)
    matcher.setUniquenessRatio(settings.uniqueness_ratio)
    matcher.setSpeckleWindowSize(settings.speckle_size)
    matcher.setSpeckleRange(settings.speckle_range)
    return _to_pixels(matcher.compute(left, right), min_disparity)

