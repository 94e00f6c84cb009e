"""SGM stereo node: census Semi-Global Matching, a drop-in for stereo_image_proc's
DisparityNode.

Subscribes ``left/image_rect``, ``right/image_rect``, ``left/camera_info`` and
``right/camera_info`` (exact stamps by default; ``approximate_sync`` for the
ApproximateTime policy). Publishes ``disparity`` (stereo_msgs/DisparityImage, left view),
``disparity_right`` (DisparityImage in the right view: x_left = x_right + d) and
``cost_ratio`` (sensor_msgs/Image 32FC1, best / second-best aggregated cost of the left
winner: low means unambiguous), the signals the cross-check node needs.

Parameters share stereo_image_proc's names where the meaning is the same (min_disparity,
disparity_range, uniqueness_ratio, P1, P2, speckle_size, speckle_range, disp12_max_diff,
queue_size, approximate_sync, and for the ``opencv`` backend correlation_window_size,
full_dp, prefilter_cap); all but the synchronisation ones change at runtime and apply from
the next frame. ``backend: opencv`` runs OpenCV's StereoSGBM for comparison (it publishes
``disparity`` only).

The census matcher's ``disparity`` is checked like StereoSGBM's: uniqueness, a left-right
check against the right view taken from the same volume (``disp12_max_diff``), speckle
removal. Its left border strip, where the match may lie outside the right image, takes
the disparity its neighbours carry in (``border_cost``) up to ``border_extrapolation`` x
disparity_range px past the border; beyond that the pixels are invalid.

Frames without output are counted and logged with a reason: ``size_mismatch``,
``encoding_mismatch``, ``unsupported_encoding``, ``malformed_image``, ``uncalibrated``,
``bad_calibration``, ``camera_info_mismatch`` (camera_info size differs from the image),
``range_too_wide`` (the disparity window does not fit the image), ``sync_*``, and
``match_failed`` (the matcher raised; not expected, but never silent).

``parallel_frames`` > 1 matches that many frames at once on worker threads (each with its
own matcher and buffers) and publishes them in stamp order (``ros/workers.py``); the
offline harness always matches frame by frame.
"""

from __future__ import annotations

import queue
import sys
import time
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np
from sensor_msgs.msg import CameraInfo, Image
from stereo_msgs.msg import DisparityImage

from depth_nodes.core.baseline import SgbmSettings, opencv_sgbm
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.core.sgm.aggregate import VERTICAL_DIRECTIONS
from depth_nodes.core.sgm.cost import OUT_OF_RANGE_COST
from depth_nodes.core.sgm.select import SUBPIXEL_MODES, SUBPIXEL_STEP
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image
from depth_nodes.ros.node import DepthNode, run_node
from depth_nodes.ros.params import IMAGE_TRANSPORT, NodeParameters, ParamSpec
from depth_nodes.ros.workers import OrderedWorkers, use_threads

BACKENDS = ('census_sgm', 'opencv')


def _one_of(choices: tuple[str, ...] | list[str]) -> Any:
    def check(value: Any) -> str | None:
        return None if value in choices else f'must be one of {", ".join(map(str, choices))}'
    return check


def _odd(value: int) -> str | None:
    return None if value % 2 == 1 else 'must be odd'


def _paths(value: int) -> str | None:
    return None if value in VERTICAL_DIRECTIONS else 'must be 4, 5, 8 or 16'


PARAMETERS = [
    IMAGE_TRANSPORT,
    ParamSpec('queue_size', 5, 'Synchroniser queue of the four inputs', 1, 1000,
              read_only=True),
    ParamSpec('approximate_sync', False, 'Match inputs by the ApproximateTime policy '
              'instead of exact stamps', read_only=True),
    ParamSpec('approximate_sync_tolerance_seconds', 0.0, 'Largest stamp spread of a set '
              'with approximate_sync (0: no limit)', 0.0, 10.0, read_only=True),
    ParamSpec('backend', 'census_sgm', 'census_sgm (this package) or opencv (StereoSGBM)',
              check=_one_of(BACKENDS)),
    ParamSpec('min_disparity', 0, 'Smallest disparity searched, px (may be negative)',
              -2048, 2048),
    ParamSpec('disparity_range', 128, 'Number of disparities searched (any number with '
              'census_sgm, a multiple of 16 with opencv)', 1, 4096),
    ParamSpec('P1', 18.0, 'Penalty of a 1 px disparity change between neighbours',
              0.0, 4000.0),
    ParamSpec('P2', 220.0, 'Penalty of a larger disparity change (>= P1)', 0.0, 7936.0),
    ParamSpec('uniqueness_ratio', 10.0, 'Percent by which the best cost must beat the best '
              'non-neighbouring disparity', 0.0, 99.0),
    ParamSpec('paths', 8, 'Aggregation paths: 4, 5 (one pass), 8 or 16', 4, 16, check=_paths),
    ParamSpec('census_width', 5, 'Census window width (odd)', 3, 9, check=_odd),
    ParamSpec('census_height', 5, 'Census window height (odd)', 3, 9, check=_odd),
    ParamSpec('census_weight', 1, 'Weight of the census Hamming cost', 0, 8),
    ParamSpec('intensity_weight', 1, 'Weight of the intensity cost (0: census only)', 0, 8),
    ParamSpec('intensity_cost', 'bt', 'Intensity cost: bt (Birchfield-Tomasi) or ad',
              check=_one_of(('bt', 'ad'))),
    ParamSpec('intensity_truncation', 30, 'Cap of the intensity cost, grey levels', 1, 255),
    ParamSpec('p2_adaptive_scale', 8.0, 'Grey-level scale of the image-adaptive P2 (0: '
              'constant P2)', 0.0, 255.0),
    ParamSpec('subpixel', 'parabola', 'Sub-pixel refinement: parabola, equiangular or none',
              check=_one_of(list(SUBPIXEL_MODES))),
    ParamSpec('median_filter', False, '3x3 median on the left disparity'),
    ParamSpec('match_brightness', True, 'census_sgm: give the right image the left\'s mean '
              'and spread before the intensity cost (a gain or offset between the cameras)'),
    ParamSpec('border_cost', 3.5, 'census_sgm: cost of a disparity whose match is outside '
              'the right image, in units of the frame\'s mean best cost; the left border '
              'strip then takes its neighbours\' disparity (0: never chosen)', 0.0, 100.0),
    ParamSpec('border_extrapolation', 0.25, 'census_sgm: how far past the image border an '
              'extrapolated disparity is published, as a fraction of disparity_range',
              0.0, 1.0),
    ParamSpec('speckle_size', 100, 'Largest area in px of a disparity region removed as a '
              'speckle (0: off)', 0, 100000),
    ParamSpec('speckle_range', 2, 'Largest disparity step in px within one speckle region',
              0, 64),
    ParamSpec('disp12_max_diff', 2, 'Left-right check: largest |d_left - d_right| in px '
              '(0 or -1: off)', -1, 128),
    ParamSpec('threads', 0, 'Threads of the matcher (both backends); 0 (or more than the '
              'cores): every core. In a '
              'graph of several processes on few cores, 1 wastes less CPU on waiting '
              'threads (see the README, bench --live)', 0, 1024),
    ParamSpec('parallel_frames', 1, 'census_sgm: frames matched at once, each on its own '
              'thread with its own buffers (640x480x128: 48 MB with 5 paths, 129 MB with 8); '
              '2 keeps two cores busy without per-row synchronisation (see the README, '
              'bench --live)', 1, 16,
              read_only=True),
    ParamSpec('correlation_window_size', 5, 'opencv backend: block size (odd)', 1, 255,
              check=_odd),
    ParamSpec('full_dp', True, 'opencv backend: MODE_HH (8 paths) instead of MODE_SGBM'),
    ParamSpec('prefilter_cap', 63, 'opencv backend: prefilter cap', 1, 63),
]


def _cross_check(values: Mapping[str, Any]) -> str | None:
    """Reject combinations no matcher accepts, with the reason."""
    if values['P2'] < values['P1']:
        return f'P2 ({values["P2"]}) must be >= P1 ({values["P1"]})'
    limit = 65535 // values['paths'] - OUT_OF_RANGE_COST
    if values['P2'] > limit:
        return f'P2 ({values["P2"]}) must be <= {limit} with {values["paths"]} paths'
    if values['census_width'] * values['census_height'] - 1 > 63:
        return 'census window has more than 63 neighbours (at most 9x7)'
    if values['census_weight'] == 0 and values['intensity_weight'] == 0:
        return 'census_weight and intensity_weight cannot both be 0'
    if values['backend'] == 'opencv' and values['disparity_range'] % 16:
        return (f'disparity_range ({values["disparity_range"]}) must be a multiple of 16 '
                'with the opencv backend')
    return None


def sgm_params(values: Mapping[str, Any]) -> SgmParams:
    """The matcher settings of a parameter snapshot."""
    return SgmParams(
        min_disparity=values['min_disparity'], disparity_range=values['disparity_range'],
        census_width=values['census_width'], census_height=values['census_height'],
        census_weight=values['census_weight'], intensity_weight=values['intensity_weight'],
        intensity_cost=values['intensity_cost'],
        intensity_truncation=values['intensity_truncation'],
        P1=round(values['P1']), P2=round(values['P2']),
        p2_adaptive_scale=values['p2_adaptive_scale'], paths=values['paths'],
        uniqueness_ratio=values['uniqueness_ratio'], subpixel=values['subpixel'],
        median_filter=values['median_filter'], match_brightness=values['match_brightness'],
        border_cost=values['border_cost'],
        border_extrapolation=values['border_extrapolation'],
        disp12_max_diff=values['disp12_max_diff'], speckle_size=values['speckle_size'],
        speckle_range=values['speckle_range'])


def opencv_settings(values: Mapping[str, Any]) -> SgbmSettings:
    """StereoSGBM settings of a parameter snapshot (names as stereo_image_proc's)."""
    return SgbmSettings(
        'opencv', mode=cv2.STEREO_SGBM_MODE_HH if values['full_dp'] else cv2.STEREO_SGBM_MODE_SGBM,
        correlation_window_size=values['correlation_window_size'], P1=round(values['P1']),
        P2=round(values['P2']), uniqueness_ratio=round(values['uniqueness_ratio']),
        speckle_size=values['speckle_size'], speckle_range=values['speckle_range'],
        disp12_max_diff=values['disp12_max_diff'], prefilter_cap=values['prefilter_cap'])


def _encoding(msg: Any) -> str:
    return str(getattr(msg, 'encoding', None) or getattr(msg, 'format', '?'))


class SgmStereoNode(DepthNode):
    """Census SGM on rectified stereo pairs; publishes both views' disparity and cost ratio."""

    def __init__(self, node_name: str = 'sgm_stereo', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS, cross_check=_cross_check)
        values = self.params.values
        # matchers (each with its buffers) for the frames in flight, reused frame to frame
        self._matchers: queue.SimpleQueue[SgmMatcher] = queue.SimpleQueue()
        self._matchers.put(SgmMatcher(sgm_params(values)))
        self._workers = None
        if values['parallel_frames'] > 1:
            self._workers = OrderedWorkers(values['parallel_frames'], self._frame_failed,
                                           name='sgm_frame')
            self.callback_is_frame_time = False
        self.pub_disparity = self.add_output(DisparityImage, 'disparity')
        self.pub_disparity_right = self.add_output(DisparityImage, 'disparity_right')
        self.pub_cost_ratio = self.add_output(Image, 'cost_ratio')
        tolerance = values['approximate_sync_tolerance_seconds']
        self.add_synced_inputs(
            [(Image, 'left/image_rect', values['image_transport']),
             (CameraInfo, 'left/camera_info'),
             (Image, 'right/image_rect', values['image_transport']),
             (CameraInfo, 'right/camera_info')],
            self.on_frame, queue_size=values['queue_size'],
            approximate=values['approximate_sync'], max_interval=tolerance or None)

    def _grey_pair(self, left_msg: Any, right_msg: Any) -> tuple[Any, Any] | None:
        """Both images (raw or compressed, any camera encoding) as grey arrays of one size
        and depth, or None after counting the reason."""
        left = self.gray_image(left_msg, 'left image')
        right = self.gray_image(right_msg, 'right image') if left is not None else None
        if right is None:
            return None
        if left.shape != right.shape:
            self.drop('size_mismatch', f'left image is {left.shape[1]}x{left.shape[0]}, '
                      f'right image {right.shape[1]}x{right.shape[0]}')
            return None
        if left.dtype != right.dtype:
            self.drop('encoding_mismatch', f'left image has {left.dtype} samples, the right '
                      f'one {right.dtype} (left {_encoding(left_msg)}, right '
                      f'{_encoding(right_msg)})')
            return None
        return left, right

    def on_frame(self, left_msg: Any, left_info: CameraInfo, right_msg: Any,
                 right_info: CameraInfo) -> None:
        """Match one synchronised stereo pair."""
        values = self.params.values
        pair = self._grey_pair(left_msg, right_msg)
        if pair is None:
            return
        left, right = pair
        stereo = self.stereo_model(left_info, right_info)
        if stereo is None:
            return
        h, w = left.shape
        if (stereo.left.width, stereo.left.height) != (w, h):
            self.drop('camera_info_mismatch', f'images are {w}x{h} but camera_info describes '
                      f'{stereo.left.width}x{stereo.left.height}')
            return
        lo, n = values['min_disparity'], values['disparity_range']
        if n >= w or not -w < lo < w:
            self.drop('range_too_wide', f'disparities {lo}..{lo + n - 1} do not fit an image '
                      f'{w} px wide')
            return
        header = left_msg.header
        common = {'focal': stereo.focal, 'baseline': stereo.baseline, 'min_disparity': lo,
                  'max_disparity': lo + n - 1,
                  'valid_window': (max(0, lo), 0, min(w, w + lo + n - 1), h)}
        if values['backend'] == 'opencv':  # frame by frame (parallel_frames: census_sgm)
            start = time.perf_counter()
            use_threads(values['threads'])
            disparity = opencv_sgbm(np.ascontiguousarray(left, np.uint8),
                                    np.ascontiguousarray(right, np.uint8),
                                    opencv_settings(values), min_disparity=lo,
                                    disparity_range=n)
            self.pub_disparity.publish(build_disparity(disparity, header, delta_d=1 / 16,
                                                       **common))
            if not self.callback_is_frame_time:
                self.record_frame_time(time.perf_counter() - start)
            return
        params = sgm_params(values)
        threads = values['threads']
        delta_d = SUBPIXEL_STEP if values['subpixel'] != 'none' else 1.0
        right_common = dict(common, valid_window=(max(0, -lo - n + 1), 0, min(w, w - lo), h))

        def compute() -> tuple[tuple[Any, Any, Any], float]:
            start = time.perf_counter()
            use_threads(threads)  # numba's setting is per thread
            matcher = self._take_matcher(params)
            try:
                result = matcher.match(left, right)
                msgs = (build_disparity(result.disparity, header, delta_d=delta_d, **common),
                        build_disparity(result.disparity_right, right_msg.header,
                                        delta_d=delta_d, **right_common),
                        array_to_image(result.cost_ratio, '32FC1', header))
            finally:
                self._matchers.put(matcher)
            return msgs, time.perf_counter() - start

        def publish(done: tuple[tuple[Any, Any, Any], float]) -> None:
            (disparity, disparity_right, cost_ratio), seconds = done
            start = time.perf_counter()
            self.pub_disparity.publish(disparity)
            self.pub_disparity_right.publish(disparity_right)
            self.pub_cost_ratio.publish(cost_ratio)
            if not self.callback_is_frame_time:
                self.record_frame_time(seconds + time.perf_counter() - start)

        if self._workers is None or self.sink is not None:  # the offline harness: in turn
            publish(compute())
        else:
            self._workers.submit(compute, publish)

    def _take_matcher(self, params: SgmParams) -> SgmMatcher:
        """An idle matcher set to ``params`` (a new one when every matcher is busy)."""
        try:
            matcher = self._matchers.get_nowait()
        except queue.Empty:
            return SgmMatcher(params)
        if params != matcher.params:
            matcher.set_params(params)
        return matcher

    def _frame_failed(self, exc: BaseException) -> None:
        self.drop('match_failed', f'the matcher failed on a frame: {type(exc).__name__}: {exc}')

    def destroy_node(self) -> None:
        """Finish the frames in flight, then destroy the node."""
        if self._workers is not None:
            self._workers.shutdown()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Console script ``sgm_stereo`` (``ros2 run depth_nodes sgm_stereo``)."""
    sys.exit(run_node(SgmStereoNode, args))


if __name__ == '__main__':
    main()
