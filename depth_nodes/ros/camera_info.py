"""sensor_msgs/CameraInfo <-> :class:`~depth_nodes.core.camera.CameraModel`.

Works on rclpy messages and on rosbags messages (same lower-case field names: ``k``, ``d``,
``r``, ``p``, ``binning_x``, ``roi.x_offset``...).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Generic, TypeVar

import numpy as np
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from depth_nodes.core.camera import CameraModel, StereoModel
from depth_nodes.errors import CalibrationError, UncalibratedError

T = TypeVar('T')


def _matrix(msg: Any, name: str, size: int) -> np.ndarray:
    try:
        arr = np.asarray(getattr(msg, name), dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise CalibrationError(f'CameraInfo {name} is not numeric') from None
    if size > 0 and arr.size != size:
        raise CalibrationError(f'CameraInfo {name} has {arr.size} values, expected {size}')
    return arr.copy()


def camera_info_to_model(msg: Any) -> CameraModel:
    """Convert a CameraInfo message to a validated :class:`CameraModel`.

    Binning and ROI are kept as fields of the model; use :meth:`CameraModel.binned` for the
    model of the delivered image.

    Args:
        msg: An rclpy or rosbags sensor_msgs/CameraInfo.

    Returns:
        The model, with ``frame_id`` taken from the header.

    Raises:
        CalibrationError: The calibration fails
            :func:`~depth_nodes.core.camera.validate_camera` (e.g. all-zero K, which is how
            drivers mark an uncalibrated camera).
    """
    roi = msg.roi
    model = CameraModel(
        width=int(msg.width),
        height=int(msg.height),
        K=_matrix(msg, 'k', 9).reshape(3, 3),
        D=_matrix(msg, 'd', -1),
        R=_matrix(msg, 'r', 9).reshape(3, 3),
        P=_matrix(msg, 'p', 12).reshape(3, 4),
        distortion_model=str(msg.distortion_model),
        binning_x=int(msg.binning_x),
        binning_y=int(msg.binning_y),
        roi=(int(roi.x_offset), int(roi.y_offset), int(roi.width), int(roi.height),
             bool(roi.do_rectify)),
        frame_id=str(msg.header.frame_id),
    )
    try:
        return model.validate()
    except CalibrationError as exc:
        frame = f' (frame {model.frame_id!r})' if model.frame_id else ''
        raise CalibrationError(f'CameraInfo{frame}: {exc}') from None


def model_to_camera_info(model: CameraModel, header: Any = None) -> CameraInfo:
    """Build an rclpy CameraInfo from a model (not validated: an uncalibrated model is legal).

    Args:
        model: The camera.
        header: std_msgs/Header to copy; default one with ``frame_id = model.frame_id``.

    Returns:
        The message.
    """
    msg = CameraInfo()
    msg.header = header if header is not None else Header(frame_id=model.frame_id)
    msg.width, msg.height = int(model.width), int(model.height)
    msg.distortion_model = model.distortion_model
    msg.k = np.asarray(model.K, dtype=np.float64).reshape(9)
    msg.d = np.asarray(model.D, dtype=np.float64).reshape(-1).tolist()
    msg.r = np.asarray(model.R, dtype=np.float64).reshape(9)
    msg.p = np.asarray(model.P, dtype=np.float64).reshape(12)
    msg.binning_x, msg.binning_y = int(model.binning_x), int(model.binning_y)
    x, y, w, h, do_rectify = model.roi
    msg.roi.x_offset, msg.roi.y_offset = int(x), int(y)
    msg.roi.width, msg.roi.height, msg.roi.do_rectify = int(w), int(h), bool(do_rectify)
    return msg


def stereo_model_from_infos(left_msg: Any, right_msg: Any) -> StereoModel:
    """Build a :class:`StereoModel` from the two CameraInfo messages of a rectified pair.

    The models are the effective ones (binning and ROI applied), i.e. those of the images
    the rectifier publishes.

    Args:
        left_msg: Left camera's CameraInfo (rclpy or rosbags).
        right_msg: Right camera's CameraInfo, ``p[3] = -fx * baseline``.

    Returns:
        The validated stereo model.

    Raises:
        CalibrationError: Either camera invalid, rectified fx differ, sizes differ or a
            non-positive baseline.
    """
    left = camera_info_to_model(left_msg).binned()
    right = camera_info_to_model(right_msg).binned()
    return StereoModel(left, right)


def info_key(msg: Any) -> tuple[Any, ...]:
    """Everything of a CameraInfo that the camera model depends on, hashable."""
    return (msg.width, msg.height, msg.distortion_model, tuple(msg.k), tuple(msg.d),
            tuple(msg.r), tuple(msg.p), msg.binning_x, msg.binning_y, msg.roi.x_offset,
            msg.roi.y_offset, msg.roi.width, msg.roi.height)


class InfoCache(Generic[T]):
    """A value built from CameraInfo messages (a model, rectification maps, a projector
    geometry), built again only when a message's content changes: drivers resend the same
    calibration with every frame.

    Args:
        build: Makes the value from the messages; what it raises reaches the caller, and
            the next call tries again.
    """

    def __init__(self, build: Callable[..., T]) -> None:
        self._build = build
        self._key: tuple[Any, ...] | None = None
        self._value: T

    def get(self, *msgs: Any) -> T:
        """The value for ``msgs`` (CameraInfos, rclpy or rosbags)."""
        key = tuple(info_key(m) for m in msgs)
        if key != self._key:
            self._value = self._build(*msgs)
            self._key = key
        return self._value


def _calibrated_stereo(left_msg: Any, right_msg: Any) -> StereoModel:
    if not np.any(np.asarray(left_msg.k)) or not np.any(np.asarray(right_msg.k)):
        raise UncalibratedError('a camera_info has K all zero: the stereo pair is not '
                                'calibrated')
    return stereo_model_from_infos(left_msg, right_msg)


class StereoInfoCache(InfoCache[StereoModel]):
    """The stereo model of a left/right CameraInfo pair (see :class:`InfoCache`); models
    are those of the delivered images (binning and ROI applied).
    """

    def __init__(self) -> None:
        super().__init__(_calibrated_stereo)

    def model(self, left_msg: Any, right_msg: Any) -> StereoModel:
        """The StereoModel of the pair.

        Raises:
            UncalibratedError: A K is all zero.
            CalibrationError: Anything else makes the pair unusable.
        """
        return self.get(left_msg, right_msg)
