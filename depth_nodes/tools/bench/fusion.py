"""`depth-nodes bench fusion`: the TSDF volume's stages per 640x480 frame at 5 cm and 2 cm
voxels, on one core and on two, beside Open3D's VoxelBlockGrid integrating the same frames
in the same run (the ``open3d`` extra), and the memory of each.

The frames: a simulated depth camera circling a scene (``depth_orbit``'s camera: noise
0.0015 Z^2), ``max_integration_distance`` 5 m, truncation 4 voxels. Each integration
figure is the median over the frames after the first (which allocates the tables and, for
ours, compiles nothing: the kernels are compiled before); a fresh volume per run, so new
blocks keep coming as the camera moves, as they do on a robot. Meshing is the mesh layer's
update after each frame (the blocks that frame changed), the slice one ``esdf_slice`` of
the plane through the scene at 5 m around the camera. Open3D's mesh is its whole-grid
extraction (it has no incremental one), shown for scale.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import numba
import numpy as np

from depth_nodes.core.fusion import TsdfParams, TsdfVolume
from depth_nodes.core.fusion.esdf import esdf_slice
from depth_nodes.core.fusion.layer import MeshLayer
from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.errors import ConfigError
from depth_nodes.sim.depth_sequence import DepthSequenceConfig, simulate_depth_sequence
from depth_nodes.tools.bench.sgm import busy_loops

__all__ = ['FusionBench', 'bench_fusion']

#: Voxel sizes timed, metres.
VOXELS = (0.05, 0.02)
MAX_DEPTH = 5.0
TRUNCATION = 4.0


@dataclass
class Run:
    """One voxel size and thread count: median ms (or None when not measured)."""

    voxel: float
    threads: int
    integrate: float
    mesh: float
    esdf: float
    memory_mb: float
    open3d_integrate: float | None = None
    open3d_mesh: float | None = None
    open3d_memory_mb: float | None = None


@dataclass
class FusionBench:
    """The report (see the module notes)."""

    width: int
    height: int
    frames: int
    busy: int
    runs: list[Run] = field(default_factory=list)
    note: str = ''

    def format(self) -> str:
        lines = [f'tsdf fusion, {self.width}x{self.height}, {self.frames} frames of a '
                 'circling depth camera (median ms a frame after the first), truncation 4 '
                 f'voxels, depths to {MAX_DEPTH:g} m' +
                 (f', {self.busy} busy core(s) beside' if self.busy else ''),
                 f'{"voxel":>6s} {"threads":>7s} {"integrate":>10s} {"Open3D":>8s} '
                 f'{"ratio":>6s} {"mesh":>7s} {"slice":>7s} {"memory MB":>10s} '
                 f'{"Open3D mesh":>12s} {"Open3D MB":>10s}']
        for run in self.runs:
            o3d = run.open3d_integrate
            lines.append(
                f'{run.voxel * 100:4.0f}cm {run.threads:7d} {run.integrate:10.2f} '
                f'{_ms(o3d):>8s} {_ratio(run.integrate, o3d):>6s} {run.mesh:7.2f} '
                f'{run.esdf:7.2f} {run.memory_mb:10.1f} {_ms(run.open3d_mesh):>12s} '
                f'{_ms(run.open3d_memory_mb, 1):>10s}')
        if self.note:
            lines.append(self.note)
        return '\n'.join(lines)


def _ms(value: float | None, digits: int = 2) -> str:
    return '-' if value is None else f'{value:.{digits}f}'


def _ratio(ours: float, theirs: float | None) -> str:
    return '-' if theirs is None else f'{ours / theirs:.2f}x'


def _frames(width: int, height: int, count: int) -> tuple[Intrinsics, list[tuple[np.ndarray,
                                                                                 Pose]]]:
    config = DepthSequenceConfig(kind='orbit', width=width, height=height, n_frames=count,
                                 baseline_m=0.05, disparity_sigma=0.0384, supersample=1)
    frames = list(simulate_depth_sequence(config))
    return config.camera, [(f.depth, f.pose) for f in frames]


@contextlib.contextmanager
def _threads(count: int) -> Iterator[None]:
    before = numba.get_num_threads()
    numba.set_num_threads(min(count, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    try:
        yield
    finally:
        numba.set_num_threads(before)


def _ours(camera: Intrinsics, frames: list[tuple[np.ndarray, Pose]], voxel: float,
          threads: int) -> Run:
    volume = TsdfVolume(TsdfParams(voxel_size=voxel, truncation_distance=TRUNCATION,
                                   max_integration_distance=MAX_DEPTH, memory_mb=4096.0))
    layer = MeshLayer()
    integrate, mesh, esdf = [], [], []
    axis_height = float(np.median([pose.position[1] for _, pose in frames]))
    with _threads(threads):
        for depth, pose in frames:
            start = time.perf_counter()
            volume.integrate(depth, camera, pose)
            integrated = time.perf_counter()
            layer.update(volume)
            meshed = time.perf_counter()
            esdf_slice(volume, axis='y', height=axis_height, max_distance=2.0,
                       centre=pose.position, radius=5.0)
            done = time.perf_counter()
            integrate.append(integrated - start)
            mesh.append(meshed - integrated)
            esdf.append(done - meshed)
    median = lambda values: 1000 * float(np.median(values[1:]))  # noqa: E731
    return Run(voxel, threads, median(integrate), median(mesh), median(esdf),
               volume.memory_bytes / 2 ** 20)


def _warm_up(camera: Intrinsics, frames: list[tuple[np.ndarray, Pose]]) -> None:
    """Compile the kernels (cached on disk after the first run) on a small volume."""
    volume = TsdfVolume(TsdfParams(voxel_size=0.1, max_integration_distance=MAX_DEPTH))
    layer = MeshLayer()
    for depth, pose in frames[:2]:
        volume.integrate(depth, camera, pose)
        layer.update(volume)
        esdf_slice(volume, axis='y', height=0.0, centre=pose.position, radius=2.0)


def bench_fusion(*, size: tuple[int, int] = (640, 480), frames: int = 12,
                 busy: int = 0, open3d: bool = True) -> FusionBench:
    """Time the stages (see the module notes).

    Raises:
        ConfigError: ``open3d`` without the open3d extra (the report then says so instead
            when ``open3d`` is left to its default by the caller).
    """
    camera, sequence = _frames(size[0], size[1], frames)
    report = FusionBench(size[0], size[1], frames, busy)
    _warm_up(camera, sequence)
    timing = None
    if open3d:
        try:
            from depth_nodes.tools.evaluation.open3d_fusion import time_open3d_integration
            timing = time_open3d_integration
        except ConfigError as exc:
            report.note = f'Open3D not timed: {exc}'
    loops = busy_loops(busy)
    try:
        for voxel in VOXELS:
            for threads in (1, 2):
                run = _ours(camera, sequence, voxel, threads)
                if timing is not None:
                    theirs = timing([(depth, _matrix(pose)) for depth, pose in sequence],
                                    camera, voxel, TRUNCATION, MAX_DEPTH, threads,
                                    block_count=40000 if voxel < 0.03 else 8000)
                    run.open3d_integrate = 1000 * float(np.median(theirs.integrate_s[1:]))
                    run.open3d_mesh = 1000 * theirs.mesh_s
                    run.open3d_memory_mb = theirs.buffer_bytes / 2 ** 20
                report.runs.append(run)
    finally:
        for loop in loops:
            loop.terminate()
            loop.wait()
    return report


def _matrix(pose: Pose) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = pose.rotation, pose.position
    return out
