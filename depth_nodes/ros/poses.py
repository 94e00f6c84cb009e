"""Camera poses from what a robot publishes: a visual odometry's ``nav_msgs/Odometry``, a
SLAM system's ``geometry_msgs/PoseStamped``, or ``/tf`` and ``/tf_static`` (where
tf2_msgs is installed: a ROS install; the PyPI wheels have none).

:class:`PoseInput` subscribes to the chosen source on a node and answers, for an image's
stamp, the camera's optical frame in the world (:mod:`depth_nodes.core.mvs.poses`: the
nearest pose within a tolerance, never a guess). A pose message that is not a rigid
transform (NaN, a zero quaternion) is a counted ``bad_pose`` drop.

With odometry or a pose topic, the published pose is the body's (its ``child_frame_id``,
or the PoseStamped's own frame): ``camera_in_body`` places the camera's optical frame in it
(identity when the pose is the camera's own). With tf, the lookup chains the edges between
``world_frame`` and the image's frame id (or ``camera_frame``), each moving edge taken at
the image's stamp.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy

from depth_nodes.core.mvs.geometry import Pose
from depth_nodes.core.mvs.poses import PoseHistory, PoseMiss, TimedTransforms
from depth_nodes.errors import ArgumentError, ConfigError
from depth_nodes.ros.params import ParamSpec, one_of

try:  # optional: on a ROS install only
    from nav_msgs.msg import Odometry
except ImportError:  # pragma: no cover (the package's venv has nav_msgs)
    Odometry = None
try:  # a ROS install only (not on PyPI)
    from tf2_msgs.msg import TFMessage
except ImportError:
    TFMessage = None

__all__ = ['POSE_SOURCES', 'PoseInput', 'PoseWaiter', 'pose_parameters']

T = TypeVar('T')

POSE_SOURCES = ('odometry', 'pose', 'tf', 'none')
NS_PER_S = 1_000_000_000
#: /tf_static is latched (transient local), as tf2 publishes it.
TF_STATIC_QOS = QoSProfile(depth=100, durability=QoSDurabilityPolicy.TRANSIENT_LOCAL,
                           reliability=QoSReliabilityPolicy.RELIABLE)


def _check_mount(value: Any) -> str | None:
    try:
        mount_pose(value)
    except ArgumentError as exc:
        return str(exc)
    return None


def pose_parameters(*, allow_none: bool) -> list[ParamSpec]:
    """The parameters of a node's pose input (``allow_none``: ``pose_source: none`` is
    allowed, for a rig that does not move)."""
    sources = POSE_SOURCES if allow_none else POSE_SOURCES[:-1]
    return [
        ParamSpec('pose_source', 'odometry', 'Where the camera poses come from: odometry '
                  '(nav_msgs/Odometry on odom), pose (geometry_msgs/PoseStamped on pose), tf '
                  '(/tf and /tf_static; needs tf2_msgs, a ROS install)' +
                  (' or none (a rig that does not move)' if allow_none else ''),
                  read_only=True, check=one_of(sources)),
        ParamSpec('world_frame', 'odom', 'tf: the fixed frame the camera moves in',
                  read_only=True),
        ParamSpec('camera_frame', '', 'tf: the camera optical frame (empty: the image '
                  "header's frame_id)", read_only=True),
        ParamSpec('camera_in_body', [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], 'odometry, pose: '
                  'the camera optical frame in the frame whose pose is published, x y z (m) '
                  'qx qy qz qw (identity: the pose is the camera\'s own)', read_only=True,
                  check=_check_mount),
        ParamSpec('pose_tolerance', 0.02, 'Largest time between an image and the pose taken '
                  'for it, s', 0.0, 10.0),
        ParamSpec('pose_wait', 0.5, 'Longest an image waits for its pose (by stamps: the '
                  'later images\'), s', 0.0, 60.0),
    ]


def mount_pose(values: Sequence[float]) -> Pose:
    """A pose from ``x y z qx qy qz qw``.

    Raises:
        ArgumentError: Not 7 finite numbers, or a zero quaternion.
    """
    numbers = list(values)
    if len(numbers) != 7 or not all(isinstance(v, (int, float)) and math.isfinite(v)
                                    for v in numbers):
        raise ArgumentError(f'a pose needs 7 finite numbers x y z qx qy qz qw, got {numbers}')
    return Pose.from_quaternion(np.array(numbers[:3]), np.array(numbers[3:]))


def _pose_of(position: Any, orientation: Any) -> Pose:
    return Pose.from_quaternion((position.x, position.y, position.z),
                                (orientation.x, orientation.y, orientation.z, orientation.w))


def _stamp(header: Any) -> int:
    return int(header.stamp.sec) * NS_PER_S + int(header.stamp.nanosec)


class PoseInput:
    """A node's camera poses (see the module notes).

    Args:
        node: The node (a :class:`~depth_nodes.ros.node.DepthNode`): its inputs and drops.
        values: Its parameter values (:func:`pose_parameters`).
        on_pose: Called after every pose (or tf edge) kept: images may wait for it.

    Raises:
        ConfigError: ``pose_source: tf`` where tf2_msgs is not installed.
    """

    def __init__(self, node: Any, values: Any, on_pose: Callable[[], None] | None = None
                 ) -> None:
        self.node = node
        self.on_pose_kept = on_pose or (lambda: None)
        self.source: str = values['pose_source']
        self.world: str = values['world_frame']
        self.camera_frame: str = values['camera_frame']
        self.mount = mount_pose(values['camera_in_body'])
        self.history = PoseHistory()
        self.tree = TimedTransforms()
        if self.source == 'odometry':
            if Odometry is None:  # pragma: no cover (the package's venv has nav_msgs)
                raise ConfigError('pose_source odometry needs nav_msgs')
            node.add_input(Odometry, 'odom', self.on_odometry)
        elif self.source == 'pose':
            node.add_input(PoseStamped, 'pose', self.on_pose)
        elif self.source == 'tf':
            if TFMessage is None:
                raise ConfigError('pose_source tf needs tf2_msgs, which a ROS 2 install has '
                                  'and the PyPI wheels do not: use pose_source odometry or '
                                  'pose (what a VIO or SLAM node publishes)')
            node.add_input(TFMessage, '/tf_static', self.on_tf_static, qos=TF_STATIC_QOS,
                           check_stamps=False)
            node.add_input(TFMessage, '/tf', self.on_tf, qos=100, check_stamps=False)

    def clear(self) -> None:
        """Forget the poses (a time jump)."""
        self.history.clear()
        self.tree.clear()

    def on_odometry(self, msg: Any) -> None:
        """Keep an Odometry message's pose (the body's, ``child_frame_id``, in its header
        frame)."""
        self._keep(msg.header, msg.pose.pose)

    def on_pose(self, msg: Any) -> None:
        """Keep a PoseStamped."""
        self._keep(msg.header, msg.pose)

    def _keep(self, header: Any, pose: Any) -> None:
        try:
            self.history.add(_stamp(header), _pose_of(pose.position, pose.orientation))
        except ArgumentError as exc:
            self.node.drop('bad_pose', f'pose at {_stamp(header) / 1e9:.3f} s skipped: {exc}')
            return
        self.on_pose_kept()

    def on_tf(self, msg: Any) -> None:
        """Keep the moving edges of a tf2_msgs/TFMessage."""
        self._edges(msg, static=False)

    def on_tf_static(self, msg: Any) -> None:
        """Keep the fixed edges of a /tf_static TFMessage."""
        self._edges(msg, static=True)

    def _edges(self, msg: Any, *, static: bool) -> None:
        for tf in msg.transforms:
            t, q = tf.transform.translation, tf.transform.rotation
            try:
                self.tree.set(tf.header.frame_id, tf.child_frame_id, _stamp(tf.header),
                              _pose_of(t, q), static=static)
            except ArgumentError as exc:
                self.node.drop('bad_pose', f'transform {tf.header.frame_id!r} -> '
                               f'{tf.child_frame_id!r} skipped: {exc}')
        self.on_pose_kept()

    def at(self, stamp_ns: int, frame_id: str, tolerance_s: float) -> Pose | PoseMiss:
        """The camera's optical frame in the world at ``stamp_ns`` (``frame_id``: the
        image's, for tf), or why there is none."""
        tolerance = round(tolerance_s * NS_PER_S)
        if self.source == 'none':
            return Pose()
        if self.source == 'tf':
            return self.tree.lookup(self.world, self.camera_frame or frame_id, stamp_ns,
                                    tolerance)
        body = self.history.at(stamp_ns, tolerance)
        return body if isinstance(body, PoseMiss) else body.compose(self.mount)


@dataclass
class _Waiting(Generic[T]):
    stamp: int
    frame_id: str
    item: T


class PoseWaiter(Generic[T]):
    """Frames waiting for their pose, handed on in order once it is known.

    A frame whose pose is still missing waits while the frames after it span at most
    ``pose_wait`` seconds (by their stamps); then it is dropped as ``pose_timeout``, and a
    frame whose pose will not come (``no_pose``, ``bad_pose``: see
    :class:`~depth_nodes.core.mvs.poses.PoseMiss`) is dropped at once.

    Args:
        node: The node (a :class:`~depth_nodes.ros.node.DepthNode`): its drops.
        poses: Its pose input.
        process: Called with each frame's item and pose, in stamp order.
    """

    def __init__(self, node: Any, poses: PoseInput, process: Callable[[T, Pose], None]
                 ) -> None:
        self.node = node
        self.poses = poses
        self.process = process
        self._waiting: deque[_Waiting[T]] = deque()

    def __len__(self) -> int:
        return len(self._waiting)

    def add(self, stamp_ns: int, frame_id: str, item: T, tolerance_s: float,
            wait_s: float) -> None:
        """Queue a frame, then hand on every frame whose pose is known."""
        self._waiting.append(_Waiting(stamp_ns, frame_id, item))
        self.resolve(tolerance_s, wait_s)

    def resolve(self, tolerance_s: float, wait_s: float) -> None:
        """Hand on the waiting frames whose pose is known, in order; drop those whose pose
        will not come."""
        while self._waiting:
            first = self._waiting[0]
            pose = self.poses.at(first.stamp, first.frame_id, tolerance_s)
            if isinstance(pose, PoseMiss):
                waited = (self._waiting[-1].stamp - first.stamp) / NS_PER_S
                if pose.reason == 'pose_pending' and waited <= wait_s:
                    return  # its pose may still come
                self._waiting.popleft()
                reason = 'pose_timeout' if pose.reason == 'pose_pending' else pose.reason
                self.node.drop(reason, f'frame at {first.stamp / 1e9:.3f} s: {pose.detail}')
                continue
            self._waiting.popleft()
            self.process(first.item, pose)

    def clear(self) -> None:
        """Forget the waiting frames without counting them (nobody wants their output)."""
        self._waiting.clear()

    def discard(self, reason: str, why: str) -> None:
        """Drop every waiting frame as ``reason`` (a time jump, the end of the stream)."""
        if self._waiting:
            self.node.drop(reason, f'{len(self._waiting)} frame(s) waiting for a pose {why}',
                           count=len(self._waiting))
        self._waiting.clear()
