"""TSDF fusion node: depth images at known poses fused into one 3-D model, a truncated
signed distance function over blocks of voxels (:mod:`depth_nodes.core.fusion`), for any
depth source of the package or a driver's, each observation weighted by its noise.

Subscribes ``image_rect`` (REP 118: 16UC1 mm or 32FC1 m; raw or, with
``depth_image_transport: compressedDepth``, ``image_rect/compressedDepth``) and
``camera_info``, matched by exact stamp, with ``weighting_mode: sigma`` also ``sigma``
(32FC1 m: the depth filter's ``filtered/sigma``, multiview_stereo's ``sigma``), with
``confidence`` also ``confidence`` (32FC1, 0 - 1: cross_check's, the tof node's); and the
camera's poses (``pose_source``: ``odometry`` on ``odom``, ``pose``, or ``tf``:
:mod:`depth_nodes.ros.poses`). Which noise image it subscribes to is set by the
``weighting_mode`` it starts with; changing to a mode that needs another image is refused.

Publishes, in ``global_frame`` (empty: the frame the poses are given in):

* ``mesh``: visualization_msgs/MarkerArray, one TRIANGLE_LIST marker per block whose
  triangles changed (its id the block's) and a DELETE for a block with none left, at most
  ``mesh_rate_hz`` (by the images' stamps), so that RViz and Foxglove redraw it block by
  block; the first message after a start or a ``clear`` begins with a DELETEALL;
* ``surface_points``: PointCloud2 (x, y, z) of the surface, where the field crosses 0 between
  two observed voxels, with each mesh;
* ``esdf_slice``: PointCloud2 (x, y, z, distance) of the signed distance field on the plane
  ``esdf_slice_axis = esdf_slice_height`` within ``esdf_slice_radius`` of the camera, at
  most ``esdf_rate_hz``. A point cloud keeps the
  distance in metres, as voxblox's slice does, where an OccupancyGrid would cut it to a
  0 - 100 cost; ``distance`` is negative behind surfaces, unknown space is left out.

Services: ``~/save_mesh`` (std_srvs/Trigger: the whole mesh as binary PLY to ``mesh_path``)
and ``~/clear`` (std_srvs/Trigger: forget the map).

Every setting of the volume (:class:`~depth_nodes.core.fusion.params.TsdfParams`: nvblox's
and voxblox's names) is a runtime parameter checked by the core's rules; a new
``voxel_size`` or ``block_size`` starts the map over. The map is built whether or not
anyone subscribes (the services read it); the mesh, points and slice are computed only while
wanted (always offline). Stamps that jump back (a looping bag) start the map over
(logged). Diagnostics add the blocks, the voxels' memory and each stage's time.

Frames without output are counted and logged with a reason: ``unsupported_encoding`` and
the decoding reasons, ``uncalibrated``, ``bad_calibration``, ``size_mismatch`` (a sigma or
confidence image of another size, or a camera_info whose size is not the image's,
scaled), ``no_depth`` (no pixel with a depth: NaN, zero or negative), ``nothing_fused``
(no voxel updated: every depth outside ``min_integration_distance`` -
``max_integration_distance`` or off the image), ``no_pose``, ``pose_timeout``,
``bad_pose``, ``no_transform``, ``sync_*``, ``time_jump``, ``stream_ended``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from depth_nodes.core.fusion import TsdfParams, TsdfVolume, surface_points
from depth_nodes.core.fusion.esdf import AXES, esdf_slice
from depth_nodes.core.fusion.layer import MeshLayer
from depth_nodes.core.fusion.ply import write_ply
from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.core.stamps import NS_PER_S, stamp_ns
from depth_nodes.errors import DepthNodesError
from depth_nodes.nodes.depth_common import QUEUE_SIZE, DepthImageNode, depth_transport
from depth_nodes.ros.params import THREADS, NodeParameters, ParamSpec, one_of, specs_from, validated
from depth_nodes.ros.pointcloud import build_pointcloud
from depth_nodes.ros.serialized import marker_array
from depth_nodes.ros.workers import use_threads

SETTINGS = tuple(f.name for f in fields(TsdfParams))
#: The noise image each weighting mode reads.
NOISE_INPUT = {'sigma': 'sigma', 'confidence': 'confidence'}
#: The mesh's colour (RGBA): a light grey that RViz shades.
MESH_COLOR = (0.8, 0.8, 0.8, 1.0)
#: Seconds between two warnings that the map started over.
RESET_LOG_PERIOD_S = 5.0

PARAMETERS = [
    depth_transport('depth_image_transport'),
    *specs_from(TsdfParams, SETTINGS),
    ParamSpec('global_frame', '', 'Frame of the outputs (empty: the frame the poses are '
              'given in: the odometry\'s or pose\'s header, or world_frame with tf)',
              read_only=True),
    ParamSpec('mesh_rate_hz', 2.0, 'Most meshes (and surface points) a second, by the '
              'images\' stamps (0: none, but for save_mesh)', 0.0, 1000.0),
    ParamSpec('esdf_rate_hz', 2.0, 'Most distance slices a second, by the images\' stamps '
              '(0: none)', 0.0, 1000.0),
    ParamSpec('esdf_slice_height', 0.0, 'Where the distance slice cuts, metres along '
              'esdf_slice_axis', -1e6, 1e6),
    ParamSpec('esdf_slice_axis', 'z', 'The axis the slice is across: z (a REP 103 world, '
              'z up), x or y', check=one_of(AXES)),
    ParamSpec('esdf_max_distance', 2.0, 'Distances beyond this, metres, are given as this',
              0.01, 100.0),
    ParamSpec('esdf_slice_radius', 8.0, 'The slice covers a square of this half side, '
              'metres, around the camera', 0.1, 1000.0),
    ParamSpec('mesh_path', 'mesh.ply', 'Where ~/save_mesh writes the mesh (binary PLY)'),
    QUEUE_SIZE,
    THREADS,
]


def _settings(values: Mapping[str, Any]) -> TsdfParams:
    return TsdfParams(**{name: values[name] for name in SETTINGS})


@dataclass
class _Frame:
    """A frame read and checked, waiting for its pose."""

    stamp: int
    depth: Any
    noise: Any
    camera: Intrinsics


class TsdfFusionNode(DepthImageNode):
    """Depth image + camera_info (+ sigma or confidence) + poses -> mesh, surface points,
    distance slice."""

    keeps_state = True

    def __init__(self, node_name: str = 'tsdf_fusion', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._noise_input: str | None = None
        self._started = False
        self.params = NodeParameters(self, PARAMETERS, check_values=self._check)
        values = self.params.values
        self._noise_input = NOISE_INPUT.get(values['weighting_mode'])
        self._started = True
        self.volume = TsdfVolume(_settings(values))
        self.layer = MeshLayer()
        self.poses = self.add_pose_input(self._fuse, allow_none=False)
        self.pub_mesh = self.add_output(MarkerArray, 'mesh')
        self.pub_points = self.add_output(PointCloud2, 'surface_points')
        self.pub_esdf = self.add_output(PointCloud2, 'esdf_slice')
        inputs: list[tuple[Any, ...]] = [
            (Image, 'image_rect', values['depth_image_transport']), (CameraInfo, 'camera_info')]
        if self._noise_input:
            inputs.append((Image, self._noise_input))
        self.add_synced_inputs(inputs, self.on_frame, queue_size=values['queue_size'])
        self.create_service(Trigger, '~/save_mesh', self._save_mesh_service)
        self.create_service(Trigger, '~/clear', self._clear_service)
        self._last_mesh = self._last_esdf = None
        self._delete_all = True
        self._last_stamp = 0
        self._camera = np.zeros(3)
        self._last_reset_log = -RESET_LOG_PERIOD_S
        self.resets = 0
        self.stage_ms: dict[str, float] = {}

    def _check(self, values: Mapping[str, Any]) -> str | None:
        reason = validated(_settings)(values)
        if reason:
            return reason
        wanted = NOISE_INPUT.get(values['weighting_mode'])
        if self._started and wanted and wanted != self._noise_input:
            return (f'weighting_mode {values["weighting_mode"]} needs the {wanted} input, '
                    'which the node subscribes to only when it starts with that mode')
        return None

    # ------------------------------------------------------------------ inputs
    def on_frame(self, depth_msg: Any, info: CameraInfo, noise_msg: Any = None) -> None:
        """One depth image (with its camera_info, and its noise image if any)."""
        read = self.read_depth(depth_msg, 'image_rect')
        if read is None:
            return
        depth = read[0]
        h, w = depth.shape
        if info.width and info.height and (info.width, info.height) != (w, h) and \
                abs(w / info.width - h / info.height) > 0.01 * max(w / info.width,
                                                                    h / info.height):
            # a decimated image keeps its camera's shape; another shape would be fused
            # into the map at a wrong geometry for good
            self.drop('size_mismatch', f'camera_info is {info.width}x{info.height} for a '
                      f'{w}x{h} depth image: not the same shape, scaled')
            return
        camera = self.camera(info, 'camera_info', depth.shape)
        if camera is None:
            return
        noise = None
        if self._noise_input:
            image = self.frame_image(noise_msg, self._noise_input, depth.shape, ('32FC1',))
            if image is None:
                return
            noise = np.ascontiguousarray(image[0], np.float32)
        with np.errstate(invalid='ignore'):
            if not (depth > 0).any():
                self.drop('no_depth', 'no pixel of the depth image has a depth (NaN, zero or '
                          'negative)')
                return
        self.poses.submit(depth_msg.header, _Frame(stamp_ns(depth_msg.header), depth, noise,
                                                   camera))

    # ------------------------------------------------------------------ work
    def _fuse(self, frame: _Frame, pose: Pose | None) -> None:
        assert pose is not None  # pose_source none is not allowed
        values = self.params.values
        use_threads(values['threads'])
        if self.volume.configure(_settings(values)):
            self._started_over('the voxel or block size changed')
        result = self.volume.integrate(frame.depth, frame.camera, pose, noise=frame.noise)
        if not result.voxels:
            self.drop('nothing_fused', 'no voxel was updated: every depth lies outside '
                      'min_integration_distance - max_integration_distance, or its voxels '
                      'project off the image')
            return
        self.stage_ms = {k: 1000 * v for k, v in result.seconds.items()}
        self._last_stamp = frame.stamp
        self._camera = pose.position
        header = self._header(frame.stamp)
        if self._due('_last_mesh', frame.stamp, values['mesh_rate_hz']) and \
                (self.pub_mesh.wanted or self.pub_points.wanted):
            self._publish_mesh(header)
        if self._due('_last_esdf', frame.stamp, values['esdf_rate_hz']) and \
                self.pub_esdf.wanted:
            self._publish_esdf(header, values)

    def _due(self, attribute: str, stamp: int, rate: float) -> bool:
        """Whether ``rate`` allows another output at ``stamp`` (and note it)."""
        last = getattr(self, attribute)
        if rate <= 0 or (last is not None and stamp - last < NS_PER_S / rate):
            return False
        setattr(self, attribute, stamp)
        return True

    def _header(self, stamp: int) -> Any:
        from std_msgs.msg import Header
        frame = self.params.values['global_frame'] or self.poses.pose_frame
        header = Header(frame_id=frame)
        header.stamp.sec, header.stamp.nanosec = divmod(stamp, NS_PER_S)
        return header

    def _publish_mesh(self, header: Any) -> None:
        start = time.perf_counter()
        update = self.layer.update(self.volume)
        markers: list[tuple[int, Any]] = [(slot, None) for slot in update.deleted]
        markers += sorted(update.blocks.items())
        self.stage_ms['mesh'] = 1000 * (time.perf_counter() - start)
        if self.pub_mesh.wanted and (markers or self._delete_all):
            stamp = (header.stamp.sec, header.stamp.nanosec)
            self.pub_mesh.publish(marker_array(stamp, header.frame_id, 'tsdf_mesh', markers,
                                               MESH_COLOR, delete_all=self._delete_all))
            self._delete_all = False
        if self.pub_points.wanted:
            points = surface_points(self.volume)
            if len(points):  # no surface yet: no cloud (never an empty one)
                self.pub_points.publish(build_pointcloud(points[None], header, pad=False))

    def _publish_esdf(self, header: Any, values: Mapping[str, Any]) -> None:
        start = time.perf_counter()
        cut = esdf_slice(self.volume, axis=values['esdf_slice_axis'],
                         height=values['esdf_slice_height'],
                         max_distance=values['esdf_max_distance'], centre=self._camera,
                         radius=values['esdf_slice_radius'])
        self.stage_ms['esdf'] = 1000 * (time.perf_counter() - start)
        if not len(cut.points):  # nothing observed on the plane: no cloud
            return
        self.pub_esdf.publish(build_pointcloud(cut.points[None], header, pad=False,
                                               extra_fields={'distance': cut.distance[None]}))

    # ------------------------------------------------------------------ services
    def _save_mesh_service(self, request: Any, response: Any) -> Any:
        path = Path(self.params.values['mesh_path']).expanduser()
        try:
            self.layer.update(self.volume)
            vertices, faces = self.layer.mesh()
            write_ply(path, vertices, faces)
        except (OSError, DepthNodesError) as exc:
            response.success = False
            response.message = f'cannot write {path}: {getattr(exc, "strerror", None) or exc}'
            self.get_logger().error(response.message)
            return response
        response.success = True
        response.message = f'{path}: {len(vertices)} vertices, {len(faces)} triangles'
        self.get_logger().info(f'mesh saved to {response.message}')
        return response

    def _clear_service(self, request: Any, response: Any) -> Any:
        blocks = self.volume.block_count
        self._clear()
        response.success = True
        response.message = f'map cleared ({blocks} blocks)'
        self.get_logger().info(response.message)
        return response

    def _clear(self) -> None:
        self.volume.clear()
        self.volume.take_changes()
        self.layer.clear()
        self._delete_all = True
        self._last_mesh = self._last_esdf = None

    def _started_over(self, why: str) -> None:
        self._clear()
        self.resets += 1
        now = self.get_clock().now().nanoseconds / NS_PER_S
        if now - self._last_reset_log >= RESET_LOG_PERIOD_S:
            self._last_reset_log = now
            self.get_logger().warning(f'map started over ({self.resets} so far): {why}')

    # ------------------------------------------------------------------ hooks
    def on_time_jump(self) -> None:
        """The stamps went back (a looping bag): start the map over."""
        self._started_over('the stamps jumped back')

    def finish_stream(self) -> None:
        """The input ended (offline): the last mesh and slice, whatever the rates."""
        super().finish_stream()
        if self._last_stamp:
            header = self._header(self._last_stamp)
            self._publish_mesh(header)
            if self.params.values['esdf_rate_hz'] > 0:
                self._publish_esdf(header, self.params.values)

    def diagnostics(self) -> Any:
        status = super().diagnostics()
        from diagnostic_msgs.msg import KeyValue
        status.values += [
            KeyValue(key='blocks', value=str(self.volume.block_count)),
            KeyValue(key='voxel memory (MB)', value=f'{self.volume.memory_bytes / 2**20:.1f}'),
            KeyValue(key='mesh triangles', value=str(self.layer.triangle_count)),
            KeyValue(key='map restarts', value=str(self.resets)),
        ] + [KeyValue(key=f'{stage} (ms)', value=f'{ms:.1f}')
             for stage, ms in self.stage_ms.items()]
        return status
