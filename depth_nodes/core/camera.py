"""Pinhole camera models with lens distortion, as ROS CameraInfo describes them.

Conventions follow sensor_msgs/CameraInfo: ``K`` is the 3x3 intrinsic matrix of the raw
(distorted) image, ``D`` the distortion coefficients of ``distortion_model``, ``R`` the
rotation from the raw camera frame to the rectified frame (x_rect = R @ x_raw) and ``P`` the
3x4 projection matrix of the rectified camera. For the right camera of a rectified stereo
pair ``P[0, 3] = -fx * baseline``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

PLUMB_BOB = 'plumb_bob'
RATIONAL_POLYNOMIAL = 'rational_polynomial'
EQUIDISTANT = 'equidistant'

FloatArray = NDArray[np.float64]


def _identity3() -> FloatArray:
    return np.eye(3)


@dataclass
class CameraModel:
    """One calibrated camera (the content of a sensor_msgs/CameraInfo, as arrays).

    Attributes:
        width: Full-resolution image width in pixels.
        height: Full-resolution image height in pixels.
        K: (3, 3) raw-image intrinsics.
        D: (n,) distortion coefficients of ``distortion_model``.
        R: (3, 3) rectification rotation, raw camera frame -> rectified frame.
        P: (3, 4) projection matrix of the rectified camera.
        distortion_model: ``plumb_bob``, ``rational_polynomial`` or ``equidistant``.
        binning_x: Horizontal binning (0 and 1 both mean none).
        binning_y: Vertical binning (0 and 1 both mean none).
        roi: (x_offset, y_offset, width, height, do_rectify); width 0 means full image.
        frame_id: Optical frame of the camera.
    """

    width: int
    height: int
    K: FloatArray
    D: FloatArray = field(default_factory=lambda: np.zeros(5))
    R: FloatArray = field(default_factory=_identity3)
    P: FloatArray = field(default_factory=lambda: np.zeros((3, 4)))
    distortion_model: str = PLUMB_BOB
    binning_x: int = 0
    binning_y: int = 0
    roi: tuple[int, int, int, int, bool] = (0, 0, 0, 0, False)
    frame_id: str = ''
