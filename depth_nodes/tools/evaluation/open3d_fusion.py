"""Open3D's TSDF on our own depth frames, for comparison with the ``tsdf_fusion`` node: the
tensor ``open3d.t.geometry.VoxelBlockGrid`` on the CPU, fed the same frames, voxel size and
truncation.

Open3D is the optional ``open3d`` extra (``pip install .[open3d]``): no node imports it,
only evaluation and benchmark tools, through :func:`load_open3d`.

Behaviour of Open3D 0.20 (``open3d-cpu``) measured on crafted frames (not read from its
source):

* voxel ``(i, j, k)`` samples the distance at ``(i, j, k) * voxel_size`` in the world;
* the distance is projective (measured depth minus the voxel's Z in the camera), stored
  divided by the truncation distance and clipped to +1 in front of the surface; voxels more
  than the truncation behind it are left alone; every observation weighs 1, without a cap;
* a voxel reads the pixel ``floor(u), floor(v)`` of its projection: a pixel spans
  ``[i, i + 1)``, its centre at ``i + 0.5``. This package's pixel centres are integers, so
  :class:`Open3dTsdf` hands Open3D ``cx + 0.5`` and ``cy + 0.5`` and each voxel reads the
  pixel nearest its projection (without the shift, the test's plane, 1.5 - 2.4 m away and
  sloping 0.5 m per metre, came out 2.5 mm nearer than it is on average, 3.1 mm at most
  with it);
* a depth of 0 (Open3D's own "no depth"), NaN or inf, or beyond ``max_depth_m``, is no
  measurement (:class:`Open3dTsdf` turns NaN and inf into 0 all the same), and a frame
  with none in ``(0, max_depth_m]`` is an error (:class:`Open3dTsdf` skips it);
* extraction keeps the voxels whose weight is strictly above ``weight_threshold``: a
  surface seen in n frames needs a threshold below n;
* meshes and points can only be extracted from a grid that has a colour attribute (without
  one, Open3D fails setting the vertex colours), so the grid carries a float32 RGB that
  depth-only integration never writes: 12 of the 20 bytes a voxel takes;
* the block table starts with room for ``block_count`` blocks and grows when a frame
  needs more, to fit that frame and then by doubling (from 1000, the simulator's
  640 x 480 frames at 2 cm made it 5065, 10130, 20260), all of it allocated and zeroed;
* the CPU kernels run on oneTBB, which ``OMP_NUM_THREADS`` does not limit;
  ``open3d.utility.set_max_threads`` does, at any time and for the whole process
  (:func:`open3d_threads`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics, check_rotation
from depth_nodes.errors import ArgumentError, ConfigError
from depth_nodes.tools.evaluation.librealsense import _preload_libusb

__all__ = ['BLOCK_RESOLUTIONS', 'PIXEL_CENTRE', 'WEIGHT_THRESHOLD', 'Open3dTiming', 'Open3dTsdf',
           'load_open3d', 'open3d_threads', 'time_open3d_integration']

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
I32 = NDArray[np.int32]

#: Voxels along a block's side that Open3D's TSDF takes here (tsdf_fusion's block sizes).
BLOCK_RESOLUTIONS = (8, 16)
#: Where Open3D puts a pixel's centre, from the pixel's integer index (this package: 0).
PIXEL_CENTRE = 0.5
#: Default of :meth:`Open3dTsdf.mesh` and :meth:`Open3dTsdf.surface_points`: every voxel
#: observed at least once, as tsdf_fusion's ``min_weight`` (Open3D's own default, 3, hides
#: what fewer than 4 frames saw).
WEIGHT_THRESHOLD = 0.0
#: The grid's attributes: names, float32, channels (see the module notes for the colour).
_ATTRIBUTES = (('tsdf', 'weight', 'color'), (1, 1, 3))


def load_open3d() -> ModuleType:
    """Import Open3D, or raise a one-line ConfigError saying how to get it.

    Its native library links libusb-1.0 (for its RealSense support), which the extra's
    libusb-package provides, loaded first as for pyrealsense2.

    Raises:
        ConfigError: Open3D is not installed, or it or one of its modules cannot load.
    """
    _preload_libusb()
    try:
        import open3d
    except ModuleNotFoundError as exc:
        if exc.name != 'open3d':
            raise ConfigError(f'open3d cannot be loaded (it needs the module {exc.name}): '
                              f'pip install .[open3d] brings it') from None
        raise ConfigError('open3d is not installed: pip install .[open3d] (the optional extra '
                          'for the comparison with Open3D\'s TSDF)') from None
    except ImportError as exc:
        reason = ' '.join(str(exc).split())
        raise ConfigError(f'open3d cannot be loaded ({reason}); it needs libusb-1.0: '
                          f'pip install .[open3d] brings libusb-package') from None
    module: ModuleType = open3d
    return module


@contextmanager
def open3d_threads(threads: int) -> Iterator[None]:
    """Limit Open3D's CPU kernels to ``threads`` threads (the calling one included) inside
    the block, then give back the limit Open3D reported before (with no limit set, that is
    the hardware's thread count: the same in effect).

    Raises:
        ArgumentError: ``threads`` is not a positive integer.
        ConfigError: Open3D is missing or cannot load.
    """
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ArgumentError(f'threads must be a positive integer, got {threads!r}')
    utility = load_open3d().utility
    before = utility.get_max_threads()
    utility.set_max_threads(threads)
    try:
        yield
    finally:
        utility.set_max_threads(before)


class Open3dTsdf:
    """Open3D's TSDF (``VoxelBlockGrid``) on the CPU, integrating depth only.

    Args:
        voxel_size_m: Side of a voxel, metres.
        truncation_voxels: Truncation distance in voxels (Open3D's
            ``trunc_voxel_multiplier``; tsdf_fusion's ``truncation_distance``).
        max_depth_m: Depths beyond this, metres, are not integrated.
        block_resolution: Voxels along a block's side, one of :data:`BLOCK_RESOLUTIONS`.
        block_count: Blocks the table has room for at first (it grows when full).

    Raises:
        ArgumentError: A value out of range, naming it.
        ConfigError: Open3D is missing or cannot load.
    """

    def __init__(self, voxel_size_m: float, truncation_voxels: float, max_depth_m: float, *,
                 block_resolution: int = 8, block_count: int = 1000) -> None:
        for name, value in (('voxel_size_m', voxel_size_m),
                            ('truncation_voxels', truncation_voxels),
                            ('max_depth_m', max_depth_m)):
            if not _positive(value):
                raise ArgumentError(f'{name} must be a positive finite number, got {value!r}')
        if block_resolution not in BLOCK_RESOLUTIONS:
            raise ArgumentError(f'block_resolution must be one of {BLOCK_RESOLUTIONS}, got '
                                f'{block_resolution!r}')
        if isinstance(block_count, bool) or not isinstance(block_count, int) or block_count < 1:
            raise ArgumentError(f'block_count must be a positive integer, got {block_count!r}')
        self.voxel_size_m = float(voxel_size_m)
        self.truncation_voxels = float(truncation_voxels)
        self.max_depth_m = float(max_depth_m)
        self.block_resolution = block_resolution
        self._o3d = load_open3d()
        core = self._o3d.core
        names, channels = _ATTRIBUTES
        self._grid = self._o3d.t.geometry.VoxelBlockGrid(
            attr_names=names, attr_dtypes=(core.float32,) * len(names), attr_channels=channels,
            voxel_size=self.voxel_size_m, block_resolution=block_resolution,
            block_count=block_count, device=core.Device('CPU:0'))
        self._depth = np.zeros((0, 0), np.float32)  # reused while the image size stays

    def integrate(self, depth_m: F32, fx: float, fy: float, cx: float, cy: float,
                  world_from_camera: F64) -> None:
        """Fuse one depth image taken from ``world_from_camera``.

        Args:
            depth_m: (H, W) float32 depth in metres; NaN, inf, 0 or negative = unknown.
            fx: Focal length along x, pixels.
            fy: Focal length along y, pixels.
            cx: Principal point x, pixels.
            cy: Principal point y, pixels.
            world_from_camera: (4, 4) float64 pose of the camera's optical frame in the
                world (``X_world = T @ X_camera``).

        Raises:
            ArgumentError: A wrong image, intrinsics or pose, naming it.
        """
        frame = self._prepare(depth_m, fx, fy, cx, cy, world_from_camera)
        if frame is not None:
            _fuse(self._grid, frame, self.truncation_voxels, self.max_depth_m)

    def mesh(self, *, weight_threshold: float = WEIGHT_THRESHOLD) -> tuple[F32, I32]:
        """The zero level set by marching cubes over the voxels weighing more than
        ``weight_threshold``: (vertices (N, 3) float32 in metres, in the world; faces
        (M, 3) int32 indices into them); both empty before any block holds voxels (Open3D
        refuses an empty table)."""
        threshold = _threshold(weight_threshold)
        if self.active_blocks == 0:
            return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)
        mesh = self._grid.extract_triangle_mesh(weight_threshold=threshold)
        vertices = mesh.vertex.positions.numpy().astype(np.float32).reshape(-1, 3)
        faces = (mesh.triangle.indices.numpy().astype(np.int32).reshape(-1, 3)
                 if 'indices' in mesh.triangle else np.zeros((0, 3), np.int32))
        return vertices, faces

    def surface_points(self, *, weight_threshold: float = WEIGHT_THRESHOLD) -> F32:
        """Open3D's points of the zero crossings between neighbouring voxels weighing more
        than ``weight_threshold``: (N, 3) float32, metres, in the world (empty before any
        block holds voxels)."""
        threshold = _threshold(weight_threshold)
        if self.active_blocks == 0:
            return np.zeros((0, 3), np.float32)
        cloud = self._grid.extract_point_cloud(weight_threshold=threshold)
        points: F32 = cloud.point.positions.numpy().astype(np.float32).reshape(-1, 3)
        return points

    @property
    def active_blocks(self) -> int:
        """Blocks that hold voxels."""
        return int(self._grid.hashmap().size())

    def buffer_bytes(self) -> int:
        """Bytes of the block table's buffers: keys and attributes of every block it has
        room for (its capacity, not only the active blocks); the hash index is not counted."""
        table = self._grid.hashmap()
        tensors = [table.key_tensor(), *table.value_tensors()]
        return sum(int(t.num_elements()) * int(t.dtype.byte_size()) for t in tensors)

    def _prepare(self, depth_m: F32, fx: float, fy: float, cx: float, cy: float,
                 world_from_camera: F64) -> _Frame | None:
        """Checked inputs in Open3D's terms, or None for a frame with nothing to fuse."""
        depth = _checked_depth(depth_m)
        for name, value in (('fx', fx), ('fy', fy)):
            if not _positive(value):
                raise ArgumentError(f'{name} must be a positive finite number, got {value!r}')
        for name, value in (('cx', cx), ('cy', cy)):
            if not _finite(value):
                raise ArgumentError(f'{name} must be a finite number, got {value!r}')
        camera_from_world = _camera_from_world(world_from_camera)
        if self._depth.shape != depth.shape:
            self._depth = np.empty(depth.shape, np.float32)
        known = _known_depth(depth, self._depth, self.max_depth_m)
        if not known:
            return None
        core = self._o3d.core
        # Open3D's pixel centres are at + 0.5 (see the module notes)
        ox, oy = cx + PIXEL_CENTRE, cy + PIXEL_CENTRE
        intrinsic = np.array([[fx, 0.0, ox], [0.0, fy, oy], [0.0, 0.0, 1.0]])
        return _Frame(self._o3d.t.geometry.Image(core.Tensor.from_numpy(self._depth)),
                      core.Tensor(intrinsic, core.float64),
                      core.Tensor(camera_from_world, core.float64))


@dataclass(frozen=True)
class _Frame:
    """One depth image as Open3D takes it: image (metres, 0 unknown), K, camera_from_world."""

    image: Any
    intrinsic: Any
    extrinsic: Any


def _fuse(grid: Any, frame: _Frame, truncation_voxels: float, max_depth_m: float) -> None:
    """Open3D's two steps: the blocks the frame touches, then the update of their voxels."""
    blocks = grid.compute_unique_block_coordinates(
        frame.image, frame.intrinsic, frame.extrinsic, depth_scale=1.0,
        depth_max=max_depth_m, trunc_voxel_multiplier=truncation_voxels)
    grid.integrate(blocks, frame.image, frame.intrinsic, frame.extrinsic, depth_scale=1.0,
                   depth_max=max_depth_m, trunc_voxel_multiplier=truncation_voxels)


def _known_depth(depth: F32, out: F32, max_depth_m: float) -> bool:
    """``depth`` into ``out`` with NaN and inf as 0; whether any depth is in
    ``(0, max_depth_m]``."""
    np.copyto(out, depth)
    np.nan_to_num(out, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
    return bool(((out > 0) & (out <= max_depth_m)).any())


def _checked_depth(depth_m: Any) -> F32:
    if not isinstance(depth_m, np.ndarray) or depth_m.dtype != np.float32:
        raise ArgumentError(f'depth_m must be a float32 array, got '
                            f'{getattr(depth_m, "dtype", type(depth_m).__name__)}')
    if depth_m.ndim != 2 or min(depth_m.shape) < 1:
        raise ArgumentError(f'depth_m must be a non-empty (H, W) image, got shape '
                            f'{depth_m.shape}')
    return depth_m


def _camera_from_world(world_from_camera: Any) -> F64:
    """The inverse of a checked rigid (4, 4) pose: Open3D's extrinsic."""
    pose = np.asarray(world_from_camera, dtype=np.float64)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise ArgumentError(f'world_from_camera must be a finite (4, 4) matrix, got shape '
                            f'{pose.shape}')
    if not np.array_equal(pose[3], [0.0, 0.0, 0.0, 1.0]):
        raise ArgumentError(f'world_from_camera\'s last row must be 0 0 0 1, got {pose[3]}')
    rotation = check_rotation(pose[:3, :3], 'world_from_camera\'s rotation')
    out = np.eye(4)
    out[:3, :3] = rotation.T
    out[:3, 3] = -rotation.T @ pose[:3, 3]
    return out


def _threshold(weight_threshold: float) -> float:
    if not _finite(weight_threshold) or weight_threshold < 0:
        raise ArgumentError(f'weight_threshold must be a finite number >= 0, got '
                            f'{weight_threshold!r}')
    return float(weight_threshold)


def _finite(value: Any) -> bool:
    return (isinstance(value, (int, float, np.integer, np.floating))
            and not isinstance(value, bool) and math.isfinite(value))


def _positive(value: Any) -> bool:
    return _finite(value) and value > 0


@dataclass(frozen=True)
class Open3dTiming:
    """What :func:`time_open3d_integration` measured.

    Attributes:
        threads: The thread limit Open3D reported during the run.
        integrate_s: Seconds of each frame's integration (block activation and voxel
            update; the conversion of the image, done before, is not timed), in order.
        mesh_s: Seconds of one :meth:`Open3dTsdf.mesh` after the last frame (Open3D's
            extraction and the copy to numpy).
        vertices: Vertices of that mesh.
        active_blocks: Blocks holding voxels after the last frame.
        buffer_bytes: :meth:`Open3dTsdf.buffer_bytes` after the last frame.
    """

    threads: int
    integrate_s: list[float]
    mesh_s: float
    vertices: int
    active_blocks: int
    buffer_bytes: int


def time_open3d_integration(frames: Sequence[tuple[F32, F64]], camera: Intrinsics,
                            voxel_size_m: float, truncation_voxels: float, max_depth_m: float,
                            threads: int, *, block_resolution: int = 8,
                            block_count: int = 1000,
                            weight_threshold: float = WEIGHT_THRESHOLD) -> Open3dTiming:
    """Fuse ``frames`` into a new :class:`Open3dTsdf` on ``threads`` threads, timing each
    frame, then time one mesh extraction.

    Args:
        frames: (depth (H, W) float32 metres with NaN unknown, world_from_camera (4, 4)
            float64) pairs, in order.
        camera: Their intrinsics.
        voxel_size_m: Side of a voxel, metres.
        truncation_voxels: Truncation distance in voxels.
        max_depth_m: Depths beyond this are not integrated.
        threads: Open3D's thread limit during the run (the previous one comes back after).
        block_resolution: Voxels along a block's side.
        block_count: Blocks the table holds at first.
        weight_threshold: The mesh's (see :meth:`Open3dTsdf.mesh`).

    Raises:
        ArgumentError: No frames, or a bad value, naming it.
        ConfigError: Open3D is missing or cannot load.
    """
    if len(frames) == 0:
        raise ArgumentError('frames must hold at least one (depth, world_from_camera) pair')
    tsdf = Open3dTsdf(voxel_size_m, truncation_voxels, max_depth_m,
                      block_resolution=block_resolution, block_count=block_count)
    seconds = []
    with open3d_threads(threads):
        reported = int(load_open3d().utility.get_max_threads())
        for depth, pose in frames:
            frame = tsdf._prepare(depth, camera.fx, camera.fy, camera.cx, camera.cy, pose)
            start = time.perf_counter()
            if frame is not None:
                _fuse(tsdf._grid, frame, tsdf.truncation_voxels, tsdf.max_depth_m)
            seconds.append(time.perf_counter() - start)
        start = time.perf_counter()
        vertices, _ = tsdf.mesh(weight_threshold=weight_threshold)
        mesh_s = time.perf_counter() - start
    return Open3dTiming(reported, seconds, mesh_s, len(vertices), tsdf.active_blocks,
                        tsdf.buffer_bytes())
