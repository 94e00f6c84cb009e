"""Multi-view stereo node: depth for one moving camera whose poses a visual odometry or SLAM
system publishes, or for a rig of synchronised cameras with fixed extrinsics.

One camera (``cameras`` empty): subscribes ``image_rect`` (grey, colour, Bayer or
16-bit; raw or through ``image_transport``) and ``camera_info`` (matched by exact stamp),
and the poses of ``pose_source``: ``odometry`` (nav_msgs/Odometry on ``odom``), ``pose``
(geometry_msgs/PoseStamped on ``pose``) or ``tf`` (``/tf`` and ``/tf_static``, where
tf2_msgs is installed), taken at each image's stamp within ``pose_tolerance``
(:mod:`depth_nodes.ros.poses`).
Every image is swept against the most recent keyframes that are far enough from it (plane
sweep with SGM over the planes, best-k views, :mod:`depth_nodes.core.mvs`), its estimate
checked against the keyframes' depths and fused over time with the estimates before it,
moved with the poses.

A rig (``cameras: [a, b, c]``): subscribes ``<camera>/image_rect`` and
``<camera>/camera_info`` of each, all matched by exact stamp; ``rig_extrinsics`` places
each camera's optical frame on the rig (7 numbers each: x y z qx qy qz qw);
``reference_camera`` is the one whose depth is published, swept against the others at the
same stamp and, with a pose source, against its own earlier keyframes (``pose_source:
none``: a rig that does not move).

Publishes, stamped with the reference image's stamp and in its frame:

* ``depth``: Z (REP 118, not the ray length), 32FC1 metres, NaN where unknown (or
  ``depth_encoding: 16UC1``: millimetres, 0 unknown), and ``depth/camera_info``;
* ``sigma``: 32FC1 standard deviation of Z, metres (NaN where no depth);
* ``confidence``: 32FC1 in [0, 1]; ``converged``: mono8, 255 where the filter converged;
* ``points2``: organised PointCloud2, x, y, z and the ``extra_fields`` asked for
  (``confidence``, ``depth_std``).

With ``delay`` N, the depth of an image is published when N more have come (it is then also
swept against them: what one side hides the other shows), with that image's stamp.

Parameters: the sweep's (``min_depth``, ``max_depth``, ``planes``, ``best_views``, census and
intensity costs, ``P1``, ``P2``, ``paths``, ...) and the stream's (keyframes, ``delay``,
``temporal_filter``, the geometric check) change at runtime, from the next image, with the
core's validation; the inputs and the pose source are read at start-up. ``depth_filter``,
the old name of ``temporal_filter``, is still taken, with a warning.

Poses come through the node base's pose input (:mod:`depth_nodes.ros.poses`): a single
wild pose (a stamp an hour ahead, a 100 m jump) costs at most its own frame; it is dropped
as ``bad_pose`` and the filter carries on.

Outputs are computed only while subscribed (lazy), or always offline; a node nobody
listens to forgets its keyframes and filter.

Frames without output are counted and logged with a reason: ``no_baseline`` (no keyframe
both far enough and turned at most ``max_view_angle_deg``: nothing is published from it),
``no_pose`` (no pose within pose_tolerance),
``pose_timeout`` (no pose came within pose_wait), ``bad_pose``, ``size_mismatch``,
``unsupported_encoding`` and the decoding reasons, ``uncalibrated``, ``bad_calibration``,
``sync_*``, ``time_jump``, ``stream_ended``.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from depth_nodes.core.depth_image import depth_to_points
from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.core.mvs.cost import DEPRECATED_COSTS, MAX_SOURCES
from depth_nodes.core.mvs.fusion import FILTERS
from depth_nodes.core.mvs.matcher import MvsParams
from depth_nodes.core.mvs.stream import Frame, MvsStream, NoDepth, StreamDepth, StreamParams
from depth_nodes.core.reproject import depth_to_millimetres
from depth_nodes.core.stamps import stamp_ns
from depth_nodes.errors import ArgumentError, ConfigError
from depth_nodes.ros.image import array_to_image
from depth_nodes.ros.node import DepthNode
from depth_nodes.ros.params import (
    IMAGE_TRANSPORT,
    THREADS,
    NodeParameters,
    ParamSpec,
    one_of,
    specs_from,
)
from depth_nodes.ros.pointcloud import build_pointcloud
from depth_nodes.ros.workers import use_threads

SWEEP = tuple(f.name for f in fields(MvsParams))
STREAM = tuple(f.name for f in fields(StreamParams))
EXTRA_FIELDS = ('confidence', 'depth_std')
#: Old parameter names still taken for a release: {old: new}.
RENAMED = {'depth_filter': 'temporal_filter'}


def _check_fields(value: str) -> str | None:
    names = [n.strip() for n in value.split(',') if n.strip()]
    unknown = [n for n in names if n not in EXTRA_FIELDS]
    return f'unknown field(s) {", ".join(unknown)}; allowed: {", ".join(EXTRA_FIELDS)}' \
        if unknown else None


PARAMETERS = [
    IMAGE_TRANSPORT,
    ParamSpec('cameras', [''], 'A rig: the namespaces of its synchronised cameras (each with '
              'image_rect and camera_info), e.g. [left, centre, right]; [\'\'] or []: one camera '
              '(image_rect, camera_info)', read_only=True),
    ParamSpec('reference_camera', 0, 'A rig: the index of the camera whose depth is published',
              0, 63, read_only=True),
    ParamSpec('rig_extrinsics', [0.0], 'A rig: each camera\'s optical frame on the rig, 7 '
              'numbers per camera (x y z qx qy qz qw), in the order of cameras',
              read_only=True),
    *specs_from(MvsParams, SWEEP),
    *specs_from(StreamParams, STREAM),
    ParamSpec('depth_filter', '', 'Deprecated: the old name of temporal_filter (empty: not '
              'set); a value given here wins, with a warning',
              check=one_of(('', *FILTERS, 'none'))),
    ParamSpec('depth_encoding', '32FC1', 'depth: 32FC1 metres (NaN unknown) or 16UC1 '
              'millimetres (0 unknown)', check=one_of(('32FC1', '16UC1'))),
    ParamSpec('extra_fields', '', 'Comma-separated extra float32 fields of points2: '
              'confidence, depth_std', check=_check_fields),
    ParamSpec('queue_size', 5, 'Synchroniser queue of the images and camera_infos', 1, 1000,
              read_only=True),
    THREADS,
]


def _sweep(values: Mapping[str, Any]) -> MvsParams:
    return MvsParams(**{name: values[name] for name in SWEEP})


def _stream(values: Mapping[str, Any]) -> StreamParams:
    renamed = {new: values[old] for old, new in RENAMED.items() if values[old]}
    return StreamParams(**{name: renamed.get(name, values[name]) for name in STREAM})


def _check_values(values: Mapping[str, Any]) -> str | None:
    try:
        _sweep(values).validate()
        _stream(values).validate()
    except ArgumentError as exc:
        return str(exc)
    return None


@dataclass
class _Views:
    """An image set read and checked, waiting for its pose."""

    stamp: int
    header: Any
    views: list[tuple[Any, Intrinsics, CameraInfo]]  # grey image, camera, its CameraInfo


class MultiViewStereoNode(DepthNode):
    """Posed images (one camera or a rig) -> depth, sigma, confidence, points2."""

    keeps_state = True

    def __init__(self, node_name: str = 'multiview_stereo', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS, check_values=_check_values)
        values = self.params.values
        self.cameras = [c for c in values['cameras'] if c]
        self.reference = values['reference_camera']
        self.extrinsics = self._extrinsics(values)
        self.poses = self.add_pose_input(self._process, allow_none=True)
        if self.poses.source == 'none' and not self.cameras:
            raise ConfigError('pose_source none needs a rig (cameras): one camera without '
                              'poses has no baseline')
        self._warn_renamed(values)
        self.add_post_set_parameters_callback(self._on_renamed)  # once a change is taken
        self.stream = MvsStream(_sweep(values), _stream(values))
        self.pub_depth = self.add_output(Image, 'depth')
        self.pub_info = self.add_output(CameraInfo, 'depth/camera_info')
        self.pub_sigma = self.add_output(Image, 'sigma')
        self.pub_confidence = self.add_output(Image, 'confidence')
        self.pub_converged = self.add_output(Image, 'converged')
        self.pub_points = self.add_output(PointCloud2, 'points2')
        transport = values['image_transport']
        names = [f'{c}/' for c in self.cameras] or ['']
        inputs: list[Any] = []
        for prefix in names:
            inputs += [(Image, f'{prefix}image_rect', transport),
                       (CameraInfo, f'{prefix}camera_info')]
        self.add_synced_inputs(inputs, self.on_images, queue_size=values['queue_size'])

    def _extrinsics(self, values: Mapping[str, Any]) -> list[Pose]:
        if not self.cameras:
            return [Pose()]
        numbers = list(values['rig_extrinsics'])
        if not 2 <= len(self.cameras) <= MAX_SOURCES + 1:
            raise ConfigError(f'a rig needs 2 to {MAX_SOURCES + 1} cameras (or none: one '
                              f'camera), got {len(self.cameras)}')
        if not self.reference < len(self.cameras):
            raise ConfigError(f'reference_camera {self.reference} is not one of the '
                              f'{len(self.cameras)} cameras')
        if len(numbers) != 7 * len(self.cameras):
            raise ConfigError(f'rig_extrinsics needs 7 numbers per camera ({7 * len(self.cameras)}'
                              f' for {len(self.cameras)}), got {len(numbers)}')
        try:
            return [Pose.from_values(numbers[7 * k:7 * k + 7]) for k in range(len(self.cameras))]
        except ArgumentError as exc:
            raise ConfigError(f'rig_extrinsics: {exc}') from None

    def _warn_renamed(self, values: Mapping[str, Any]) -> None:
        for old, new in RENAMED.items():
            if values.get(old):
                self.get_logger().warning(f'parameter {old} is deprecated: it is now {new} '
                                          f'({old}: {values[old]} taken as {new})')
        cost = values.get('matching_cost')
        if cost in DEPRECATED_COSTS:
            self.get_logger().warning(f'matching_cost {cost} is deprecated: it is now '
                                      f'{DEPRECATED_COSTS[cost]} (taken as that)')

    def _on_renamed(self, params: list[Any]) -> None:
        self._warn_renamed({p.name: p.value for p in params
                            if p.name in RENAMED or p.name == 'matching_cost'})

    # ------------------------------------------------------------------ inputs
    def on_images(self, *msgs: Any) -> None:
        """One synchronised set: (image, camera_info) per camera."""
        outputs = (self.pub_depth, self.pub_info, self.pub_sigma, self.pub_confidence,
                   self.pub_converged, self.pub_points)
        if self.skip_unwanted(*(out.wanted for out in outputs)):
            self.stream.reset()  # nobody listens: the keyframes and the filter go stale
            self.poses.clear()
            return
        views = []
        for k in range(len(msgs) // 2):
            image, info = msgs[2 * k], msgs[2 * k + 1]
            what = f'{self.cameras[k]}/image_rect' if self.cameras else 'image_rect'
            grey = self.gray_image(image, what)
            if grey is None:
                return
            camera = self.camera(info, what.replace('image_rect', 'camera_info'),
                                 (int(grey.shape[0]), int(grey.shape[1])))
            if camera is None:
                return
            views.append((grey, camera, info))
        header = copy.deepcopy(msgs[2 * self.reference if self.cameras else 0].header)
        self.poses.submit(header, _Views(stamp_ns(header), header, views))

    # ------------------------------------------------------------------ work
    def _process(self, item: _Views, body: Pose | None) -> None:
        values = self.params.values
        use_threads(values['threads'])
        sweep, stream = _sweep(values), _stream(values)
        if (sweep, stream) != (self.stream.params, self.stream.stream):
            self.stream.set_params(sweep, stream)
        body = body or Pose()  # a rig that does not move
        reference = self.reference if self.cameras else 0
        frames = [Frame(grey, camera, body.compose(mount), item.stamp,
                        (item.header, info) if k == reference else None)
                  for k, ((grey, camera, info), mount) in
                  enumerate(zip(item.views, self.extrinsics, strict=True))]
        rig = [f for k, f in enumerate(frames) if self.cameras and k != reference]
        self._publish(self.stream.process(frames[reference], rig))

    def _publish(self, result: StreamDepth | NoDepth | None) -> None:
        if result is None:
            return
        if isinstance(result, NoDepth):
            self.drop(result.reason, result.detail)
            return
        header, info = result.frame.context
        values = self.params.values
        camera = result.frame.camera
        if self.pub_depth.wanted:
            encoding = values['depth_encoding']
            depth = depth_to_millimetres(result.depth) if encoding == '16UC1' else result.depth
            self.pub_depth.publish(array_to_image(depth, encoding, header))
        if self.pub_info.wanted:
            out = copy.deepcopy(info)
            out.header = header
            self.pub_info.publish(out)
        if self.pub_sigma.wanted:
            self.pub_sigma.publish(array_to_image(result.sigma, '32FC1', header))
        if self.pub_confidence.wanted:
            self.pub_confidence.publish(array_to_image(result.confidence, '32FC1', header))
        if self.pub_converged.wanted:
            self.pub_converged.publish(array_to_image(
                np.where(result.converged, 255, 0).astype(np.uint8), 'mono8', header))
        if self.pub_points.wanted:
            extra: dict[str, Any] = {}
            for name in (n.strip() for n in values['extra_fields'].split(',') if n.strip()):
                extra[name] = result.confidence if name == 'confidence' else result.sigma
            self.pub_points.publish(build_pointcloud(depth_to_points(result.depth, camera),
                                                     header, extra_fields=extra))

    # ------------------------------------------------------------------ hooks
    def on_time_jump(self) -> None:
        """The stamps went back (a looping bag): start over."""
        self.stream.reset()

    def holds_input(self) -> bool:
        """Images wait for a pose, or for later images (``delay``)."""
        return super().holds_input() or self.stream.waiting > 0

    def finish_stream(self) -> None:
        """The stream ended: the delayed images get their depth from the later images there
        are; those still waiting for a pose are counted as ``stream_ended``."""
        super().finish_stream()
        for result in self.stream.flush():
            self._publish(result)
