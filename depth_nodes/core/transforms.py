"""Rigid transforms for the camera frames of REP 103 / REP 105 (no ROS).

A camera's *optical* frame has z forward, x right and y down; its body frame (and a
robot's base) has x forward, y left and z up. :func:`camera_transform` gives the
quaternion of a camera mounted at a body orientation, optionally composed with the
body-to-optical rotation, as ``static_transform`` publishes it.
"""

from __future__ import annotations

import math

from depth_nodes.errors import ArgumentError

__all__ = ['OPTICAL_RPY', 'camera_transform', 'quaternion_from_rpy', 'quaternion_multiply']

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
