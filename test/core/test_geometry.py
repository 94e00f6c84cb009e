"""The package's one geometry (depth_nodes.core.geometry): poses, rotations and their one
tolerance, and the forward splat every warp uses, its kernel against the plain reference
(test/reference/geometry.py) for each footprint.

Tolerances: rigid motions to 1e-12 (float64 arithmetic on values of order 1); the kernel's
Z and source index equal the reference's exactly (the same arithmetic, term by term)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import kernel_size
from reference.geometry import splat_reference

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.geometry import (
    FOOTPRINTS,
    ROTATION_TOLERANCE,
    Intrinsics,
    Pose,
    check_rotation,
    quaternion_from_rpy,
    quaternion_of,
    rotation_from_vector,
    rotation_matrix,
    rotation_vector,
    splat,
)
from depth_nodes.errors import ArgumentError, CalibrationError


# ------------------------------------------------------------------ poses
def test_pose_relative_motion_maps_points_between_frames() -> None:
    a = Pose(rotation_matrix(quaternion_from_rpy(0.1, -0.2, 0.3)), np.array([1.0, 2.0, 3.0]))
    b = Pose(rotation_matrix(quaternion_from_rpy(-0.3, 0.1, 0.05)), np.array([0.5, 2.5, 2.0]))
    point_in_a = np.array([0.2, -0.1, 4.0])
    world = a.rotation @ point_in_a + a.position
    rotation, translation = a.relative_to(b)
    np.testing.assert_allclose(rotation @ point_in_a + translation,
                               b.rotation.T @ (world - b.position), atol=1e-12)
    assert a.distance_to(b) == pytest.approx(float(np.linalg.norm([0.5, -0.5, 1.0])))
    inverse = a.inverse()
    np.testing.assert_allclose(inverse.rotation @ world + inverse.position, point_in_a,
                               atol=1e-12)


def test_quaternion_round_trip_in_every_branch() -> None:
    for rpy in [(0.1, 0.2, 0.3), (math.pi - 0.01, 0.0, 0.0), (0.0, math.pi - 0.02, 0.0),
                (0.0, 0.0, math.pi - 0.03), (1.0, -1.2, 2.9)]:
        q = quaternion_from_rpy(*rpy)
        back = quaternion_of(rotation_matrix(q))
        sign = 1.0 if q[3] >= 0 else -1.0
        np.testing.assert_allclose(back, [sign * c for c in q], atol=1e-9)
        pose = Pose.from_quaternion((1, 2, 3), q)
        np.testing.assert_allclose(pose.quaternion, back, atol=1e-12)


@pytest.mark.parametrize(('rotation', 'position', 'message'), [
    (np.eye(3) * 2, np.zeros(3), 'not a rotation matrix'),
    (np.diag([1.0, 1.0, -1.0]), np.zeros(3), 'reflection'),
    (np.eye(3), np.array([np.nan, 0, 0]), 'finite'),
    (np.eye(2), np.zeros(3), '(3, 3)'),
])
def test_a_bad_pose_is_refused(rotation: np.ndarray, position: np.ndarray,
                               message: str) -> None:
    with pytest.raises(ArgumentError, match=message.replace('(', r'\(').replace(')', r'\)')):
        Pose(rotation, position).validate()


def test_a_pose_from_seven_numbers() -> None:
    pose = Pose.from_values([1, 2, 3, 0.0, 0.0, 0.0, 2.0])  # the quaternion is normalised
    np.testing.assert_array_equal(pose.position, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(pose.rotation, np.eye(3))
    for bad in ([1, 2, 3], [0, 0, 0, 0, 0, 0, 0], [0, 0, math.nan, 0, 0, 0, 1],
                [0, 0, 0, 0, 0, 0, True]):
        with pytest.raises(ArgumentError, match=r'7 finite numbers|not all zero'):
            Pose.from_values(bad)


@pytest.mark.parametrize('rpy', [(0.1, -0.2, 0.3), (0.0, 0.0, 0.0), (math.pi, 0.0, 0.0),
                                 (0.0, math.pi - 1e-8, 0.0), (2.0, 1.0, -2.5)])
def test_rotation_vector_round_trip(rpy: tuple[float, float, float]) -> None:
    rotation = rotation_matrix(quaternion_from_rpy(*rpy))
    vector = rotation_vector(rotation)
    assert np.linalg.norm(vector) <= math.pi + 1e-9
    np.testing.assert_allclose(rotation_from_vector(vector), rotation, atol=1e-7)


def test_one_tolerance_for_every_rotation() -> None:
    """A pose's rotation, a warp's motion and a calibration's R are held to the same
    tolerance: a matrix one accepts, none refuses."""
    exact = rotation_matrix(quaternion_from_rpy(0.2, 0.1, -0.3))
    within = exact + 0.4 * ROTATION_TOLERANCE * np.eye(3)
    beyond = exact + 2.0 * ROTATION_TOLERANCE * np.eye(3)
    camera = Intrinsics(10.0, 10.0, 1.5, 1.5, 4, 4)
    depth = np.ones((4, 4), np.float32)
    info = CameraModel(4, 4, np.array([[10.0, 0, 1.5], [0, 10.0, 1.5], [0, 0, 1]]), np.zeros(5))
    for matrix, ok in ((within, True), (beyond, False)):
        checks = [lambda m=matrix: Pose(m, np.zeros(3)).validate(),
                  lambda m=matrix: splat(depth, camera, camera, (m, np.zeros(3)),
                                         footprint='box'),
                  lambda m=matrix: CameraModel(4, 4, info.K, info.D, R=m).validate()]
        for check in checks:
            if ok:
                check()
            else:
                with pytest.raises((ArgumentError, CalibrationError), match='rotation'):
                    check()
    np.testing.assert_array_equal(check_rotation(exact), exact)


# ------------------------------------------------------------------ splatting

def _scene(shape: tuple[int, int], seed: int) -> np.ndarray:
    """Blocks of depth 0.5 - 4 m with holes, a few pixels behind the camera once moved."""
    rng = np.random.default_rng(seed)
    h, w = shape
    blocks = rng.uniform(0.5, 4.0, (h // 4 + 1, w // 4 + 1))
    z = np.kron(blocks, np.ones((4, 4)))[:h, :w].astype(np.float32)
    z[rng.random(shape) < 0.1] = np.nan
    z[0, 0] = 0.0  # unknown too
    return z


@pytest.mark.kernels
@pytest.mark.parametrize('footprint', FOOTPRINTS)
@pytest.mark.parametrize('inverse', [False, True])
def test_splat_kernel_equals_reference(footprint: str, inverse: bool) -> None:
    """Upsampling, downsampling, a turn and a shift that puts some points behind the
    camera: the same Z and the same source pixel everywhere."""
    w, h = kernel_size((40, 30), (16, 12))
    source = Intrinsics(30.0, 31.0, (w - 1) / 2, (h - 1) / 2, w, h)
    depth = _scene((h, w), 3)
    with np.errstate(divide='ignore'):
        values = (1.0 / depth).astype(np.float32) if inverse else depth
    turned = rotation_matrix(quaternion_from_rpy(0.2, -0.3, 0.15))
    for target, motion in (
            (Intrinsics(50.0, 50.0, w * 0.8, h * 0.7, int(w * 1.6), int(h * 1.4)),
             (turned, np.array([0.1, -0.05, 0.3]))),
            (Intrinsics(12.0, 12.0, w / 4, h / 4, w // 2, h // 2),
             (np.eye(3), np.array([0.02, 0.0, 0.0]))),
            (source, (turned, np.array([0.0, 0.0, -1.5])))):  # some points end behind it
        got = splat(values, source, target, motion, footprint=footprint, inverse=inverse)
        want = splat_reference(values, source, target, motion, footprint=footprint,
                               inverse=inverse)
        np.testing.assert_array_equal(got.depth, want.depth)
        np.testing.assert_array_equal(got.index, want.index)
        assert got.landed.sum() >= 3  # the comparison is not of two empty images


@pytest.mark.parametrize('footprint', FOOTPRINTS)
def test_a_camera_that_stays_keeps_every_pixel(footprint: str) -> None:
    camera = Intrinsics(30.0, 30.0, 9.5, 7.5, 20, 16)
    depth = _scene((16, 20), 4)
    landed = splat(depth, camera, camera, (np.eye(3), np.zeros(3)), footprint=footprint)
    known = depth > 0
    flat = np.arange(depth.size).reshape(depth.shape)
    np.testing.assert_array_equal(landed.index[known], flat[known])
    np.testing.assert_array_equal(landed.depth[known], depth[known].astype(np.float64))
    assert not landed.landed[~known].any()  # a hole stays a hole: the footprint is a pixel


@pytest.mark.parametrize('footprint', FOOTPRINTS)
def test_the_nearest_surface_wins_whichever_comes_first(footprint: str) -> None:
    """Two points that land on one pixel, the far one first in row order and then the
    near one first: the near one's Z and index both times."""
    camera = Intrinsics(10.0, 10.0, 1.0, 0.0, 3, 1)
    shift = (np.eye(3), np.array([0.1, 0.0, 0.0]))
    near_first = splat(np.array([[0.5, 1.0, np.nan]], np.float32), camera, camera, shift,
                       footprint=footprint)
    assert near_first.depth[0, 2] == 0.5
    assert near_first.index[0, 2] == 0
    far_first = splat(np.array([[1.0, 0.5, np.nan]], np.float32), camera, camera,
                      (np.eye(3), np.array([0.05, 0.0, 0.0])), footprint=footprint)
    assert far_first.depth[0, 2] == 0.5
    assert far_first.index[0, 2] == 1


def test_a_box_footprint_fills_a_zoom_and_a_point_does_not() -> None:
    """Moving 1 m towards a wall 2 m away doubles its image: a box footprint covers every
    pixel of the middle, a point footprint every other one."""
    camera = Intrinsics(20.0, 20.0, 15.5, 11.5, 32, 24)
    wall = np.full((24, 32), 2.0, np.float32)
    closer = (np.eye(3), np.array([0.0, 0.0, -1.0]))
    box = splat(wall, camera, camera, closer, footprint='box')
    point = splat(wall, camera, camera, closer, footprint='point')
    middle = (slice(6, 18), slice(8, 24))
    assert box.landed[middle].all()
    assert 0.2 < point.landed[middle].mean() < 0.3
    np.testing.assert_allclose(box.depth[middle], 1.0, rtol=1e-12)


@pytest.mark.parametrize(('motion', 'footprint', 'message'), [
    ((np.eye(2), np.zeros(3)), 'box', r'must be a finite \(3, 3\)'),
    ((np.eye(3), np.zeros(2)), 'box', 'translation must be 3 finite'),
    ((np.eye(3), np.zeros(3)), 'disc', 'footprint'),
])
def test_splat_refuses_what_it_cannot_take(motion: tuple[np.ndarray, np.ndarray],
                                           footprint: str, message: str) -> None:
    camera = Intrinsics(10.0, 10.0, 1.5, 1.5, 4, 4)
    with pytest.raises(ArgumentError, match=message):
        splat(np.ones((4, 4), np.float32), camera, camera, motion, footprint=footprint)
    with pytest.raises(ArgumentError, match='camera'):
        splat(np.ones((3, 4), np.float32), camera, camera, (np.eye(3), np.zeros(3)),
              footprint='box')
