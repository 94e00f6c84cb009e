"""`depth-nodes import-pair`: a real image pair (and its ground truth) as a bag that
`process` runs the graph on and `eval` scores.

The bag has the topics of a generated one (``depth_nodes.tools.bags.generate``), so the shipped
stereo graph runs unchanged:

* ``<ns>/left|right/image_raw`` (rgb8, mono8 or mono16, as the files are) and
  ``<ns>/left|right/camera_info``. A rectified pair gets an identity calibration (no
  distortion, R = I, equal principal points, focal length ``--focal`` and baseline
  ``--baseline``: only disparity is scored, so any values will do), which the rectifier
  passes through pixel for pixel. A raw pair takes the two camera_info YAML files of its
  calibration (``--calibration``); its ground truth must then be in the rectified left
  frame.
* ``<ns>/left/disparity_gt`` (DisparityImage) when a ground truth is given, and
  ``<ns>/left/occlusion_gt`` (0 visible, 255 occluded, 128 outside the right image) when a
  non-occlusion mask is given or can be derived from a right-view ground truth.

The pair is written ``frames`` times, 0.1 s apart, so it can also be played live.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from std_msgs.msg import Header

from depth_nodes.core.camera import CameraModel, read_camera_yaml
from depth_nodes.core.groundtruth import (
    OCCLUDED,
    VISIBLE,
    nonoccluded_from_right,
    read_disparity_file,
    read_image,
)
from depth_nodes.core.stamps import NS_PER_S, stamp_parts
from depth_nodes.errors import CalibrationError, ConfigError, InputFileError
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image
from depth_nodes.tools.bags.io import BagWriter

#: Stamp of the first frame (s) and the period between copies (ns).
FIRST_STAMP_S = 1
PERIOD_NS = 100_000_000


@dataclass(frozen=True)
class PairSource:
    """What to import (see the module notes and ``depth-nodes import-pair --help``)."""

    left: Path
    right: Path
    ground_truth: Path | None = None
    gt_format: str = 'auto'
    gt_scale: float | None = None
    ground_truth_right: Path | None = None
    nonoccluded_mask: Path | None = None
    calibration: tuple[Path, Path] | None = None
    focal: float = 0.0
    baseline: float = 0.1
    namespace: str = '/stereo'
    mono: bool = False
    frames: int = 1


@dataclass(frozen=True)
class ImportSummary:
    """What :func:`import_pair` wrote."""

    size: tuple[int, int]
    encoding: str
    messages: int
    gt_range: tuple[float, float] | None
    occlusion: str | None
    nonoccluded_fraction: float | None

    def format(self, bag: Path) -> str:
        """The lines ``depth-nodes import-pair`` prints."""
        lines = [f'{bag}: {self.size[0]}x{self.size[1]} {self.encoding}, {self.messages} '
                 'messages']
        if self.gt_range is None:
            lines.append('no ground truth: process works, eval needs one')
        else:
            top = self.gt_range[1]
            window = int(np.ceil((top + 1) / 16.0) * 16)
            lines.append(f'ground truth {self.gt_range[0]:.2f}..{top:.2f} px: search at least '
                         f'0..{int(np.ceil(top))} (e.g. disparity_range {window})')
        if self.occlusion is not None and self.nonoccluded_fraction is not None:
            lines.append(f'non-occluded pixels ({self.occlusion}): '
                         f'{self.nonoccluded_fraction:.1%} of those with ground truth')
        return '\n'.join(lines)


def _header(stamp_ns: int, frame_id: str) -> Header:
    header = Header()
    header.stamp.sec, header.stamp.nanosec = stamp_parts(stamp_ns)
    header.frame_id = frame_id
    return header


def _encoding(image: NDArray[np.generic], mono: bool, path: Path) -> tuple[NDArray[np.generic],
                                                                          str]:
    if image.ndim == 3:
        if image.dtype != np.uint8:
            raise InputFileError(f'{path}: colour images must be 8-bit, this one is '
                                 f'{image.dtype}')
        if mono:
            grey = np.rint(image.astype(np.float32) @ np.array([0.299, 0.587, 0.114],
                                                               np.float32))
            return np.clip(grey, 0, 255).astype(np.uint8), 'mono8'
        return image, 'rgb8'
    if image.dtype == np.uint8:
        return image, 'mono8'
    if image.dtype == np.uint16:
        return image, 'mono16'
    raise InputFileError(f'{path}: unsupported pixel type {image.dtype} (8 or 16 bit)')


def _identity_cameras(width: int, height: int, focal: float,
                      baseline: float) -> tuple[CameraModel, CameraModel]:
    f = focal if focal > 0 else float(width)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]], np.float64)
    P = np.hstack([K, np.zeros((3, 1))])
    right_p = P.copy()
    right_p[0, 3] = -f * baseline
    left = CameraModel(width, height, K, np.zeros(5), np.eye(3), P, frame_id='left')
    right = CameraModel(width, height, K.copy(), np.zeros(5), np.eye(3), right_p,
                        frame_id='right')
    return left, right


def _cameras(source: PairSource, width: int, height: int) -> tuple[CameraModel, CameraModel]:
    if source.calibration is None:
        return _identity_cameras(width, height, source.focal, source.baseline)
    models = []
    for side, path in zip(('left', 'right'), source.calibration, strict=True):
        model, _ = read_camera_yaml(path)
        if (model.width, model.height) != (width, height):
            raise CalibrationError(f'{path}: calibrated for {model.width}x{model.height}, '
                                   f'but the images are {width}x{height}')
        models.append(CameraModel(model.width, model.height, model.K, model.D, model.R,
                                  model.P, model.distortion_model, frame_id=side))
    return models[0], models[1]


def _occlusion(source: PairSource, gt: NDArray[np.float32]) -> tuple[NDArray[np.uint8] | None,
                                                                     str | None]:
    if source.nonoccluded_mask is not None:
        mask = read_image(source.nonoccluded_mask)
        if mask.ndim != 2 or mask.shape != gt.shape:
            raise InputFileError(f'{source.nonoccluded_mask}: a non-occlusion mask must be '
                                 f'one channel of {gt.shape[1]}x{gt.shape[0]}, got '
                                 f'{mask.shape[1]}x{mask.shape[0]}'
                                 f'{"" if mask.ndim == 2 else "x" + str(mask.shape[2])}')
        occlusion = np.where(np.asarray(mask, np.float64) > 0, VISIBLE, OCCLUDED).astype(np.uint8)
        return occlusion, f'mask {source.nonoccluded_mask.name}'
    if source.ground_truth_right is not None:
        right = read_disparity_file(source.ground_truth_right, fmt=source.gt_format,
                                    scale=source.gt_scale)
        if right.shape != gt.shape:
            raise InputFileError(f'{source.ground_truth_right}: {right.shape[1]}x'
                                 f'{right.shape[0]}, the left ground truth is {gt.shape[1]}x'
                                 f'{gt.shape[0]}')
        return nonoccluded_from_right(gt, right), 'derived from the right ground truth'
    return None, None


def import_pair(source: PairSource, out: str | Path, *, overwrite: bool = False
                ) -> ImportSummary:
    """Write the bag of ``source`` at ``out`` (see the module notes).

    Raises:
        InputFileError: An image, ground truth or mask cannot be used.
        CalibrationError: A calibration file cannot be used or does not fit the images.
        ConfigError: Bad options (frames, namespace).
        BagError: ``out`` exists (without ``overwrite``) or cannot be written.
    """
    if source.frames < 1:
        raise ConfigError(f'frames must be at least 1, got {source.frames}')
    if not source.namespace.startswith('/') or source.namespace.endswith('/'):
        raise ConfigError(f'namespace must start with / and not end with one, got '
                          f'{source.namespace!r}')
    left_img, encoding = _encoding(read_image(source.left), source.mono, source.left)
    right_img, right_encoding = _encoding(read_image(source.right), source.mono, source.right)
    if left_img.shape != right_img.shape or encoding != right_encoding:
        raise InputFileError(f'{source.right}: {right_img.shape[1]}x{right_img.shape[0]} '
                             f'{right_encoding}, but the left image is {left_img.shape[1]}x'
                             f'{left_img.shape[0]} {encoding}')
    height, width = left_img.shape[:2]
    left_cam, right_cam = _cameras(source, width, height)
    gt = occlusion = None
    occlusion_source = None
    if source.ground_truth is not None:
        gt = read_disparity_file(source.ground_truth, fmt=source.gt_format,
                                 scale=source.gt_scale)
        if gt.shape != (height, width):
            raise InputFileError(f'{source.ground_truth}: {gt.shape[1]}x{gt.shape[0]}, the '
                                 f'images are {width}x{height}')
        if not np.isfinite(gt).any():
            raise InputFileError(f'{source.ground_truth}: no pixel has a ground truth')
        occlusion, occlusion_source = _occlusion(source, gt)
    elif source.ground_truth_right is not None or source.nonoccluded_mask is not None:
        raise ConfigError('a right ground truth or non-occlusion mask needs the left ground '
                          'truth (--gt)')
    ns = source.namespace
    focal = float(left_cam.P[0, 0])
    baseline = float(left_cam.P[0, 3] / left_cam.P[0, 0] - right_cam.P[0, 3] / right_cam.P[0, 0])
    count = 0
    with BagWriter(out, overwrite=overwrite) as writer:
        for i in range(source.frames):
            stamp = FIRST_STAMP_S * NS_PER_S + i * PERIOD_NS
            lh, rh = _header(stamp, left_cam.frame_id), _header(stamp, right_cam.frame_id)
            msgs: list[tuple[str, object]] = [
                (f'{ns}/left/image_raw', array_to_image(left_img, encoding, lh)),
                (f'{ns}/left/camera_info', model_to_camera_info(left_cam, lh)),
                (f'{ns}/right/image_raw', array_to_image(right_img, encoding, rh)),
                (f'{ns}/right/camera_info', model_to_camera_info(right_cam, rh)),
            ]
            if gt is not None:
                finite = gt[np.isfinite(gt)]
                msgs.append((f'{ns}/left/disparity_gt', build_disparity(
                    gt, lh, focal=focal, baseline=baseline,
                    min_disparity=float(np.floor(finite.min())),
                    max_disparity=float(np.ceil(finite.max())), delta_d=0.0)))
            if occlusion is not None:
                msgs.append((f'{ns}/left/occlusion_gt', array_to_image(occlusion, 'mono8', lh)))
            for topic, msg in msgs:
                writer.write(topic, msg, stamp)
                count += 1
    gt_range = None
    fraction = None
    if gt is not None:
        finite = gt[np.isfinite(gt)]
        gt_range = (float(finite.min()), float(finite.max()))
        if occlusion is not None:
            fraction = float(np.mean(occlusion[np.isfinite(gt)] == VISIBLE))
    return ImportSummary((width, height), encoding, count, gt_range, occlusion_source, fraction)
