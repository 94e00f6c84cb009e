"""Point cloud node: disparity -> organised PointCloud2 and REP 118 depth image.

A drop-in for stereo_image_proc's PointCloudNode, plus the depth image users have asked it
for. Subscribes ``disparity`` (stereo_msgs/DisparityImage; remap it to ``disparity_checked``
when the cross-check node runs), ``left/camera_info``, ``right/camera_info``, and
``left/image_rect_color`` when ``use_color`` is true, ``confidence`` (32FC1) when
``use_confidence`` is true. One synchroniser over exactly those inputs is built at
start-up (exact stamps, or ``approximate_sync``), so ``use_color`` and ``use_confidence``
are read-only: a cloud is never published without the colour a set should have carried.

Publishes, with the disparity's header (the left optical frame):

* ``points2``: organised H x W, ``is_dense`` false, NaN x/y/z for invalid points; x, y, z
  float32 at 0, 4, 8; with colour ``rgb`` (PCL's packed float) at 16 and 32-byte points,
  or at 12 and 16-byte points with ``avoid_point_cloud_padding``; without colour 16 or 12
  bytes. ``extra_fields`` (comma-separated: ``confidence``, ``depth_std``) follow as
  float32 fields (:mod:`depth_nodes.ros.pointcloud` gives the layouts).
* ``depth``: 32FC1 metres with NaN unknown, or (``depth_encoding: 16UC1``) millimetres
  with 0 unknown (beyond 65.535 m too).

Geometry comes from the CameraInfos' rectified projection matrices, cx offset between the
cameras included (:mod:`depth_nodes.core.reproject`); the DisparityImage's ``f``/``t`` are
not used. ``min_range``/``max_range`` bound the depth Z, ``min_confidence`` the confidence;
all but the synchronisation parameters change at runtime and apply from the next frame.

Outputs are computed only while subscribed (lazy), or always offline; the colour image
and ``extra_fields`` are read only for ``points2``.

Frames without output are counted and logged with a reason: ``disparity_encoding`` (not
32FC1), ``unsupported_encoding`` (colour image not mono8/mono16/rgb8/bgr8/rgba8/bgra8, or
confidence not 32FC1), ``malformed_image``, ``size_mismatch`` (disparity vs image,
confidence or camera_info), ``uncalibrated``, ``bad_calibration``, ``sync_*``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any

from rclpy.qos import qos_profile_system_default
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from stereo_msgs.msg import DisparityImage

from depth_nodes.core.reproject import (
    ReprojectParams,
    depth_std,
    depth_to_millimetres,
    reproject_disparity,
)
from depth_nodes.errors import ArgumentError, MessageError
from depth_nodes.ros.disparity import read_disparity
from depth_nodes.ros.image import array_to_image, to_rgb8
from depth_nodes.ros.node import DepthNode
from depth_nodes.ros.params import (
    IMAGE_TRANSPORT,
    THREADS,
    NodeParameters,
    ParamSpec,
    one_of,
    specs_from,
    synchroniser_specs,
)
from depth_nodes.ros.pointcloud import build_pointcloud
from depth_nodes.ros.workers import use_threads

#: Colour encodings the cloud's rgb can be taken from.
#: Colour images accepted, after camera encodings (Bayer, YUV) are decoded to bgr8 / bgr16.
COLOR_ENCODINGS = ('mono8', 'mono16', 'rgb8', 'bgr8', 'rgba8', 'bgra8', 'rgb16', 'bgr16',
                   'rgba16', 'bgra16')
#: Names accepted in ``extra_fields``.
EXTRA_FIELDS = ('confidence', 'depth_std')
DEPTH_ENCODINGS = ('32FC1', '16UC1')


def parse_extra_fields(value: str) -> list[str]:
    """The field names of an ``extra_fields`` value: comma-separated, blanks ignored."""
    return [name.strip() for name in value.split(',') if name.strip()]


def _check_extra_fields(value: str) -> str | None:
    names = parse_extra_fields(value)
    unknown = [n for n in names if n not in EXTRA_FIELDS]
    if unknown:
        return f'unknown field(s) {", ".join(unknown)}; allowed: {", ".join(EXTRA_FIELDS)}'
    if len(set(names)) != len(names):
        return 'a field is listed twice'
    return None


PARAMETERS = [
    IMAGE_TRANSPORT,
    *synchroniser_specs('the inputs'),
    ParamSpec('use_color', True, 'Subscribe left/image_rect_color and add rgb to points2 '
              '(start-up only)', read_only=True),
    ParamSpec('use_confidence', False, 'Subscribe confidence (32FC1 in [0, 1]) for '
              'min_confidence and the confidence field (start-up only)', read_only=True),
    ParamSpec('avoid_point_cloud_padding', False, 'Pack points (12/16 bytes) instead of '
              'padding them to 16/32 bytes'),
    *specs_from(ReprojectParams, ('min_range', 'max_range', 'min_confidence')),
    ParamSpec('depth_encoding', '32FC1', 'depth image: 32FC1 metres (NaN unknown) or 16UC1 '
              'millimetres (0 unknown)', check=one_of(DEPTH_ENCODINGS)),
    ParamSpec('extra_fields', '', 'Comma-separated extra float32 fields of points2: '
              'confidence (needs use_confidence), depth_std', check=_check_extra_fields),
    *specs_from(ReprojectParams, ('disparity_std',)),
    THREADS,
]


def _reprojection(values: Mapping[str, Any]) -> ReprojectParams:
    """The reprojection settings of a parameter snapshot (checked when they were set)."""
    return ReprojectParams(**{f.name: values[f.name] for f in fields(ReprojectParams)})


def _check_values(values: Mapping[str, Any]) -> str | None:
    try:
        _reprojection(values).validate()
    except ArgumentError as exc:
        return str(exc)
    if not values['use_confidence']:
        if values['min_confidence'] > 0:
            return 'min_confidence needs use_confidence: true (set at start-up)'
        if 'confidence' in parse_extra_fields(values['extra_fields']):
            return 'extra field confidence needs use_confidence: true (set at start-up)'
    return None


def _depth_image(depth: Any, encoding: str, header: Any) -> Image:
    """The ``depth`` message: 32FC1 metres, or 16UC1 millimetres."""
    if encoding == '16UC1':
        return array_to_image(depth_to_millimetres(depth), '16UC1', header)
    return array_to_image(depth, '32FC1', header)


class PointCloudNode(DepthNode):
    """Disparity (+ colour, + confidence) -> organised ``points2`` and ``depth``."""

    def __init__(self, node_name: str = 'point_cloud', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS, check_values=_check_values)
        values = self.params.values
        self.use_color: bool = values['use_color']
        self.use_confidence: bool = values['use_confidence']
        self.pub_points = self.add_output(PointCloud2, 'points2')
        self.pub_depth = self.add_output(Image, 'depth')
        inputs: list[Any] = [(DisparityImage, 'disparity'), (CameraInfo, 'left/camera_info'),
                             (CameraInfo, 'right/camera_info')]
        if self.use_color:
            inputs.append((Image, 'left/image_rect_color', values['image_transport']))
        if self.use_confidence:
            inputs.append((Image, 'confidence'))
        tolerance = values['approximate_sync_tolerance_seconds']
        self.add_synced_inputs(
            inputs, self._on_synced, queue_size=values['queue_size'],
            approximate=values['approximate_sync'], max_interval=tolerance or None,
            qos=qos_profile_system_default if values['use_system_default_qos'] else None)

    def _on_synced(self, disparity: DisparityImage, left_info: CameraInfo,
                   right_info: CameraInfo, *rest: Image) -> None:
        extra = list(rest)
        image = extra.pop(0) if self.use_color else None
        confidence = extra.pop(0) if self.use_confidence else None
        self.on_frame(disparity, left_info, right_info, image=image, confidence=confidence)

    def on_frame(self, disparity_msg: DisparityImage, left_info: CameraInfo,
                 right_info: CameraInfo, *, image: Image | None = None,
                 confidence: Image | None = None) -> None:
        """Turn one synchronised set into ``points2`` and ``depth`` (those wanted)."""
        want_points, want_depth = self.pub_points.wanted, self.pub_depth.wanted
        if self.skip_unwanted(want_points, want_depth):
            return
        values = self.params.values
        use_threads(values['threads'])
        if disparity_msg.image.encoding != '32FC1':
            self.drop('disparity_encoding', f'DisparityImage image encoding must be 32FC1, '
                      f'got {disparity_msg.image.encoding!r}')
            return
        try:
            disparity = read_disparity(disparity_msg).disparity
        except MessageError as exc:
            self.drop('malformed_image', f'disparity: {exc}')
            return
        shape = disparity.shape
        stereo = self.stereo_model(left_info, right_info)
        if stereo is None:
            return
        if (stereo.left.height, stereo.left.width) != shape:
            self.drop('size_mismatch', f'disparity is {shape[1]}x{shape[0]} but camera_info '
                      f'describes {stereo.left.width}x{stereo.left.height}')
            return
        rgb = conf = None
        if self.use_color and image is None:
            raise ArgumentError('use_color is true: on_frame needs the colour image')
        if self.use_color and want_points:  # the colour is only the cloud's
            colour = self.frame_image(image, 'colour image', shape, COLOR_ENCODINGS,
                                      camera=True)
            if colour is None:
                return
            rgb = to_rgb8(*colour)
        if self.use_confidence:
            if confidence is None:
                raise ArgumentError('use_confidence is true: on_frame needs the confidence')
            conf_pixels = self.frame_image(confidence, 'confidence', shape, ('32FC1',))
            if conf_pixels is None:
                return
            conf = conf_pixels[0]
        limits = _reprojection(values)
        result = reproject_disparity(
            disparity, stereo, min_range=limits.min_range, max_range=limits.max_range,
            confidence=conf, min_confidence=limits.min_confidence)
        header = disparity_msg.header
        if want_points:
            extra: dict[str, Any] = {}
            for name in parse_extra_fields(values['extra_fields']):
                if name == 'confidence':
                    extra[name] = conf
                else:
                    extra[name] = depth_std(result.depth, stereo.focal, stereo.baseline,
                                            limits.disparity_std)
            self.pub_points.publish(build_pointcloud(
                result.points, header, rgb=rgb, pad=not values['avoid_point_cloud_padding'],
                extra_fields=extra))
        if want_depth:
            self.pub_depth.publish(_depth_image(result.depth, values['depth_encoding'], header))
