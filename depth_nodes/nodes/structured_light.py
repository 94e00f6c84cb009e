"""Structured-light node: a camera's pattern sequence (or one speckle image) -> depth.

Subscribes ``image`` (mono8/mono16/colour, converted to grey), ``camera_info`` (matched by
exact stamp), ``pattern`` (std_msgs/Header: the frame's position in its sequence, see
:mod:`depth_nodes.core.structured_light.framing`; not needed in speckle mode) and
``projector/camera_info`` (the projector calibration, ``P = K_p [R | t]``; the latest one
is used). Publishes, once per complete sequence (with the header of its first frame) or
per speckle image: ``depth`` (32FC1 metres, NaN unknown; REP 118), ``points2`` (organised
PointCloud2 in the camera frame) and ``confidence`` (32FC1 in [0, 1]).

Parameters (all but ``queue_size`` changeable at runtime; a sequence is decoded with the
values current when its last frame arrives; changing ``mode`` or the pattern layout drops
a sequence in progress): ``mode`` (gray, phase, opencv, speckle), ``axes``,
``phase_steps``, ``phase_period``, ``shadow_threshold``, ``min_modulation``,
``epipolar_tolerance`` (axes both: a code off its epipolar line is false), ``depth_min``,
``depth_max``, ``speckle_reference`` (image file), ``speckle_reference_depth``,
``speckle_window``, ``speckle_min_score``, ``speckle_uniqueness``,
``avoid_point_cloud_padding``,
``max_sequence_frames``, ``sequence_timeout``, ``queue_size``.

Outputs are computed only while subscribed (lazy), or always offline: a complete sequence
(or a speckle image) nobody wants is not decoded; the frames of a sequence are gathered
whatever is subscribed, so a subscriber that comes mid-sequence gets that sequence.

Memory is bounded by the parameters, never by what a sender claims: frames waiting for
their tag and tags waiting for their frame by ``queue_size``, a sequence by
``max_sequence_frames`` (a tag announcing more is refused, ``pattern_count_too_large``,
also before the projector's camera_info has told the real count), and a sequence that
stops arriving is abandoned after ``sequence_timeout`` seconds (``sequence_incomplete``),
as is one still incomplete when the stream ends.

A frame or sequence without output is counted in ``drops`` and logged, by reason: the
framing reasons of :mod:`~depth_nodes.core.structured_light.framing`, ``bad_pattern_tag``,
``pattern_count_too_large``, ``pattern_tag_missing``, ``pattern_tag_unmatched``,
``no_projector_info``, ``bad_calibration``, ``bad_pattern_set``, ``unsupported_encoding``,
``malformed_image``, ``size_mismatch``, ``speckle_reference``, ``sync_*``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import fields
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header

from depth_nodes.core.structured_light import (
    PatternSet,
    ProjectorGeometry,
    camera_rays,
    points_on_rays,
    speckle_depth,
)
from depth_nodes.core.structured_light.framing import (
    Drop,
    SequenceAssembler,
    TagPairer,
    parse_tag,
)
from depth_nodes.core.structured_light.params import StructuredLightParams
from depth_nodes.core.structured_light.reconstruct import reconstruct
from depth_nodes.core.structured_light.speckle import SpeckleMatcher, SpeckleReference
from depth_nodes.errors import (
    CalibrationError,
    ConfigError,
    InputFileError,
    MessageError,
)
from depth_nodes.ros.camera_info import InfoCache, camera_info_to_model
from depth_nodes.ros.image import array_to_image
from depth_nodes.ros.node import DepthNode
from depth_nodes.ros.params import (
    IMAGE_TRANSPORT,
    NodeParameters,
    ParamSpec,
    specs_from,
    validated,
)
from depth_nodes.ros.pointcloud import build_pointcloud
from depth_nodes.ros.sync import stamp_to_ns


def _settings(values: Mapping[str, Any]) -> StructuredLightParams:
    """The decoder's settings of a parameter snapshot (checked when they were set)."""
    return StructuredLightParams(**{name: values[name] for name in SETTINGS})


#: The decoder's parameters, declared from StructuredLightParams' settings.
SETTINGS = tuple(f.name for f in fields(StructuredLightParams))

PARAMETERS = [
    IMAGE_TRANSPORT,
    *specs_from(StructuredLightParams, SETTINGS),
    ParamSpec('avoid_point_cloud_padding', False, 'Pack points2 to 12 bytes per point'),
    ParamSpec('queue_size', 5, 'Frames held while their camera_info or pattern tag is '
              'missing', min_value=1, max_value=1000, read_only=True),
]


class StructuredLightNode(DepthNode):
    """Decodes Gray-code / phase-shift sequences or speckle images into depth."""

    def __init__(self, node_name: str = 'structured_light', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS, validated(_settings))
        self.queue_size = int(self.params.values['queue_size'])
        self.assembler = SequenceAssembler()
        self.projector_info: CameraInfo | None = None
        self.pairer = TagPairer(self.queue_size)
        self._layout: tuple[Any, ...] | None = None
        self._geometry = InfoCache(_geometry)
        self._rays: NDArray[np.float64]
        self.reference = SpeckleReference()
        self.speckle_matcher = SpeckleMatcher()  # keeps the reference's census
        self.pub_depth = self.add_output(Image, 'depth')
        self.pub_points = self.add_output(PointCloud2, 'points2')
        self.pub_confidence = self.add_output(Image, 'confidence')
        self.add_synced_inputs([(Image, 'image', self.params.values['image_transport']),
                                (CameraInfo, 'camera_info')], self.on_frame,
                               queue_size=self.queue_size)
        self.add_input(Header, 'pattern', self.on_tag)
        self._last_sequence_frame = time.monotonic()
        self.create_timer(0.5, lambda: self.guarded(self.check_sequence_timeout,
                                                    where='the sequence timer'))
        # the projector's calibration: only the latest matters, whatever its stamp
        self.add_input(CameraInfo, 'projector/camera_info', self.on_projector_info,
                       check_stamps=False)

    # ---------------------------------------------------------------- inputs

    def on_projector_info(self, msg: CameraInfo) -> None:
        """Keep the latest projector calibration."""
        self.projector_info = msg

    def on_tag(self, msg: Header) -> None:
        """A pattern tag: release its waiting frame, or keep it for the frame to come."""
        frame, drops = self.pairer.add_tag(stamp_to_ns(msg.stamp), msg)
        self._drops(drops)
        if frame is not None:
            image, info = frame
            self._sequence_frame(image, info, msg)

    def on_frame(self, image: Image, info: CameraInfo) -> None:
        """An image with its camera_info: speckle now, or one frame of a sequence."""
        if self.params.values['mode'] == 'speckle':
            self._speckle(image, info)
            return
        tag, drops = self.pairer.add_frame(stamp_to_ns(image.header.stamp), (image, info))
        self._drops(drops)
        if tag is not None:
            self._sequence_frame(image, info, tag)

    def _drops(self, drops: list[Drop]) -> None:
        for d in drops:
            self.drop(d.reason, d.detail, count=d.count)

    def check_sequence_timeout(self, now: float | None = None) -> None:
        """Abandon an incomplete sequence whose last frame came ``sequence_timeout`` s
        ago (the timer's callback; ``now``: monotonic seconds, for tests)."""
        timeout = self.params.values['sequence_timeout']
        now = time.monotonic() if now is None else now
        if timeout > 0 and self.assembler.pending and now - self._last_sequence_frame > timeout:
            self.drop('sequence_incomplete', f'{self.assembler.pending} frame(s) of a sequence '
                      f'held, no frame for {now - self._last_sequence_frame:.1f} s '
                      f'(sequence_timeout {timeout:g} s)')
            self.assembler.reset()

    def holds_input(self) -> bool:
        """Also a sequence being gathered, or frames and tags waiting for each other."""
        return super().holds_input() or bool(self.assembler.pending or self.pairer.held)

    def finish_stream(self) -> None:
        """The stream ended: count the incomplete sequence and the unpaired frames and
        tags (see :meth:`DepthNode.finish_stream`)."""
        super().finish_stream()
        if self.assembler.pending:
            self.drop('sequence_incomplete', f'{self.assembler.pending} frame(s) of a '
                      'sequence held when the stream ended')
            self.assembler.reset()
        self._drops(self.pairer.finish())

    # ---------------------------------------------------------------- sequences

    def _pattern_set(self, values: Mapping[str, Any]) -> PatternSet | None:
        proj = self.projector_info
        if proj is None:
            self.drop('no_projector_info', 'no projector/camera_info received yet')
            return None
        try:
            pattern_set = _settings(values).pattern_set(int(proj.width), int(proj.height))
        except ConfigError as exc:
            self.drop('bad_pattern_set', str(exc))
            return None
        layout = (pattern_set,)
        if layout != self._layout:
            if self._layout is not None and self.assembler.pending:
                self.drop('sequence_incomplete', 'pattern layout changed (parameters or '
                          'projector size) in the middle of a sequence')
                self.assembler.reset()
            self._layout = layout
        return pattern_set

    def _sequence_frame(self, image: Image, info: CameraInfo, tag_msg: Header) -> None:
        values = self.params.values
        try:
            tag = parse_tag(tag_msg.frame_id)
        except MessageError as exc:
            self.drop('bad_pattern_tag', str(exc))
            return
        if tag.count > values['max_sequence_frames']:
            self.drop('pattern_count_too_large', f'pattern tag {tag} announces {tag.count} '
                      f'frames, more than max_sequence_frames {values["max_sequence_frames"]}')
            return
        # Without projector info yet (it may arrive just after the first frame) the tag's
        # count is taken on trust and checked when the sequence is complete.
        pattern_set = self._pattern_set(values) if self.projector_info is not None else None
        if pattern_set is None and self.projector_info is not None:
            return
        grey = self._grey(image)
        if grey is None:
            return
        expected = pattern_set.count if pattern_set is not None else tag.count
        self._last_sequence_frame = time.monotonic()
        frames, drops = self.assembler.add(tag, (grey, image.header, info), expected)
        self._drops(drops)
        if frames is None:
            return
        pattern_set = pattern_set or self._pattern_set(values)
        if pattern_set is None:
            return
        if pattern_set.count != len(frames):
            self.drop('pattern_count_mismatch', f'sequence {tag.sequence} has {len(frames)} '
                      f'frames, the configured pattern set needs {pattern_set.count}')
            return
        self._decode(frames, pattern_set, values)

    def _grey(self, image: Image) -> Any:
        return self.gray_image(image, 'pattern image')

    def _geometry_for(self, info: CameraInfo) -> ProjectorGeometry | None:
        proj = self.projector_info
        if proj is None:
            self.drop('no_projector_info', 'no projector/camera_info received yet')
            return None
        try:
            geometry, self._rays = self._geometry.get(info, proj)
        except CalibrationError as exc:
            self.drop('bad_calibration', str(exc))
            return None
        return geometry

    def _decode(self, frames: list[tuple[Any, Header, CameraInfo]], pattern_set: PatternSet,
                values: Mapping[str, Any]) -> None:
        wanted = self._wanted()
        if self.skip_unwanted(*wanted):
            return
        first, header, info = frames[0]
        if any(f[0].shape != first.shape for f in frames):
            self.drop('size_mismatch', 'images of one sequence differ in size')
            return
        geometry = self._geometry_for(info)
        if geometry is None:
            return
        cam = geometry.camera
        if first.shape != (cam.height, cam.width):
            self.drop('size_mismatch', f'image is {first.shape[1]}x{first.shape[0]} but '
                      f'camera_info describes {cam.width}x{cam.height}')
            return
        try:
            result = reconstruct(np.stack([f[0] for f in frames]), pattern_set, geometry,
                                 rays=self._rays, shadow_threshold=values['shadow_threshold'],
                                 min_modulation=values['min_modulation'],
                                 depth_min=values['depth_min'], depth_max=values['depth_max'],
                                 epipolar_tolerance=values['epipolar_tolerance'])
        except (ConfigError, CalibrationError) as exc:
            self.drop('bad_calibration', str(exc))
            return
        self._publish(result.depth, result.confidence, header, values, wanted)

    # ---------------------------------------------------------------- speckle

    def _speckle(self, image: Image, info: CameraInfo) -> None:
        wanted = self._wanted()
        if self.skip_unwanted(*wanted):
            return
        values = self.params.values
        grey = self._grey(image)
        if grey is None:
            return
        geometry = self._geometry_for(info)
        if geometry is None:
            return
        if grey.shape != (geometry.camera.height, geometry.camera.width):
            self.drop('size_mismatch', f'image is {grey.shape[1]}x{grey.shape[0]} but '
                      f'camera_info describes {geometry.camera.width}x'
                      f'{geometry.camera.height}')
            return
        try:
            ref = self.reference.load(values['speckle_reference'], grey.shape)
        except InputFileError as exc:
            self.drop('speckle_reference', str(exc))
            return
        try:
            depth, conf = speckle_depth(
                grey, ref, focal=geometry.camera.K[0, 0], baseline=float(geometry.centre[0]),
                reference_depth=values['speckle_reference_depth'],
                depth_min=values['depth_min'], depth_max=values['depth_max'],
                window=values['speckle_window'], min_score=values['speckle_min_score'],
                uniqueness=values['speckle_uniqueness'], matcher=self.speckle_matcher)
        except ConfigError as exc:
            self.drop('bad_calibration', str(exc))
            return
        self._publish(depth, conf, image.header, values, wanted)

    # ---------------------------------------------------------------- output

    def _wanted(self) -> tuple[bool, bool, bool]:
        """Whether depth, points2 and confidence are wanted (once per decoded frame)."""
        return self.pub_depth.wanted, self.pub_points.wanted, self.pub_confidence.wanted

    def _publish(self, depth: NDArray[np.float32], confidence: NDArray[np.float32],
                 header: Header, values: Mapping[str, Any],
                 wanted: tuple[bool, bool, bool]) -> None:
        want_depth, want_points, want_confidence = wanted
        if want_depth:
            self.pub_depth.publish(array_to_image(depth, '32FC1', header))
        if want_points:
            points = points_on_rays(self._rays, depth)
            self.pub_points.publish(build_pointcloud(
                points, header, pad=not values['avoid_point_cloud_padding']))
        if want_confidence:
            self.pub_confidence.publish(array_to_image(confidence, '32FC1', header))


def _geometry(info: CameraInfo, projector_info: CameraInfo
              ) -> tuple[ProjectorGeometry, NDArray[np.float64]]:
    """The camera-projector geometry and the camera's rays (a CameraInfo cache's value)."""
    camera = camera_info_to_model(info).binned()
    geometry = ProjectorGeometry.from_models(camera, camera_info_to_model(projector_info))
    return geometry, camera_rays(camera)
