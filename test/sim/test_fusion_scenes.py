"""The truth a fusion (TSDF) evaluator needs from the simulator: the exact distance of any
point to a scene's surfaces, and the exact scene and pose of every frame of every kind of
depth sequence (depth_nodes.sim.scene, depth_nodes.sim.depth_sequence).

Distances are checked against brute force: the surface sampled on a grid whose cells are at
most ``spacing`` across (in arc length), so a point's distance to its nearest sample lies
between the exact distance and the exact distance plus ``spacing / sqrt(2)`` (half a cell's
diagonal). The frames are small (64 x 48, or 96 x 72) so every test takes seconds.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
from numpy.typing import NDArray

from depth_nodes.core.geometry import Pose
from depth_nodes.errors import ArgumentError, ConfigError
from depth_nodes.sim.depth_sequence import (
    KINDS,
    LONG_CLEARANCE_M,
    LONG_RADIUS_M,
    ROOM_HALF_M,
    DepthSequenceConfig,
    pose_at,
    scene_at,
    simulate_depth_sequence,
    stamp_at,
)
from depth_nodes.sim.layout import build_scene, rotation
from depth_nodes.sim.scene import Box, Cylinder, Material, Primitive, Rect, Scene, Sphere
from depth_nodes.sim.sequence import ORBIT_CENTRE, pixel_rays
from depth_nodes.sim.texture import NOISE, Texture

F64 = NDArray[np.float64]
MATERIAL = Material((0.1, 0.1, 0.1), (0.9, 0.9, 0.9), Texture(NOISE, 0.1))
#: Grid spacing of the brute-force samples, metres.
SPACING = 0.01
#: How much further the nearest sample may be than the surface (half a cell's diagonal).
SAMPLING_TOL = SPACING / math.sqrt(2)
#: Truth depth is float32: a back-projected truth point is off its surface by less than
#: this at the simulator's depths (float32 rounding of 10 m is 0.5 um).
FLOAT32_SURFACE_TOL = 1e-5
SMALL = DepthSequenceConfig(width=64, height=48, n_frames=4, supersample=1, seed=5)


def _grid(half: float, spacing: float = SPACING) -> F64:
    """Coordinates from -half to half, the ends included, at most ``spacing`` apart."""
    return np.linspace(-half, half, max(2, math.ceil(2 * half / spacing) + 1))


def _patch(centre: F64, e1: F64, e2: F64, half1: float, half2: float) -> F64:
    a, b = np.meshgrid(_grid(half1), _grid(half2), indexing='ij')
    return centre + a.reshape(-1, 1) * e1 + b.reshape(-1, 1) * e2


def _samples(prim: Primitive, plane_half: float) -> F64:
    """Points on the surface of ``prim``, at most SPACING apart (arc length) on a grid."""
    if isinstance(prim, Rect):
        h1, h2 = (min(h, plane_half) for h in prim.half_size)
        return _patch(prim.centre, prim.e1, prim.e2, h1, h2)
    if isinstance(prim, Box):
        faces = []
        for k in range(3):
            i, j = [a for a in range(3) if a != k]
            for sign in (-1.0, 1.0):
                centre = prim.centre + sign * prim.half_size[k] * prim.rotation[:, k]
                faces.append(_patch(centre, prim.rotation[:, i], prim.rotation[:, j],
                                    prim.half_size[i], prim.half_size[j]))
        return np.vstack(faces)
    if isinstance(prim, Sphere):  # latitude rings, each sampled SPACING apart along it
        rings = []
        for lat in _grid(math.pi / 2, SPACING / prim.radius):
            ring = max(1, math.ceil(2 * math.pi * prim.radius * math.cos(lat) / SPACING))
            lon = np.arange(ring) * 2 * math.pi / ring
            rings.append(np.column_stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon),
                                          np.full(ring, np.sin(lat))]))
        return prim.centre + prim.radius * np.vstack(rings)
    assert isinstance(prim, Cylinder)
    ring = math.ceil(2 * math.pi * prim.radius / SPACING)
    theta = np.arange(ring) * 2 * math.pi / ring
    a, th = np.meshgrid(_grid(prim.half_length), theta, indexing='ij')
    around = np.cos(th).reshape(-1, 1) * prim.e1 + np.sin(th).reshape(-1, 1) * prim.e2
    points: F64 = prim.centre + a.reshape(-1, 1) * prim.axis + prim.radius * around
    return points


def _nearest_sample(points: F64, samples: F64) -> F64:
    """Distance of each point to its nearest sample, in chunks of points."""
    out = np.empty(len(points))
    for start in range(0, len(points), 16):
        diff = points[start:start + 16, None, :] - samples[None, :, :]
        out[start:start + 16] = np.sqrt(np.einsum('ijk,ijk->ij', diff, diff).min(axis=1))
    return out


def _around(prim: Primitive, reach: float, n: int, seed: int) -> F64:
    """``n`` random points within ``reach`` (per axis) of ``prim``'s centre."""
    rng = np.random.default_rng(seed)
    points: F64 = prim.centre + rng.uniform(-reach, reach, (n, 3))
    return points


PRIMITIVES = {
    'rect': (Rect('r', MATERIAL, [0.2, -0.1, 2.0], rotation(30, 10) @ [1.0, 0, 0],
                  rotation(30, 10) @ [0, -1.0, 0], (0.4, 0.25)), 0.8),
    'plane': (Rect('p', MATERIAL, [0.0, 1.2, 0.0], [1.0, 0, 0], rotation(0, 3) @ [0, 0, 1.0]),
              0.6),
    'box': (Box('b', MATERIAL, [0.5, 0.4, 2.5], rotation(40, -8, 6), [0.3, 0.15, 0.25]), 0.6),
    'sphere': (Sphere('s', MATERIAL, [-0.4, 0.2, 1.9], 0.25), 0.5),
    'cylinder': (Cylinder('c', MATERIAL, [0.3, 0.0, 2.7], rotation(0, 5, -20) @ [0, 1.0, 0],
                          0.08, 0.3), 0.5),
}


@pytest.mark.parametrize('name', PRIMITIVES)
def test_distance_matches_brute_force(name: str) -> None:
    """Exact <= nearest sample <= exact + SAMPLING_TOL at 300 points around the primitive
    (inside and outside it; for the plane, over a patch wider than the points' reach)."""
    prim, reach = PRIMITIVES[name]
    points = _around(prim, reach, 300, seed=len(name))
    exact = prim.distance(points)
    brute = _nearest_sample(points, _samples(prim, plane_half=3 * reach))
    assert exact.shape == (300,)
    assert exact.dtype == np.float64
    assert np.all(exact <= brute + 1e-12)
    assert np.all(brute - exact <= SAMPLING_TOL), float(np.max(brute - exact))


def test_distance_special_points() -> None:
    """Closed forms: inside a box, the nearest face; on an open cylinder's axis past its
    end, the rim; on its axis inside, the radius; a plane's points off it, their height."""
    box = Box('b', MATERIAL, [0.0, 0.0, 0.0], np.eye(3), [0.3, 0.2, 0.5])
    inside = np.array([[0.0, 0.0, 0.0], [0.25, 0.0, 0.0], [0.0, 0.0, -0.45]])
    np.testing.assert_allclose(box.distance(inside), [0.2, 0.05, 0.05], atol=1e-15)
    np.testing.assert_allclose(box.distance([[0.4, 0.3, 0.0], [0.0, 0.0, 0.9]]),
                               [math.hypot(0.1, 0.1), 0.4], atol=1e-15)
    cyl = Cylinder('c', MATERIAL, [1.0, 2.0, 3.0], [0.0, 0.0, 1.0], 0.1, 0.5)
    on_axis = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.8], [1.0, 2.0, 2.3]])
    np.testing.assert_allclose(cyl.distance(on_axis),
                               [0.1, math.hypot(0.3, 0.1), math.hypot(0.2, 0.1)], atol=1e-15)
    plane = Rect('p', MATERIAL, [0.0, 1.0, 0.0], [1.0, 0, 0], [0, 0, 1.0])
    np.testing.assert_allclose(plane.distance([[1e6, 3.0, -1e6], [0.0, 0.5, 0.0]]), [2.0, 0.5])
    sphere = Sphere('s', MATERIAL, [0.0, 0.0, 0.0], 2.0)
    np.testing.assert_allclose(sphere.distance([[0.0, 0.0, 0.0], [0.0, 3.0, 4.0]]), [2.0, 3.0])


def test_scene_distance_is_the_nearest_primitive_in_chunks() -> None:
    """More points than one chunk: the scene's distance is the minimum of its primitives'."""
    scene = build_scene(3, 0, 256.0, 320, 240)
    rng = np.random.default_rng(1)
    points = rng.uniform([-2.0, -1.5, 0.5], [2.0, 1.5, 7.0], (40_000, 3))
    each = np.stack([prim.distance(points) for prim in scene.primitives])
    np.testing.assert_array_equal(scene.distance(points), each.min(axis=0))
    assert Scene(()).distance(points[:3]).tolist() == [np.inf] * 3


def test_ray_hits_are_on_the_surface() -> None:
    """Points where cast rays hit lie on the scene's surface (distance 0 to 1e-9 m)."""
    scene = build_scene(4, 0, 64.0, 80, 60)
    camera = SMALL.camera
    rays = pixel_rays(camera, 1)
    t, hit = scene.cast(np.zeros(3), rays)
    points = t[hit >= 0, None] * rays[hit >= 0]
    assert len(points) == len(rays)
    assert scene.distance(points).max() < 1e-9


@pytest.mark.parametrize(('bad', 'message'), [
    (np.zeros((4, 2)), r'p must be an \(N, 3\) array of points, got shape \(4, 2\)'),
    (np.zeros(3), r'got shape \(3,\)'),
    (np.array([[0.0, np.nan, 1.0]]), 'p must hold finite coordinates'),
])
def test_distance_refuses_bad_points(bad: F64, message: str) -> None:
    scene = build_scene(0, 0, 256.0, 320, 240)
    with pytest.raises(ArgumentError, match=message):
        scene.distance(bad)
    with pytest.raises(ArgumentError, match=message):
        scene.primitives[0].distance(bad)


def _cast_truth(config: DepthSequenceConfig, index: int) -> NDArray[np.float32]:
    """Z at the pixel centres of frame ``index``, cast afresh into scene_at / pose_at."""
    pose = pose_at(config, index)
    rays = pixel_rays(config.camera, 1)
    t, _ = scene_at(config, index).cast(pose.position, rays @ pose.rotation.T)
    depth: NDArray[np.float32] = np.where(np.isfinite(t), t, np.nan).reshape(
        config.height, config.width).astype(np.float32)
    return depth


@pytest.mark.parametrize('kind', KINDS)
def test_scene_at_and_pose_at_reproduce_every_frame(kind: str) -> None:
    """For every kind and frame: the pose is pose_at's, the stamp stamp_at's, and the truth
    depth is what a ray cast into scene_at gives (exactly: the same rays into the same
    surfaces); its back-projected points lie on scene_at's surface."""
    config = dataclasses.replace(SMALL, kind=kind)
    rays = pixel_rays(config.camera, 1)
    for frame in simulate_depth_sequence(config):
        pose = pose_at(config, frame.index)
        np.testing.assert_array_equal(frame.pose.rotation, pose.rotation)
        np.testing.assert_array_equal(frame.pose.position, pose.position)
        assert frame.stamp_ns == stamp_at(config, frame.index)
        np.testing.assert_array_equal(frame.truth, _cast_truth(config, frame.index))
        seen = np.isfinite(frame.truth).ravel()
        points = pose.position + (rays[seen] * frame.truth.ravel()[seen, None]) @ \
            pose.rotation.T
        assert scene_at(config, frame.index).distance(points).max() < FLOAT32_SURFACE_TOL


def test_moving_object_scene_is_build_scene_of_the_frame() -> None:
    config = dataclasses.replace(SMALL, kind='moving_object')
    camera = config.camera
    for index in range(config.n_frames):
        expected = build_scene(config.seed, index, camera.fx, camera.width, camera.height)
        got = scene_at(config, index)
        assert got.labels == expected.labels
        for a, b in zip(got.primitives, expected.primitives, strict=True):
            np.testing.assert_array_equal(a.centre, b.centre)


def test_scene_at_and_pose_at_refuse_what_is_not_a_frame() -> None:
    with pytest.raises(ArgumentError, match=r'index 4: not a frame of the sequence \(0..3\)'):
        scene_at(SMALL, 4)
    with pytest.raises(ArgumentError, match=r'index -1: not a frame'):
        pose_at(SMALL, -1)
    with pytest.raises(ConfigError, match=r'orbit_deg=120.0: must be in \[0, 90\]'):
        scene_at(dataclasses.replace(SMALL, kind='orbit', orbit_deg=120.0), 0)
    with pytest.raises(ConfigError, match=r"kind='spiral': must be one of static, "):
        pose_at(dataclasses.replace(SMALL, kind='spiral'), 0)


def test_orbit_looks_at_its_centre_along_the_arc() -> None:
    """Every pose looks at ORBIT_CENTRE (it projects onto the principal point), from the
    same distance, at the cameras' height; the arc from the first to the last frame is
    orbit_deg, the middle frame (odd count) the static camera's."""
    config = DepthSequenceConfig(kind='orbit', n_frames=9, orbit_deg=40.0)
    centre = np.asarray(ORBIT_CENTRE)
    poses = [pose_at(config, i) for i in range(config.n_frames)]
    for pose in poses:
        local = pose.rotation.T @ (centre - pose.position)
        np.testing.assert_allclose(local[:2], 0.0, atol=1e-12)
        assert local[2] == pytest.approx(np.linalg.norm(centre))  # the origin's distance
        assert pose.position[1] == 0.0
    np.testing.assert_allclose(poses[4].position, 0.0, atol=1e-12)
    first, last = (np.delete(p.position - centre, 1) for p in (poses[0], poses[-1]))
    cosine = first @ last / (np.linalg.norm(first) * np.linalg.norm(last))
    assert math.degrees(math.acos(cosine)) == pytest.approx(40.0)


def test_orbit_keeps_the_scene_in_view() -> None:
    """Every frame of a 40-degree orbit: every pixel sees a surface, more than 80 % of them
    measured (the rest: the left band and the holes), and more than 30 % on the scene's
    objects (not the background or ground)."""
    config = DepthSequenceConfig(kind='orbit', width=96, height=72, n_frames=7,
                                 supersample=1, orbit_deg=40.0)
    for frame in simulate_depth_sequence(config):
        assert np.isfinite(frame.truth).all()
        assert np.isfinite(frame.depth).mean() > 0.8
        pose = frame.pose
        _, hit = scene_at(config, frame.index).cast(
            pose.position, pixel_rays(config.camera, 1) @ pose.rotation.T)
        labels = np.asarray(scene_at(config, frame.index).labels)[hit]
        assert np.isin(labels, ['background', 'ground'], invert=True).mean() > 0.3


def test_object_leaves_after_half_the_frames() -> None:
    """The box is in the scene and the truth (flagged moving, in front of what it hides,
    mostly the background) for frames < n // 2; afterwards the scene and the truth are
    the static kind's exactly and nothing is flagged."""
    config = dataclasses.replace(SMALL, kind='object_leaves', width=96, height=72, n_frames=6)
    static = next(iter(simulate_depth_sequence(dataclasses.replace(config, kind='static'))))
    frames = list(simulate_depth_sequence(config))
    box = frames[0].moving
    assert 0.01 < box.mean() < 0.2
    rays = pixel_rays(config.camera, 1)
    _, behind = scene_at(config, 5).cast(np.zeros(3), rays)
    assert np.mean(behind.reshape(box.shape)[box] == 0) > 0.5  # primitive 0: background
    for frame in frames:
        labels = scene_at(config, frame.index).labels
        if frame.index < 3:
            assert labels[-1] == 'leaving'
            assert labels.count('leaving') == 1
            np.testing.assert_array_equal(frame.moving, box)
            assert np.all(frame.truth[box] < static.truth[box])
            np.testing.assert_array_equal(frame.truth[~box], static.truth[~box])
        else:
            assert 'leaving' not in labels
            assert not frame.moving.any()
            np.testing.assert_array_equal(frame.truth, static.truth)


def test_long_room_and_path() -> None:
    """The room is 9 - 10 m across and the same for the same seed; over 300 frames of 2 cm
    the camera moves 2 cm a frame, turns less than a degree, stays inside and at least
    the clearance off every surface, and (every 30th frame, 48 x 36) sees a surface at
    every pixel and objects besides the room at more than 3 % of them."""
    config = DepthSequenceConfig(kind='long', width=48, height=36, n_frames=300,
                                 step_m=0.02)
    scene = scene_at(config, 0)
    room = scene.primitives[0]
    assert isinstance(room, Box)
    assert room.label == 'room'
    assert np.all((2 * room.half_size[[0, 2]] >= 2 * ROOM_HALF_M[0]) &
                  (2 * room.half_size[[0, 2]] <= 2 * ROOM_HALF_M[1]))
    assert len(scene.primitives) > 20
    again, other = scene_at(config, 299), scene_at(dataclasses.replace(config, seed=1), 0)
    assert [p.centre.tolist() for p in again.primitives] == \
        [p.centre.tolist() for p in scene.primitives]
    assert [p.centre.tolist() for p in other.primitives] != \
        [p.centre.tolist() for p in scene.primitives]
    poses = [pose_at(config, i) for i in range(config.n_frames)]
    positions = np.array([p.position for p in poses])
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    np.testing.assert_allclose(steps, 0.02, rtol=1e-4)  # a chord of a 2.5 m circle
    turns = [a.angle_to(b) for a, b in itertools.pairwise(poses)]
    assert max(turns) < 1.0
    np.testing.assert_allclose(np.hypot(positions[:, 0], positions[:, 2]), LONG_RADIUS_M)
    assert scene.distance(positions).min() > LONG_CLEARANCE_M
    rays = pixel_rays(config.camera, 1)
    for pose in poses[::30]:
        t, hit = scene.cast(pose.position, rays @ pose.rotation.T)
        assert np.isfinite(t).all()
        assert np.mean(hit > 0) > 0.03


def test_existing_kinds_keep_their_poses() -> None:
    """static and moving_object stand at the origin; moving_camera slides step_m and
    turns turn_deg a frame (the committed depth bag depends on it)."""
    for kind in ('static', 'moving_object', 'object_leaves'):
        pose = pose_at(dataclasses.replace(SMALL, kind=kind), 3)
        np.testing.assert_array_equal(pose.rotation, Pose().rotation)
        np.testing.assert_array_equal(pose.position, Pose().position)
    pose = pose_at(dataclasses.replace(SMALL, kind='moving_camera'), 3)
    np.testing.assert_allclose(pose.position, [3 * SMALL.step_m, 0.0, 0.0])
    assert pose.angle_to(Pose()) == pytest.approx(3 * SMALL.turn_deg)
