"""Poses over time: what a visual odometry or SLAM system publishes, looked up at an
image's stamp (no ROS).

:class:`PoseHistory` keeps the latest poses of one frame in the world (a
``nav_msgs/Odometry`` or ``geometry_msgs/PoseStamped`` stream); :class:`TimedTransforms`
keeps a tf tree whose edges change over time (``/tf``) or not (``/tf_static``) and chains
them. A lookup takes, per moving edge, the value nearest in time to the stamp asked for, and
only within ``tolerance``: a view without a pose that close gets none, never a guess.

A lookup also says why it failed (:class:`PoseMiss`): ``no_pose`` (nothing near that stamp
although later poses exist), ``pose_pending`` (the newest pose is older than the stamp: one
may still come) or ``no_transform`` (the frames are not connected).
"""

from __future__ import annotations

import bisect
from collections import deque
from dataclasses import dataclass

from depth_nodes.core.mvs.geometry import Pose
from depth_nodes.errors import ArgumentError

__all__ = ['PoseHistory', 'PoseMiss', 'TimedTransforms']


@dataclass(frozen=True)
class PoseMiss:
    """Why a lookup found no pose: a short stable ``reason`` and a sentence."""

    reason: str
    detail: str


class PoseHistory:
    """The last ``capacity`` poses of one frame, by stamp.

    Args:
        capacity: Poses kept (older ones are forgotten).
    """

    def __init__(self, capacity: int = 400) -> None:
        if capacity < 1:
            raise ArgumentError(f'a pose history holds at least 1 pose, got {capacity}')
        self._stamps: deque[int] = deque(maxlen=capacity)
        self._poses: deque[Pose] = deque(maxlen=capacity)

    def __len__(self) -> int:
        return len(self._stamps)

    def clear(self) -> None:
        """Forget every pose (a time jump)."""
        self._stamps.clear()
        self._poses.clear()

    @property
    def newest(self) -> int | None:
        """The newest stamp held, ns."""
        return self._stamps[-1] if self._stamps else None

    def add(self, stamp_ns: int, pose: Pose) -> None:
        """Keep ``pose`` at ``stamp_ns`` (validated; poses may come out of order).

        Raises:
            ArgumentError: The pose is not a rigid transform (NaN, not a rotation).
        """
        pose.validate()
        if self._stamps and stamp_ns <= self._stamps[-1]:
            index = bisect.bisect_left(list(self._stamps), stamp_ns)
            if index < len(self._stamps) and self._stamps[index] == stamp_ns:
                self._poses[index] = pose
                return
            stamps, poses = list(self._stamps), list(self._poses)
            stamps.insert(index, stamp_ns)
            poses.insert(index, pose)
            self._stamps = deque(stamps, maxlen=self._stamps.maxlen)
            self._poses = deque(poses, maxlen=self._poses.maxlen)
            return
        self._stamps.append(stamp_ns)
        self._poses.append(pose)

    def at(self, stamp_ns: int, tolerance_ns: int) -> Pose | PoseMiss:
        """The pose nearest to ``stamp_ns`` if within ``tolerance_ns``, else why not."""
        if not self._stamps:
            return PoseMiss('pose_pending', 'no pose received yet')
        stamps = list(self._stamps)
        index = bisect.bisect_left(stamps, stamp_ns)
        nearest = min((i for i in (index - 1, index) if 0 <= i < len(stamps)),
                      key=lambda i: abs(stamps[i] - stamp_ns))
        gap = abs(stamps[nearest] - stamp_ns)
        if gap <= tolerance_ns:
            return self._poses[nearest]
        if stamps[-1] < stamp_ns:
            return PoseMiss('pose_pending', f'the newest pose is '
                            f'{(stamp_ns - stamps[-1]) / 1e9:.3f} s older than the image')
        return PoseMiss('no_pose', f'the nearest pose is {gap / 1e9:.3f} s from the image '
                        f'(tolerance {tolerance_ns / 1e9:g} s)')


class TimedTransforms:
    """A tf tree: static edges (one value) and moving edges (a :class:`PoseHistory` each,
    the child frame's pose in the parent frame).

    Args:
        capacity: Values kept per moving edge.
    """

    def __init__(self, capacity: int = 400) -> None:
        self._static: dict[tuple[str, str], Pose] = {}
        self._moving: dict[tuple[str, str], PoseHistory] = {}
        self._capacity = capacity

    def clear(self) -> None:
        """Forget the moving edges (a time jump); static ones stay."""
        self._moving.clear()

    def set(self, parent: str, child: str, stamp_ns: int, pose: Pose, *,
            static: bool = False) -> None:
        """Where ``child`` sits in ``parent`` at ``stamp_ns`` (``static``: at all times).

        Raises:
            ArgumentError: Empty or equal frame names, or a pose that is not rigid.
        """
        if not parent or not child or parent == child:
            raise ArgumentError(f'a transform needs two different frame names, got '
                                f'{parent!r} and {child!r}')
        pose.validate()
        if static:
            self._static[(parent, child)] = pose
        else:
            self._moving.setdefault((parent, child), PoseHistory(self._capacity)).add(
                stamp_ns, pose)

    def lookup(self, world: str, frame: str, stamp_ns: int,
               tolerance_ns: int) -> Pose | PoseMiss:
        """The pose of ``frame`` in ``world`` at ``stamp_ns``: the chain of edges between
        them, each moving edge taken at that stamp."""
        if world == frame:
            return Pose()
        path = self._path(world, frame)
        if path is None:
            return PoseMiss('no_transform', f'frames {world!r} and {frame!r} are not '
                            'connected on /tf and /tf_static (yet)')
        pose = Pose()
        for parent, child, forward in path:
            key = (parent, child)
            if key in self._static:
                edge: Pose | PoseMiss = self._static[key]
            else:
                edge = self._moving[key].at(stamp_ns, tolerance_ns)
            if isinstance(edge, PoseMiss):
                return PoseMiss(edge.reason, f'{parent} -> {child}: {edge.detail}')
            pose = pose.compose(edge if forward else edge.inverse())
        return pose

    def _path(self, world: str, frame: str) -> list[tuple[str, str, bool]] | None:
        """Edges from ``world`` to ``frame``: (parent, child, walked parent to child)."""
        neighbours: dict[str, list[tuple[str, tuple[str, str, bool]]]] = {}
        for parent, child in [*self._static, *self._moving]:
            neighbours.setdefault(parent, []).append((child, (parent, child, True)))
            neighbours.setdefault(child, []).append((parent, (parent, child, False)))
        previous: dict[str, tuple[str, tuple[str, str, bool]] | None] = {world: None}
        queue = [world]
        while queue:
            node = queue.pop(0)
            if node == frame:
                break
            for nxt, edge in neighbours.get(node, []):
                if nxt not in previous:
                    previous[nxt] = (node, edge)
                    queue.append(nxt)
        if frame not in previous:
            return None
        path = []
        node = frame
        while previous[node] is not None:
            before, edge = previous[node]  # type: ignore[misc]
            path.append(edge)
            node = before
        return path[::-1]

