"""Open3D's TSDF through depth_nodes/tools/evaluation/open3d_fusion.py (the `open3d` extra):
fused frames of an analytic plane give a mesh on that plane, within the error of reading
the nearest pixel and without bias (the pixel-centre convention); unknown depth is skipped;
the weight threshold is strict; the thread limit holds during a timed run and is given
back; a missing or broken Open3D, and every bad argument, is a one-line error."""

from __future__ import annotations

import builtins
import sys
from typing import Any

import numpy as np
import pytest

from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.errors import ArgumentError, ConfigError
from depth_nodes.tools.evaluation.open3d_fusion import (
    Open3dTsdf,
    load_open3d,
    open3d_threads,
    time_open3d_integration,
)

CAMERA = Intrinsics(160.0, 160.0, 79.5, 59.5, 160, 120)
#: The plane ``NORMAL . x = OFFSET`` (world = the first camera's optical frame): 1.5 - 2.4 m
#: in front of the cameras, its depth changing 0.5 m per metre down the image.
NORMAL = np.array([0.0, -0.5, -1.0]) / np.sqrt(1.25)
OFFSET = -1.6
VOXEL = 0.02
TRUNCATION = 4.0
MAX_DEPTH = 5.0
#: Largest mean signed distance of the mesh from the plane, metres: a voxel that read the
#: pixel at floor(u) instead of the nearest one would put it 2.5 mm in front.
BIAS = 0.0005


def pose_matrix(pose: Pose) -> np.ndarray:
    """The (4, 4) world_from_camera of a pose."""
    out = np.eye(4)
    out[:3, :3] = pose.rotation
    out[:3, 3] = pose.position
    return out


def turned(angle: float, position: tuple[float, float, float]) -> Pose:
    """A camera turned ``angle`` radians about its vertical (y) axis, at ``position``."""
    c, s = np.cos(angle), np.sin(angle)
    return Pose(np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]), np.array(position))


POSES = [turned(-0.1, (-0.1, 0.0, 0.0)), turned(0.0, (0.0, 0.02, 0.0)),
         turned(0.1, (0.1, 0.04, 0.0))]


def render_plane(pose: Pose) -> np.ndarray:
    """Exact float32 depth of the plane seen from ``pose`` (Z at the pixel centres)."""
    u, v = np.meshgrid(np.arange(CAMERA.width), np.arange(CAMERA.height))
    rays = np.stack([(u - CAMERA.cx) / CAMERA.fx, (v - CAMERA.cy) / CAMERA.fy,
                     np.ones(u.shape)], axis=-1)  # Z = 1 in the camera
    along = (OFFSET - NORMAL @ pose.position) / ((rays @ pose.rotation.T) @ NORMAL)
    return np.where(along > 0, along, np.nan).astype(np.float32)


def nearest_pixel_error(depths: list[np.ndarray]) -> float:
    """Bound on a voxel's error from reading the pixel nearest its projection: half the
    largest depth step to a neighbouring pixel along x plus along y (the distance to the
    plane is at most the error in depth)."""
    steps = [np.nanmax(np.abs(np.diff(d, axis=1))) + np.nanmax(np.abs(np.diff(d, axis=0)))
             for d in depths]
    return float(max(steps) / 2)


def fused(frames: list[tuple[np.ndarray, Pose]], **kwargs: Any) -> Open3dTsdf:
    tsdf = Open3dTsdf(VOXEL, TRUNCATION, MAX_DEPTH, **kwargs)
    for depth, pose in frames:
        tsdf.integrate(depth, CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy, pose_matrix(pose))
    return tsdf


@pytest.fixture(scope='module')
def plane_frames() -> list[tuple[np.ndarray, Pose]]:
    """The plane from three poses, the middle frame with a hole of NaN and one of inf."""
    frames = [(render_plane(pose), pose) for pose in POSES]
    frames[1][0][40:70, 60:100] = np.nan
    frames[1][0][:10, :20] = np.inf
    return frames


def test_mesh_of_a_fused_plane_lies_on_the_plane(
        plane_frames: list[tuple[np.ndarray, Pose]]) -> None:
    tolerance = nearest_pixel_error([render_plane(pose) for pose in POSES])
    assert 0.003 < tolerance < VOXEL / 3  # 5.8 mm: a bound that means something
    tsdf = fused(plane_frames)
    vertices, faces = tsdf.mesh()
    assert vertices.dtype == np.float32
    assert faces.dtype == np.int32
    assert len(vertices) > 10_000  # 13,600 at 2 cm
    assert faces.shape[1] == 3
    assert faces.min() >= 0
    assert faces.max() < len(vertices)
    distance = vertices.astype(np.float64) @ NORMAL - OFFSET
    assert np.abs(distance).max() <= tolerance
    assert abs(distance.mean()) <= BIAS
    points = tsdf.surface_points()
    assert points.dtype == np.float32
    assert len(points) > 10_000
    assert np.abs(points.astype(np.float64) @ NORMAL - OFFSET).max() <= tolerance


def test_the_mesh_covers_what_the_cameras_saw(
        plane_frames: list[tuple[np.ndarray, Pose]]) -> None:
    """Every pixel of the first frame back-projected lands within a voxel of a vertex
    (checked on a grid of pixels): no part of the seen plane is missing."""
    vertices, _ = fused(plane_frames).mesh()
    depth, pose = plane_frames[0]
    v, u = np.mgrid[5:CAMERA.height - 5:10, 5:CAMERA.width - 5:10]
    z = depth[v, u].astype(np.float64)
    camera = np.stack([(u - CAMERA.cx) / CAMERA.fx * z, (v - CAMERA.cy) / CAMERA.fy * z, z],
                      axis=-1).reshape(-1, 3)
    world = camera @ pose.rotation.T + pose.position
    nearest = np.array([np.linalg.norm(vertices - p, axis=1).min() for p in world])
    assert nearest.max() <= VOXEL


def test_unknown_depth_is_skipped_and_an_empty_frame_changes_nothing(
        plane_frames: list[tuple[np.ndarray, Pose]]) -> None:
    tsdf = Open3dTsdf(VOXEL, TRUNCATION, MAX_DEPTH)
    identity = np.eye(4)
    for fill in (np.nan, 0.0, -1.0, MAX_DEPTH + 1.0):  # none in (0, max_depth]
        tsdf.integrate(np.full((CAMERA.height, CAMERA.width), fill, np.float32),
                       CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy, identity)
    assert tsdf.active_blocks == 0
    vertices, faces = tsdf.mesh()
    assert vertices.shape == (0, 3)
    assert faces.shape == (0, 3)
    assert tsdf.surface_points().shape == (0, 3)
    # beyond max_depth: the plane is not integrated at all
    far = Open3dTsdf(VOXEL, TRUNCATION, 1.0)
    depth, pose = plane_frames[0]
    far.integrate(depth, CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy, pose_matrix(pose))
    assert far.active_blocks == 0


def test_the_weight_threshold_is_strict(plane_frames: list[tuple[np.ndarray, Pose]]) -> None:
    """Two frames of the same view weigh 2: a threshold of 2 hides them, 1.9 does not."""
    depth, pose = plane_frames[0]
    tsdf = fused([(depth, pose), (depth, pose)])
    assert len(tsdf.mesh(weight_threshold=1.9)[0]) > 0
    assert len(tsdf.mesh(weight_threshold=2.0)[0]) == 0
    assert len(tsdf.surface_points(weight_threshold=2.0)) == 0


def test_buffers_are_the_table_capacity_times_a_block(
        plane_frames: list[tuple[np.ndarray, Pose]]) -> None:
    """Keys (3 int32) and tsdf, weight, colour (1 + 1 + 3 float32) for every voxel of every
    block the table has room for; the table grows when full."""
    for resolution in (8, 16):
        tsdf = Open3dTsdf(VOXEL, TRUNCATION, MAX_DEPTH, block_resolution=resolution,
                          block_count=16)
        per_block = 3 * 4 + resolution ** 3 * 5 * 4
        assert tsdf.buffer_bytes() == 16 * per_block
        depth, pose = plane_frames[0]
        tsdf.integrate(depth, CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy, pose_matrix(pose))
        assert tsdf.active_blocks > 16
        capacity, rest = divmod(tsdf.buffer_bytes(), per_block)
        assert rest == 0
        assert capacity >= tsdf.active_blocks


def test_a_timed_run_holds_the_thread_limit_and_gives_it_back(
        plane_frames: list[tuple[np.ndarray, Pose]]) -> None:
    utility = load_open3d().utility
    before = utility.get_max_threads()
    frames = [(depth, pose_matrix(pose)) for depth, pose in plane_frames]
    timing = time_open3d_integration(frames, CAMERA, VOXEL, TRUNCATION, MAX_DEPTH, threads=1)
    assert timing.threads == 1
    assert utility.get_max_threads() == before
    assert len(timing.integrate_s) == len(frames)
    assert all(s > 0 for s in timing.integrate_s)
    assert timing.mesh_s > 0
    assert timing.vertices == len(fused(plane_frames).mesh()[0])
    assert timing.active_blocks > 0
    assert timing.buffer_bytes > 0
    with open3d_threads(2):
        assert utility.get_max_threads() == 2
    assert utility.get_max_threads() == before


def _without(module: str, error: ImportError, monkeypatch: pytest.MonkeyPatch) -> None:
    """Make ``import <module>`` raise ``error``."""
    real_import = builtins.__import__

    def failing_import(name: str, *args: Any, **kwargs: Any) -> Any:
        if name == module:
            raise error
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, module, raising=False)
    monkeypatch.setattr(builtins, '__import__', failing_import)


@pytest.mark.parametrize(('error', 'message'), [
    (ModuleNotFoundError("No module named 'open3d'", name='open3d'),
     r'^open3d is not installed: pip install \.\[open3d\] \(the optional extra'),
    (ModuleNotFoundError("No module named 'plotly'", name='plotly'),
     r'^open3d cannot be loaded \(it needs the module plotly\): pip install \.\[open3d\]'),
    (ImportError('libusb-1.0.so.0: cannot open shared object file:\nNo such file'),
     r'^open3d cannot be loaded \(libusb-1.0.so.0: cannot open shared object file: No such '
     r'file\); it needs libusb-1.0: pip install \.\[open3d\] brings libusb-package$'),
])
def test_an_open3d_that_cannot_load_is_a_one_line_config_error(
        error: ImportError, message: str, monkeypatch: pytest.MonkeyPatch) -> None:
    _without('open3d', error, monkeypatch)
    with pytest.raises(ConfigError, match=message) as info:
        load_open3d()
    assert '\n' not in str(info.value)
    with pytest.raises(ConfigError, match='open3d'):
        Open3dTsdf(VOXEL, TRUNCATION, MAX_DEPTH)


@pytest.mark.parametrize(('kwargs', 'message'), [
    ({'voxel_size_m': 0.0}, 'voxel_size_m must be a positive finite number, got 0.0'),
    ({'truncation_voxels': float('nan')}, 'truncation_voxels must be a positive finite'),
    ({'max_depth_m': -1.0}, 'max_depth_m must be a positive finite number, got -1.0'),
    ({'block_resolution': 4}, r'block_resolution must be one of \(8, 16\), got 4'),
    ({'block_count': 0}, 'block_count must be a positive integer, got 0'),
    ({'block_count': 1.5}, 'block_count must be a positive integer, got 1.5'),
])
def test_a_bad_setting_is_named(kwargs: dict[str, Any], message: str) -> None:
    settings: dict[str, Any] = {'voxel_size_m': VOXEL, 'truncation_voxels': TRUNCATION,
                                'max_depth_m': MAX_DEPTH, **kwargs}
    with pytest.raises(ArgumentError, match=message):
        Open3dTsdf(**settings)


GOOD_DEPTH = np.full((CAMERA.height, CAMERA.width), 2.0, np.float32)
BAD_POSE = np.eye(4)
BAD_POSE[3, 0] = 1.0
REFLECTION = np.diag([1.0, 1.0, -1.0, 1.0])


@pytest.mark.parametrize(('args', 'message'), [
    ({'depth_m': GOOD_DEPTH.astype(np.float64)}, 'depth_m must be a float32 array, got float64'),
    ({'depth_m': [[2.0]]}, 'depth_m must be a float32 array, got list'),
    ({'depth_m': GOOD_DEPTH[0]}, r'depth_m must be a non-empty \(H, W\) image, got shape'),
    ({'depth_m': GOOD_DEPTH[:0]}, r'depth_m must be a non-empty \(H, W\) image, got shape'),
    ({'fx': 0.0}, 'fx must be a positive finite number, got 0.0'),
    ({'fy': float('inf')}, 'fy must be a positive finite number, got inf'),
    ({'cx': float('nan')}, 'cx must be a finite number, got nan'),
    ({'cy': None}, 'cy must be a finite number, got None'),
    ({'world_from_camera': np.eye(3)}, r'world_from_camera must be a finite \(4, 4\) matrix'),
    ({'world_from_camera': np.full((4, 4), np.nan)}, 'world_from_camera must be a finite'),
    ({'world_from_camera': BAD_POSE}, 'world_from_camera\'s last row must be 0 0 0 1'),
    ({'world_from_camera': REFLECTION}, 'world_from_camera\'s rotation is not a rotation'),
])
def test_a_bad_frame_is_named(args: dict[str, Any], message: str) -> None:
    frame: dict[str, Any] = {'depth_m': GOOD_DEPTH, 'fx': CAMERA.fx, 'fy': CAMERA.fy,
                             'cx': CAMERA.cx, 'cy': CAMERA.cy, 'world_from_camera': np.eye(4),
                             **args}
    tsdf = Open3dTsdf(VOXEL, TRUNCATION, MAX_DEPTH)
    with pytest.raises(ArgumentError, match=message):
        tsdf.integrate(**frame)
    assert tsdf.active_blocks == 0


def test_bad_extraction_and_timing_arguments_are_named() -> None:
    tsdf = Open3dTsdf(VOXEL, TRUNCATION, MAX_DEPTH)
    for threshold in (-1.0, float('nan')):
        with pytest.raises(ArgumentError, match='weight_threshold must be a finite number >= 0'):
            tsdf.mesh(weight_threshold=threshold)
        with pytest.raises(ArgumentError, match='weight_threshold must be a finite number >= 0'):
            tsdf.surface_points(weight_threshold=threshold)
    for threads in (0, 1.0, True):
        with pytest.raises(ArgumentError, match='threads must be a positive integer'), \
                open3d_threads(threads):  # type: ignore[arg-type]
            pass
    with pytest.raises(ArgumentError, match='frames must hold at least one'):
        time_open3d_integration([], CAMERA, VOXEL, TRUNCATION, MAX_DEPTH, threads=1)
