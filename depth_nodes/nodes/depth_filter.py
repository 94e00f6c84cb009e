"""Depth filter node: post-processing for the depth images of any depth camera (stereo,
time of flight, structured light, this package's or a driver's), in librealsense's order:
decimation, flying pixels, edge-preserving spatial smoothing, temporal smoothing moved with
the camera's motion, hole filling (:mod:`depth_nodes.core.depth_filter`).

Subscribes ``image_rect`` (REP 118: 16UC1 mm or 32FC1 m; raw or, with
``depth_image_transport: compressedDepth``, ``image_rect/compressedDepth``) and
``camera_info``, matched by exact stamp, as depth_image_proc's nodes; with ``noise_model:
sigma`` also ``sigma`` (32FC1 m, multiview_stereo's), with ``noise_model: tof`` also
``confidence`` (32FC1, the tof node's ``confidence/image_rect``). With a ``pose_source``
(``odometry``, ``pose`` or ``tf``: :mod:`depth_nodes.ros.poses`) the temporal stage moves
its memory with the camera; without (``none``, the default) it takes the camera as still.

Publishes, with the depth image's stamp and frame:

* ``filtered/image_rect``: the filtered depth, in the input's encoding (or
  ``depth_encoding``); unknown is NaN (32FC1) or 0 (16UC1);
* ``filtered/camera_info``: its camera (scaled when decimated: K, P, width, height);
* ``filtered/filled``: mono8, 255 where the depth was filled (spatial hole fill, temporal
  persistence, hole filling) rather than measured in this frame, 0 elsewhere;
* ``filtered/sigma``: 32FC1 standard deviation of the depth, metres (NaN unknown), from
  ``noise_model``: ``stereo`` (``stereo_baseline``, ``disparity_sigma``), ``tof``
  (``noise_reference``) or ``sigma``; never published with ``none``.

Every stage's setting (:class:`~depth_nodes.core.depth_filter.DepthFilterParams`) is a
runtime parameter, checked by the core's rules; the inputs, the noise model and the pose
source are read at start-up. A change of frame size, or stamps that jump back, start the
temporal memory over (logged).

Outputs are computed only while subscribed (lazy), or always offline; a filter nobody
listens to forgets its past.

Frames without output are counted and logged with a reason: ``unsupported_encoding`` and
the decoding reasons, ``uncalibrated``, ``bad_calibration``, ``size_mismatch`` (a sigma or
confidence image of another size), ``too_small`` (smaller than the decimation),
``no_pose``, ``pose_timeout``, ``bad_pose``, ``sync_*``, ``time_jump``, ``stream_ended``.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.core.depth_filter import (
    NOISE_MODELS,
    DepthFilter,
    DepthFilterParams,
    FilterResult,
    stereo_sigma,
    tof_sigma,
    warm_up,
)
from depth_nodes.core.depth_image import from_metres
from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.core.stamps import NS_PER_S
from depth_nodes.nodes.depth_common import QUEUE_SIZE, DepthImageNode, depth_transport
from depth_nodes.ros.image import array_to_image
from depth_nodes.ros.params import THREADS, NodeParameters, ParamSpec, one_of, specs_from, validated
from depth_nodes.ros.workers import use_threads

SETTINGS = tuple(f.name for f in fields(DepthFilterParams))
#: Seconds between two warnings that the temporal memory started over.
RESET_LOG_PERIOD_S = 5.0


PARAMETERS = [
    depth_transport('depth_image_transport'),
    *specs_from(DepthFilterParams, SETTINGS),
    ParamSpec('noise_model', 'none', 'Where filtered/sigma comes from: none (not published), '
              'stereo (stereo_baseline, disparity_sigma), tof (the confidence input, '
              'noise_reference) or sigma (a sigma input)', read_only=True,
              check=one_of(NOISE_MODELS)),
    ParamSpec('stereo_baseline', 0.05, 'noise_model stereo: the baseline, metres', 1e-4,
              100.0),
    ParamSpec('disparity_sigma', 0.1, 'noise_model stereo: standard deviation of the '
              'disparity, pixels', 0.0, 100.0),
    ParamSpec('noise_reference', 0.01, 'noise_model tof: the tof node\'s noise_reference '
              '(relative noise at confidence 0.5)', 1e-4, 1.0),
    ParamSpec('depth_encoding', 'same', 'filtered/image_rect: same (as the input), 32FC1 '
              'metres or 16UC1 millimetres', check=one_of(('same', '32FC1', '16UC1'))),
    QUEUE_SIZE,
    THREADS,
]


def _settings(values: Mapping[str, Any]) -> DepthFilterParams:
    return DepthFilterParams(**{name: values[name] for name in SETTINGS})


@dataclass
class _Frame:
    """A frame read and checked, waiting for its pose or filtered at once."""

    header: Any
    info: CameraInfo
    encoding: str
    depth: Any
    sigma: Any
    camera: Intrinsics


def filtered_info(info: CameraInfo, camera: Intrinsics, header: Any) -> CameraInfo:
    """``info`` for the filtered image: itself when the size is the same, else K and P of
    ``camera`` (the decimated intrinsics), with no binning or ROI."""
    out = copy.deepcopy(info)
    out.header = header
    if (info.width, info.height) == (camera.width, camera.height) and \
            not (info.binning_x > 1 or info.binning_y > 1 or info.roi.width):
        return out
    k = np.array([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]])
    p_in = np.asarray(info.p, np.float64).reshape(3, 4)
    p = np.zeros((3, 4))
    p[:, :3] = k
    if p_in[0, 0] > 0:
        p[:, 3] = p_in[:, 3] * camera.fx / p_in[0, 0]  # a stereo camera's Tx = -fx B
    out.width, out.height = camera.width, camera.height
    out.k, out.p = k.reshape(9), p.reshape(12)
    out.binning_x = out.binning_y = 0
    out.roi.x_offset = out.roi.y_offset = out.roi.width = out.roi.height = 0
    out.roi.do_rectify = False
    return out


class DepthFilterNode(DepthImageNode):
    """Depth image + camera_info (+ sigma or confidence, + poses) -> filtered depth,
    camera_info, filled mask, sigma."""

    keeps_state = True

    def __init__(self, node_name: str = 'depth_filter', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS, validated(_settings))
        values = self.params.values
        self.noise_model = values['noise_model']
        warm_up()  # before subscribing: the first live frame then takes a frame's time
        self.filter = DepthFilter()
        self.poses = self.add_pose_input(self._filter, allow_none=True, default_source='none')
        self._last_reset_log = -RESET_LOG_PERIOD_S
        self.resets = 0
        self.pub_depth = self.add_output(Image, 'filtered/image_rect')
        self.pub_info = self.add_output(CameraInfo, 'filtered/camera_info')
        self.pub_filled = self.add_output(Image, 'filtered/filled')
        self.pub_sigma = self.add_output(Image, 'filtered/sigma')
        inputs: list[tuple[Any, ...]] = [
            (Image, 'image_rect', values['depth_image_transport']), (CameraInfo, 'camera_info')]
        if self.noise_model == 'sigma':
            inputs.append((Image, 'sigma'))
        elif self.noise_model == 'tof':
            inputs.append((Image, 'confidence'))
        self.add_synced_inputs(inputs, self.on_frame, queue_size=values['queue_size'])

    # ------------------------------------------------------------------ inputs
    def on_frame(self, depth_msg: Any, info: CameraInfo, noise_msg: Any = None) -> None:
        """One depth image (with its camera_info, and its noise image if any)."""
        outputs = [self.pub_depth, self.pub_info, self.pub_filled]
        if self.noise_model != 'none':  # else it is never published: no reason to filter
            outputs.append(self.pub_sigma)
        if self.skip_unwanted(*(out.wanted for out in outputs)):
            self.filter.reset()  # nobody listens: the temporal memory goes stale
            self.poses.clear()
            return
        read = self.read_depth(depth_msg, 'image_rect')
        if read is None:
            return
        depth, encoding = read
        camera = self.camera(info, 'camera_info', depth.shape)
        if camera is None:
            return
        factor = self.params.values['decimation']
        if camera.width < factor or camera.height < factor:
            self.drop('too_small', f'a {camera.width}x{camera.height} depth image is smaller '
                      f'than the decimation factor {factor}')
            return
        sigma = self._sigma(depth, camera, noise_msg)
        if sigma is False:
            return
        header = copy.deepcopy(depth_msg.header)
        self.poses.submit(header, _Frame(header, info, encoding, depth, sigma, camera))

    def _sigma(self, depth: Any, camera: Intrinsics, noise_msg: Any) -> Any:
        """The depth's standard deviation by the noise model (None: no model); False after
        counting a drop."""
        values = self.params.values
        if self.noise_model == 'none':
            return None
        if self.noise_model == 'stereo':
            return stereo_sigma(depth, camera.fx, values['stereo_baseline'],
                                values['disparity_sigma'])
        what = 'sigma' if self.noise_model == 'sigma' else 'confidence'
        read = self.frame_image(noise_msg, what, depth.shape, ('32FC1',))
        if read is None:
            return False
        pixels = read[0]
        if self.noise_model == 'sigma':
            with np.errstate(invalid='ignore'):
                return np.where(pixels >= 0, pixels, np.nan).astype(np.float32)
        return tof_sigma(depth, pixels, values['noise_reference'])

    # ------------------------------------------------------------------ work
    def _filter(self, frame: _Frame, pose: Pose | None) -> None:
        values = self.params.values
        use_threads(values['threads'])
        result = self.filter.process(frame.depth, frame.camera, _settings(values),
                                     sigma=frame.sigma, pose=pose)
        if result.reset is not None:
            self._reset(result.reset)
        self._publish(frame, result)

    def _reset(self, why: str) -> None:
        self.resets += 1
        now = self.get_clock().now().nanoseconds / NS_PER_S
        if now - self._last_reset_log >= RESET_LOG_PERIOD_S:
            self._last_reset_log = now
            self.get_logger().warning(f'temporal filter started over ({self.resets} so far): '
                                      f'{why}')

    def _publish(self, frame: _Frame, result: FilterResult) -> None:
        values = self.params.values
        header = frame.header
        if self.pub_depth.wanted:
            encoding = frame.encoding if values['depth_encoding'] == 'same' else \
                values['depth_encoding']
            self.pub_depth.publish(array_to_image(from_metres(result.depth, encoding),
                                                  encoding, header))
        if self.pub_info.wanted:
            self.pub_info.publish(filtered_info(frame.info, result.camera, header))
        if self.pub_filled.wanted:
            self.pub_filled.publish(array_to_image(
                np.where(result.filled, 255, 0).astype(np.uint8), 'mono8', header))
        if self.pub_sigma.wanted and result.sigma is not None:
            self.pub_sigma.publish(array_to_image(result.sigma, '32FC1', header))

    # ------------------------------------------------------------------ hooks
    def on_time_jump(self) -> None:
        """The stamps went back (a looping bag): start over."""
        self.filter.reset()
        self._reset('the stamps jumped back')
