"""The rigid pose of the package: where a frame (a camera's optical frame, a robot's body)
sits in another (no ROS).

``X_parent = rotation @ X_child + position``: the convention of a tf transform from the
parent frame to the child and of a ``geometry_msgs/Pose``. A camera's :class:`Pose` in the
world places its optical frame there; :meth:`Pose.relative_to` gives the motion between two
cameras that warps and plane sweeps use, :meth:`Pose.compose` chains a mount onto a body.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from depth_nodes.core.geometry.rotation import (
    Quaternion,
    check_rotation,
    quaternion_of,
    rotation_matrix,
)
from depth_nodes.errors import ArgumentError

__all__ = ['Motion', 'Pose']

F64 = NDArray[np.float64]
#: ``(R, t)`` taking points of one frame into another: ``X_to = R @ X_from + t``.
Motion = tuple[F64, F64]


@dataclass(frozen=True)
class Pose:
    """A frame in its parent: ``X_parent = rotation @ X_child + position``.

    Attributes:
        rotation: (3, 3) child -> parent rotation (its columns are the child's axes).
        position: (3,) the child's origin in the parent, metres.
    """

    rotation: F64 = field(default_factory=lambda: np.eye(3))
    position: F64 = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def from_quaternion(cls, position: ArrayLike, quaternion: ArrayLike) -> Pose:
        """A pose from a translation and a quaternion (x, y, z, w), as ROS messages give it.

        Raises:
            ArgumentError: A value that is not finite, or a zero quaternion.
        """
        t = np.asarray(position, dtype=np.float64)
        if t.shape != (3,) or not np.isfinite(t).all():
            raise ArgumentError(f'a position needs 3 finite values, got {tuple(t.ravel())}')
        return cls(rotation_matrix(quaternion), t)

    @classmethod
    def from_values(cls, values: Sequence[Any]) -> Pose:
        """A pose from 7 numbers ``x y z qx qy qz qw`` (a parameter's value).

        Raises:
            ArgumentError: Not 7 finite numbers, or a zero quaternion.
        """
        numbers = list(values)
        if len(numbers) != 7 or not all(
                isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
                and math.isfinite(v) for v in numbers):
            raise ArgumentError(f'a pose needs 7 finite numbers x y z qx qy qz qw, got '
                                f'{numbers}')
        return cls.from_quaternion(np.array(numbers[:3], np.float64),
                                   np.array(numbers[3:], np.float64))

    def validate(self) -> Pose:
        """Check shapes, finiteness and that the rotation is one
        (:func:`~depth_nodes.core.geometry.rotation.check_rotation`); returns self.

        Raises:
            ArgumentError: Naming what is wrong.
        """
        t = np.asarray(self.position)
        if t.shape != (3,) or not np.isfinite(t).all():
            raise ArgumentError(f'a pose needs a finite (3,) position, got shape {t.shape}'
                                + ('' if t.shape != (3,) else ' with NaN or inf'))
        check_rotation(self.rotation, 'a pose\'s rotation')
        return self

    @property
    def quaternion(self) -> Quaternion:
        """The rotation as a unit quaternion (x, y, z, w)."""
        return quaternion_of(self.rotation)

    def inverse(self) -> Pose:
        """The parent's frame seen from the child."""
        r = self.rotation.T
        return Pose(r, -r @ self.position)

    def compose(self, other: Pose) -> Pose:
        """``self * other``: ``other`` given in this frame, expressed in this frame's parent
        (a camera's mount ``other`` on a body at ``self``)."""
        return Pose(self.rotation @ other.rotation,
                    self.rotation @ other.position + self.position)

    def relative_to(self, other: Pose) -> Motion:
        """``(R, t)`` taking points of this frame into ``other``'s:
        ``X_other = R @ X_self + t`` (both poses in the same parent)."""
        rotation = other.rotation.T @ self.rotation
        translation = other.rotation.T @ (self.position - other.position)
        return rotation, translation

    def distance_to(self, other: Pose) -> float:
        """Distance between the two origins, metres."""
        return float(np.linalg.norm(self.position - other.position))

    def angle_to(self, other: Pose) -> float:
        """Angle of the rotation between the two frames, degrees."""
        r = self.rotation.T @ other.rotation
        cosine = (float(np.trace(r)) - 1.0) / 2.0
        return math.degrees(math.acos(min(1.0, max(-1.0, cosine))))
