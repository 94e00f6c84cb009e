"""Poses over time (depth_nodes.core.mvs.poses): the nearest pose within a tolerance, never
a guess; a tf tree with moving and fixed edges, chained at a stamp."""

from __future__ import annotations

import numpy as np
import pytest

from depth_nodes.core.mvs.geometry import Pose
from depth_nodes.core.mvs.poses import PoseHistory, PoseMiss, TimedTransforms
from depth_nodes.core.transforms import quaternion_from_rpy, rotation_matrix
from depth_nodes.errors import ArgumentError

MS = 1_000_000


def _at(x: float) -> Pose:
    return Pose(np.eye(3), np.array([x, 0.0, 0.0]))


def test_the_nearest_pose_within_the_tolerance() -> None:
    history = PoseHistory()
    for k in range(5):
        history.add(k * 100 * MS, _at(k))
    got = history.at(205 * MS, 10 * MS)
    assert isinstance(got, Pose)
    assert got.position[0] == 2
    got = history.at(251 * MS, 60 * MS)  # 49 ms from 300, 51 from 200
    assert isinstance(got, Pose)
    assert got.position[0] == 3


def test_no_pose_near_the_stamp_or_none_yet() -> None:
    history = PoseHistory()
    empty = history.at(0, MS)
    assert isinstance(empty, PoseMiss)
    assert empty.reason == 'pose_pending'
    history.add(0, _at(0))
    history.add(100 * MS, _at(1))
    between = history.at(50 * MS, 10 * MS)
    assert isinstance(between, PoseMiss)
    assert between.reason == 'no_pose'
    assert '0.050 s from the image' in between.detail
    later = history.at(300 * MS, 10 * MS)  # newer than every pose: one may still come
    assert isinstance(later, PoseMiss)
    assert later.reason == 'pose_pending'


def test_poses_out_of_order_are_kept_in_order_and_a_repeat_replaces() -> None:
    history = PoseHistory(capacity=3)
    for stamp, x in ((200, 2.0), (0, 0.0), (100, 1.0), (100, 1.5), (300, 3.0)):
        history.add(stamp * MS, _at(x))
    assert len(history) == 3  # the oldest went
    assert history.newest == 300 * MS
    got = history.at(100 * MS, 0)
    assert isinstance(got, Pose)
    assert got.position[0] == 1.5


def test_a_bad_pose_is_refused() -> None:
    history = PoseHistory()
    with pytest.raises(ArgumentError, match='finite'):
        history.add(0, Pose(np.eye(3), np.array([np.nan, 0, 0])))
    assert len(history) == 0


def test_a_tf_chain_is_taken_at_the_stamp() -> None:
    """world -> odom (fixed) -> base (moving) -> camera (fixed, mounted turned): the
    camera's pose at a stamp is the chain with base's value at that stamp."""
    tree = TimedTransforms()
    odom = Pose(rotation_matrix(quaternion_from_rpy(0, 0, 0.3)), np.array([1.0, 2.0, 0.0]))
    mount = Pose(rotation_matrix(quaternion_from_rpy(-np.pi / 2, 0, -np.pi / 2)),
                 np.array([0.1, 0.0, 0.5]))
    tree.set('world', 'odom', 0, odom, static=True)
    tree.set('base', 'camera', 0, mount, static=True)
    for k in range(3):
        tree.set('odom', 'base', k * 100 * MS, _at(k))
    got = tree.lookup('world', 'camera', 105 * MS, 10 * MS)
    assert isinstance(got, Pose)
    want = odom.compose(_at(1)).compose(mount)
    np.testing.assert_allclose(got.rotation, want.rotation, atol=1e-12)
    np.testing.assert_allclose(got.position, want.position, atol=1e-12)
    # the other way round: the inverse
    back = tree.lookup('camera', 'world', 105 * MS, 10 * MS)
    assert isinstance(back, Pose)
    np.testing.assert_allclose(back.compose(got).position, 0, atol=1e-12)
    missing = tree.lookup('world', 'camera', 150 * MS, 10 * MS)
    assert isinstance(missing, PoseMiss)
    assert missing.reason == 'no_pose'
    assert missing.detail.startswith('odom -> base')
    unknown = tree.lookup('world', 'nowhere', 0, MS)
    assert isinstance(unknown, PoseMiss)
    assert unknown.reason == 'no_transform'


def test_a_tf_edge_needs_two_frames_and_a_rigid_pose() -> None:
    tree = TimedTransforms()
    with pytest.raises(ArgumentError, match='two different frame names'):
        tree.set('a', 'a', 0, Pose())
    with pytest.raises(ArgumentError, match='orthonormal'):
        tree.set('a', 'b', 0, Pose(2 * np.eye(3), np.zeros(3)))
