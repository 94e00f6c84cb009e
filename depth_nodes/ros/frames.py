"""Reading a frame's inputs, every failure a counted drop: image pixels (raw or
compressed) that must fit the frame, camera images as grey, a single camera's intrinsics
and the stereo geometry of a CameraInfo pair (each converted again only when its
CameraInfo changes)."""

from __future__ import annotations

from typing import Any

import numpy as np

from depth_nodes.core.camera import CameraModel, StereoModel
from depth_nodes.core.geometry import Intrinsics, intrinsics
from depth_nodes.errors import (
    CalibrationError,
    DecodeError,
    EncodingError,
    MessageError,
    UncalibratedError,
    UnsupportedFormatError,
)
from depth_nodes.ros.accounting import DropCounter
from depth_nodes.ros.camera_info import InfoCache, StereoInfoCache, camera_info_to_model
from depth_nodes.ros.image import CAMERA_ENCODINGS
from depth_nodes.ros.transport import MAX_PIXELS, decode_image, gray_image, image_pixels


def drop_reason(exc: MessageError) -> str:
    """The drop reason of an image that could not be read: ``unsupported_format`` (a
    compressed format or transport not known), ``unsupported_encoding``, ``decode_failed``
    (damaged compressed data) or ``malformed_image`` (fields that disagree, odd Bayer
    sizes)."""
    if isinstance(exc, UnsupportedFormatError):
        return 'unsupported_format'
    if isinstance(exc, EncodingError):
        return 'unsupported_encoding'
    if isinstance(exc, DecodeError):
        return 'decode_failed'
    return 'malformed_image'


class FrameReader:
    """Reads a node's input messages, counting each failure on ``drops``.

    Args:
        drops: Where the frames that cannot be read are counted (the node).
    """

    def __init__(self, drops: DropCounter) -> None:
        self._drops = drops
        self._stereo_cache: StereoInfoCache | None = None
        self._cameras: dict[str, InfoCache[CameraModel]] = {}

    def decoding_failed(self, exc: MessageError, what: str) -> None:
        """Count an image that could not be read, under :func:`drop_reason`."""
        self._drops.drop(drop_reason(exc), f'{what}: {exc}')

    def frame_image(self, msg: Any, what: str, shape: tuple[int, ...],
                    encodings: tuple[str, ...], *, camera: bool = False) -> Any:
        """The pixels of an input image (raw or compressed) that must fit the frame being
        processed.

        Args:
            msg: An Image or CompressedImage.
            what: How the logs name it.
            shape: The frame's (height, width).
            encodings: The encodings accepted.
            camera: Decode camera encodings (Bayer, YUV) to bgr8 / bgr16 first; the
                encodings are then those of the decoded pixels.

        Returns:
            ``(pixels, encoding)``, or None after counting the drop: the decoding's reason
            (see :func:`drop_reason`), ``unsupported_encoding`` (not one of ``encodings``)
            or ``size_mismatch`` (not ``shape``).
        """
        declared = getattr(msg, 'encoding', None)  # a raw Image says before it is read
        if declared is not None and declared not in encodings and not (
                camera and declared in CAMERA_ENCODINGS):
            encoding = declared
        else:
            try:
                pixels, encoding = image_pixels(msg) if camera else decode_image(msg)
            except MessageError as exc:
                self.decoding_failed(exc, what)
                return None
        if encoding not in encodings:
            self._drops.drop('unsupported_encoding', f'{what} encoding {encoding!r} is not '
                             f'{" or ".join(encodings)}')
            return None
        if pixels.shape[:2] != tuple(shape[:2]):
            self._drops.drop('size_mismatch', f'{what} is {pixels.shape[1]}x'
                             f'{pixels.shape[0]}, the frame {shape[1]}x{shape[0]}')
            return None
        return pixels, encoding

    def gray_image(self, msg: Any, what: str) -> Any:
        """A camera image (raw or compressed, any camera encoding) as one grey channel, or
        None after counting the drop (see :func:`drop_reason`)."""
        try:
            return gray_image(msg)
        except MessageError as exc:
            self.decoding_failed(exc, what)
        return None

    def camera(self, info: Any, what: str,
               shape: tuple[int, int] | None = None) -> Intrinsics | None:
        """The intrinsics a CameraInfo gives an image of ``shape`` (scaled when the sizes
        differ, see :func:`~depth_nodes.core.geometry.pinhole.intrinsics`), or None after
        counting the drop: ``uncalibrated`` (K and P all zero) or ``bad_calibration``
        (anything else unusable, or an image of more than
        :data:`~depth_nodes.ros.transport.MAX_PIXELS` pixels)."""
        try:
            camera = intrinsics(self.camera_model(info, what), shape)
            if camera.width * camera.height > MAX_PIXELS:
                raise CalibrationError(f'its {camera.width}x{camera.height} image has more '
                                       f'than {MAX_PIXELS} pixels')
            return camera
        except UncalibratedError:
            self._drops.drop('uncalibrated', f'{what} has K and P all zero: the camera is '
                             'not calibrated')
        except CalibrationError as exc:
            self._drops.drop('bad_calibration', f'{what} unusable: {exc}')
        return None

    def camera_model(self, info: Any, what: str) -> CameraModel:
        """The validated camera model of a CameraInfo (built again only when its content
        changes).

        Raises:
            UncalibratedError: K and P all zero.
            CalibrationError: Anything else unusable.
        """
        cache = self._cameras.setdefault(what, InfoCache(_camera))
        return cache.get(info)

    def stereo_model(self, left_info: Any, right_info: Any) -> StereoModel | None:
        """The stereo geometry of a CameraInfo pair (converted again only when one changes),
        or None after counting the drop: ``uncalibrated`` (a K all zero) or
        ``bad_calibration`` (anything else unusable)."""
        if self._stereo_cache is None:
            self._stereo_cache = StereoInfoCache()
        try:
            return self._stereo_cache.model(left_info, right_info)
        except UncalibratedError as exc:
            self._drops.drop('uncalibrated', str(exc))
        except CalibrationError as exc:
            self._drops.drop('bad_calibration', f'camera_info unusable: {exc}')
        return None


def _camera(info: Any) -> CameraModel:
    if not np.any(np.asarray(info.k)) and not np.any(np.asarray(info.p)):
        raise UncalibratedError('K and P all zero')  # how drivers say: not calibrated
    return camera_info_to_model(info)
