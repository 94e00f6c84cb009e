"""Poses and transforms from what a robot publishes, for the node base: a visual odometry's
``nav_msgs/Odometry``, a SLAM system's ``geometry_msgs/PoseStamped``, or ``/tf`` and
``/tf_static`` (where tf2_msgs is installed: a ROS install; the PyPI wheels have none).

A node never subscribes to poses itself: it calls :meth:`DepthNode.add_pose_input
<depth_nodes.ros.node.DepthNode.add_pose_input>` with the function that processes a frame,
and hands each frame to :meth:`PoseInput.submit`. The :class:`PoseInput` owns the rest:

* the parameters (:func:`pose_parameters`: the source, the frames, the tolerances, the
  limits of a plausible step), read through their own snapshot;
* the subscription to the chosen source, and the poses kept
  (:class:`~depth_nodes.core.geometry.timed.PoseHistory`, or the tf tree), each looked up
  at a frame's stamp within ``pose_tolerance``, never a guess;
* the frames waiting for their pose, handed to the node in stamp order once it is known
  (a frame waits while the frames after it span at most ``pose_wait`` seconds);
* the drops: ``no_pose``, ``pose_timeout``, ``no_transform``, and ``bad_pose`` for a pose
  message that is not a rigid transform or that the history judged wild (a stamp an hour
  ahead, a 100 m jump: it costs at most its own frame, and the stream carries on);
* starting over: when the inputs' stamps jump back (a looping bag), or the poses' own
  stamps do and the next pose confirms it, the poses and the waiting frames are dropped
  and the node's ``on_time_jump`` hook runs, once.

With odometry or a pose topic, the published pose is the body's (its ``child_frame_id``, or
the PoseStamped's own frame): ``camera_in_body`` places the camera's optical frame in it
(identity when the pose is the camera's own). With tf, the lookup chains the edges between
``world_frame`` and the image's frame id (or ``camera_frame``), each moving edge taken at
the image's stamp. :class:`TfInput` alone (``register_depth``) keeps the tf tree and looks
up the latest transform between two frames.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from geometry_msgs.msg import PoseStamped
from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy

from depth_nodes.core.geometry import Added, Pose, PoseHistory, PoseMiss, TransformTree
from depth_nodes.core.stamps import NS_PER_S, stamp_ns
from depth_nodes.errors import ArgumentError, ConfigError
from depth_nodes.ros.params import NodeParameters, ParamSpec, one_of

if TYPE_CHECKING:
    from depth_nodes.ros.node import DepthNode

try:  # optional: on a ROS install only
    from nav_msgs.msg import Odometry
except ImportError:  # pragma: no cover (the package's venv has nav_msgs)
    Odometry = None
try:  # a ROS install only (not on PyPI)
    from tf2_msgs.msg import TFMessage
except ImportError:
    TFMessage = None

__all__ = ['POSE_SOURCES', 'TF_STATIC_QOS', 'PoseInput', 'TFMessage', 'TfInput',
           'pose_parameters']

T = TypeVar('T')

POSE_SOURCES = ('odometry', 'pose', 'tf', 'none')
#: /tf_static is latched (transient local), as tf2 publishes and reads it.
TF_STATIC_QOS = QoSProfile(depth=100, durability=QoSDurabilityPolicy.TRANSIENT_LOCAL,
                           reliability=QoSReliabilityPolicy.RELIABLE)
#: /tf's depth, as tf2's listener subscribes.
TF_DEPTH = 100


def _check_mount(value: Any) -> str | None:
    try:
        Pose.from_values(value)
    except ArgumentError as exc:
        return str(exc)
    return None


def pose_parameters(*, allow_none: bool, default_source: str = 'odometry') -> list[ParamSpec]:
    """The parameters of a node's pose input (``allow_none``: ``pose_source: none`` is
    allowed: a still camera, or a rig that does not move)."""
    sources = POSE_SOURCES if allow_none else POSE_SOURCES[:-1]
    return [
        ParamSpec('pose_source', default_source, 'Where the camera poses come from: odometry '
                  '(nav_msgs/Odometry on odom), pose (geometry_msgs/PoseStamped on pose), tf '
                  '(/tf and /tf_static; needs tf2_msgs, a ROS install)' +
                  (' or none (the camera does not move)' if allow_none else ''),
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
        ParamSpec('pose_jump_limit', 1.0, 'A pose farther than this from where the poses '
                  'before it put the camera is held until the next pose says whether the '
                  'camera jumped (kept) or the pose is wild (dropped), m', 1e-3, 1e6,
                  read_only=True),
        ParamSpec('pose_turn_limit', 30.0, 'The same for a pose turned more than this from '
                  'where the poses before it point the camera, degrees', 0.1, 180.0,
                  read_only=True),
    ]


def _count(node: DepthNode, added: Added, what: str) -> None:
    """Count the poses a history dropped: ``bad_pose`` (wild), ``stamp_out_of_order``."""
    for stamp, why in added.rejected:
        node.drop('bad_pose', f'{what} at {stamp / NS_PER_S:.3f} s skipped: {why}')
    for stamp, why in added.late:
        node.drop('stamp_out_of_order', f'{what} at {stamp / NS_PER_S:.3f} s skipped: {why}')


@dataclass
class _Waiting(Generic[T]):
    stamp: int
    frame_id: str
    item: T


class TfInput:
    """``/tf`` and ``/tf_static`` kept in a :class:`TransformTree` on a node.

    Args:
        node: The node (its inputs and drops).
        on_change: Called with what each moving edge's value did (kept, held, rejected),
            and with ``None`` after static edges came.
        jump_limit: Metres a moving edge may jump before it is held.
        turn_limit_deg: Degrees it may turn before it is held.

    Raises:
        ConfigError: tf2_msgs is not installed.
    """

    def __init__(self, node: DepthNode, on_change: Callable[[Added | None], None] | None = None,
                 *, jump_limit: float = 1.0, turn_limit_deg: float = 30.0) -> None:
        if TFMessage is None:
            raise ConfigError('reading /tf needs tf2_msgs, which a ROS 2 install has and the '
                              'PyPI wheels do not')
        self._node = node
        self._on_change = on_change or (lambda added: None)
        self.tree = TransformTree(jump_limit=jump_limit, turn_limit_deg=turn_limit_deg)
        node.add_input(TFMessage, '/tf_static', self.on_tf_static, qos=TF_STATIC_QOS,
                       check_stamps=False)
        node.add_input(TFMessage, '/tf', self.on_tf, qos=TF_DEPTH, check_stamps=False)

    def on_tf(self, msg: Any) -> None:
        """Keep the moving edges of a tf2_msgs/TFMessage."""
        for tf in msg.transforms:
            added = self._set(tf, static=False)
            if added is not None:
                self._on_change(added)

    def on_tf_static(self, msg: Any) -> None:
        """Keep the fixed edges of a /tf_static TFMessage."""
        for tf in msg.transforms:
            self._set(tf, static=True)
        self._on_change(None)

    def _set(self, tf: Any, *, static: bool) -> Added | None:
        parent, child = tf.header.frame_id, tf.child_frame_id
        t, q = tf.transform.translation, tf.transform.rotation
        try:
            added = self.tree.set(parent, child, 0 if static else stamp_ns(tf.header),
                                  Pose.from_quaternion((t.x, t.y, t.z), (q.x, q.y, q.z, q.w)),
                                  static=static)
        except ArgumentError as exc:
            self._node.drop('bad_pose', f'transform {parent!r} -> {child!r} skipped: {exc}')
            return None
        _count(self._node, added, f'transform {parent!r} -> {child!r}')
        return added

    def lookup(self, target: str, source: str, stamp: int = 0,
               tolerance_ns: int | None = None) -> Pose | PoseMiss:
        """The pose of frame ``source`` in frame ``target`` (at ``stamp`` within
        ``tolerance_ns``; None: each edge's latest value)."""
        return self.tree.lookup(target, source, stamp, tolerance_ns)

    def clear(self) -> None:
        """Forget the moving edges (a time jump)."""
        self.tree.clear()


class PoseInput(Generic[T]):
    """A node's camera poses, and its frames waiting for them (see the module notes).

    Args:
        node: The node.
        process: Called with each frame's item and its camera pose (None with
            ``pose_source: none``), in stamp order.
        allow_none: ``pose_source: none`` is allowed.
        default_source: The default of ``pose_source``.

    Raises:
        ConfigError: A start-up value the parameters refuse, or ``pose_source: tf`` where
            tf2_msgs is not installed.
    """

    def __init__(self, node: DepthNode, process: Callable[[T, Pose | None], None], *,
                 allow_none: bool, default_source: str = 'odometry') -> None:
        self._node = node
        self._process = process
        self.params = NodeParameters(node, pose_parameters(allow_none=allow_none,
                                                           default_source=default_source))
        values = self.params.values
        self.source: str = values['pose_source']
        self.world: str = values['world_frame']
        #: The frame the poses are given in: the last odometry's or pose's header frame,
        #: or ``world_frame`` with tf (and before any pose came).
        self.pose_frame: str = self.world
        self.camera_frame: str = values['camera_frame']
        self.mount = Pose.from_values(values['camera_in_body'])
        limits = {'jump_limit': values['pose_jump_limit'],
                  'turn_limit_deg': values['pose_turn_limit']}
        self.history = PoseHistory(**limits)
        self.tf: TfInput | None = None
        self._waiting: deque[_Waiting[T]] = deque()
        self._restarting = False
        if self.source == 'odometry':
            if Odometry is None:  # pragma: no cover (the package's venv has nav_msgs)
                raise ConfigError('pose_source odometry needs nav_msgs')
            node.add_input(Odometry, 'odom', self.on_odometry, check_stamps=False)
        elif self.source == 'pose':
            node.add_input(PoseStamped, 'pose', self.on_pose, check_stamps=False)
        elif self.source == 'tf':
            if TFMessage is None:
                raise ConfigError('pose_source tf needs tf2_msgs, which a ROS 2 install has '
                                  'and the PyPI wheels do not: use pose_source odometry or '
                                  'pose (what a VIO or SLAM node publishes)')
            self.tf = TfInput(node, self._tf_changed, **limits)

    # ------------------------------------------------------------------ frames
    def submit(self, header: Any, item: T) -> None:
        """A frame (its header, and what the node needs to process it): processed at once
        with ``pose_source: none``, else queued until its pose is known."""
        if self.source == 'none':
            self._process(item, None)
            return
        self._waiting.append(_Waiting(stamp_ns(header), header.frame_id, item))
        self.resolve()

    def resolve(self) -> None:
        """Hand on the waiting frames whose pose is known, in order; drop those whose pose
        will not come."""
        values = self.params.values
        tolerance, wait = round(values['pose_tolerance'] * NS_PER_S), values['pose_wait']
        while self._waiting:
            first = self._waiting[0]
            pose = self.at(first.stamp, first.frame_id, tolerance)
            if isinstance(pose, PoseMiss):
                waited = (self._waiting[-1].stamp - first.stamp) / NS_PER_S
                if pose.reason == 'pose_pending' and waited <= wait:
                    return  # its pose may still come
                self._waiting.popleft()
                reason = 'pose_timeout' if pose.reason == 'pose_pending' else pose.reason
                self._node.drop(reason, f'frame at {first.stamp / NS_PER_S:.3f} s: '
                                f'{pose.detail}')
                continue
            self._waiting.popleft()
            self._process(first.item, pose)

    def at(self, stamp: int, frame_id: str, tolerance_ns: int) -> Pose | PoseMiss:
        """The camera's optical frame in the world at ``stamp`` (``frame_id``: the image's,
        for tf), or why there is none."""
        if self.source == 'none':
            return Pose()
        if self.tf is not None:
            return self.tf.lookup(self.world, self.camera_frame or frame_id, stamp,
                                  tolerance_ns)
        body = self.history.at(stamp, tolerance_ns)
        return body if isinstance(body, PoseMiss) else body.compose(self.mount)

    def __len__(self) -> int:
        """Frames waiting for their pose."""
        return len(self._waiting)

    # ------------------------------------------------------------------ poses
    def on_odometry(self, msg: Any) -> None:
        """Keep an Odometry message's pose (the body's, ``child_frame_id``, in its header
        frame)."""
        self._keep(msg.header, msg.pose.pose)

    def on_pose(self, msg: Any) -> None:
        """Keep a PoseStamped."""
        self._keep(msg.header, msg.pose)

    def _keep(self, header: Any, pose: Any) -> None:
        stamp = stamp_ns(header)
        p, q = pose.position, pose.orientation
        try:
            added = self.history.add(stamp, Pose.from_quaternion(
                (p.x, p.y, p.z), (q.x, q.y, q.z, q.w)))
        except ArgumentError as exc:
            self._node.drop('bad_pose', f'pose at {stamp / NS_PER_S:.3f} s skipped: {exc}')
            return
        _count(self._node, added, 'pose')
        if added.kept:
            self.pose_frame = header.frame_id or self.pose_frame
        self._changed(added, stamp)

    def _tf_changed(self, added: Added | None) -> None:
        if added is None:  # static edges
            self.resolve()
            return
        self._changed(added, added.kept[-1] if added.kept else 0)

    def _changed(self, added: Added, stamp: int) -> None:
        if added.restarted:  # the poses' stamps went back, and the next pose agrees
            self._restarting = True
            try:
                self._node.input_set.restart(stamp, 'the pose stamps jumped back')
            finally:
                self._restarting = False
        if added.kept or added.rejected:
            self.resolve()

    # ------------------------------------------------------------------ the node's hooks
    def on_time_jump(self, stamp: int | None) -> None:
        """The inputs started over at ``stamp`` (called by the node base): the waiting
        frames are dropped as ``time_jump``, and the poses forgotten, but for a held pose
        that went back in time with the images (the first of the new timeline)."""
        self.discard('time_jump', 'discarded when the stamps jumped back')
        if self._restarting:  # this input's own restart: its history is the new timeline
            return
        if not self.history.restart_from_held():
            self.history.clear()
        if self.tf is not None:
            self.tf.clear()

    def clear(self) -> None:
        """Forget the waiting frames without counting them (nobody wants their output)."""
        self._waiting.clear()

    def discard(self, reason: str, why: str) -> None:
        """Drop every waiting frame as ``reason`` (a time jump, the end of the stream)."""
        if self._waiting:
            self._node.drop(reason, f'{len(self._waiting)} frame(s) waiting for a pose {why}',
                            count=len(self._waiting))
        self._waiting.clear()
