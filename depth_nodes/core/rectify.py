"""Undistortion and rectification of raw images from a calibrated camera model.

The rectified camera is the model's ``P`` (``[K | 0]`` when ``P`` is all zero) and the
rotation ``R`` is always applied, also when every distortion coefficient is zero (a pair
whose only flaw is a relative rotation still needs it). Binning and ROI are honoured by
working in the delivered image's own pixel frame (:meth:`CameraModel.binned`): the
rectified image covers the same pixel window as the raw one, as image_geometry does.

Maps are expensive (tens of ms at 640x480) and depend only on the calibration, so
:class:`Rectifier` builds them once and reuses them until the calibration changes; per
frame it costs one ``cv2.remap``.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import EQUIDISTANT, CameraModel, validate_camera
from depth_nodes.errors import ArgumentError

Map = NDArray[Any]

#: Interpolation names and the OpenCV flags behind them. image_proc's integer parameter
#: values are these flags (0 nearest, 1 linear, 2 cubic, 3 area, 4 lanczos4). For a remap,
#: OpenCV treats ``area`` as ``linear``.
INTERPOLATIONS: dict[str, int] = {
    'nearest': cv2.INTER_NEAREST,
    'linear': cv2.INTER_LINEAR,
    'cubic': cv2.INTER_CUBIC,
    'area': cv2.INTER_AREA,
    'lanczos4': cv2.INTER_LANCZOS4,
}


def interpolation_flag(value: int | str) -> int:
    """The OpenCV flag for an interpolation given by name or by image_proc's integer code.

    Raises:
        ArgumentError: Neither a known name nor a code in 0..4.
    """
    if isinstance(value, str) and value.lower() in INTERPOLATIONS:
        return INTERPOLATIONS[value.lower()]
    if isinstance(value, int) and not isinstance(value, bool) and value in INTERPOLATIONS.values():
        return value
    names = ', '.join(f'{name} ({flag})' for name, flag in INTERPOLATIONS.items())
    raise ArgumentError(f'interpolation must be one of {names}; got {value!r}')


def calibration_key(model: CameraModel) -> tuple[Any, ...]:
    """Everything the rectification maps depend on, as a hashable value."""
    return (
        int(model.width), int(model.height), model.distortion_model,
        int(model.binning_x), int(model.binning_y), tuple(model.roi[:4]),
        *(np.asarray(m, dtype=np.float64).tobytes() for m in (model.K, model.D, model.R,
                                                               model.P)),
    )


def rectification_maps(model: CameraModel, *, fixed_point: bool = True) -> tuple[Map, Map]:
    """For every rectified pixel of the delivered image, the raw coordinates to sample.

    Args:
        model: The calibrated camera (binning and ROI included).
        fixed_point: Return OpenCV's fixed-point maps (CV_16SC2 + CV_16UC1, 1/32 px
            steps), about twice as fast to remap as float maps; else float32 maps.

    Returns:
        (map1, map2) for ``cv2.remap``, each of the delivered (binned / ROI) image size.

    Raises:
        CalibrationError: The model is not usable (uncalibrated, non-finite, ...).
    """
    validate_camera(model)
    cam = model.binned()
    size = (int(cam.width), int(cam.height))
    new_k = cam.projection[:, :3]
    K = np.asarray(cam.K, dtype=np.float64).reshape(3, 3)
    D = np.asarray(cam.D, dtype=np.float64).ravel()
    R = np.asarray(cam.R, dtype=np.float64).reshape(3, 3)
    map_type = cv2.CV_16SC2 if fixed_point else cv2.CV_32FC1
    if cam.distortion_model == EQUIDISTANT:
        D = D if D.size else np.zeros(4)
        map1, map2 = cv2.fisheye.initUndistortRectifyMap(K, D, R, new_k, size, map_type)
    else:
        map1, map2 = cv2.initUndistortRectifyMap(K, D, R, new_k, size, map_type)
    return np.asarray(map1), np.asarray(map2)


def rectify_image(image: NDArray[Any], model: CameraModel,
                  interpolation: int | str = cv2.INTER_LINEAR) -> NDArray[Any]:
    """Rectify one raw image, building the maps for this call only.

    For a stream use :class:`Rectifier`, which keeps the maps.
    """
    map1, map2 = rectification_maps(model)
    return np.asarray(cv2.remap(image, map1, map2, interpolation_flag(interpolation)))


class Rectifier:
    """Rectifies a stream of images, rebuilding the maps only when the calibration changes.

    Attributes:
        rebuilds: How many times maps were built (1 for a fixed calibration).
    """

    def __init__(self, *, fixed_point: bool = True) -> None:
        self.fixed_point = fixed_point
        self.rebuilds = 0
        self._key: tuple[Any, ...] | None = None
        self._maps: tuple[Map, Map] | None = None
        self._model: CameraModel | None = None
        self._out: NDArray[Any] | None = None

    def maps(self, model: CameraModel) -> tuple[Map, Map]:
        """The maps of ``model``, from the cache when its calibration is unchanged.

        Passing the very same model object again skips even the comparison, so a model must
        not be modified in place once used: pass a new one when the calibration changes.

        Raises:
            CalibrationError: The model is not usable; the cache is left as it was.
        """
        if model is self._model and self._maps is not None:
            return self._maps  # the caller passes the same (unchanged) model every frame
        key = calibration_key(model)
        if key != self._key or self._maps is None:
            self._maps = rectification_maps(model, fixed_point=self.fixed_point)
            self._key = key
            self.rebuilds += 1
        self._model = model
        return self._maps

    def rectify(self, image: NDArray[Any], model: CameraModel,
                interpolation: int | str = cv2.INTER_LINEAR, *,
                reuse_output: bool = False) -> NDArray[Any]:
        """Rectify ``image`` taken by ``model``.

        Args:
            image: (H, W) or (H, W, C) raw image of the delivered size (any dtype remap
                supports: uint8, uint16, float32).
            model: Its calibration.
            interpolation: A name of :data:`INTERPOLATIONS` or an OpenCV flag.
            reuse_output: Write into a buffer kept between calls instead of a new array
                (no per-frame allocation); the result is then overwritten by the next call
                with the same shape and dtype, so copy it to keep it.

        Raises:
            CalibrationError: The model is not usable.
            ArgumentError: The image size differs from the calibration's, or a bad
                interpolation.
        """
        map1, map2 = self.maps(model)
        if image.shape[:2] != map1.shape[:2]:
            raise ArgumentError(
                f'image is {image.shape[1]}x{image.shape[0]} but the camera_info describes '
                f'{map1.shape[1]}x{map1.shape[0]} (after binning/ROI)'
            )
        flag = interpolation_flag(interpolation)
        if not reuse_output:
            return np.asarray(cv2.remap(image, map1, map2, flag))
        shape = map1.shape[:2] + image.shape[2:]
        if self._out is None or self._out.shape != shape or self._out.dtype != image.dtype:
            self._out = np.empty(shape, image.dtype)
        cv2.remap(image, map1, map2, flag, dst=self._out)
        return self._out
