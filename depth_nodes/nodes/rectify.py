"""Rectifier node: a drop-in for image_proc's RectifyNode, one instance per camera.

Subscribes ``image`` (raw) and ``camera_info`` (matched by exact stamp); publishes
``image_rect`` (mono: the input encoding for one-channel images, mono8 / mono16 for colour
ones) and, for colour input, ``image_rect_color`` (the input encoding; ``bgr8`` / ``bgr16``
for a Bayer mosaic or a YUV image, which are decoded first: demosaicing before the remap,
never after). Parameters, as image_proc's: ``queue_size`` (start-up only),
``interpolation`` (a name or image_proc's integer code) and ``debayer`` (image_proc's
debayer node's codes), both changeable at runtime and applied from the next frame.

Unlike image_proc, ``R`` is applied even when every distortion coefficient is zero, so a
stereo pair whose only flaw is a relative rotation is still rectified.

Outputs are computed only while subscribed (lazy), or always offline: a mono input with
only ``image_rect_color`` subscribed is not rectified (it has no colour output).

A frame without output is counted in ``drops`` and logged (throttled) with its reason:
``uncalibrated`` (K all zero), ``bad_calibration`` (non-finite values, wrong D length, ...),
``unsupported_encoding``, ``malformed_image``, ``size_mismatch`` (image vs CameraInfo), or
``sync_*`` (an image or camera_info whose partner never arrived).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.rectify import INTERPOLATIONS, Rectifier, interpolation_flag
from depth_nodes.errors import CalibrationError, MessageError
from depth_nodes.ros.camera_info import InfoCache, camera_info_to_model
from depth_nodes.ros.image import (
    DEBAYER_METHODS,
    READABLE_ENCODINGS,
    array_to_image,
    to_gray,
)
from depth_nodes.ros.node import DepthNode
from depth_nodes.ros.params import (
    IMAGE_TRANSPORT,
    THREADS,
    NodeParameters,
    ParamSpec,
)
from depth_nodes.ros.transport import image_pixels, is_compressed
from depth_nodes.ros.workers import use_threads


def _check_interpolation(value: Any) -> str | None:
    try:
        interpolation_flag(value)
    except ValueError as exc:
        return str(exc)
    return None


PARAMETERS = [
    IMAGE_TRANSPORT,
    ParamSpec('queue_size', 5, 'Queue of the image / camera_info stamp synchroniser',
              min_value=1, max_value=1000, read_only=True),
    ParamSpec('interpolation', 1,
              'Interpolation: ' + ', '.join(f'{n} ({f})' for n, f in INTERPOLATIONS.items())
              + '; a name or image_proc\'s integer code',
              dynamic_typing=True, check=_check_interpolation),
    ParamSpec('debayer', 3, 'Demosaicing of Bayer images (image_proc\'s debayer codes): '
              '0 bilinear, 1 edge-aware, 2 edge-aware weighted (as 1 here), 3 VNG (8-bit '
              'only; 16-bit mosaics use edge-aware)', min(DEBAYER_METHODS),
              max(DEBAYER_METHODS)),
    THREADS,
]


def _models(info_msg: CameraInfo) -> tuple[CameraModel, CameraModel]:
    model = camera_info_to_model(info_msg)
    return model, model.binned()


class RectifyNode(DepthNode):
    """Undistorts and rectifies one camera's raw images with its CameraInfo."""

    def __init__(self, node_name: str = 'rectify', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS)
        self.rectifier = Rectifier()
        # the camera model of a CameraInfo and of the image it delivers (binning, ROI)
        self._calibration = InfoCache(_models)
        self.pub_rect = self.add_output(Image, 'image_rect')
        self.pub_rect_color = self.add_output(Image, 'image_rect_color')
        self.add_synced_inputs([(Image, 'image', self.params.values['image_transport']),
                                (CameraInfo, 'camera_info')], self.on_frame,
                               queue_size=self.params.values['queue_size'])

    def _size_mismatch(self, width: int, height: int, model: CameraModel,
                       delivered: CameraModel) -> None:
        self.drop('size_mismatch', f'image is {width}x{height} but camera_info describes '
                  f'{delivered.width}x{delivered.height} (binning {model.binning_x}/'
                  f'{model.binning_y}, roi {model.roi[:4]})')

    def on_frame(self, image_msg: Any, info_msg: CameraInfo) -> None:
        """Rectify one raw image with the CameraInfo of the same stamp (for the outputs
        wanted)."""
        want_rect, want_color = self.pub_rect.wanted, self.pub_rect_color.wanted
        if self.skip_unwanted(want_rect, want_color):
            return
        interpolation = self.params.values['interpolation']
        use_threads(self.params.values['threads'])
        if not np.any(np.asarray(info_msg.k)):
            self.drop('uncalibrated', 'camera_info K is all zero: the camera is not '
                      'calibrated, nothing to rectify with')
            return
        raw_message = not is_compressed(image_msg)  # its fields say what it holds
        if raw_message and image_msg.encoding not in READABLE_ENCODINGS:
            self.drop('unsupported_encoding', f'image encoding {image_msg.encoding!r} is not '
                      f'supported (supported: {", ".join(READABLE_ENCODINGS)})')
            return
        try:
            model, delivered = self._calibration.get(info_msg)
        except CalibrationError as exc:
            self.drop('bad_calibration', f'camera_info unusable: {exc}')
            return
        if raw_message and (image_msg.width, image_msg.height) != (delivered.width,
                                                                   delivered.height):
            self._size_mismatch(image_msg.width, image_msg.height, model, delivered)
            return
        try:
            raw, encoding = image_pixels(image_msg, debayer=self.params.values['debayer'])
        except MessageError as exc:
            self.decoding_failed(exc, 'image')
            return
        if raw.shape[:2] != (delivered.height, delivered.width):  # a compressed image's
            self._size_mismatch(raw.shape[1], raw.shape[0], model, delivered)
            return
        if raw.ndim == 2 and self.skip_unwanted(want_rect):  # mono: no colour output
            return
        try:
            rectified = self.rectifier.rectify(raw, model, interpolation, reuse_output=True)
        except CalibrationError as exc:  # validated above; kept for a cache rebuild failing
            self.drop('bad_calibration', f'camera_info unusable: {exc}')
            return
        if rectified.ndim == 2:
            self.pub_rect.publish(array_to_image(rectified, encoding, image_msg.header))
            return
        if want_color:
            self.pub_rect_color.publish(array_to_image(rectified, encoding, image_msg.header))
        if want_rect:
            mono = 'mono16' if rectified.dtype == np.uint16 else 'mono8'
            self.pub_rect.publish(
                array_to_image(to_gray(rectified, encoding), mono, image_msg.header))
