"""Time-of-flight node: a continuous-wave camera's raw correlation frames -> REP 118 depth,
amplitude, confidence and an organised cloud.

Input convention (the raw frame as one image, as ToF drivers that expose raw data hand it
over: one buffer of sub-frames): ``correlation/image_raw`` (sensor_msgs/Image, 16UC1 or
mono16 counts, or 32FC1) holds the ``F x N`` correlation planes of one frame stacked
vertically, each the camera's full ``H x W``: plane ``j * N + k`` is modulation frequency
``j`` (the order of ``modulation_frequencies``) at phase step ``k`` (the reference delayed
by ``2 pi k / N``), so the image is ``W`` wide and ``F N H`` high. ``camera_info``
describes one plane (``H x W``: K, D, R, P of the raw camera), matched by exact stamp.
The decoding is in :mod:`depth_nodes.core.tof`.

Publishes, with the frame's stamp and frame (all on the rectified grid of the
CameraInfo's ``P``, lens distortion removed):

* ``depth/image_rect``: Z (REP 118; not the ray length the camera measures), 32FC1
  metres, NaN where unknown, or (``depth_encoding: 16UC1``) millimetres, 0 unknown;
* ``depth/camera_info``: the rectified camera of those images (D zero, K from P), so
  depth_image_proc's nodes take the depth as it is;
* ``amplitude/image_rect`` (32FC1 counts) and ``confidence/image_rect`` (32FC1 in [0, 1]);
* ``points``: organised PointCloud2, x, y, z and ``intensity`` (the amplitude), NaN points
  where there is no depth.

Parameters (all but ``queue_size`` change at runtime, from the next frame):
``modulation_frequencies`` (MHz, one to three), the decoding's (:class:`ToFParams`:
``phase_steps``, ``saturation_level``, ``min_amplitude``, ``electrons_per_count``,
``noise_reference``, ``min_confidence``, ``flying_pixel_threshold``,
``jump_edge_threshold``, ``depth_min``, ``depth_max``),
``depth_encoding``, ``threads`` (of the numba kernels and OpenCV; 2 on two cores: 32
frames/s at 640x480, 23 on one, ``depth-nodes bench tof``), ``queue_size``.

Outputs are computed only while subscribed (lazy), or always offline: with only
``depth/camera_info`` wanted the frame is not decoded, and the cloud is built only while
``points`` is wanted.

Frames without output are counted and logged: ``unsupported_encoding``,
``malformed_image``, ``size_mismatch`` (the image is not ``F N`` planes of the
CameraInfo's size), ``uncalibrated``, ``bad_calibration``, ``sync_*``.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import fields
from typing import Any

import numpy as np
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.depth_image import depth_to_points, from_metres
from depth_nodes.core.geometry import intrinsics
from depth_nodes.core.tof import ToFDecoder, ToFParams, check_frequencies
from depth_nodes.errors import ArgumentError, CalibrationError, MessageError
from depth_nodes.ros.camera_info import InfoCache, camera_info_to_model, model_to_camera_info
from depth_nodes.ros.image import array_to_image
from depth_nodes.ros.node import DepthNode
from depth_nodes.ros.params import (
    THREADS,
    NodeParameters,
    ParamSpec,
    one_of,
    specs_from,
    validated,
)
from depth_nodes.ros.pointcloud import build_pointcloud
from depth_nodes.ros.transport import decode_image
from depth_nodes.ros.workers import use_threads

#: Encodings of the raw frame.
RAW_ENCODINGS = ('16UC1', 'mono16', '32FC1')
SETTINGS = tuple(f.name for f in fields(ToFParams))


def _check_frequencies(value: Any) -> str | None:
    try:
        check_frequencies(value)
    except ArgumentError as exc:
        return str(exc)
    return None


PARAMETERS = [
    ParamSpec('modulation_frequencies', [80.0, 100.0], 'Modulation frequencies, MHz, in the '
              'order of the planes (one to three)', check=_check_frequencies,
              dynamic_typing=True),
    *specs_from(ToFParams, SETTINGS),
    ParamSpec('depth_encoding', '32FC1', 'depth/image_rect: 32FC1 metres (NaN unknown) or '
              '16UC1 millimetres (0 unknown)', check=one_of(('32FC1', '16UC1'))),
    ParamSpec('queue_size', 5, 'Frames held while waiting for their camera_info', 1, 1000,
              read_only=True),
    THREADS,
]


def _settings(values: Mapping[str, Any]) -> ToFParams:
    return ToFParams(**{name: values[name] for name in SETTINGS})


def _camera(info: Any) -> CameraModel:
    model = camera_info_to_model(info).binned()
    return model


def rectified_info(camera: CameraModel, header: Any) -> CameraInfo:
    """The CameraInfo of images on ``camera``'s rectified grid: D zero, R identity, K the
    left 3 x 3 of P."""
    P = camera.projection
    model = CameraModel(camera.width, camera.height, K=P[:, :3].copy(), D=np.zeros(5),
                        R=np.eye(3), P=P.copy(), frame_id=camera.frame_id)
    return model_to_camera_info(model, header)


class ToFNode(DepthNode):
    """Raw correlation frames -> depth, amplitude, confidence, points."""

    def __init__(self, node_name: str = 'tof', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS, validated(_settings))
        self.decoder = ToFDecoder()
        self._cameras = InfoCache(_camera)
        self.pub_depth = self.add_output(Image, 'depth/image_rect')
        self.pub_info = self.add_output(CameraInfo, 'depth/camera_info')
        self.pub_amplitude = self.add_output(Image, 'amplitude/image_rect')
        self.pub_confidence = self.add_output(Image, 'confidence/image_rect')
        self.pub_points = self.add_output(PointCloud2, 'points')
        self.add_synced_inputs([(Image, 'correlation/image_raw'), (CameraInfo, 'camera_info')],
                               self.on_frame, queue_size=self.params.values['queue_size'])

    def on_frame(self, image: Image, info: CameraInfo) -> None:
        """Decode one raw frame and publish its outputs (those wanted)."""
        want_depth, want_info, want_amplitude, want_confidence, want_points = (
            out.wanted for out in (self.pub_depth, self.pub_info, self.pub_amplitude,
                                   self.pub_confidence, self.pub_points))
        decoded = want_depth or want_amplitude or want_confidence or want_points
        if self.skip_unwanted(decoded, want_info):
            return
        values = self.params.values
        use_threads(values['threads'])
        freqs = check_frequencies(values['modulation_frequencies'])
        settings = _settings(values)
        if image.encoding not in RAW_ENCODINGS:
            self.drop('unsupported_encoding', f'correlation/image_raw encoding '
                      f'{image.encoding!r} is not one of {", ".join(RAW_ENCODINGS)}')
            return
        try:
            pixels, _ = decode_image(image)
        except MessageError as exc:
            self.decoding_failed(exc, 'correlation/image_raw')
            return
        try:
            camera = self._cameras.get(info)
        except CalibrationError as exc:
            reason = 'uncalibrated' if not np.any(np.asarray(info.k)) else 'bad_calibration'
            self.drop(reason, f'camera_info unusable: {exc}')
            return
        planes = len(freqs) * settings.phase_steps
        if pixels.shape != (planes * camera.height, camera.width):
            self.drop('size_mismatch', f'correlation/image_raw is {pixels.shape[1]}x'
                      f'{pixels.shape[0]}: expected {planes} planes ({len(freqs)} '
                      f'frequencies x {settings.phase_steps} phase steps) of the camera_info\'s '
                      f'{camera.width}x{camera.height}, stacked vertically')
            return
        header = copy.deepcopy(image.header)
        if not decoded:
            self.pub_info.publish(rectified_info(camera, header))
            return
        samples = pixels.reshape(planes, camera.height, camera.width)
        result = self.decoder.decode(samples, camera, freqs, settings)
        if want_depth:
            encoding = values['depth_encoding']
            self.pub_depth.publish(array_to_image(from_metres(result.depth, encoding),
                                                  encoding, header))
        if want_info:
            self.pub_info.publish(rectified_info(camera, header))
        if want_amplitude:
            self.pub_amplitude.publish(array_to_image(result.amplitude, '32FC1', header))
        if want_confidence:
            self.pub_confidence.publish(array_to_image(result.confidence, '32FC1', header))
        if want_points:
            points = depth_to_points(result.depth, intrinsics(camera))
            self.pub_points.publish(build_pointcloud(
                points, header, extra_fields={'intensity': result.amplitude}))
