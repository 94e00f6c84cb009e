"""Rectification maps from a camera model (raw pixel coordinates per rectified pixel)."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import EQUIDISTANT, CameraModel

Map = NDArray[np.float32]


def rectification_maps(model: CameraModel) -> tuple[Map, Map]:
    """For every rectified pixel, the raw-image coordinates to sample.

    Uses K, D, R and the rectified camera matrix P[:, :3] (K when P is all zero); R is
    applied even when every distortion coefficient is zero.

    Args:
        model: The calibrated camera; its full-resolution size is the output size.

    Returns:
        (map_x, map_y), each (height, width) float32, for ``cv2.remap``.
    """
    size = (int(model.width), int(model.height))
    new_k = model.projection[:, :3]
    K = np.asarray(model.K, dtype=np.float64)
    D = np.asarray(model.D, dtype=np.float64)
    R = np.asarray(model.R, dtype=np.float64)
    if model.distortion_model == EQUIDISTANT:
        map_x, map_y = cv2.fisheye.initUndistortRectifyMap(K, D, R, new_k, size, cv2.CV_32FC1)
    else:
        map_x, map_y = cv2.initUndistortRectifyMap(K, D, R, new_k, size, cv2.CV_32FC1)
    return np.asarray(map_x, dtype=np.float32), np.asarray(map_y, dtype=np.float32)


def rectify_image(image: NDArray[Any], model: CameraModel,
                  interpolation: int = cv2.INTER_LINEAR) -> NDArray[Any]:
    """Rectify one raw image (computes the maps each call; cache them for streams)."""
    map_x, map_y = rectification_maps(model)
    return np.asarray(cv2.remap(image, map_x, map_y, interpolation))
