"""Poses over time: what a visual odometry, a SLAM system or tf publishes, looked up at an
image's stamp (no ROS).

:class:`PoseHistory` keeps the latest poses of one frame (a ``nav_msgs/Odometry`` or
``geometry_msgs/PoseStamped`` stream, or one moving tf edge); :class:`TransformTree` is a tf
tree of static edges (``/tf_static``) and moving ones (``/tf``), chained between any two
frames. A lookup takes, per moving edge, the value nearest in time to the stamp asked for,
and only within a tolerance: a view without a pose that close gets none, never a guess.
Without a tolerance it takes each edge's latest value (fixed extrinsics).

A lookup that fails says why (:class:`PoseMiss`): ``no_pose`` (nothing near that stamp
although later poses exist), ``pose_pending`` (no pose at or after the stamp yet: one may
still come) or ``no_transform`` (the frames are not connected).

**One wild pose costs at most its own frame.** A pose far from where the poses before it
say the frame is (more than ``jump_limit`` metres from the constant-velocity prediction, or
turned more than ``turn_limit_deg`` from the constant-rate one), or stamped more than
:data:`HORIZON_S` ahead of the newest or :data:`BACK_S` behind it, is *held*, not used, until
the next pose shows which it is:

* the next pose continues the poses before it: the held one was an outlier and is rejected
  (:attr:`Added.rejected`), the next one kept;
* the next pose continues from the held one (it lies on the line from the pose before the
  held one, within ``jump_limit`` plus half that step, and within the time window of the
  held one): the frame really moved (a SLAM loop closure, a gap in the stream), both are
  kept; a held pose that went back in time then starts the history over
  (:attr:`Added.restarted`: a looping bag, a restarted source).

A pose not newer than the newest (within :data:`BACK_S`) is dropped as any input out of
order is (:attr:`Added.late`). While a pose is held, a lookup that finds no pose within the
tolerance answers ``pose_pending``.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np

from depth_nodes.core.geometry.pose import Pose
from depth_nodes.core.geometry.rotation import rotation_from_vector, rotation_vector
from depth_nodes.core.stamps import NS_PER_S, STAMP_RESET_S
from depth_nodes.errors import ArgumentError

__all__ = ['BACK_S', 'HORIZON_S', 'Added', 'PoseHistory', 'PoseMiss', 'TransformTree']

#: A pose stamped this many seconds or more after the newest one is held until the next
#: pose says whether the stream jumped ahead or the stamp is wrong.
HORIZON_S = 10.0
#: A pose stamped this many seconds or more before the newest one is held likewise (the
#: stamps of a looping bag, or a wrong stamp); a later one is a late pose, judged at once.
BACK_S = STAMP_RESET_S
#: Least time over which the poses' motion is measured for the prediction, s.
MOTION_BASELINE_S = 0.05


@dataclass(frozen=True)
class PoseMiss:
    """Why a lookup found no pose: a short stable ``reason`` and a sentence."""

    reason: str
    detail: str


@dataclass
class Added:
    """What adding one pose did.

    Attributes:
        kept: Stamps (ns) of the poses that became usable (the one added, and a held one
            it confirmed).
        rejected: ``(stamp ns, why)`` of the poses judged wild and dropped.
        late: ``(stamp ns, why)`` of a pose not newer than the newest (out of order, or a
            repeat), dropped as any input out of order is.
        held: True when the pose added is held until the next one.
        restarted: True when the history started over from a held pose that went back in
            time, confirmed by this one.
    """

    kept: list[int] = field(default_factory=list)
    rejected: list[tuple[int, str]] = field(default_factory=list)
    late: list[tuple[int, str]] = field(default_factory=list)
    held: bool = False
    restarted: bool = False


@dataclass(frozen=True)
class _Held:
    stamp: int
    pose: Pose
    why: str
    #: Held for its stamp, not its motion.
    timed: bool = False
    #: Stamped before the newest pose (a looping bag, or a wrong stamp).
    back: bool = False


class PoseHistory:
    """The last ``capacity`` poses of one frame, by stamp, with wild poses held back (see
    the module notes).

    Args:
        capacity: Poses kept (older ones are forgotten).
        jump_limit: Metres a pose may lie from where the poses before it say it is
            (``inf``: never held for its position).
        turn_limit_deg: Degrees a pose may be turned from where they say it points.

    Raises:
        ArgumentError: A capacity below 1 or a limit that is not positive.
    """

    def __init__(self, capacity: int = 400, *, jump_limit: float = 1.0,
                 turn_limit_deg: float = 30.0) -> None:
        if capacity < 1:
            raise ArgumentError(f'a pose history holds at least 1 pose, got {capacity}')
        if not (jump_limit > 0 and turn_limit_deg > 0):
            raise ArgumentError(f'the pose limits must be positive, got {jump_limit} m and '
                                f'{turn_limit_deg} degrees')
        self._capacity = capacity
        self.jump_limit = jump_limit
        self.turn_limit = math.radians(turn_limit_deg)
        self._stamps: list[int] = []
        self._poses: list[Pose] = []
        self._held: _Held | None = None

    def __len__(self) -> int:
        return len(self._stamps)

    def clear(self) -> None:
        """Forget every pose, the held one too (a time jump)."""
        self._stamps.clear()
        self._poses.clear()
        self._held = None

    @property
    def newest(self) -> int | None:
        """The newest stamp kept, ns."""
        return self._stamps[-1] if self._stamps else None

    @property
    def held(self) -> int | None:
        """The stamp of the pose held until the next one, if any."""
        return self._held.stamp if self._held is not None else None

    def restart_from_held(self) -> bool:
        """Start over from the held pose (the inputs said the stamps jumped back): forget
        the kept poses and keep the held one if it went back in time. True if it did."""
        held = self._held
        self.clear()
        if held is None or not held.back:
            return False
        self._keep(held.stamp, held.pose)
        return True

    def add(self, stamp_ns: int, pose: Pose) -> Added:
        """Offer ``pose`` at ``stamp_ns``; what became of it and of a held one.

        Raises:
            ArgumentError: The pose is not a rigid transform (NaN, not a rotation).
        """
        pose.validate()
        out = Added()
        if self._held is not None:
            self._resolve(stamp_ns, pose, out)
            return out
        why = self._wild(stamp_ns, pose)
        if why is None:
            self._keep(stamp_ns, pose)
            out.kept.append(stamp_ns)
        elif why.startswith('late:'):
            out.late.append((stamp_ns, why[5:]))
        else:
            timed = why.startswith('stamped')
            self._held = _Held(stamp_ns, pose, why, timed, timed and 'before' in why)
            out.held = True
        return out

    def at(self, stamp_ns: int, tolerance_ns: int | None) -> Pose | PoseMiss:
        """The pose nearest to ``stamp_ns`` if within ``tolerance_ns`` (None: the newest
        pose, whatever its stamp), else why not."""
        if not self._stamps:
            return PoseMiss('pose_pending', 'no pose received yet')
        if tolerance_ns is None:
            return self._poses[-1]
        stamps = self._stamps
        index = bisect.bisect_left(stamps, stamp_ns)
        nearest = min((i for i in (index - 1, index) if 0 <= i < len(stamps)),
                      key=lambda i: abs(stamps[i] - stamp_ns))
        gap = abs(stamps[nearest] - stamp_ns)
        if gap <= tolerance_ns:
            return self._poses[nearest]
        if stamps[-1] < stamp_ns:
            return PoseMiss('pose_pending', f'the newest pose is '
                            f'{(stamp_ns - stamps[-1]) / NS_PER_S:.3f} s older than the image')
        if self._held is not None:
            return PoseMiss('pose_pending', 'a pose that jumped is held until the next one')
        return PoseMiss('no_pose', f'the nearest pose is {gap / NS_PER_S:.3f} s from the image '
                        f'(tolerance {tolerance_ns / NS_PER_S:g} s)')

    # ------------------------------------------------------------------ judging
    def _wild(self, stamp: int, pose: Pose) -> str | None:
        """Why ``pose`` is held (or, prefixed ``late:``, dropped as out of order); None: keep
        it."""
        if not self._stamps:
            return None
        newest = self._stamps[-1]
        if stamp - newest >= HORIZON_S * NS_PER_S:
            return f'stamped {(stamp - newest) / NS_PER_S:.3f} s after the newest pose'
        if newest - stamp >= BACK_S * NS_PER_S:
            return f'stamped {(newest - stamp) / NS_PER_S:.3f} s before the newest pose'
        if stamp <= newest:  # a late pose, or a repeat: as any input out of order
            return f'late:stamped {(newest - stamp) / NS_PER_S:.3f} s before the newest pose'
        return self._off_prediction(stamp, pose)

    def _off_prediction(self, stamp: int, pose: Pose) -> str | None:
        """Why ``pose`` is not where the newest poses say the frame is, or None."""
        last, last_pose = self._stamps[-1], self._poses[-1]
        index = self._baseline()
        if index is not None:
            position, rotation = _extrapolate(self._poses[index], self._stamps[index],
                                              last_pose, last, stamp)
        else:
            position, rotation = last_pose.position, last_pose.rotation
        jump = float(np.linalg.norm(pose.position - position))
        if jump > self.jump_limit:
            return f'{jump:.3f} m from where the poses before it put the frame'
        turn = _angle(rotation, pose.rotation)
        if turn > self.turn_limit:
            return (f'turned {math.degrees(turn):.1f} degrees from where the poses before it '
                    'point the frame')
        return None

    def _off_path(self, ta: int, a: Pose, tb: int, b: Pose, tc: int, c: Pose) -> str | None:
        """Why ``b`` (between ``a`` and ``c`` in time) is off their path: farther than
        ``jump_limit`` plus half the step from ``a`` to ``c`` from the point the path has at
        ``tb``, or turned more than ``turn_limit`` plus half the turn from the orientation
        it has there; None when it is on it."""
        share = (tb - ta) / (tc - ta) if tc != ta else 0.5
        expected = a.position + (c.position - a.position) * share
        off = float(np.linalg.norm(b.position - expected))
        if off > self.jump_limit + 0.5 * float(np.linalg.norm(c.position - a.position)):
            return f'{off:.3f} m off the path'
        turn = rotation_vector(a.rotation.T @ c.rotation)
        pointing = a.rotation @ rotation_from_vector(turn * share)
        angle = _angle(pointing, b.rotation)
        if angle > self.turn_limit + 0.5 * float(np.linalg.norm(turn)):
            return f'turned {math.degrees(angle):.1f} degrees off the path'
        return None

    def _resolve(self, stamp: int, pose: Pose, out: Added) -> None:
        """The pose after a held one: say which of the two is wild."""
        held = self._held
        assert held is not None
        self._held = None
        if self._continues(held, stamp, pose):  # both are kept: the frame did move
            if held.back:
                self.clear()
                out.restarted = True
            self._keep(held.stamp, held.pose)
            self._keep(stamp, pose)
            out.kept += [held.stamp, stamp]
            return
        out.rejected.append((held.stamp, held.why))
        again = self.add(stamp, pose)
        out.kept += again.kept
        out.rejected += again.rejected
        out.late += again.late
        out.held = again.held

    def _continues(self, held: _Held, stamp: int, pose: Pose) -> bool:
        """True when ``pose``, the one after ``held``, continues from it rather than from
        the kept poses."""
        newest = self._stamps[-1] if self._stamps else None
        if stamp <= held.stamp or (newest is not None and
                                   abs(stamp - newest) <= abs(stamp - held.stamp)):
            return False  # nearer in time to the kept poses: the held one stands alone
        if newest is not None and not held.timed:  # held for its motion: on the path?
            return self._off_path(newest, self._poses[-1], held.stamp, held.pose, stamp,
                                  pose) is None
        # held for its stamp: the kept poses' motion, carried on from the held one
        velocity = np.zeros(3)
        index = self._baseline()
        if index is not None:
            velocity = (self._poses[-1].position - self._poses[index].position) / (
                (self._stamps[-1] - self._stamps[index]) / NS_PER_S)
        expected = held.pose.position + velocity * ((stamp - held.stamp) / NS_PER_S)
        return float(np.linalg.norm(pose.position - expected)) <= self.jump_limit and \
            _angle(held.pose.rotation, pose.rotation) <= self.turn_limit

    def _baseline(self) -> int | None:
        """The newest kept pose at least :data:`MOTION_BASELINE_S` before the newest: the
        motion is measured between the two (over a shorter span its noise would be
        magnified into the prediction); None when there is none."""
        if not self._stamps:
            return None
        index = bisect.bisect_right(self._stamps,
                                    self._stamps[-1] - MOTION_BASELINE_S * NS_PER_S) - 1
        return index if index >= 0 else None

    # ------------------------------------------------------------------ storage
    def _keep(self, stamp: int, pose: Pose) -> None:
        index = bisect.bisect_left(self._stamps, stamp)
        if index < len(self._stamps) and self._stamps[index] == stamp:
            self._poses[index] = pose  # a repeat replaces
            return
        self._stamps.insert(index, stamp)
        self._poses.insert(index, pose)
        if len(self._stamps) > self._capacity:
            del self._stamps[0]
            del self._poses[0]


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle of the rotation between two orientations, radians."""
    cosine = (float(np.trace(a.T @ b)) - 1.0) / 2.0
    return math.acos(min(1.0, max(-1.0, cosine)))


def _extrapolate(first: Pose, t0: int, last: Pose, t1: int, stamp: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Position and orientation at ``stamp`` if the frame kept the motion from ``first``
    (at ``t0``) to ``last`` (at ``t1``)."""
    if t1 <= t0:
        return last.position, last.rotation
    share = (stamp - t1) / (t1 - t0)
    position = last.position + (last.position - first.position) * share
    step = rotation_vector(first.rotation.T @ last.rotation)
    return position, last.rotation @ rotation_from_vector(step * share)


class TransformTree:
    """A tf tree: static edges (one value) and moving edges (a :class:`PoseHistory` each,
    the child frame's pose in the parent frame).

    Args:
        capacity: Values kept per moving edge.
        jump_limit: A moving edge's :class:`PoseHistory` limit, metres.
        turn_limit_deg: Its turn limit, degrees.
    """

    def __init__(self, capacity: int = 400, *, jump_limit: float = 1.0,
                 turn_limit_deg: float = 30.0) -> None:
        self._static: dict[tuple[str, str], Pose] = {}
        self._moving: dict[tuple[str, str], PoseHistory] = {}
        self._limits = (capacity, jump_limit, turn_limit_deg)

    def clear(self) -> None:
        """Forget the moving edges (a time jump); static ones stay."""
        self._moving.clear()

    def set(self, parent: str, child: str, stamp_ns: int, pose: Pose, *,
            static: bool = False) -> Added:
        """Where ``child`` sits in ``parent`` at ``stamp_ns`` (``static``: at all times).

        Returns:
            What became of a moving edge's value (:meth:`PoseHistory.add`); a static one is
            always kept.

        Raises:
            ArgumentError: Empty or equal frame names, or a pose that is not rigid.
        """
        if not parent or not child or parent == child:
            raise ArgumentError(f'a transform needs two different frame names, got '
                                f'{parent!r} and {child!r}')
        pose.validate()
        if static:
            self._static[(parent, child)] = pose
            return Added(kept=[stamp_ns])
        history = self._moving.get((parent, child))
        if history is None:
            capacity, jump_limit, turn_limit = self._limits
            history = self._moving[(parent, child)] = PoseHistory(
                capacity, jump_limit=jump_limit, turn_limit_deg=turn_limit)
        return history.add(stamp_ns, pose)

    def lookup(self, target: str, source: str, stamp_ns: int = 0,
               tolerance_ns: int | None = None) -> Pose | PoseMiss:
        """The pose of frame ``source`` in frame ``target`` (it takes ``source``'s points
        into ``target``'s) at ``stamp_ns``: the chain of edges between them, each moving
        edge taken at that stamp within ``tolerance_ns`` (None: its latest value)."""
        if target == source:
            return Pose()
        path = self._path(target, source)
        if path is None:
            return PoseMiss('no_transform', f'frames {target!r} and {source!r} are not '
                            'connected on /tf and /tf_static (yet)')
        pose = Pose()
        for parent, child, forward in path:
            key = (parent, child)
            edge: Pose | PoseMiss = self._static[key] if key in self._static else \
                self._moving[key].at(stamp_ns, tolerance_ns)
            if isinstance(edge, PoseMiss):
                return PoseMiss(edge.reason, f'{parent} -> {child}: {edge.detail}')
            pose = pose.compose(edge if forward else edge.inverse())
        return pose

    def _path(self, start: str, goal: str) -> list[tuple[str, str, bool]] | None:
        """Edges from ``start`` to ``goal``: (parent, child, walked parent to child)."""
        neighbours: dict[str, list[tuple[str, tuple[str, str, bool]]]] = {}
        for parent, child in [*self._static, *self._moving]:
            neighbours.setdefault(parent, []).append((child, (parent, child, True)))
            neighbours.setdefault(child, []).append((parent, (parent, child, False)))
        previous: dict[str, tuple[str, tuple[str, str, bool]] | None] = {start: None}
        queue = [start]
        while queue:
            node = queue.pop(0)
            if node == goal:
                break
            for nxt, edge in neighbours.get(node, []):
                if nxt not in previous:
                    previous[nxt] = (node, edge)
                    queue.append(nxt)
        if goal not in previous:
            return None
        path = []
        node = goal
        while (step := previous[node]) is not None:
            node, edge = step
            path.append(edge)
        return path[::-1]
