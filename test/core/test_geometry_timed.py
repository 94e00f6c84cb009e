"""Poses over time (depth_nodes.core.geometry.timed): the nearest pose within a tolerance,
never a guess; a wild pose held, then dropped or kept by the pose after it; a tf tree with
moving and fixed edges, chained at a stamp or at each edge's latest value.

Tolerances: positions compared to 1e-12 m where they are computed, exactly where they are
kept as given."""

from __future__ import annotations

import numpy as np
import pytest

from depth_nodes.core.geometry import (
    Added,
    Pose,
    PoseHistory,
    PoseMiss,
    TransformTree,
    quaternion_from_rpy,
    rotation_matrix,
)
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


def test_the_oldest_poses_are_forgotten() -> None:
    history = PoseHistory(capacity=3)
    for stamp, x in ((0, 0.0), (100, 0.1), (200, 0.2), (300, 0.3)):
        history.add(stamp * MS, _at(x))
    assert len(history) == 3  # the oldest went
    assert history.newest == 300 * MS
    gone = history.at(0, 0)
    assert isinstance(gone, PoseMiss)
    assert gone.reason == 'no_pose'


def test_a_bad_pose_is_refused() -> None:
    history = PoseHistory()
    with pytest.raises(ArgumentError, match='finite'):
        history.add(0, Pose(np.eye(3), np.array([np.nan, 0, 0])))
    assert len(history) == 0


def test_a_tf_chain_is_taken_at_the_stamp() -> None:
    """world -> odom (fixed) -> base (moving) -> camera (fixed, mounted turned): the
    camera's pose at a stamp is the chain with base's value at that stamp."""
    tree = TransformTree()
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
    tree = TransformTree()
    with pytest.raises(ArgumentError, match='two different frame names'):
        tree.set('a', 'a', 0, Pose())
    with pytest.raises(ArgumentError, match='not a rotation matrix'):
        tree.set('a', 'b', 0, Pose(2 * np.eye(3), np.zeros(3)))


# ------------------------------------------------------------------ the latest value

def _random_pose(rng: np.random.Generator) -> Pose:
    return Pose.from_quaternion(rng.normal(size=3), rng.normal(size=4))


def test_the_latest_transform_between_two_frames_both_ways() -> None:
    """register_depth's lookup: no stamp, each edge's latest value; a chain through a
    common parent, and its inverse."""
    rng = np.random.default_rng(3)
    tree = TransformTree()
    rig_depth, rig_rgb = _random_pose(rng), _random_pose(rng)
    tree.set('base', 'rig', 0, _random_pose(rng), static=True)
    tree.set('rig', 'depth', 0, rig_depth, static=True)
    nudged = Pose(rig_rgb.rotation, rig_rgb.position + 0.01)
    tree.set('rig', 'rgb', 5 * MS, nudged)
    tree.set('rig', 'rgb', 10 * MS, rig_rgb)  # a later value of a moving edge wins
    found = tree.lookup('rgb', 'depth')
    assert isinstance(found, Pose)
    want = rig_rgb.inverse().compose(rig_depth)
    np.testing.assert_allclose(found.rotation, want.rotation, atol=1e-12)
    np.testing.assert_allclose(found.position, want.position, atol=1e-12)
    back = tree.lookup('depth', 'rgb')
    assert isinstance(back, Pose)
    np.testing.assert_allclose(back.rotation, found.rotation.T, atol=1e-12)
    assert isinstance(tree.lookup('rgb', 'rgb'), Pose)
    assert isinstance(tree.lookup('rgb', 'elsewhere'), PoseMiss)


# ------------------------------------------------------------------ wild poses

def _stream(history: PoseHistory, stamps_ms: list[int], xs: list[float]) -> list[Added]:
    return [history.add(t * MS, _at(x)) for t, x in zip(stamps_ms, xs, strict=True)]


def test_a_pose_an_hour_ahead_is_held_then_dropped_by_the_next() -> None:
    history = PoseHistory()
    _stream(history, [0, 100, 200], [0.0, 0.1, 0.2])
    wild = history.add(3600_000 * MS, _at(0.3))
    assert wild.held
    assert not wild.kept
    assert history.held == 3600_000 * MS
    # meanwhile an image after the newest pose waits: its pose may still come
    pending = history.at(300 * MS, 10 * MS)
    assert isinstance(pending, PoseMiss)
    assert pending.reason == 'pose_pending'
    nxt = history.add(300 * MS, _at(0.3))
    assert nxt.kept == [300 * MS]
    assert [stamp for stamp, _ in nxt.rejected] == [3600_000 * MS]
    assert 'after the newest pose' in nxt.rejected[0][1]
    assert history.newest == 300 * MS
    assert history.held is None
    got = history.at(300 * MS, 10 * MS)
    assert isinstance(got, Pose)
    assert got.position[0] == 0.3


def test_a_100_m_jump_is_dropped_when_the_next_pose_carries_on() -> None:
    history = PoseHistory()
    _stream(history, [0, 100, 200], [0.0, 0.1, 0.2])
    jump = history.add(300 * MS, _at(100.3))
    assert jump.held
    assert history.at(300 * MS, 10 * MS) == PoseMiss(
        'pose_pending', 'the newest pose is 0.100 s older than the image')
    nxt = history.add(400 * MS, _at(0.4))
    assert nxt.kept == [400 * MS]
    assert nxt.rejected[0][0] == 300 * MS
    assert 'm from where the poses before it put the frame' in nxt.rejected[0][1]
    miss = history.at(300 * MS, 10 * MS)  # the wild pose's frame: no pose, one frame lost
    assert isinstance(miss, PoseMiss)
    assert miss.reason == 'no_pose'


def test_a_real_jump_is_kept_once_the_next_pose_follows_it() -> None:
    """A SLAM loop closure moves the track by 3 m: the first pose after it is held, the
    next one continues from it, and both are kept (one pose of latency, no loss)."""
    history = PoseHistory()
    _stream(history, [0, 100, 200], [0.0, 0.1, 0.2])
    assert history.add(300 * MS, _at(3.3)).held
    nxt = history.add(400 * MS, _at(3.4))
    assert nxt.kept == [300 * MS, 400 * MS]
    assert not nxt.rejected
    assert history.add(500 * MS, _at(3.5)).kept == [500 * MS]  # the new track predicts


def test_a_fast_vehicle_is_never_held_back() -> None:
    """40 m/s at 10 Hz, 4 m a pose, from the first pose on: the second is held (no motion
    known yet) and kept by the third; none is dropped."""
    history = PoseHistory()
    added = _stream(history, list(range(0, 2000, 100)), [4.0 * k for k in range(20)])
    assert not any(a.rejected for a in added)
    assert len(history) == 20


def test_a_turned_pose_is_dropped_like_a_jump() -> None:
    history = PoseHistory()
    _stream(history, [0, 100, 200], [0.0, 0.1, 0.2])
    flipped = Pose(rotation_matrix(quaternion_from_rpy(0.0, 0.0, 2.0)), np.array([0.3, 0, 0]))
    held = history.add(300 * MS, flipped)
    assert held.held
    nxt = history.add(400 * MS, _at(0.4))
    assert nxt.rejected[0][0] == 300 * MS
    assert 'turned' in nxt.rejected[0][1]


def test_a_late_pose_or_a_repeat_is_out_of_order() -> None:
    history = PoseHistory()
    _stream(history, [0, 200, 400], [0.0, 0.2, 0.4])
    for stamp in (300, 400):
        late = history.add(stamp * MS, _at(0.3))
        assert not late.kept
        assert not late.held
        assert late.late[0][0] == stamp * MS
        assert 'before the newest pose' in late.late[0][1]
    assert len(history) == 3


def test_the_motion_is_measured_over_a_baseline() -> None:
    """Two poses 1 ms apart and 5 cm apart (a jittery 1 kHz source) say nothing of the
    speed: the next pose, 100 ms on and barely moved, is kept, not held for missing a
    50 m/s prediction."""
    history = PoseHistory()
    _stream(history, [0, 1], [0.0, 0.05])
    assert history.add(101 * MS, _at(0.06)).kept == [101 * MS]


def test_stamps_that_jump_back_start_the_history_over_once_confirmed() -> None:
    """A looping source: the first pose of the new pass is held (it may be one wrong
    stamp); the second continues from it, and the history starts over from the two."""
    history = PoseHistory()
    _stream(history, [30_000, 30_100, 30_200], [3.0, 3.1, 3.2])
    first = history.add(0, _at(0.0))
    assert first.held
    assert not first.restarted
    second = history.add(100 * MS, _at(0.1))
    assert second.restarted
    assert second.kept == [0, 100 * MS]
    assert len(history) == 2
    assert history.newest == 100 * MS


def test_one_pose_stamped_back_is_dropped_when_the_stream_carries_on() -> None:
    history = PoseHistory()
    _stream(history, [30_000, 30_100, 30_200], [3.0, 3.1, 3.2])
    assert history.add(0, _at(3.3)).held
    nxt = history.add(30_300 * MS, _at(3.3))
    assert not nxt.restarted
    assert nxt.rejected[0][0] == 0
    assert 'before the newest pose' in nxt.rejected[0][1]
    assert len(history) == 4


def test_the_inputs_restart_keeps_the_held_pose_that_went_back() -> None:
    """The images jumped back first: the held pose stamped back is the new timeline's."""
    history = PoseHistory()
    _stream(history, [30_000, 30_100], [3.0, 3.1])
    history.add(0, _at(0.0))
    assert history.restart_from_held()
    assert len(history) == 1
    assert history.newest == 0
    history.add(3600_000 * MS, _at(0.0))  # held for being far ahead: not the new timeline
    assert not history.restart_from_held()
    assert len(history) == 0


def test_limits_must_be_positive() -> None:
    with pytest.raises(ArgumentError, match='positive'):
        PoseHistory(jump_limit=0.0)
