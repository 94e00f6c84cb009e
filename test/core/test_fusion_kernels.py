"""The fused volume's kernels against their plain references (test/reference/fusion.py):
the blocks a frame touches, the voxel update in every weighting mode with carving and
drop-off, each block's marching-cubes triangles, the distance at a point; and the block
hash against a dict.

Tolerances: block sets and triangle counts equal; voxel values and weights to 1e-5
(float32 storage of the same float64 arithmetic); triangle vertices to 1e-6 m; distances
to 1e-6 m."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import kernel_size
from reference.fusion import (
    block_triangles_reference,
    integrate_reference,
    site_distance_reference,
    touched_blocks_reference,
)

from depth_nodes.core.fusion import TsdfParams, TsdfVolume, block_meshes
from depth_nodes.core.fusion.blocks import BlockTable, coords_keys, key_coords
from depth_nodes.core.fusion.esdf import esdf_distance
from depth_nodes.core.fusion.integrate import (
    touch_samples,
    touch_stride,
    touched_keys,
    visible_blocks,
)
from depth_nodes.core.geometry import Intrinsics, Pose, quaternion_from_rpy, rotation_matrix

pytestmark = pytest.mark.kernels


def _scene(width: int, height: int, pose: Pose, seed: int = 0) -> tuple[Intrinsics, np.ndarray]:
    """A camera and its depth of a sphere before a tilted plane, with holes and noise."""
    f = 0.9 * width
    camera = Intrinsics(f, f, (width - 1) / 2, (height - 1) / 2, width, height)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    rays = np.stack([(xs - camera.cx) / f, (ys - camera.cy) / f, np.ones_like(xs)], -1)
    rays = rays @ pose.rotation.T
    o = pose.position
    centre, radius = np.array([0.05, 0.02, 1.2]), 0.25
    oc = o - centre
    a, b = (rays * rays).sum(-1), (rays @ oc)
    disc = b * b - a * (oc @ oc - radius ** 2)
    t_sphere = (-b - np.sqrt(np.maximum(disc, 0))) / a
    normal = np.array([0.2, 0.1, -1.0]) / np.linalg.norm([0.2, 0.1, -1.0])
    t_plane = ((np.array([0, 0, 1.8]) - o) @ normal) / (rays @ normal)
    t = np.where(disc > 0, t_sphere, t_plane)
    depth = t * (rays @ pose.rotation[:, 2])  # Z along the optical axis
    rng = np.random.default_rng(seed)
    depth = depth + rng.normal(0, 0.003, depth.shape)
    depth[rng.random(depth.shape) < 0.05] = np.nan
    return camera, depth.astype(np.float32)


def _pose(yaw: float, x: float) -> Pose:
    return Pose(rotation_matrix(quaternion_from_rpy(0.02, np.radians(yaw), 0.01)),
                np.array([x, -0.01, 0.05]))


SIZE = kernel_size((64, 48), (24, 18))


def test_touched_blocks_are_the_reference_s() -> None:
    voxel, block, trunc = 0.04, 8, 0.16
    pose = _pose(5, 0.1)
    camera, depth = _scene(*SIZE, pose)
    samples = touch_samples(voxel, block, trunc)
    scratch = np.empty(depth.size * samples, np.int64)
    keys = touched_keys(depth, camera.vector, pose.rotation, pose.position, voxel=voxel,
                        block=block, truncation=trunc, min_depth=1.1, max_depth=3.0,
                        buffer=scratch)
    stride = touch_stride(voxel, camera.vector, 3.0)
    assert stride == 1  # 64 px wide: no ray left out ...
    expected = touched_blocks_reference(depth, camera, pose, voxel=voxel, block=block,
                                        truncation=trunc, min_depth=1.1, max_depth=3.0,
                                        samples=samples, stride=stride)
    assert {tuple(c) for c in key_coords(keys).tolist()} == expected
    assert len(keys) == len(np.unique(keys))
    # ... and a coarser voxel casts every other ray
    far = camera.fx * 0.12 / 2
    assert touch_stride(0.12, camera.vector, far) == 2
    keys = touched_keys(depth, camera.vector, pose.rotation, pose.position, voxel=0.12,
                        block=block, truncation=trunc, min_depth=0.1, max_depth=far,
                        buffer=scratch)
    expected = touched_blocks_reference(depth, camera, pose, voxel=0.12, block=block,
                                        truncation=trunc, min_depth=0.1, max_depth=far,
                                        samples=touch_samples(0.12, block, trunc), stride=2)
    assert {tuple(c) for c in key_coords(keys).tolist()} == expected


@pytest.mark.parametrize('mode', ['constant', 'inverse_square', 'sigma', 'confidence'])
def test_integration_is_the_reference_s_in_every_weighting_mode(mode: str) -> None:
    params = TsdfParams(voxel_size=0.04, truncation_distance=3.0, weighting_mode=mode,
                        max_weight=2.5)
    volume = TsdfVolume(params)
    reference = TsdfVolume(params)
    rng = np.random.default_rng(3)
    for k, (yaw, x) in enumerate([(0, 0.0), (6, 0.05), (-4, -0.04)]):
        pose = _pose(yaw, x)
        camera, depth = _scene(*SIZE, pose, seed=k)
        noise = None
        if mode == 'sigma':
            noise = (0.002 + 0.01 * rng.random(depth.shape)).astype(np.float32)
            noise[rng.random(depth.shape) < 0.05] = np.nan
        elif mode == 'confidence':
            noise = rng.random(depth.shape).astype(np.float32)
        volume.integrate(depth, camera, pose, noise=noise)
        _reference_frame(volume, reference, depth, camera, pose, noise)
        np.testing.assert_allclose(volume.tsdf, reference.tsdf, atol=1e-5)
        np.testing.assert_allclose(volume.weight, reference.weight, atol=1e-5)
    assert volume.weight.max() <= 2.5  # max_weight caps the sum
    if mode == 'constant':  # three frames of weight 1
        assert volume.weight.max() == 2.5
    assert (volume.weight > 0).sum() > 500


def _reference_frame(volume: TsdfVolume, reference: TsdfVolume, depth: np.ndarray,
                     camera: Intrinsics, pose: Pose, noise: np.ndarray | None) -> None:
    """The frame the volume just took, into the reference: the same new blocks, then the
    reference's update of every block the camera sees."""
    known = set(reference.slots().tolist())
    _copy_allocation(volume, reference, [s for s in volume.slots().tolist() if s not in known])
    params = reference.params
    to_camera = pose.inverse()
    seen = visible_blocks(reference.coords, reference.used, params.voxel_size,
                          params.block_size, to_camera.rotation, to_camera.position,
                          camera.vector, camera.width, camera.height,
                          params.max_integration_distance + params.truncation_m)
    integrate_reference(reference, np.flatnonzero(seen), depth, camera, pose, noise)


def _copy_allocation(source: TsdfVolume, target: TsdfVolume, slots: list[int]) -> None:
    """Allocate ``slots`` in ``target`` as they are in ``source`` (same slot, coords)."""
    while target.capacity < source.capacity:
        target._grow(source.capacity)
    for slot in slots:
        target._free.remove(slot)
        target.coords[slot] = source.coords[slot]
        target.keys[slot] = source.keys[slot]
        target.used[slot] = True
        target.tsdf[slot] = 0.0
        target.weight[slot] = 0.0
        target.table.add(source.keys[[slot]], np.array([slot], np.int32))


def test_free_space_carving_and_drop_off_follow_the_reference() -> None:
    params = TsdfParams(voxel_size=0.04, truncation_distance=2.0, free_space_carving=True,
                        weight_dropoff=True)
    volume = TsdfVolume(params)
    reference = TsdfVolume(params)
    pose = _pose(0, 0.0)
    camera, depth = _scene(*SIZE, pose)
    volume.integrate(depth, camera, pose)
    _reference_frame(volume, reference, depth, camera, pose, None)
    # the sphere gone: the plane behind is seen through where it was
    farther = np.where(depth < 1.5, depth + 0.6, depth).astype(np.float32)
    carved, before = volume.weight.copy(), volume.tsdf.copy()
    volume.integrate(farther, camera, pose)
    _reference_frame(volume, reference, farther, camera, pose, None)
    np.testing.assert_allclose(volume.tsdf, reference.tsdf, atol=1e-5)
    np.testing.assert_allclose(volume.weight, reference.weight, atol=1e-5)
    # seen through where a surface was: half the weight (1) plus the new observation's 1,
    # pulled towards free space
    through = (carved == 1.0) & (before < 0.5) & np.isclose(volume.weight, 1.5)
    assert through.sum() > 20
    assert (volume.tsdf[through] > before[through]).all()


@pytest.mark.parametrize('allow_clear', [True, False])
def test_a_depth_past_the_limit_clears_as_the_reference_does(allow_clear: bool) -> None:
    params = TsdfParams(voxel_size=0.04, truncation_distance=2.0, allow_clear=allow_clear,
                        max_integration_distance=2.5)
    volume = TsdfVolume(params)
    reference = TsdfVolume(params)
    pose = _pose(0, 0.0)
    camera, depth = _scene(*SIZE, pose)
    volume.integrate(depth, camera, pose)
    _reference_frame(volume, reference, depth, camera, pose, None)
    # the sphere gone, and what is behind it past max_integration_distance
    beyond = np.where(depth < 1.5, 4.0, depth).astype(np.float32)
    before = volume.tsdf.copy()
    volume.integrate(beyond, camera, pose)
    _reference_frame(volume, reference, beyond, camera, pose, None)
    np.testing.assert_allclose(volume.tsdf, reference.tsdf, atol=1e-5)
    np.testing.assert_allclose(volume.weight, reference.weight, atol=1e-5)
    moved = int((volume.tsdf > before + 0.1).sum())
    if allow_clear:
        assert moved > 20  # the sphere's voxels pulled towards free space
    else:
        assert moved == 0


def test_each_block_s_triangles_are_the_reference_s() -> None:
    volume = TsdfVolume(TsdfParams(voxel_size=0.04, truncation_distance=3.0))
    for k, (yaw, x) in enumerate([(0, 0.0), (8, 0.06)]):
        pose = _pose(yaw, x)
        camera, depth = _scene(*SIZE, pose, seed=k)
        volume.integrate(depth, camera, pose)
    slots = volume.slots()[:kernel_size(40, 6)]
    meshes = block_meshes(volume, slots)
    assert meshes.offsets[-1] > 50
    for n, slot in enumerate(slots):
        np.testing.assert_allclose(meshes.triangles(n), block_triangles_reference(volume, slot),
                                   atol=1e-6)


def test_the_distance_at_a_point_is_the_reference_s() -> None:
    volume = TsdfVolume(TsdfParams(voxel_size=0.05, truncation_distance=3.0))
    pose = _pose(0, 0.0)
    camera, depth = _scene(*SIZE, pose)
    volume.integrate(depth, camera, pose)
    rng = np.random.default_rng(1)
    points = np.array([[0.05, 0.02, 0.8], [0.3, 0.0, 1.0], [0.05, 0.02, 1.0], [0.0, 0.0, 5.0]])
    points = np.concatenate([points, rng.uniform([-0.3, -0.2, 0.8], [0.3, 0.2, 1.9],
                                                 (kernel_size(12, 3), 3))])
    got = esdf_distance(volume, points, max_distance=0.6)
    expected = [site_distance_reference(volume, p, 0.6) for p in points]
    np.testing.assert_allclose(got, expected, atol=1e-6, equal_nan=True)
    assert np.isnan(got[3])  # nothing observed there
    assert got[0] > 0.1  # in front of the sphere
    assert got[2] < 0  # just inside it


def test_the_block_table_agrees_with_a_dict_through_inserts_and_removals() -> None:
    table = BlockTable(4)
    truth: dict[int, int] = {}
    rng = np.random.default_rng(0)
    for round_ in range(kernel_size(30, 5)):
        coords = rng.integers(-2000, 2000, (rng.integers(1, 60), 3)).astype(np.int32)
        keys = np.unique(coords_keys(coords))
        fresh = np.array([k for k in keys.tolist() if k not in truth], np.int64)
        slots = np.arange(len(fresh), dtype=np.int32) + 1000 * round_
        table.add(fresh, slots)
        truth.update(zip(fresh.tolist(), slots.tolist(), strict=True))
        held = np.array(sorted(truth), np.int64)
        gone = held[rng.random(len(held)) < 0.3]
        table.remove(gone)
        for key in gone.tolist():
            del truth[key]
        probe = np.concatenate([held, coords_keys(rng.integers(-2000, 2000, (20, 3)))])
        found = table.find(probe)
        assert found.tolist() == [truth.get(k, -1) for k in probe.tolist()]
        assert len(table) == len(truth)
    assert (key_coords(coords_keys(np.array([[-5, 7, 1 << 19]]))) == [[-5, 7, 1 << 19]]).all()
