"""Pinhole camera models with lens distortion, as ROS CameraInfo describes them.

Conventions follow sensor_msgs/CameraInfo: ``K`` is the 3x3 intrinsic matrix of the raw
(distorted) image, ``D`` the distortion coefficients of ``distortion_model``, ``R`` the
rotation from the raw camera frame to the rectified frame (x_rect = R @ x_raw) and ``P`` the
3x4 projection matrix of the rectified camera. For the right camera of a rectified stereo
pair ``P[0, 3] = -fx * baseline``.

Decisions:
    * ``P`` all zero (some drivers publish it so) means "the rectified camera is ``K``":
      :attr:`CameraModel.projection` is then ``[K | 0]``.
    * ``D`` may be empty for any known model, meaning no distortion; otherwise plumb_bob
      needs 5 coefficients, rational_polynomial 8 and equidistant 4.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from depth_nodes.core.geometry.rotation import ROTATION_TOLERANCE, rotation_error
from depth_nodes.errors import CalibrationError, yaml_problem

PLUMB_BOB = 'plumb_bob'
RATIONAL_POLYNOMIAL = 'rational_polynomial'
EQUIDISTANT = 'equidistant'

#: Number of distortion coefficients each supported model takes (an empty D is also valid).
DISTORTION_SIZES: dict[str, int] = {PLUMB_BOB: 5, RATIONAL_POLYNOMIAL: 8, EQUIDISTANT: 4}

FloatArray = NDArray[np.float64]

_FOCAL_RTOL = 1e-6


def _identity3() -> FloatArray:
    return np.eye(3)


@dataclass
class CameraModel:
    """One calibrated camera (the content of a sensor_msgs/CameraInfo, as arrays).

    Attributes:
        width: Full-resolution image width in pixels.
        height: Full-resolution image height in pixels.
        K: (3, 3) raw-image intrinsics.
        D: (n,) distortion coefficients of ``distortion_model``.
        R: (3, 3) rectification rotation, raw camera frame -> rectified frame.
        P: (3, 4) projection matrix of the rectified camera.
        distortion_model: ``plumb_bob``, ``rational_polynomial`` or ``equidistant``.
        binning_x: Horizontal binning (0 and 1 both mean none).
        binning_y: Vertical binning (0 and 1 both mean none).
        roi: (x_offset, y_offset, width, height, do_rectify); width 0 means full image.
        frame_id: Optical frame of the camera.
    """

    width: int
    height: int
    K: FloatArray
    D: FloatArray = field(default_factory=lambda: np.zeros(5))
    R: FloatArray = field(default_factory=_identity3)
    P: FloatArray = field(default_factory=lambda: np.zeros((3, 4)))
    distortion_model: str = PLUMB_BOB
    binning_x: int = 0
    binning_y: int = 0
    roi: tuple[int, int, int, int, bool] = (0, 0, 0, 0, False)
    frame_id: str = ''

    def validate(self) -> CameraModel:
        """Check the calibration; see :func:`validate_camera`. Returns ``self``."""
        validate_camera(self)
        return self

    @property
    def projection(self) -> FloatArray:
        """(3, 4) rectified projection: ``P``, or ``[K | 0]`` when ``P`` is all zero."""
        P = np.asarray(self.P, dtype=np.float64).reshape(3, 4)
        if not P.any():
            P = np.hstack([np.asarray(self.K, dtype=np.float64).reshape(3, 3), np.zeros((3, 1))])
        return P

    @property
    def fx(self) -> float:
        """Rectified focal length along x, in pixels."""
        return float(self.projection[0, 0])

    @property
    def fy(self) -> float:
        """Rectified focal length along y, in pixels."""
        return float(self.projection[1, 1])

    @property
    def cx(self) -> float:
        """Rectified principal point x, in pixels."""
        return float(self.projection[0, 2])

    @property
    def cy(self) -> float:
        """Rectified principal point y, in pixels."""
        return float(self.projection[1, 2])

    @property
    def Tx(self) -> float:  # noqa: N802 (the CameraInfo name)
        """``P[0, 3]``: ``-fx * baseline`` for the right camera of a stereo pair, else 0."""
        return float(self.projection[0, 3])

    @property
    def Ty(self) -> float:  # noqa: N802 (the CameraInfo name)
        """``P[1, 3]``: nonzero only for vertical stereo."""
        return float(self.projection[1, 3])

    @property
    def is_distorted(self) -> bool:
        """True when any distortion coefficient is nonzero."""
        return bool(np.any(np.asarray(self.D) != 0))

    def binned(
        self,
        binning_x: int | None = None,
        binning_y: int | None = None,
        roi: tuple[int, int, int, int, bool] | None = None,
    ) -> CameraModel:
        """Model of the image actually delivered after binning and ROI (as image_geometry).

        The ROI offset (in full-resolution pixels) is subtracted from ``cx``/``cy`` of ``K``
        and ``P``, then rows 0 and 1 of ``K`` and ``P`` are divided by the binning. The size
        becomes the ROI size (full image when the ROI width or height is 0) divided by the
        binning. ``D`` and ``R`` do not change.

        Args:
            binning_x: Horizontal binning; ``None`` uses ``self.binning_x``.
            binning_y: Vertical binning; ``None`` uses ``self.binning_y``.
            roi: (x_offset, y_offset, width, height, do_rectify); ``None`` uses ``self.roi``.

        Returns:
            A new model with binning 0 and an empty ROI, whose ``width``/``height`` are those
            of the delivered image.

        Raises:
            CalibrationError: Negative binning, or an ROI outside the image.
        """
        bx = self.binning_x if binning_x is None else binning_x
        by = self.binning_y if binning_y is None else binning_y
        x0, y0, rw, rh, do_rect = self.roi if roi is None else roi
        if bx < 0 or by < 0:
            raise CalibrationError(f'binning must be >= 0, got binning_x {bx}, binning_y {by}')
        if rw == 0 or rh == 0:
            x0, y0, rw, rh = 0, 0, self.width, self.height
        if x0 < 0 or y0 < 0 or x0 + rw > self.width or y0 + rh > self.height:
            raise CalibrationError(
                f'roi (x_offset {x0}, y_offset {y0}, width {rw}, height {rh}) is outside the '
                f'{self.width}x{self.height} image'
            )
        sx, sy = max(bx, 1), max(by, 1)
        if rw // sx == 0 or rh // sy == 0:
            raise CalibrationError(
                f'binning {bx}x{by} of a {rw}x{rh} image leaves {rw // sx}x{rh // sy} pixels')
        K = np.array(self.K, dtype=np.float64).reshape(3, 3)
        P = np.array(self.P, dtype=np.float64).reshape(3, 4)
        for M in (K, P) if P.any() else (K,):  # an all-zero P keeps meaning [K | 0]
            M[0, 2] -= x0
            M[1, 2] -= y0
            M[0] /= sx
            M[1] /= sy
        return replace(
            self, width=rw // sx, height=rh // sy, K=K, P=P, binning_x=0, binning_y=0,
            roi=(0, 0, 0, 0, bool(do_rect)),
        )


def validate_camera(model: CameraModel) -> None:
    """Raise :class:`CalibrationError` if ``model`` cannot be used for geometry.

    Checks: positive size; K, D, R, P finite and of the right size; K not all zero
    (uncalibrated) with fx, fy > 0; a known distortion model with the right number of
    coefficients; R a proper rotation (orthonormal, det +1, tolerance 1e-6); P either all
    zero (meaning ``[K | 0]``) or with positive fx and fy.

    Args:
        model: The camera to check.

    Raises:
        CalibrationError: Naming the first field found wrong and its value.
    """
    if model.width <= 0 or model.height <= 0:
        raise CalibrationError(f'image size must be positive, got {model.width}x{model.height}')
    arrays: dict[str, FloatArray] = {}
    for name, size in (('K', 9), ('D', -1), ('R', 9), ('P', 12)):
        try:
            arr = np.asarray(getattr(model, name), dtype=np.float64)
        except (TypeError, ValueError):
            raise CalibrationError(f'{name} is not numeric: {getattr(model, name)!r}') from None
        if size > 0 and arr.size != size:
            raise CalibrationError(f'{name} has {arr.size} values, expected {size}')
        if not np.all(np.isfinite(arr)):
            raise CalibrationError(f'{name} has non-finite values: {arr.ravel().tolist()}')
        arrays[name] = arr.reshape(-1)
    K, D, R = arrays['K'].reshape(3, 3), arrays['D'], arrays['R'].reshape(3, 3)
    P = arrays['P'].reshape(3, 4)
    if not K.any():
        raise CalibrationError('K is all zero: the camera is not calibrated')
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CalibrationError(f'K must have fx > 0 and fy > 0, got fx {K[0, 0]}, fy {K[1, 1]}')
    expected = DISTORTION_SIZES.get(model.distortion_model)
    if expected is None:
        raise CalibrationError(
            f'unknown distortion_model {model.distortion_model!r}; '
            f'supported: {", ".join(DISTORTION_SIZES)}'
        )
    if D.size not in (0, expected):
        raise CalibrationError(
            f'distortion_model {model.distortion_model} needs {expected} coefficients in D, '
            f'got {D.size}'
        )
    err = rotation_error(R)
    if err > ROTATION_TOLERANCE:
        raise CalibrationError(
            f'R is not a rotation: |R R^T - I| = {err:.3g}, det(R) = '
            f'{float(np.linalg.det(R)):.6g} (R = {R.ravel().tolist()})'
        )
    if P.any() and (P[0, 0] <= 0 or P[1, 1] <= 0):
        raise CalibrationError(f'P must have fx > 0 and fy > 0, got fx {P[0, 0]}, fy {P[1, 1]}')


@dataclass(frozen=True)
class StereoModel:
    """A rectified stereo pair: the two effective (binned, ROI-applied) camera models.

    With ``delta_cx = cx_right - cx_left`` (zero when rectified with
    ``CALIB_ZERO_DISPARITY``), a point at depth Z has disparity ``d = f * B / Z - delta_cx``,
    i.e. ``Z = f * B / (d + delta_cx)`` (image_geometry's ``getZ``).
    """

    left: CameraModel
    right: CameraModel

    def __post_init__(self) -> None:
        """Validate both cameras and their agreement."""
        self.left.validate()
        self.right.validate()
        if (self.left.width, self.left.height) != (self.right.width, self.right.height):
            raise CalibrationError(
                f'stereo image sizes differ: left {self.left.width}x{self.left.height}, '
                f'right {self.right.width}x{self.right.height}'
            )
        fl, fr = self.left.fx, self.right.fx
        if abs(fl - fr) > _FOCAL_RTOL * max(abs(fl), abs(fr)):
            raise CalibrationError(f'rectified fx differ: left P fx {fl}, right P fx {fr}')
        b = self.baseline
        if not (math.isfinite(b) and b > 0):
            raise CalibrationError(
                f'stereo baseline must be positive and finite, got {b} m '
                f'(left P Tx {self.left.Tx}, right P Tx {self.right.Tx})'
            )

    @property
    def baseline(self) -> float:
        """Baseline in metres: ``-Tx_right / fx_right + Tx_left / fx_left``."""
        return -self.right.Tx / self.right.fx + self.left.Tx / self.left.fx

    @property
    def focal(self) -> float:
        """Rectified focal length (left P fx) in pixels."""
        return self.left.fx

    @property
    def delta_cx(self) -> float:
        """``cx_right - cx_left`` of the rectified cameras, in pixels."""
        return self.right.cx - self.left.cx

    def disparity_to_depth(self, disparity: ArrayLike) -> NDArray[np.floating[Any]]:
        """Depth Z = f * B / (d + delta_cx) in metres; NaN where d + delta_cx <= 0 or NaN.

        Args:
            disparity: Disparities in pixels, any shape (float32 input stays float32).

        Returns:
            Depths of the same shape (a 0-d array for a scalar).
        """
        d = np.asarray(disparity)
        dtype = d.dtype if d.dtype == np.float32 else np.float64
        den = d.astype(np.float64) + self.delta_cx
        with np.errstate(divide='ignore', invalid='ignore'):
            z = np.where(den > 0, self.focal * self.baseline / den, np.nan)
        return z.astype(dtype)

    def depth_to_disparity(self, depth: ArrayLike) -> NDArray[np.floating[Any]]:
        """Disparity d = f * B / Z - delta_cx in pixels; NaN where Z <= 0 or NaN.

        Args:
            depth: Depths in metres, any shape (float32 input stays float32).

        Returns:
            Disparities of the same shape (a 0-d array for a scalar).
        """
        z = np.asarray(depth)
        dtype = z.dtype if z.dtype == np.float32 else np.float64
        z64 = z.astype(np.float64)
        with np.errstate(divide='ignore', invalid='ignore'):
            d = np.where(z64 > 0, self.focal * self.baseline / z64 - self.delta_cx, np.nan)
        return d.astype(dtype)

    @property
    def Q(self) -> FloatArray:  # noqa: N802 (OpenCV's name)
        """(4, 4) reprojection matrix as cv2.stereoRectify returns it.

        ``[X Y Z W]^T = Q [x y d 1]^T`` gives the point in the left rectified camera frame,
        consistent with :meth:`disparity_to_depth`; usable with cv2.reprojectImageTo3D.
        """
        f, b = self.focal, self.baseline
        return np.array(
            [
                [1.0, 0.0, 0.0, -self.left.cx],
                [0.0, 1.0, 0.0, -self.left.cy],
                [0.0, 0.0, 0.0, f],
                [0.0, 0.0, 1.0 / b, self.delta_cx / b],
            ]
        )


# --- camera_calibration_parsers YAML -------------------------------------------------------

_MATRICES = (
    ('camera_matrix', 'K', (3, 3)),
    ('rectification_matrix', 'R', (3, 3)),
    ('projection_matrix', 'P', (3, 4)),
)


def _read_matrix(
    doc: dict[str, Any], key: str, path: Path, shape: tuple[int, int] | None
) -> FloatArray:
    node = doc.get(key)
    if not isinstance(node, dict) or not {'rows', 'cols', 'data'} <= node.keys():
        raise CalibrationError(f'{path}: {key} must be a mapping with rows, cols and data')
    rows, cols, data = node['rows'], node['cols'], node['data']
    if not isinstance(data, list):
        raise CalibrationError(f'{path}: {key}.data must be a list, got {data!r}')
    if shape is not None and (rows, cols) != shape:
        raise CalibrationError(f'{path}: {key} must be {shape[0]}x{shape[1]}, got {rows}x{cols}')
    if not isinstance(rows, int) or not isinstance(cols, int) or rows * cols != len(data):
        raise CalibrationError(
            f'{path}: {key} has {len(data)} values, but rows {rows} x cols {cols}'
        )
    try:
        return np.array(data, dtype=np.float64).reshape(rows, cols)
    except (TypeError, ValueError):
        raise CalibrationError(f'{path}: {key}.data is not numeric: {data!r}') from None


def read_camera_yaml(path: str | Path) -> tuple[CameraModel, str]:
    """Read a camera_calibration_parsers YAML file (as written by camera_calibration).

    ``distortion_model`` may be missing (5 coefficients mean plumb_bob, 8
    rational_polynomial), as may ``camera_name`` (''), ``rectification_matrix`` (identity)
    and ``projection_matrix`` (zero, meaning ``[K | 0]``).

    Args:
        path: The YAML file.

    Returns:
        The validated model and the camera name.

    Raises:
        CalibrationError: Unreadable file, bad YAML, a missing or malformed key, or a
            calibration that fails :func:`validate_camera`; the message names the file.
    """
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text(encoding='utf-8'))
    except OSError as exc:
        raise CalibrationError(f'{path}: cannot read camera calibration: {exc.strerror}') from None
    except yaml.YAMLError as exc:
        raise CalibrationError(f'{path}: invalid YAML: {yaml_problem(exc)}') from None
    if not isinstance(doc, dict):
        raise CalibrationError(f'{path}: expected a YAML mapping, got {type(doc).__name__}')
    for key in ('image_width', 'image_height'):
        if not isinstance(doc.get(key), int):
            raise CalibrationError(f'{path}: {key} must be an integer, got {doc.get(key)!r}')
    mats = {}
    for key, attr, shape in _MATRICES:
        if key in doc or key == 'camera_matrix':
            mats[attr] = _read_matrix(doc, key, path, shape)
    D = _read_matrix(doc, 'distortion_coefficients', path, None)
    if D.shape[0] != 1 and D.size:
        raise CalibrationError(f'{path}: distortion_coefficients must have rows 1, got {D.shape}')
    default_model = {5: PLUMB_BOB, 8: RATIONAL_POLYNOMIAL}.get(D.size, '')
    dist_model = doc.get('distortion_model', default_model)
    model = CameraModel(
        width=doc['image_width'], height=doc['image_height'], K=mats['K'], D=D.reshape(-1),
        R=mats.get('R', np.eye(3)), P=mats.get('P', np.zeros((3, 4))),
        distortion_model=str(dist_model),
    )
    try:
        model.validate()
    except CalibrationError as exc:
        raise CalibrationError(f'{path}: {exc}') from None
    return model, str(doc.get('camera_name') or '')


def write_camera_yaml(path: str | Path, model: CameraModel, camera_name: str = '') -> None:
    """Write ``model`` as a camera_calibration_parsers YAML file (exact float round trip).

    Args:
        path: Destination file (overwritten).
        model: The calibration; validated first. Binning and ROI are not stored (the format
            has no place for them).
        camera_name: Value of ``camera_name``.

    Raises:
        CalibrationError: The model fails :func:`validate_camera`, or the file cannot be
            written.
    """
    model.validate()
    path = Path(path)

    def mat(a: ArrayLike, rows: int, cols: int) -> dict[str, Any]:
        return {'rows': rows, 'cols': cols,
                'data': [float(v) for v in np.asarray(a, dtype=np.float64).ravel()]}

    D = np.asarray(model.D, dtype=np.float64).ravel()
    doc = {
        'image_width': int(model.width),
        'image_height': int(model.height),
        'camera_name': camera_name,
        'camera_matrix': mat(model.K, 3, 3),
        'distortion_model': model.distortion_model,
        'distortion_coefficients': mat(D, 1, D.size),
        'rectification_matrix': mat(model.R, 3, 3),
        'projection_matrix': mat(model.P, 3, 4),
    }
    text = yaml.safe_dump(doc, default_flow_style=None, sort_keys=False, width=10_000)
    try:
        path.write_text(text, encoding='utf-8')
    except OSError as exc:
        raise CalibrationError(f'{path}: cannot write camera calibration: {exc.strerror}'
                               ) from None
