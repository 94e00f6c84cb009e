"""The multiview_stereo node: a simulated camera sequence (depth_nodes.sim.sequence) fed as
a driver and a VIO would send it (images, camera_infos, poses), the published depth checked
against the exact ground truth; the message conventions, the pose sources, the rig, and
every drop reason.

The node publishes exactly what the core (MvsStream) computes from the same views; on the
small sideways sequence (160 x 120, 10 frames, 32 planes) the last depth's median |dZ|/Z
stays below 10 % (a check of the plumbing; the accuracy targets are measured on larger
views by test/accuracy/test_multiview_accuracy.py and `depth-nodes eval`).
"""

from __future__ import annotations

import copy
import functools
import math
from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.parameter import Parameter
from ros_helpers import capture

from depth_nodes.core.mvs.matcher import MvsParams
from depth_nodes.core.mvs.stream import Frame, MvsStream, StreamDepth
from depth_nodes.errors import ConfigError
from depth_nodes.nodes.multiview_stereo import MultiViewStereoNode
from depth_nodes.ros.image import image_to_array
from depth_nodes.ros.pointcloud import read_pointcloud
from depth_nodes.sim.sequence import SequenceConfig, SequenceView, simulate_sequence
from depth_nodes.tools.bags.multiview import step_messages

pytestmark = pytest.mark.ros

SMALL = SequenceConfig(motion='sideways', width=160, height=120, n_frames=10, step_m=0.05,
                       supersample=1)
RIG = SequenceConfig(motion='rig', width=240, height=180, n_frames=1, supersample=1,
                     rig_baseline_m=0.15)
SWEEP = {'min_depth': 0.9, 'max_depth': 8.0, 'planes': 32, 'paths': 5, 'threads': 1}


@functools.cache
def _views(config: SequenceConfig) -> list[SequenceView]:
    return list(simulate_sequence(config))


def _steps(config: SequenceConfig) -> list[list[tuple[str, Any]]]:
    views = _views(config)
    per = config.rig_cameras if config.motion == 'rig' else 1
    return [step_messages(config, views[i:i + per]) for i in range(0, len(views), per)]


def _make(context: Context, **params: Any) -> Any:
    values = {**SWEEP, **params}
    return capture(MultiViewStereoNode(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in values.items()]), history=True)


def _feed(node: Any, messages: list[tuple[str, Any]], skip: tuple[str, ...] = ()) -> None:
    routes = {spec.topic: spec.callback for spec in node.inputs}
    for topic, msg in messages:
        suffix = topic.split('/', 2)[-1]
        for name, callback in routes.items():
            if name.lstrip('/') == suffix and suffix not in skip:
                callback(msg)


def _published(node: Any, topic: str) -> list[Any]:
    return [msg for t, msg in node.outbox if t == topic]


def test_a_sideways_sequence_gives_depth_near_the_truth(context: Context) -> None:
    node = _make(context)
    try:
        for step in _steps(SMALL):
            _feed(node, step, skip=('pose',))
        depths = _published(node, '/depth')
        # the first frame has no keyframe far enough yet: counted, nothing published
        assert node.drops['no_baseline'] >= 1
        assert len(depths) + node.drops['no_baseline'] == SMALL.n_frames
        truth = {v.stamp_ns: v.depth for v in _views(SMALL)}
        last = depths[-1]
        stamp = last.header.stamp.sec * 10**9 + last.header.stamp.nanosec
        depth = image_to_array(last)
        assert last.encoding == '32FC1'
        assert last.header.frame_id == 'camera_optical'
        error = np.abs(depth - truth[stamp]) / truth[stamp]
        assert np.isfinite(depth).mean() > 0.8
        assert np.nanmedian(error) < 0.10
        # the node is a wrapper: the core gives the same depths from the same views
        stream = MvsStream(MvsParams(min_depth=0.9, max_depth=8.0, planes=32, paths=5))
        core = [r for v in _views(SMALL)
                if isinstance(r := stream.process(Frame(v.image, v.intrinsics, v.pose,
                                                        v.stamp_ns)), StreamDepth)]
        assert len(core) == len(depths)
        for got, want in zip(depths, core, strict=True):
            np.testing.assert_array_equal(image_to_array(got), want.depth)
        # the other outputs share the depth's header and size
        for topic in ('/sigma', '/confidence', '/converged'):
            msg = _published(node, topic)[-1]
            assert msg.header == last.header
            assert (msg.height, msg.width) == (SMALL.height, SMALL.width)
        sigma = image_to_array(_published(node, '/sigma')[-1])
        assert np.array_equal(np.isfinite(sigma), np.isfinite(depth))
        cloud = read_pointcloud(_published(node, '/points2')[-1])
        np.testing.assert_allclose(cloud['z'], depth, equal_nan=True, rtol=1e-6)
        info = _published(node, '/depth/camera_info')[-1]
        assert info.header == last.header
        assert node.drops.get('internal_error', 0) == 0
    finally:
        node.destroy_node()


def test_poses_from_a_pose_topic_give_the_same_depth_as_from_odometry(
        context: Context) -> None:
    outputs = []
    for source, skip in (('odometry', ('pose',)), ('pose', ('odom',))):
        node = _make(context, pose_source=source)
        try:
            for step in _steps(SMALL)[:4]:
                _feed(node, step, skip=skip)
            outputs.append([image_to_array(m) for m in _published(node, '/depth')])
        finally:
            node.destroy_node()
    assert len(outputs[0]) == len(outputs[1]) >= 2
    for a, b in zip(*outputs, strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_rig_gives_depth_from_its_first_set(context: Context) -> None:
    """Three cameras side by side: the middle one's depth comes from the first set on (the
    others are the sources), under the rig's namespace, with the rig's pose or none."""
    extrinsics = []
    for k in range(RIG.rig_cameras):
        extrinsics += [k * RIG.rig_baseline_m, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    for source in ('odometry', 'none'):
        node = _make(context, cameras=['cam0', 'cam1', 'cam2'], reference_camera=1,
                     rig_extrinsics=extrinsics, pose_source=source)
        try:
            steps = _steps(RIG)
            _feed(node, steps[0])
            depths = _published(node, '/depth')
            assert len(depths) == 1, node.drops
            truth = _views(RIG)[1].depth
            error = np.abs(image_to_array(depths[0]) - truth) / truth
            assert np.nanmedian(error) < 0.05
            assert depths[0].header.frame_id == 'cam1_optical'
        finally:
            node.destroy_node()


def _pose(stamp_ns: int, x: float, quaternion: tuple[float, ...] = (0, 0, 0, 1)) -> Any:
    msg = PoseStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    msg.header.frame_id = 'world'
    msg.pose.position.x = x
    (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z,
     msg.pose.orientation.w) = quaternion
    return msg


def test_every_missing_or_bad_pose_is_a_counted_drop(context: Context) -> None:
    node = _make(context, pose_source='pose', pose_tolerance=0.01, pose_wait=0.25)
    try:
        routes = {spec.topic.lstrip('/'): spec.callback for spec in node.inputs}
        steps = _steps(SMALL)
        images = [[m for t, m in s if t.endswith(('image_rect', 'camera_info'))]
                  for s in steps]
        stamps = [v.stamp_ns for v in _views(SMALL)]
        # a NaN pose and a zero quaternion: bad_pose, and not kept
        routes['pose'](_pose(stamps[0] - 2_000_000, math.nan))
        routes['pose'](_pose(stamps[0] - 1_000_000, 0.0, (0, 0, 0, 0)))
        assert node.drops['bad_pose'] == 2
        # a pose 30 ms from its image: no_pose (tolerance 10 ms)
        routes['pose'](_pose(stamps[0] + 30_000_000, 0.0))
        for msg in images[0]:
            routes['image_rect' if hasattr(msg, 'encoding') else 'camera_info'](msg)
        assert node.drops['no_pose'] == 1
        # images whose pose never comes: pose_timeout once later images are 0.25 s on
        for k in (1, 2, 3, 4):
            for msg in images[k]:
                routes['image_rect' if hasattr(msg, 'encoding') else 'camera_info'](msg)
        assert node.drops['pose_timeout'] >= 1
        assert node.holds_input()
        node.finish_stream()
        assert not node.holds_input()
        total = sum(node.drops[r] for r in ('no_pose', 'pose_timeout', 'stream_ended'))
        assert total == 5  # every image accounted for
        assert node.drops.get('internal_error', 0) == 0
        assert not _published(node, '/depth')
    finally:
        node.destroy_node()


def test_a_camera_info_of_another_size_is_a_counted_drop(context: Context) -> None:
    node = _make(context)
    try:
        steps = [copy.deepcopy(s) for s in _steps(SMALL)[:3]]
        for topic, msg in steps[2]:
            if topic.endswith('camera_info'):
                msg.width, msg.height = 2 * msg.width, 2 * msg.height
                msg.k = [2 * v for v in msg.k[:6]] + [0.0, 0.0, 1.0]
                msg.p = [2 * v for v in msg.p[:8]] + [0.0, 0.0, 1.0, 0.0]
        for step in steps:
            _feed(node, step, skip=('pose',))
        assert len(_published(node, '/depth')) == 2
        # a CameraInfo of twice the size is scaled to the image (intrinsics at its size)
        assert node.drops.get('size_mismatch', 0) == 0
        assert node.drops.get('internal_error', 0) == 0
    finally:
        node.destroy_node()


def test_the_parameters_are_checked_like_the_core(context: Context) -> None:
    with pytest.raises(ConfigError, match='min_depth'):
        _make(context, min_depth=5.0, max_depth=2.0)
    with pytest.raises(ConfigError, match='rig_extrinsics needs 7 numbers per camera'):
        _make(context, cameras=['a', 'b'], rig_extrinsics=[0.0] * 7)
    with pytest.raises(ConfigError, match='pose_source none needs a rig'):
        _make(context, pose_source='none')
    # a sweep takes at most 16 source views: a rig of 18 cameras is refused at start-up
    with pytest.raises(ConfigError, match='a rig needs 2 to 17 cameras'):
        _make(context, cameras=[f'c{k}' for k in range(18)],
              rig_extrinsics=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0] * 18)
    with pytest.raises(ConfigError, match='tf2_msgs'):
        _make(context, pose_source='tf')
    node = _make(context)
    try:
        result = node.set_parameters([Parameter('planes', value=1)])[0]
        assert not result.successful
        result = node.set_parameters([Parameter('max_depth', value=0.5)])[0]
        assert not result.successful
        assert 'min_depth' in result.reason
        assert node.set_parameters([Parameter('planes', value=32)])[0].successful
    finally:
        node.destroy_node()


def test_the_old_name_of_the_census_cost_is_still_accepted(context: Context) -> None:
    """matching_cost census_intensity, census's name before it took sgm_stereo's, still
    starts the node and still sets while it runs, as census (test_mvs_kernels.py holds
    the two names to the same cost volume); any other name is refused with the choices."""
    node = _make(context, matching_cost='census_intensity')
    try:
        assert node.params.values['matching_cost'] == 'census_intensity'
        assert node.stream.params.matching_cost == 'census'
        assert node.set_parameters([Parameter('matching_cost', value='zncc')])[0].successful
        result = node.set_parameters([Parameter('matching_cost', value='census_intensity')])[0]
        assert result.successful, result.reason
        refused = node.set_parameters([Parameter('matching_cost', value='intensity')])[0]
        assert not refused.successful
        assert 'one of census, zncc, census_intensity' in refused.reason
    finally:
        node.destroy_node()


def test_the_old_name_of_the_temporal_filter_is_still_taken_with_a_warning(
        context: Context, capfd: pytest.CaptureFixture[str]) -> None:
    """depth_filter, the temporal filter's name before it met the depth_filter node, still
    sets it, at start-up and while running, and says the new name each time; the new name
    alone works without a word."""
    node = _make(context, depth_filter='none')
    try:
        assert node.stream.stream.temporal_filter == 'none'
        assert 'parameter depth_filter is deprecated: it is now temporal_filter' in \
            capfd.readouterr().err
        assert node.set_parameters([Parameter('depth_filter', value='gauss_uniform')])[0] \
            .successful
        assert 'depth_filter: gauss_uniform taken as temporal_filter' in capfd.readouterr().err
        refused = node.set_parameters([Parameter('depth_filter', value='median')])[0]
        assert not refused.successful
        assert 'kalman' in refused.reason
    finally:
        node.destroy_node()
    node = _make(context, temporal_filter='gauss_uniform')
    try:
        assert node.stream.stream.temporal_filter == 'gauss_uniform'
        assert 'deprecated' not in capfd.readouterr().err
    finally:
        node.destroy_node()


def test_a_wild_odometry_pose_is_held_then_dropped_and_the_stream_carries_on(
        context: Context) -> None:
    """Poses through the node base's pose input: an odometry message stamped an hour ahead
    between two frames is one bad_pose, no frame is lost, and nothing starts over."""
    node = _make(context)
    jumps = []
    node.on_time_jump = lambda: jumps.append(1)
    try:
        steps = _steps(SMALL)[:4]
        for k, step in enumerate(steps):
            _feed(node, step, skip=('pose',))
            if k == 1:
                wild = next(copy.deepcopy(m) for t, m in step if t.endswith('odom'))
                wild.header.stamp.sec += 3600
                _feed(node, [('/mvs/odom', wild)])
        assert node.drops['bad_pose'] == 1
        assert not jumps
        assert len(_published(node, '/depth')) == len(steps) - node.drops['no_baseline']
        assert set(node.drops) <= {'bad_pose', 'no_baseline'}
    finally:
        node.destroy_node()


def test_delayed_depth_comes_with_its_own_stamp_and_flushes_at_the_end(
        context: Context) -> None:
    node = _make(context, delay=2)
    try:
        for step in _steps(SMALL)[:6]:
            _feed(node, step, skip=('pose',))
        published = _published(node, '/depth')
        stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in published]
        assert stamps == sorted(stamps)
        assert node.holds_input()
        node.finish_stream()
        after = _published(node, '/depth')
        assert len(after) + node.drops['no_baseline'] == 6
        assert not node.holds_input()
    finally:
        node.destroy_node()


def test_odometry_of_the_body_with_the_camera_mounted_on_it(context: Context) -> None:
    """An odometry of a body whose camera sits 0.1 m to its left: camera_in_body moves the
    poses, and the depth equals the one from the camera's own poses."""
    mount = [-0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    outputs = []
    for shift, params in ((0.0, {}), (0.1, {'camera_in_body': mount})):
        node = _make(context, **params)
        try:
            for step in _steps(SMALL)[:4]:
                moved = []
                for topic, msg in step:
                    if isinstance(msg, Odometry):
                        msg = copy.deepcopy(msg)
                        msg.pose.pose.position.x += shift
                    moved.append((topic, msg))
                _feed(node, moved, skip=('pose',))
            outputs.append([image_to_array(m) for m in _published(node, '/depth')])
        finally:
            node.destroy_node()
    assert len(outputs[0]) == len(outputs[1]) >= 2
    for a, b in zip(*outputs, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, equal_nan=True)
