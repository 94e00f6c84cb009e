"""SGM stereo node: census Semi-Global Matching, a drop-in for stereo_image_proc's
DisparityNode.

Subscribes ``left/image_rect``, ``right/image_rect``, ``left/camera_info`` and
``right/camera_info`` (exact stamps by default; ``approximate_sync`` for the
ApproximateTime policy). Publishes ``disparity`` (stereo_msgs/DisparityImage, left view),
``disparity_right`` (DisparityImage in the right view: x_left = x_right + d) and
``cost_ratio`` (sensor_msgs/Image 32FC1, best / second-best aggregated cost of the left
winner: low means unambiguous), the signals the cross-check node needs.

Parameters: every parameter of stereo_image_proc's (Jazzy) disparity node, with its
meaning and range (``stereo_algorithm``: 0 OpenCV StereoBM, 1 OpenCV StereoSGBM, as
upstream, and 2 this package's census SGM, the default; ``sgbm_mode``, ``full_dp``,
``prefilter_size``, ``prefilter_cap``, ``correlation_window_size``, ``texture_threshold``,
``min_disparity``, ``disparity_range``, ``uniqueness_ratio``, ``speckle_size``,
``speckle_range``, ``disp12_max_diff``, ``P1``, ``P2``, ``queue_size``,
``approximate_sync``, ``approximate_sync_tolerance_seconds``, ``use_system_default_qos``),
so a stereo_image_proc parameter file runs unchanged and gives OpenCV the same settings;
plus the census matcher's own. All but the synchronisation ones change at runtime and apply
from the next frame. The OpenCV algorithms also publish ``disparity_right`` (the mirrored
pair matched again) and an all-NaN ``cost_ratio``, so the cross-check and the rest of the
graph run on them too; ``right_view: false`` publishes ``disparity`` only.

The census matcher's ``disparity`` is checked like StereoSGBM's: uniqueness, a left-right
check against the right view taken from the same volume (``disp12_max_diff``), speckle
removal. Its left border strip, where the match may lie outside the right image, takes
the disparity its neighbours carry in (``border_cost``) up to ``border_extrapolation`` x
disparity_range px past the border; beyond that the pixels are invalid.

Outputs are computed only while subscribed (lazy), or always offline: the census matcher
yields the three together (an output nobody wants is not built); with OpenCV the mirrored
pair is matched only while ``disparity_right`` is wanted.

Frames without output are counted and logged with a reason: ``size_mismatch``,
``encoding_mismatch``, ``unsupported_encoding``, ``malformed_image``, ``decode_failed``,
``unsupported_format`` (a compressed image that cannot be read), ``uncalibrated``,
``bad_calibration``, ``camera_info_mismatch`` (camera_info size differs from the image),
``range_too_wide`` (the disparity window does not fit the image), ``sync_*``, and
``no_weights`` (``matching_cost`` learned and the shipped weights cannot be read), and
``match_failed`` (the matcher raised; not expected, but never silent).

``parallel_frames`` > 1 matches that many frames at once on worker threads (each with its
own matcher and buffers) and publishes them in stamp order (``ros/workers.py``); the
offline harness always matches frame by frame, each frame on ``threads x parallel_frames``
threads (the same output).
"""

from __future__ import annotations

import dataclasses
import queue
import time
from collections.abc import Callable, Mapping
from typing import Any

import cv2
import numpy as np
from rclpy.qos import qos_profile_system_default
from sensor_msgs.msg import CameraInfo, Image
from stereo_msgs.msg import DisparityImage

from depth_nodes.core.cross_check import lr_threshold
from depth_nodes.core.learned.network import FeatureNet, WeightsError
from depth_nodes.core.opencv_stereo import BmSettings, SgbmSettings, opencv_bm, opencv_sgbm
from depth_nodes.core.settings import Rule, problem
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.core.sgm.cost import OUT_OF_RANGE_COST
from depth_nodes.core.sgm.params import P2_MAX
from depth_nodes.core.sgm.select import SUBPIXEL_STEP
from depth_nodes.errors import ArgumentError
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image, to_uint8
from depth_nodes.ros.node import DepthNode
from depth_nodes.ros.params import (
    IMAGE_TRANSPORT,
    NodeParameters,
    ParamSpec,
    specs_from,
    synchroniser_specs,
)
from depth_nodes.ros.workers import OrderedWorkers, use_threads

#: The SgmParams fields that are also stereo_image_proc's parameters (declared below with
#: its meaning; some with its defaults when an OpenCV algorithm is chosen).
SHARED_WITH_UPSTREAM = ('min_disparity', 'disparity_range', 'P1', 'P2', 'uniqueness_ratio',
                        'disp12_max_diff', 'speckle_size', 'speckle_range')
#: The census matcher's own parameters: every other SgmParams field, declared from its
#: setting (a field added to SgmParams becomes a parameter).
CENSUS_ONLY = tuple(f.name for f in dataclasses.fields(SgmParams)
                    if f.name not in SHARED_WITH_UPSTREAM)
#: How sgm_params converts a parameter into its SgmParams field (the others as they are):
#: P1 and P2 are doubles, as upstream; disp12_max_diff follows OpenCV's rule.
TO_SGM_PARAMS: dict[str, Callable[[Any], Any]] = {'P1': round, 'P2': round,
                                                  'disp12_max_diff': lr_threshold}
_ODD = Rule('', odd=True)


def _odd(value: int) -> str | None:
    return problem(_ODD, value)


#: stereo_algorithm: stereo_image_proc's 0 (OpenCV block matching) and 1 (OpenCV
#: semi-global block matching), and this package's census SGM.
BLOCK_MATCHING, SEMI_GLOBAL_BLOCK_MATCHING, CENSUS_SGM = 0, 1, 2
ALGORITHMS = {BLOCK_MATCHING: 'OpenCV StereoBM', SEMI_GLOBAL_BLOCK_MATCHING: 'OpenCV StereoSGBM',
              CENSUS_SGM: 'census SGM (this package)'}
#: sgbm_mode: OpenCV's StereoSGBM modes, stereo_image_proc's codes.
SGBM_MODES = {0: cv2.STEREO_SGBM_MODE_SGBM, 1: cv2.STEREO_SGBM_MODE_HH,
              2: cv2.STEREO_SGBM_MODE_SGBM_3WAY, 3: cv2.STEREO_SGBM_MODE_HH4}
#: stereo_image_proc's defaults where the OpenCV algorithms and the census matcher differ
#: (P1 / P2 are in the units of each algorithm's cost). A node started with stereo_algorithm
#: 0 or 1 takes these, so a stereo_image_proc parameter file gives OpenCV the settings it
#: gets upstream; with 2 (the default) the census matcher's own. Changing stereo_algorithm
#: at runtime keeps the current values.
UPSTREAM_DEFAULTS = {'disparity_range': 64, 'P1': 200.0, 'P2': 400.0, 'uniqueness_ratio': 15.0,
                     'speckle_range': 4, 'disp12_max_diff': 0}
CENSUS_DEFAULTS = {'disparity_range': 128, 'P1': 18.0, 'P2': 220.0, 'uniqueness_ratio': 10.0,
                   'speckle_range': 2, 'disp12_max_diff': 2}


def _default(name: str) -> Any:
    """The default of a parameter whose default follows stereo_algorithm (see above)."""
    def pick(values: Mapping[str, Any]) -> Any:
        table = CENSUS_DEFAULTS if values.get('stereo_algorithm') == CENSUS_SGM else \
            UPSTREAM_DEFAULTS
        return table[name]
    return pick


PARAMETERS = [
    IMAGE_TRANSPORT,
    *synchroniser_specs('the four inputs'),
    ParamSpec('stereo_algorithm', CENSUS_SGM, 'Matcher: ' + ', '.join(
        f'{code} {name}' for code, name in ALGORITHMS.items()) + ' (0 and 1 as '
        'stereo_image_proc; a node started with 0 or 1 takes stereo_image_proc\'s '
        'defaults for P1, P2, uniqueness_ratio, speckle_range, disp12_max_diff, '
        'disparity_range)', min(ALGORITHMS), max(ALGORITHMS)),
    ParamSpec('disparity_range', _default('disparity_range'), 'Number of disparities searched '
              '(any number with census SGM, a multiple of 16 with OpenCV)', 1, 4096),
    ParamSpec('P1', _default('P1'), 'Penalty of a 1 px disparity change between neighbours '
              '(semi-global algorithms)', 0.0, 4000.0),
    ParamSpec('P2', _default('P2'), 'Penalty of a larger disparity change (>= P1; census '
              f'SGM: at most {P2_MAX} with 4 paths, 65535 / paths - {OUT_OF_RANGE_COST} '
              'otherwise)', 0.0, float(P2_MAX)),
    ParamSpec('uniqueness_ratio', _default('uniqueness_ratio'), 'Percent by which the best '
              'cost must beat the best non-neighbouring disparity', 0.0, 100.0),
    *specs_from(SgmParams, ('min_disparity', 'speckle_size')),
    *specs_from(SgmParams, CENSUS_ONLY, prefix='census SGM: '),
    ParamSpec('speckle_range', _default('speckle_range'), 'Largest disparity step in px '
              'within one speckle region', 0, 64),
    ParamSpec('disp12_max_diff', _default('disp12_max_diff'), 'Left-right check: largest '
              '|d_left - d_right| in px; 0 counts as 1, as in OpenCV\'s StereoSGBM; census '
              'SGM: -1 turns the check off (block matching has none, as upstream)', -1, 128),
    ParamSpec('threads', 0, 'Threads of the matcher (every algorithm); 0 (or more than the '
              'cores): every core. In a '
              'graph of several processes on few cores, 1 wastes less CPU on waiting '
              'threads (see the README, bench live)', 0, 1024),
    ParamSpec('parallel_frames', 1, 'census SGM: frames matched at once, each on its own '
              'thread with its own buffers (640x480x128: 25 MB with 5 paths, 129 MB with 8); '
              '2 keeps two cores busy with no waiting between threads (see the README, '
              'bench live)', 1, 16,
              read_only=True),
    ParamSpec('correlation_window_size', 15, 'OpenCV: matched block size (odd; block '
              'matching 5..255)', 1, 255, check=_odd),
    ParamSpec('sgbm_mode', 0, 'OpenCV SGBM: ' + ', '.join(
        f'{code} {name}' for code, name in zip(SGBM_MODES, (
            'SGBM', 'HH', 'SGBM_3WAY', 'HH4'), strict=True)), 0, 3),
    ParamSpec('full_dp', False, 'OpenCV SGBM: the full (8-path) variant, MODE_HH, whatever '
              'sgbm_mode says'),
    ParamSpec('prefilter_size', 9, 'OpenCV block matching: normalisation window (odd)',
              5, 255, check=_odd),
    ParamSpec('prefilter_cap', 31, 'OpenCV: bound on the prefiltered values', 1, 63),
    ParamSpec('right_view', True, 'OpenCV: also match the mirrored pair for disparity_right '
              '(the cross-check\'s input; doubles the time) and publish a NaN cost_ratio '
              '(OpenCV gives no matching cost); false publishes disparity only, as '
              'stereo_image_proc'),
    ParamSpec('texture_threshold', 10, 'OpenCV block matching: least texture (sum of the '
              'prefiltered window) of a kept pixel', 0, 10000),
]


def _check_values(values: Mapping[str, Any]) -> str | None:
    """Reject combinations the chosen matcher does not accept, with the reason."""
    algorithm = values['stereo_algorithm']
    if algorithm == CENSUS_SGM:
        params = sgm_params(values)
        try:
            params.validate()
            if params.learned_weights and params.matching_cost != 'census':
                FeatureNet.load(params.learned_weights)  # a file it cannot read: refused
        except ValueError as exc:
            return str(exc)
        except WeightsError as exc:
            return f'learned_weights: {exc}'
        return None
    if values['disparity_range'] % 16:
        return (f'disparity_range ({values["disparity_range"]}) must be a multiple of 16 '
                f'with {ALGORITHMS[algorithm]}')
    if algorithm == BLOCK_MATCHING and values['correlation_window_size'] < 5:
        return (f'correlation_window_size ({values["correlation_window_size"]}) must be at '
                'least 5 with block matching')
    if algorithm == SEMI_GLOBAL_BLOCK_MATCHING and values['P2'] < values['P1']:
        return f'P2 ({values["P2"]}) must be >= P1 ({values["P1"]})'
    return None


def sgm_params(values: Mapping[str, Any]) -> SgmParams:
    """The matcher settings of a parameter snapshot: each SgmParams field from the
    parameter of its name, through :data:`TO_SGM_PARAMS` where it has an entry."""
    return SgmParams(**{f.name: TO_SGM_PARAMS.get(f.name, _as_is)(values[f.name])
                        for f in dataclasses.fields(SgmParams)})


def _as_is(value: Any) -> Any:
    return value


def opencv_settings(values: Mapping[str, Any]) -> SgbmSettings:
    """StereoSGBM settings of a parameter snapshot (names as stereo_image_proc's)."""
    mode = cv2.STEREO_SGBM_MODE_HH if values['full_dp'] else SGBM_MODES[values['sgbm_mode']]
    return SgbmSettings(
        'opencv', mode=mode, correlation_window_size=values['correlation_window_size'],
        P1=round(values['P1']), P2=round(values['P2']),
        uniqueness_ratio=round(values['uniqueness_ratio']),
        speckle_size=values['speckle_size'], speckle_range=values['speckle_range'],
        disp12_max_diff=values['disp12_max_diff'], prefilter_cap=values['prefilter_cap'])


def bm_settings(values: Mapping[str, Any]) -> BmSettings:
    """StereoBM settings of a parameter snapshot (stereo_image_proc sets no left-right
    check for block matching, nor does this)."""
    return BmSettings(
        'opencv BM', correlation_window_size=values['correlation_window_size'],
        prefilter_size=values['prefilter_size'], prefilter_cap=values['prefilter_cap'],
        texture_threshold=values['texture_threshold'],
        uniqueness_ratio=round(values['uniqueness_ratio']),
        speckle_size=values['speckle_size'], speckle_range=values['speckle_range'])


def opencv_disparity(left: Any, right: Any, values: Mapping[str, Any]) -> Any:
    """The disparity of OpenCV's algorithm of ``values`` (stereo_algorithm 0 or 1) on a
    grey pair (16-bit images are taken at their top 8 bits, as cv_bridge's mono8 would)."""
    left8, right8 = to_uint8(left), to_uint8(right)
    lo, n = values['min_disparity'], values['disparity_range']
    if values['stereo_algorithm'] == BLOCK_MATCHING:
        return opencv_bm(left8, right8, bm_settings(values), min_disparity=lo, disparity_range=n)
    return opencv_sgbm(left8, right8, opencv_settings(values), min_disparity=lo,
                       disparity_range=n)


def _encoding(msg: Any) -> str:
    return str(getattr(msg, 'encoding', None) or getattr(msg, 'format', '?'))


class SgmStereoNode(DepthNode):
    """Census SGM on rectified stereo pairs; publishes both views' disparity and cost ratio."""

    def __init__(self, node_name: str = 'sgm_stereo', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS, check_values=_check_values)
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
            approximate=values['approximate_sync'], max_interval=tolerance or None,
            qos=qos_profile_system_default if values['use_system_default_qos'] else None)

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
        """Match one synchronised stereo pair (for the outputs wanted)."""
        values = self.params.values
        census = values['stereo_algorithm'] == CENSUS_SGM
        wanted = (self.pub_disparity.wanted, self.pub_disparity_right.wanted,
                  self.pub_cost_ratio.wanted)
        # OpenCV with right_view false never publishes disparity_right and cost_ratio
        right_outputs = census or values['right_view']
        if self.skip_unwanted(wanted[0], right_outputs and any(wanted[1:])):
            return
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
        try:  # the one rule of the frame, the same for every algorithm
            SgmParams(min_disparity=lo, disparity_range=n).check_width(w)
        except ArgumentError as exc:
            self.drop('range_too_wide', f'{exc} (disparities {lo}..{lo + n - 1})')
            return
        header = left_msg.header
        common = {'focal': stereo.focal, 'baseline': stereo.baseline, 'min_disparity': lo,
                  'max_disparity': lo + n - 1,
                  'valid_window': (max(0, lo), 0, min(w, w + lo + n - 1), h)}
        right_common = dict(common, valid_window=(max(0, -lo - n + 1), 0, min(w, w - lo), h))
        if not census:  # frame by frame
            self._opencv_frame(left, right, values, wanted, left_msg.header, right_msg.header,
                               common, right_common)
            return
        params = sgm_params(values)
        threads = values['threads']
        if self.sink is not None and threads and values['parallel_frames'] > 1:
            # the offline harness matches frame by frame: the cores that parallel_frames
            # would give several frames go to the one frame (the same output whatever the
            # thread count)
            threads *= values['parallel_frames']
        delta_d = SUBPIXEL_STEP if values['subpixel'] != 'none' else 1.0

        want_disparity, want_right, want_cost = wanted
        outputs = (self.pub_disparity, self.pub_disparity_right, self.pub_cost_ratio)

        def compute() -> tuple[tuple[Any, Any, Any], float]:
            start = time.perf_counter()
            use_threads(threads)  # numba's setting is per thread
            matcher = self._take_matcher(params)
            try:
                try:
                    result = matcher.match(left, right)
                except WeightsError as exc:
                    self.drop('no_weights', str(exc))
                    return (None, None, None), time.perf_counter() - start
                msgs = (build_disparity(result.disparity, header, delta_d=delta_d, **common)
                        if want_disparity else None,
                        build_disparity(result.disparity_right, right_msg.header,
                                        delta_d=delta_d, **right_common)
                        if want_right else None,
                        array_to_image(result.cost_ratio, '32FC1', header)
                        if want_cost else None)
            finally:
                self._matchers.put(matcher)
            return msgs, time.perf_counter() - start

        def publish(done: tuple[tuple[Any, Any, Any], float]) -> None:
            msgs, seconds = done
            start = time.perf_counter()
            for output, msg in zip(outputs, msgs, strict=True):
                if msg is not None:
                    output.publish(msg)
            if not self.callback_is_frame_time:
                self.record_frame_time(seconds + time.perf_counter() - start)

        if self._workers is None or self.sink is not None:  # the offline harness: in turn
            publish(compute())
        else:
            self._workers.submit(compute, publish)

    def _opencv_frame(self, left: Any, right: Any, values: Mapping[str, Any],
                      wanted: tuple[bool, bool, bool], header: Any, right_header: Any,
                      common: dict[str, Any], right_common: dict[str, Any]) -> None:
        """Match a grey pair with OpenCV's algorithm of ``values`` and publish the outputs
        ``wanted`` (disparity, disparity_right, cost_ratio), frame by frame."""
        want_disparity, want_right, want_cost = wanted
        right_view = values['right_view']
        start = time.perf_counter()
        use_threads(values['threads'])
        try:
            disparity = opencv_disparity(left, right, values) if want_disparity else None
            mirrored = (opencv_disparity(right[:, ::-1], left[:, ::-1], values)[:, ::-1]
                        if right_view and want_right else None)
        except (cv2.error, ValueError) as exc:  # not expected, never silent
            self._frame_failed(exc)
            return
        if disparity is not None:
            self.pub_disparity.publish(build_disparity(disparity, header, delta_d=1 / 16,
                                                       **common))
        if mirrored is not None:  # what the cross-check needs
            self.pub_disparity_right.publish(build_disparity(
                np.ascontiguousarray(mirrored), right_header, delta_d=1 / 16, **right_common))
        if right_view and want_cost:  # OpenCV has no matching cost
            self.pub_cost_ratio.publish(array_to_image(
                np.full(left.shape, np.nan, np.float32), '32FC1', header))
        if not self.callback_is_frame_time:
            self.record_frame_time(time.perf_counter() - start)

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
        if self.stopping:  # a frame in flight when Ctrl-C / SIGTERM came: not a failure
            return
        self.drop('match_failed', f'the matcher failed on a frame: {type(exc).__name__}: {exc}')

    def destroy_node(self) -> None:
        """Finish the frames in flight, then destroy the node."""
        if self._workers is not None:
            self._workers.shutdown()
        super().destroy_node()
