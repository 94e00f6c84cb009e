"""`depth-nodes eval` of a fused bag: tsdf_fusion's final mesh and distance slice against
the simulator's exact surface (rebuilt from the bag's metadata:
:func:`depth_nodes.sim.depth_sequence.scene_at`), beside Open3D's VoxelBlockGrid fed the
same depth at the same poses when asked.

* accuracy: the distance of each mesh vertex to the true surface, median and 90th
  percentile;
* completeness: the share of the true surface seen by the camera (the exact depth of every
  4th pixel of the frames whose scene is the final one, up to the fusion's
  ``max_integration_distance``, back-projected at the true poses)
  that lies within two voxels of a mesh vertex (a vertex, not a triangle: a slight
  underestimate);
* the slice: its distances against the true distance to the surface, where that is below
  the slice's cap.

A fused bag of real views (`depth-nodes import-views ... --bbox`, then the multi-view
graph and fusion) has no exact surface: the share of its mesh's vertices inside the
object's bounding box is reported instead.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics, Pose, intrinsics
from depth_nodes.core.stamps import stamp_ns
from depth_nodes.errors import BagError
from depth_nodes.ros.camera_info import camera_info_to_model
from depth_nodes.ros.image import image_to_array
from depth_nodes.ros.pointcloud import read_pointcloud
from depth_nodes.sim.depth_sequence import DepthSequenceConfig, pose_at, scene_at, stamp_at
from depth_nodes.sim.scene import Scene
from depth_nodes.tools.bags import depth_filter, fusion_stereo
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bags.meshes import final_mesh
from depth_nodes.tools.bags.views import VIEWS_KEY, views_info

__all__ = ['FusionReport', 'MeshScore', 'evaluate_fusion_bag', 'nearest_distance',
           'score_mesh', 'sequence_of']

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
#: Every this many pixels, along both axes, a true surface sample.
SAMPLE_STRIDE = 4


@dataclass
class MeshScore:
    """One mesh against the truth (metres)."""

    label: str
    vertices: int
    triangles: int
    median: float
    p90: float
    completeness: float
    seconds: float | None = None


@dataclass
class FusionReport:
    """What `eval` prints of a fused bag."""

    bag: str
    kind: str
    frames: int
    voxel: float
    rows: list[MeshScore] = field(default_factory=list)
    slice_rows: list[tuple[str, int, float, float]] = field(default_factory=list)
    #: Real views: the mesh's vertices, and how many lie inside the object's box.
    inside: tuple[int, int] | None = None

    def format(self) -> str:
        if self.inside is not None:
            total, inside = self.inside
            return (f'{self.bag}: real views, {self.frames} depth frames fused; mesh vertices '
                    f"inside the object's bounding box: {inside} of {total} "
                    f'({inside / max(total, 1):.2%})')
        lines = [f'{self.bag}: {self.kind}, {self.frames} frames, voxel {self.voxel * 100:g} '
                 'cm; mesh vertices against the exact surface',
                 f'{"mesh":40s} {"vertices":>9s} {"triangles":>10s} {"median":>9s} '
                 f'{"p90":>9s} {"median":>7s} {"p90":>7s} {"complete":>9s}',
                 f'{"":40s} {"":>9s} {"":>10s} {"(mm)":>9s} {"(mm)":>9s} {"(vox)":>7s} '
                 f'{"(vox)":>7s} {"(2 vox)":>9s}']
        for row in self.rows:
            lines.append(f'{row.label:40s} {row.vertices:9d} {row.triangles:10d} '
                         f'{row.median * 1000:9.2f} {row.p90 * 1000:9.2f} '
                         f'{row.median / self.voxel:7.3f} {row.p90 / self.voxel:7.3f} '
                         f'{row.completeness:9.2%}')
        for label, count, median, p90 in self.slice_rows:
            lines.append(f'{label}: {count} cells, |distance| error median {median * 1000:.1f} '
                         f'mm, 90th percentile {p90 * 1000:.1f} mm')
        return '\n'.join(lines)


def sequence_of(custom_data: dict[str, str], path: str | Path) -> tuple[DepthSequenceConfig, str]:
    """The depth sequence a bag was made from (a depth bag's, or a fusion stereo bag's
    camera path) and the topic prefix of its truth.

    Raises:
        BagError: The bag is neither.
    """
    if depth_filter.CONFIG_KEY in custom_data:
        return depth_filter.config_from_metadata(custom_data, path), '/camera'
    if fusion_stereo.CONFIG_KEY in custom_data:
        return fusion_stereo.config_from_metadata(custom_data, path).sequence, '/stereo/left'
    raise BagError(f'{path}: a fused bag of no simulated sequence (a depth_* or stereo_orbit '
                   'bag, processed): its true surface is unknown')


def final_frames(config: DepthSequenceConfig) -> range:
    """The frames whose scene is the last frame's (the surface the mesh should end with)."""
    if config.kind == 'moving_object':
        return range(config.n_frames - 1, config.n_frames)
    if config.kind == 'object_leaves':
        return range(config.n_frames // 2, config.n_frames)
    return range(config.n_frames)


@numba.njit(cache=True, nogil=True, parallel=True)
def _nearest(points: F64, cells: NDArray[np.int64], order: NDArray[np.int64], vertices: F64,
             origin: F64, size: float, dims: NDArray[np.int64], cap: float, out: F64) -> None:
    for n in numba.prange(points.shape[0]):
        best = cap * cap
        c = np.empty(3, np.int64)
        for m in range(3):
            c[m] = math.floor((points[n, m] - origin[m]) / size)
        for dz in range(-1, 2):
            for dy in range(-1, 2):
                for dx in range(-1, 2):
                    x, y, z = c[0] + dx, c[1] + dy, c[2] + dz
                    if x < 0 or y < 0 or z < 0 or x >= dims[0] or y >= dims[1] or \
                            z >= dims[2]:
                        continue
                    key = (z * dims[1] + y) * dims[0] + x
                    lo = np.searchsorted(cells, key)
                    hi = np.searchsorted(cells, key, side='right')
                    for k in range(lo, hi):
                        v = order[k]
                        d = 0.0
                        for m in range(3):
                            d += (points[n, m] - vertices[v, m]) ** 2
                        best = min(best, d)
        out[n] = math.sqrt(best)


def nearest_distance(points: F64, vertices: F64, cap: float) -> F64:
    """Each point's distance to the nearest vertex, at most ``cap`` (a grid of cells of
    side ``cap``; vertices farther than that are not looked at)."""
    out = np.full(len(points), cap, np.float64)
    if not len(vertices) or not len(points):
        return out
    v = np.asarray(vertices, np.float64)
    origin = v.min(axis=0) - cap
    dims = (np.floor((v.max(axis=0) + cap - origin) / cap) + 1).astype(np.int64)
    cell = np.floor((v - origin) / cap).astype(np.int64)
    keys = (cell[:, 2] * dims[1] + cell[:, 1]) * dims[0] + cell[:, 0]
    order = np.argsort(keys, kind='stable')
    _nearest(np.asarray(points, np.float64), keys[order], order, v, origin, float(cap), dims,
             float(cap), out)
    return out


def score_mesh(label: str, vertices: F32, triangles: int, scene: Scene, samples: F64,
               voxel: float) -> MeshScore:
    """One mesh's accuracy and completeness (see the module notes)."""
    if not len(vertices):
        return MeshScore(label, 0, 0, math.nan, math.nan, 0.0)
    error = scene.distance(np.asarray(vertices, np.float64))
    near = nearest_distance(samples, np.asarray(vertices, np.float64), 2.0 * voxel)
    return MeshScore(label, len(vertices), triangles, float(np.median(error)),
                     float(np.percentile(error, 90)), float((near < 2.0 * voxel).mean()))


@dataclass
class _Frames:
    """The fused depth and the truth of a bag, by frame index."""

    depth: dict[int, F32]
    truth: dict[int, F32]
    camera: Any


def _frames(path: str | Path, config: DepthSequenceConfig, prefix: str,
            depth_topic: str | None) -> tuple[_Frames, str]:
    index = {stamp_at(config, i): i for i in range(config.n_frames)}
    info_topic = f'{prefix}/depth/camera_info' if prefix == '/camera' else \
        f'{prefix}/camera_info'
    truth_topic = f'{prefix}/depth_gt'
    with BagReader(path) as reader:
        if depth_topic is None:
            candidates = ['/camera/filtered/image_rect', '/stereo/depth',
                          '/camera/depth/image_rect_raw']
            depth_topic = next((t for t in candidates if t in reader.topics), None)
            if depth_topic is None:
                raise BagError(f'{path}: none of {", ".join(candidates)}: name the fused '
                               'depth with --fused-depth')
        elif depth_topic not in reader.topics:
            raise BagError(f'{path}: no topic {depth_topic}')
        frames = _Frames({}, {}, None)
        for msg in reader.messages([depth_topic, truth_topic, info_topic]):
            parsed = msg.deserialize()
            i = index.get(stamp_ns(parsed.header))
            if i is None:
                continue
            if msg.topic == info_topic:
                frames.camera = frames.camera or camera_info_to_model(parsed)
            elif msg.topic == truth_topic:
                frames.truth[i] = image_to_array(parsed).astype(np.float32)
            else:
                depth = image_to_array(parsed).astype(np.float32)
                if parsed.encoding == '16UC1':
                    depth = np.where(depth > 0, depth / 1000.0, np.nan).astype(np.float32)
                frames.depth[i] = depth
    if frames.camera is None or not frames.truth:
        raise BagError(f'{path}: no {truth_topic} and {info_topic}: not a simulated bag')
    return frames, depth_topic


def _samples(frames: _Frames, config: DepthSequenceConfig, max_depth: float) -> F64:
    camera = intrinsics(frames.camera)
    ys, xs = np.mgrid[0:camera.height:SAMPLE_STRIDE, 0:camera.width:SAMPLE_STRIDE]
    rays = np.stack([(xs - camera.cx) / camera.fx, (ys - camera.cy) / camera.fy,
                     np.ones(xs.shape)], -1).reshape(-1, 3)
    out = []
    for i in final_frames(config):
        if i not in frames.truth:
            continue
        z = frames.truth[i][::SAMPLE_STRIDE, ::SAMPLE_STRIDE].reshape(-1).astype(np.float64)
        seen = np.isfinite(z) & (z <= max_depth)
        pose = pose_at(config, i)
        out.append((rays[seen] * z[seen, None]) @ pose.rotation.T + pose.position)
    return np.concatenate(out) if out else np.empty((0, 3))


def fuse_with_open3d(frames: list[tuple[F32, Pose]], camera: Intrinsics, *, voxel: float,
                     truncation_voxels: float, max_depth: float) -> tuple[F32, Any, float]:
    """Open3D's VoxelBlockGrid fed ``frames`` (depth, camera pose): its mesh (any observed
    voxel, as tsdf_fusion's ``min_weight``) and its integration's seconds.

    Raises:
        ConfigError: Open3D is not installed.
    """
    from depth_nodes.tools.evaluation.open3d_fusion import Open3dTsdf

    grid = Open3dTsdf(voxel, truncation_voxels, max_depth, block_count=20000)
    start = time.perf_counter()
    for depth, pose in frames:
        world_from_camera = np.eye(4)
        world_from_camera[:3, :3], world_from_camera[:3, 3] = pose.rotation, pose.position
        grid.integrate(depth, camera.fx, camera.fy, camera.cx, camera.cy, world_from_camera)
    seconds = time.perf_counter() - start
    vertices, faces = grid.mesh()
    return vertices, faces, seconds


def evaluate_fusion_bag(path: str | Path, *, voxel: float, truncation: float,
                        max_depth: float = 5.0, open3d: bool = False,
                        depth_topic: str | None = None,
                        on_stage: Callable[[str], None] = lambda _: None) -> FusionReport:
    """Score a fused bag (see the module notes).

    Raises:
        BagError: Not a fused bag of a simulated sequence.
        ConfigError: ``open3d`` without the open3d extra.

    ``max_depth``: tsdf_fusion's max_integration_distance: Open3D's depth_max, and the
    farthest true surface that counts for completeness.
    """
    with BagReader(path) as reader:
        custom = dict(reader.custom_data)
        slices = [t for t, kind in reader.topics.items()
                  if kind == 'sensor_msgs/msg/PointCloud2' and t.endswith('esdf_slice')]
    if VIEWS_KEY in custom:
        return _views_report(path, custom, voxel)
    config, prefix = sequence_of(custom, path)
    on_stage('mesh')
    mesh = final_mesh(path, None)
    scene = scene_at(config, config.n_frames - 1)
    frames, fused = _frames(path, config, prefix, depth_topic)
    samples = _samples(frames, config, max_depth)
    report = FusionReport(str(path), config.kind, len(frames.depth), voxel)
    report.rows.append(score_mesh(f'tsdf_fusion ({mesh.topic})', mesh.vertices,
                                  len(mesh.faces), scene, samples, voxel))
    if open3d:
        on_stage('Open3D')
        vertices, faces, seconds = fuse_with_open3d(
            [(frames.depth[i], pose_at(config, i)) for i in sorted(frames.depth)],
            intrinsics(frames.camera), voxel=voxel, truncation_voxels=truncation,
            max_depth=max_depth)
        row = score_mesh(f"Open3D VoxelBlockGrid ({fused})", vertices, len(faces), scene,
                         samples, voxel)
        row.seconds = seconds
        report.rows.append(row)
    for topic in slices:
        report.slice_rows.append(_slice_score(path, topic, scene))
    return report


def _views_report(path: str | Path, custom: dict[str, str], voxel: float) -> FusionReport:
    """A fused bag of real views: its mesh's vertices inside the object's box."""
    info = views_info(custom, path)
    if info.bbox is None:
        raise BagError(f'{path}: real views imported without --bbox: nothing to score the '
                       'mesh against')
    mesh = final_mesh(path, None)
    low, high = np.array(info.bbox[:3]), np.array(info.bbox[3:])
    vertices = mesh.vertices.astype(np.float64)
    inside = int(((vertices >= low) & (vertices <= high)).all(axis=1).sum())
    with BagReader(path) as reader:
        depth = next((t for t in reader.topics if t.endswith('/depth')), None)
        count = sum(1 for _ in reader.messages([depth])) if depth else 0
    return FusionReport(str(path), 'real views', count, voxel,
                        inside=(len(vertices), inside))


def _slice_score(path: str | Path, topic: str, scene: Scene) -> tuple[str, int, float, float]:
    """The last slice of ``topic`` against the true distance (where it is below the
    slice's cap: the largest distance it holds)."""
    with BagReader(path) as reader:
        last = None
        for msg in reader.messages([topic]):
            last = msg
    if last is None:
        return topic, 0, math.nan, math.nan
    cloud = read_pointcloud(last.deserialize())
    points = np.stack([cloud[a].ravel() for a in 'xyz'], axis=1).astype(np.float64)
    distance = cloud['distance'].ravel().astype(np.float64)
    cap = float(np.abs(distance).max())
    truth = scene.distance(points)
    within = truth < 0.9 * cap
    error = np.abs(np.abs(distance[within]) - truth[within])
    if not len(error):
        return topic, 0, math.nan, math.nan
    return topic, int(within.sum()), float(np.median(error)), float(np.percentile(error, 90))
