"""The plane sweep's depth labels (no ROS; the cameras' poses are
:class:`~depth_nodes.core.geometry.pose.Pose`).

The sweep's labels are planes ``n . X = 1 / rho`` in the reference camera's frame, spaced
evenly in inverse depth ``rho`` (so evenly in image displacement): label 0 is the farthest
plane, label ``planes - 1`` the nearest, like a stereo disparity. A fractional label (the
matcher's sub-plane refinement) maps linearly to inverse depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import ArgumentError

__all__ = ['FRONTO_PARALLEL', 'SweepPlanes']

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]

#: The normal of fronto-parallel planes, in the reference camera's frame.
FRONTO_PARALLEL = (0.0, 0.0, 1.0)


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
