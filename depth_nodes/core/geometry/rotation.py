"""Rotations: quaternions, roll / pitch / yaw, matrices, and the one test of whether a
matrix is a rotation (no ROS).

Quaternions are ``(x, y, z, w)``, as ROS messages hold them. Frames follow REP 103: a
camera's *optical* frame has z forward, x right and y down; its body frame (and a robot's
base) x forward, y left and z up. :func:`camera_transform` gives a camera mounted at a body
orientation, optionally turned into its optical frame, as ``static_transform`` publishes it.

Every rotation matrix that enters the package (a pose, a warp's motion, a calibration's R)
is held to :data:`ROTATION_TOLERANCE` by :func:`check_rotation`, so a matrix one part takes
is never refused by another.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from depth_nodes.errors import ArgumentError

__all__ = ['OPTICAL_RPY', 'ROTATION_TOLERANCE', 'Quaternion', 'camera_transform',
           'check_rotation', 'quaternion_from_rpy', 'quaternion_multiply', 'quaternion_of',
           'rotation_error', 'rotation_from_vector', 'rotation_matrix', 'rotation_vector']

F64 = NDArray[np.float64]
Quaternion = tuple[float, float, float, float]

#: Roll, pitch, yaw (rad) of the optical frame in the body frame: z forward, x right, y down.
OPTICAL_RPY = (-math.pi / 2, 0.0, -math.pi / 2)
#: Largest ``max |R^T R - I|`` of a matrix that counts as a rotation. Rotations made from
#: quaternions are exact to about 1e-15; a calibration file's R printed to 7 digits is
#: within 1e-6.
ROTATION_TOLERANCE = 1e-6


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


def rotation_matrix(quaternion: ArrayLike) -> F64:
    """The (3, 3) rotation of a quaternion (x, y, z, w), normalised first.

    Raises:
        ArgumentError: A quaternion that is not 4 finite values or has zero length.
    """
    q = np.asarray(quaternion, dtype=np.float64)
    norm = float(np.linalg.norm(q)) if q.shape == (4,) and np.isfinite(q).all() else 0.0
    if not norm > 1e-9:
        raise ArgumentError(f'a rotation quaternion needs 4 finite values, not all zero, got '
                            f'{tuple(q.ravel().tolist())}')
    x, y, z, w = q / norm
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def quaternion_of(rotation: ArrayLike) -> Quaternion:
    """The unit quaternion (x, y, z, w) of a rotation matrix (w >= 0)."""
    m = np.asarray(rotation, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = (s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s)
    sign = -1.0 if q[3] < 0 else 1.0
    norm = math.sqrt(sum(c * c for c in q))
    x, y, z, w = (sign * c / norm for c in q)
    return x, y, z, w


def rotation_error(rotation: ArrayLike) -> float:
    """``max |R^T R - I|`` of a (3, 3) matrix, and infinity where ``det R < 0`` (a
    reflection is no rotation however orthonormal)."""
    r = np.asarray(rotation, dtype=np.float64)
    if np.linalg.det(r) < 0:
        return math.inf
    return float(np.abs(r.T @ r - np.eye(3)).max())


def check_rotation(rotation: ArrayLike, what: str = 'the rotation') -> F64:
    """``rotation`` as a (3, 3) float64 array, checked to be a finite rotation.

    Raises:
        ArgumentError: Naming ``what``: not (3, 3), not finite, not orthonormal within
            :data:`ROTATION_TOLERANCE`, or a reflection.
    """
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3) or not np.isfinite(r).all():
        raise ArgumentError(f'{what} must be a finite (3, 3) matrix, got shape {r.shape}')
    error = rotation_error(r)
    if error > ROTATION_TOLERANCE:
        why = 'a reflection (det < 0)' if math.isinf(error) else \
            f'|R^T R - I| = {error:.3g} > {ROTATION_TOLERANCE:g}'
        raise ArgumentError(f'{what} is not a rotation matrix: {why}')
    return r


def rotation_vector(rotation: ArrayLike) -> F64:
    """The rotation's axis times its angle (radians), the log of the rotation."""
    r = np.asarray(rotation, dtype=np.float64)
    cosine = min(1.0, max(-1.0, (float(np.trace(r)) - 1.0) / 2.0))
    angle = math.acos(cosine)
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if angle < 1e-6:
        return 0.5 * axis  # sin(angle) ~ angle
    if math.pi - angle < 1e-6:  # a half turn: the axis from R + I
        column = int(np.argmax(np.diag(r)))
        vector = r[:, column] + np.eye(3)[column]
        out: F64 = vector / np.linalg.norm(vector) * angle
        return out
    out = axis * (angle / (2.0 * math.sin(angle)))
    return out


def rotation_from_vector(vector: ArrayLike) -> F64:
    """The rotation of an axis times angle (radians): Rodrigues' formula."""
    v = np.asarray(vector, dtype=np.float64)
    angle = float(np.linalg.norm(v))
    if angle < 1e-12:
        return np.eye(3)
    k = v / angle
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    out: F64 = np.eye(3) + math.sin(angle) * cross + (1.0 - math.cos(angle)) * cross @ cross
    return out
