"""Camera poses and the plane sweep's depth labels (no ROS).

A :class:`Pose` places a camera's optical frame (z forward, x right, y down) in a fixed
world frame: ``X_world = rotation @ X_camera + position``, the convention of a tf
transform from the world to the camera frame and of a ``geometry_msgs/Pose`` of the
camera. :meth:`Pose.relative_to` gives the rigid motion between two cameras that the
plane-sweep homographies use.

The sweep's labels are planes ``n . X = 1 / rho`` in the reference camera's frame, spaced
evenly in inverse depth ``rho`` (so evenly in image displacement): label 0 is the farthest
plane, label ``planes - 1`` the nearest, like a stereo disparity. A fractional label (the
matcher's sub-plane refinement) maps linearly to inverse depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.transforms import rotation_matrix
from depth_nodes.errors import ArgumentError

__all__ = ['FRONTO_PARALLEL', 'Pose', 'SweepPlanes', 'quaternion_of']

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]

#: The normal of fronto-parallel planes, in the reference camera's frame.
FRONTO_PARALLEL = (0.0, 0.0, 1.0)
#: How far a rotation matrix may be from orthonormal (max |R^T R - I|) and still count.
ORTHONORMAL_TOLERANCE = 1e-4


def quaternion_of(rotation: F64) -> tuple[float, float, float, float]:
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


@dataclass(frozen=True)
class Pose:
    """A camera's optical frame in the world: ``X_world = rotation @ X_camera + position``.

    Attributes:
        rotation: (3, 3) camera -> world rotation (its columns are the camera's axes).
        position: (3,) the camera centre in the world, metres.
    """

    rotation: F64 = field(default_factory=lambda: np.eye(3))
    position: F64 = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def from_quaternion(cls, position: tuple[float, float, float] | F64,
                        quaternion: tuple[float, float, float, float] | F64) -> Pose:
        """A pose from a translation and a quaternion (x, y, z, w), as ROS messages give it.

        Raises:
            ArgumentError: A value that is not finite, or a zero quaternion.
        """
        t = np.asarray(position, dtype=np.float64)
        if t.shape != (3,) or not np.isfinite(t).all():
            raise ArgumentError(f'a position needs 3 finite values, got {tuple(t.ravel())}')
        return cls(rotation_matrix(tuple(np.asarray(quaternion, np.float64))), t)

    def validate(self) -> Pose:
        """Check shapes, finiteness and that the rotation is a rotation; returns self.

        Raises:
            ArgumentError: Naming what is wrong.
        """
        r, t = np.asarray(self.rotation), np.asarray(self.position)
        if r.shape != (3, 3) or t.shape != (3,):
            raise ArgumentError(f'a pose needs a (3, 3) rotation and a (3,) position, got '
                                f'{r.shape} and {t.shape}')
        if not (np.isfinite(r).all() and np.isfinite(t).all()):
            raise ArgumentError('a pose must be finite (it holds NaN or inf)')
        if np.abs(r.T @ r - np.eye(3)).max() > ORTHONORMAL_TOLERANCE or np.linalg.det(r) < 0:
            raise ArgumentError('a pose rotation must be orthonormal with determinant +1')
        return self

    @property
    def quaternion(self) -> tuple[float, float, float, float]:
        """The rotation as a unit quaternion (x, y, z, w)."""
        return quaternion_of(self.rotation)

    def inverse(self) -> Pose:
        """The world's frame seen from the camera."""
        r = self.rotation.T
        return Pose(r, -r @ self.position)

    def compose(self, other: Pose) -> Pose:
        """``self * other``: ``other`` given in this frame, expressed in this frame's parent
        (a camera's extrinsics ``other`` on a body at ``self``)."""
        return Pose(self.rotation @ other.rotation,
                    self.rotation @ other.position + self.position)

    def relative_to(self, other: Pose) -> tuple[F64, F64]:
        """``(R, t)`` taking points of this camera's frame into ``other``'s:
        ``X_other = R @ X_self + t``."""
        rotation = other.rotation.T @ self.rotation
        translation = other.rotation.T @ (self.position - other.position)
        return rotation, translation

    def distance_to(self, other: Pose) -> float:
        """Distance between the camera centres, metres."""
        return float(np.linalg.norm(self.position - other.position))

    def angle_to(self, other: Pose) -> float:
        """Angle of the rotation between the two cameras, degrees."""
        r = self.rotation.T @ other.rotation
        cosine = (float(np.trace(r)) - 1.0) / 2.0
        return math.degrees(math.acos(min(1.0, max(-1.0, cosine))))


@dataclass(frozen=True)
class SweepPlanes:
    """The plane hypotheses of a sweep: ``planes`` planes with normal ``normal`` (reference
    frame), evenly spaced in inverse depth between ``min_depth`` and ``max_depth``.

    For the fronto-parallel normal the plane of label k is ``Z = 1 / rho_k``; for another
    normal n it is ``n . X = 1 / rho_k`` (``min_depth`` and ``max_depth`` then bound the
    plane's offset along n, e.g. a camera's height above the ground).
    """

    min_depth: float
    max_depth: float
    planes: int
    normal: tuple[float, float, float] = FRONTO_PARALLEL
    #: Shift of every plane towards the camera, as a fraction of the step (dithering the
    #: planes from one frame to the next spreads the sub-plane refinement's bias).
    offset: float = 0.0

    def validate(self) -> SweepPlanes:
        """Raises ArgumentError naming the first invalid field; returns self."""
        if not (math.isfinite(self.min_depth) and math.isfinite(self.max_depth)
                and 0 < self.min_depth < self.max_depth):
            raise ArgumentError(f'the sweep needs 0 < min_depth < max_depth, finite, got '
                                f'{self.min_depth} and {self.max_depth}')
        if not 0.0 <= self.offset < 1.0:
            raise ArgumentError(f'the planes\' offset must be in [0, 1), got {self.offset}')
        if not 2 <= self.planes <= 4096:
            raise ArgumentError(f'the sweep needs 2 to 4096 planes, got {self.planes}')
        n = np.asarray(self.normal, dtype=np.float64)
        if n.shape != (3,) or not np.isfinite(n).all() or not np.linalg.norm(n) > 1e-9:
            raise ArgumentError(f'a plane normal needs 3 finite values, not all zero, got '
                                f'{self.normal}')
        return self

    @property
    def unit_normal(self) -> F64:
        """The normal scaled to length 1."""
        n = np.asarray(self.normal, dtype=np.float64)
        unit: F64 = n / np.linalg.norm(n)
        return unit

    @property
    def rho_step(self) -> float:
        """Inverse depth between two neighbouring labels, 1/m."""
        return (1.0 / self.min_depth - 1.0 / self.max_depth) / (self.planes - 1)

    @property
    def rho_min(self) -> float:
        """Inverse depth of label 0 (the farthest plane), 1/m."""
        return 1.0 / self.max_depth + self.offset * self.rho_step

    def inverse_depths(self) -> F64:
        """(planes,) inverse depth of each label, farthest first."""
        out: F64 = self.rho_min + self.rho_step * np.arange(self.planes, dtype=np.float64)
        return out

    def rho_of(self, label: NDArray[np.floating]) -> NDArray[np.float64]:
        """Inverse depth (1/m) of fractional labels (NaN stays NaN)."""
        out: NDArray[np.float64] = self.rho_min + self.rho_step * np.asarray(label, np.float64)
        return out

    def label_of(self, rho: NDArray[np.floating]) -> NDArray[np.float64]:
        """Fractional label of inverse depths (the inverse of :meth:`rho_of`)."""
        out: NDArray[np.float64] = (np.asarray(rho, np.float64) - self.rho_min) / self.rho_step
        return out
