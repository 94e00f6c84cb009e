"""Rigid transforms for the camera frames of REP 103 / REP 105 (no ROS).

A camera's *optical* frame has z forward, x right and y down; its body frame (and a
robot's base) has x forward, y left and z up. :func:`camera_transform` gives the
quaternion of a camera mounted at a body orientation, optionally composed with the
body-to-optical rotation, as ``static_transform`` publishes it.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import ArgumentError

__all__ = ['OPTICAL_RPY', 'TransformTree', 'camera_transform', 'quaternion_from_rpy',
           'quaternion_multiply', 'rotation_matrix']

#: Roll, pitch, yaw (rad) of the optical frame in the body frame: z forward, x right, y down.
OPTICAL_RPY = (-math.pi / 2, 0.0, -math.pi / 2)

Quaternion = tuple[float, float, float, float]


def quaternion_from_rpy(roll: float, pitch: float, yaw: float) -> Quaternion:
    """(x, y, z, w) of the rotation R = Rz(yaw) Ry(pitch) Rx(roll) (fixed axes, as tf2)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


def quaternion_multiply(a: Quaternion, b: Quaternion) -> Quaternion:
    """The rotation ``a`` then, in its frame, ``b`` (Hamilton product a * b)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def camera_transform(x: float, y: float, z: float, roll: float, pitch: float, yaw: float,
                     *, optical: bool) -> tuple[tuple[float, float, float], Quaternion]:
    """Translation and rotation of a camera frame in its parent: the camera body at
    (x, y, z) with (roll, pitch, yaw), then, with ``optical``, the optical rotation.

    Raises:
        ArgumentError: A value that is not finite.
    """
    values = (x, y, z, roll, pitch, yaw)
    if not all(math.isfinite(v) for v in values):
        raise ArgumentError(f'transform values must be finite, got {values}')
    rotation = quaternion_from_rpy(roll, pitch, yaw)
    if optical:
        rotation = quaternion_multiply(rotation, quaternion_from_rpy(*OPTICAL_RPY))
    return (x, y, z), rotation


def rotation_matrix(quaternion: Quaternion) -> NDArray[np.float64]:
    """The (3, 3) rotation of a quaternion (x, y, z, w), normalised first.

    Raises:
        ArgumentError: A quaternion that is not finite or has zero length.
    """
    q = np.asarray(quaternion, dtype=np.float64)
    norm = float(np.linalg.norm(q)) if np.isfinite(q).all() else 0.0
    if q.shape != (4,) or not norm > 1e-9:
        raise ArgumentError(f'a rotation quaternion needs 4 finite values, not all zero, got '
                            f'{tuple(quaternion)}')
    x, y, z, w = q / norm
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


Rigid = tuple[NDArray[np.float64], NDArray[np.float64]]


class TransformTree:
    """The latest transform of each parent -> child edge (tf2's ``/tf`` and
    ``/tf_static`` content), and the transform between any two connected frames.

    Only the latest value of an edge is kept, with no interpolation in time: meant for
    the fixed extrinsics between a robot's cameras, not for moving frames.
    """

    def __init__(self) -> None:
        self._edges: dict[tuple[str, str], Rigid] = {}

    def set(self, parent: str, child: str, translation: tuple[float, float, float],
            quaternion: Quaternion) -> None:
        """Where ``child`` sits in ``parent``: a point ``p`` of the child frame is
        ``R p + t`` in the parent.

        Raises:
            ArgumentError: Empty or equal frame names, or values that are not finite.
        """
        if not parent or not child or parent == child:
            raise ArgumentError(f'a transform needs two different frame names, got '
                                f'{parent!r} and {child!r}')
        t = np.asarray(translation, dtype=np.float64)
        if t.shape != (3,) or not np.isfinite(t).all():
            raise ArgumentError(f'translation must be 3 finite values, got {tuple(translation)}')
        self._edges[(parent, child)] = (rotation_matrix(quaternion), t)

    def lookup(self, target: str, source: str) -> Rigid | None:
        """``(R, t)`` taking points of frame ``source`` into frame ``target``, or None when
        the two frames are not connected (yet)."""
        if target == source:
            return np.eye(3), np.zeros(3)
        # breadth-first over the edges, both ways; each step maps into the next frame
        neighbours: dict[str, list[tuple[str, Rigid]]] = {}
        for (parent, child), (R, t) in self._edges.items():
            neighbours.setdefault(child, []).append((parent, (R, t)))
            neighbours.setdefault(parent, []).append((child, (R.T, -R.T @ t)))
        found: dict[str, Rigid] = {source: (np.eye(3), np.zeros(3))}
        queue = [source]
        while queue:
            frame = queue.pop(0)
            R0, t0 = found[frame]
            for nxt, (R, t) in neighbours.get(frame, []):
                if nxt not in found:
                    found[nxt] = (R @ R0, R @ t0 + t)
                    if nxt == target:
                        return found[nxt]
                    queue.append(nxt)
        return None
