"""The rectified pinhole camera of an image: its intrinsics at one image size, and the two
ways kernels take them (no ROS).

Intrinsics come from the rectified projection ``P`` of the image's CameraInfo (binning
and ROI applied), as image_geometry's ``PinholeCameraModel`` reads them. When the image's
size differs from the CameraInfo's (a depth image registered at another resolution, a
colour image of another size), :func:`intrinsics` scales them to the image, pixel centres
mapping to pixel centres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import CalibrationError

if TYPE_CHECKING:  # core.camera checks its rotations with this package's rotation module
    from depth_nodes.core.camera import CameraModel

__all__ = ['Intrinsics', 'intrinsics']

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Intrinsics:
    """A rectified pinhole camera at one image size (pixel centres are integers).

    Attributes:
        fx: Focal length along x, pixels.
        fy: Focal length along y, pixels.
        cx: Principal point x, pixels.
        cy: Principal point y, pixels.
        width: Image width the values are for.
        height: Image height the values are for.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @property
    def vector(self) -> F64:
        """``(fx, fy, cx, cy)`` as float64: how numba kernels take a camera."""
        return np.array([self.fx, self.fy, self.cx, self.cy], dtype=np.float64)

    @property
    def matrix(self) -> F64:
        """The (3, 3) camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of its images."""
        return self.height, self.width


def intrinsics(camera: CameraModel, shape: tuple[int, int] | None = None) -> Intrinsics:
    """The pinhole intrinsics of the images a CameraInfo describes, optionally scaled to
    another image size.

    Args:
        camera: The camera (``P`` used; binning and ROI applied here).
        shape: (height, width) of the image the intrinsics are for; ``None`` for the
            CameraInfo's own (binned) size. Scaling maps the pixel centres of one size onto
            those of the other: ``cx' = (cx + 0.5) * sx - 0.5``.

    Raises:
        CalibrationError: Focal lengths that are not positive.
    """
    model = camera.binned()
    fx, fy, cx, cy = model.fx, model.fy, model.cx, model.cy
    if not (fx > 0 and fy > 0):
        raise CalibrationError(f'rectified focal lengths must be positive, got fx {fx:g}, '
                               f'fy {fy:g}')
    width, height = int(model.width), int(model.height)
    if shape is None or (int(shape[0]), int(shape[1])) == (height, width):
        return Intrinsics(fx, fy, cx, cy, width, height)
    sy, sx = shape[0] / height, shape[1] / width
    return Intrinsics(fx * sx, fy * sy, (cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5,
                      int(shape[1]), int(shape[0]))
