"""`depth-nodes eval`: accuracy of a processed bag against its ground-truth topics.

Every DisparityImage topic that is not ground truth is scored against
``<ns>/left/disparity_gt`` frame by frame (matched by header stamp): bad-1 and bad-N
(default 2) over all pixels with ground truth and over the non-occluded ones
(``<ns>/left/occlusion_gt`` == 0, when the bag has it), density and avgerr.

A ``<ns>/confidence`` image belongs to the checked disparity of its namespace. Its
sparsification AUC / optimum is reported twice: over the pixels the *raw* matcher
(``<ns>/disparity``) estimated, ranking the raw matcher's errors (docs/design.md, "Metrics":
a pixel the check dropped is not counted as an error ranked last, which would measure the
check), and over the pixels its own disparity has, ranking that disparity's errors.

OpenCV's StereoSGBM runs on the same rectified pair as reference, with stereo_image_proc's
defaults and over an 18-setting grid (:data:`~depth_nodes.core.opencv_stereo.SGBM_GRID`) whose
best setting by each headline figure is reported: the pipeline's
``<ns>/left|right/image_rect`` when the bag has them, otherwise the raw images rectified
with their CameraInfo.
"""

from __future__ import annotations

import dataclasses
import math
from collections import defaultdict
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.metrics import (
    DepthScores,
    depth_errors,
    disparity_errors,
    sparsification_auc,
)
from depth_nodes.core.opencv_stereo import (
    SGBM_GRID,
    STEREO_IMAGE_PROC_DEFAULTS,
    opencv_range,
    opencv_sgbm,
)
from depth_nodes.core.rectify import rectify_image
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.core.stamps import stamp_ns
from depth_nodes.errors import ArgumentError, BagError
from depth_nodes.ros.camera_info import camera_info_to_model
from depth_nodes.ros.disparity import read_disparity
from depth_nodes.ros.image import image_to_array, to_rgb8, to_uint8
from depth_nodes.ros.transport import gray_image, image_pixels
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.evaluation.previews import (
    depth_metres,
    previews_folder,
    scored_views,
    write_views,
)

DISPARITY = 'stereo_msgs/msg/DisparityImage'
IMAGE = 'sensor_msgs/msg/Image'
CAMERA_INFO = 'sensor_msgs/msg/CameraInfo'
GT_SUFFIX = '/left/disparity_gt'
#: Border left out when comparing rectified images (a remap samples near the raw edge there).
RECT_MARGIN = 16

Array = NDArray[Any]


@dataclass
class MethodScores:
    """Accuracy of one method over every evaluated frame.

    ``bad_*`` are at the report's threshold N (default 2 px), ``bad1_*`` at 1 px; ``dense``
    counts a pixel without an estimate as bad, ``sparse`` scores estimated pixels only.
    ``auc_ratio``: the confidence's AUC / optimum over the raw matcher's estimated pixels
    and its errors; ``auc_ratio_own``: over the pixels of the disparity it belongs to.
    """

    method: str
    frames: int
    missing_frames: int
    bad_dense: float
    bad_sparse: float
    density: float
    avgerr: float
    bad_dense_nonocc: float
    bad_sparse_nonocc: float
    auc_ratio: float | None = None
    bad1_dense: float = math.nan
    bad1_sparse: float = math.nan
    bad1_dense_nonocc: float = math.nan
    bad1_sparse_nonocc: float = math.nan
    density_nonocc: float = math.nan
    auc_ratio_own: float | None = None


@dataclass
class EvalReport:
    """The scores of every method, and the bag facts they were computed on.

    ``rows`` hold the bag's disparities, OpenCV with stereo_image_proc's defaults and the
    grid's best settings; ``grid`` every setting of the OpenCV grid.
    """

    bag: str
    gt_topic: str
    frames: int
    size: tuple[int, int]
    gt_range: tuple[float, float]
    threshold: float
    rows: list[MethodScores] = field(default_factory=list)
    grid: list[MethodScores] = field(default_factory=list)
    #: What the non-occluded columns use: the occlusion topic, or None (all pixels).
    nonocc_source: str | None = None
    #: Fraction of ground-truth pixels that are non-occluded.
    nonocc_fraction: float = 1.0
    #: Mean |image_rect - image_rect_gt| per side (grey levels, 16 px margin), when both exist.
    rectification_mad: dict[str, float] = field(default_factory=dict)
    #: Depth images (REP 118) scored against ``<ns>/left/depth_gt``, by topic.
    depth: dict[str, DepthScores] = field(default_factory=dict)

    def format(self, *, grid: bool = False) -> str:
        """The table printed by ``depth-nodes eval`` (every grid row with ``grid``)."""
        n = f'{self.threshold:g}'
        nonocc = (f'non-occluded: {self.nonocc_source} == 0 ({self.nonocc_fraction:.1%} of '
                  'the ground-truth pixels)' if self.nonocc_source else
                  'non-occluded: no occlusion topic, all ground-truth pixels')
        head = (f'{"method":<58} {"density":>7} {"avgerr":>6} {"bad-1":>7} '
                f'{"bad-" + n:>7} {"sparse":>7} | {"bad-1":>7} {"sparse":>7} '
                f'{"bad-" + n:>7} | {"AUC/opt":>7} {"own":>5}')
        over = (f'{"":<58} {"all ground-truth pixels":^39} | {"non-occluded":^23} | '
                f'{"confidence":^13}')
        lines = [
            f'bag {self.bag}: {self.frames} frames {self.size[0]}x{self.size[1]}, '
            f'ground truth {self.gt_topic}, disparity {self.gt_range[0]:.1f}..'
            f'{self.gt_range[1]:.1f} px; {nonocc}',
            over, head, '-' * len(head),
        ]
        rows = self.rows + (self.grid if grid else [])
        for r in rows:
            auc = f'{r.auc_ratio:7.2f}' if r.auc_ratio is not None else f'{"-":>7}'
            own = f'{r.auc_ratio_own:5.2f}' if r.auc_ratio_own is not None else f'{"-":>5}'
            missing = f'  ({r.missing_frames} frames missing)' if r.missing_frames else ''
            lines.append(
                f'{r.method[:58]:<58} {r.density:7.3f} {r.avgerr:6.3f} {r.bad1_dense:7.4f} '
                f'{r.bad_dense:7.4f} {r.bad_sparse:7.4f} | {r.bad1_dense_nonocc:7.4f} '
                f'{r.bad1_sparse_nonocc:7.4f} {r.bad_dense_nonocc:7.4f} | {auc} {own}{missing}'
            )
        for topic, d in sorted(self.depth.items()):
            lines.append(f'depth {topic} vs ground truth: mean |dZ| {d.mae * 1e3:.1f} mm, '
                         f'relative {d.rel * 100:.2f}%, rmse {d.rmse * 1e3:.1f} mm, '
                         f'density {d.density:.3f}')
        for side, mad in sorted(self.rectification_mad.items()):
            lines.append(f'rectified {side} vs ground-truth render: mean |diff| {mad:.2f} grey '
                         f'levels ({RECT_MARGIN} px margin)')
        if not self.rows:
            lines.append('(no disparity to score: nothing was published and no baseline ran)')
        return '\n'.join(lines)

    def row(self, method: str) -> MethodScores:
        """The row of ``method`` (a topic or an OpenCV label).

        Raises:
            KeyError: No such row.
        """
        for r in self.rows + self.grid:
            if r.method == method:
                return r
        raise KeyError(method)

    def opencv_best(self, key: str = 'bad_dense') -> MethodScores:
        """The grid's best setting by ``key`` (a :class:`MethodScores` field, lower better).

        Raises:
            ArgumentError: The OpenCV grid did not run.
        """
        if not self.grid:
            raise ArgumentError('the OpenCV grid did not run (baselines off)')
        return min(self.grid, key=lambda r: getattr(r, key))


def _stamp(msg: Any) -> int:
    return stamp_ns(msg)


def _load(reader: BagReader, topics: list[str]) -> dict[str, dict[int, Any]]:
    by_topic: dict[str, dict[int, Any]] = defaultdict(dict)
    for bag_msg in reader.messages(topics):
        msg = bag_msg.deserialize()
        by_topic[bag_msg.topic][_stamp(msg)] = msg
    return by_topic


def rectified_pair(data: dict[str, dict[int, Any]], ns: str, stamp: int) -> tuple[Array, Array]:
    left = data.get(f'{ns}/left/image_rect', {}).get(stamp)
    right = data.get(f'{ns}/right/image_rect', {}).get(stamp)
    if left is not None and right is not None:
        pair = [gray_image(m) for m in (left, right)]
    else:
        pair = []
        for side in ('left', 'right'):
            raw = (data.get(f'{ns}/{side}/image_raw', {}).get(stamp)
                   or data.get(f'{ns}/{side}/image_raw/compressed', {}).get(stamp))
            info = data.get(f'{ns}/{side}/camera_info', {}).get(stamp)
            if raw is None or info is None:
                raise BagError(f'no rectified or raw {side} image with camera_info at stamp '
                               f'{stamp} under {ns}: cannot run the OpenCV baseline '
                               '(use --no-baseline)')
            pair.append(rectify_image(gray_image(raw), camera_info_to_model(info)))
    left_img, right_img = (to_uint8(p) for p in pair)
    return left_img, right_img


class _Accumulator:
    """Collects per-frame estimates so scores are pixel-weighted over all frames."""

    def __init__(self) -> None:
        self.est: list[Array] = []
        self.gt: list[Array] = []
        self.nonocc: list[Array] = []
        self.conf: list[Array] = []
        self.raw: list[Array] = []
        self.missing = 0

    def add(self, est: Array | None, gt: Array, nonocc: Array, conf: Array | None = None,
            raw: Array | None = None) -> None:
        if est is None:
            self.missing += 1
            est = np.full(gt.shape, np.nan, np.float32)
        self.est.append(est)
        self.gt.append(gt)
        self.nonocc.append(nonocc)
        if conf is not None:
            self.conf.append(conf)
            self.raw.append(est if raw is None else raw)

    def scores(self, method: str, threshold: float) -> MethodScores:
        # frames stacked vertically: the metrics are per pixel, so this pools all frames
        est, gt, nonocc = (np.concatenate(x) for x in (self.est, self.gt, self.nonocc))
        every = disparity_errors(est, gt, n=threshold)
        visible = disparity_errors(est, gt, valid_mask=nonocc, n=threshold)
        every1 = disparity_errors(est, gt, n=1.0)
        visible1 = disparity_errors(est, gt, valid_mask=nonocc, n=1.0)
        auc = auc_own = None
        if self.conf and len(self.conf) == len(self.est):
            conf = np.concatenate(self.conf)
            raw = np.concatenate(self.raw)
            has_gt = np.isfinite(gt)
            auc = sparsification_auc(conf, np.abs(raw - gt),
                                     valid_mask=has_gt & np.isfinite(raw), n=threshold).ratio
            auc_own = sparsification_auc(conf, np.abs(est - gt),
                                         valid_mask=has_gt & np.isfinite(est),
                                         n=threshold).ratio
        return MethodScores(method, len(self.est), self.missing, every.bad_dense,
                            every.bad_sparse, every.density, every.avgerr,
                            visible.bad_dense, visible.bad_sparse, auc,
                            bad1_dense=every1.bad_dense, bad1_sparse=every1.bad_sparse,
                            bad1_dense_nonocc=visible1.bad_dense,
                            bad1_sparse_nonocc=visible1.bad_sparse,
                            density_nonocc=visible.density, auc_ratio_own=auc_own)


def has_ground_truth(path: str | Path) -> bool:
    """True when the bag has a ``.../left/disparity_gt`` DisparityImage topic.

    Raises:
        BagError: The bag is missing or unreadable.
    """
    with BagReader(path) as reader:
        return any(t.endswith(GT_SUFFIX) and kind == DISPARITY
                   for t, kind in reader.topics.items())


def evaluate_bag(
    path: str | Path,
    *,
    threshold: float = 2.0,
    baselines: bool = True,
    previews: str | Path | None = None,
    preview_frames: int = 10,
    matching_costs: tuple[str, ...] = (),
) -> EvalReport:
    """Score every disparity in the bag at ``path`` against its ground truth.

    ``matching_costs`` adds a row per matching cost (``census``, ``learned``,
    ``census+learned``): the census SGM matcher alone (default settings, the baseline's
    disparity window) on the same rectified pair as the OpenCV baseline.

    Raises:
        BagError: The bag is missing/corrupt or has no ``.../left/disparity_gt`` topic.
        ConfigError: ``previews`` cannot be created.
    """
    if previews is not None:
        previews_folder(Path(previews))
    with BagReader(path) as reader:
        gt_topics = sorted(t for t, ty in reader.topics.items()
                           if t.endswith(GT_SUFFIX) and ty == DISPARITY)
        if not gt_topics:
            raise BagError(f'{path} has no ground-truth topic (…{GT_SUFFIX}, '
                           'stereo_msgs/msg/DisparityImage): nothing to evaluate against')
        gt_topic = gt_topics[0]
        ns = gt_topic[: -len(GT_SUFFIX)]
        # left-view disparities only: a right-view one (disparity_right) has no ground truth
        estimates = sorted(t for t, ty in reader.topics.items()
                           if ty == DISPARITY and not t.endswith(('_gt', '_right')))
        confidences = sorted(t for t, ty in reader.topics.items()
                             if ty == IMAGE and t.endswith('/confidence'))
        depths = sorted(t for t, ty in reader.topics.items()
                        if ty == IMAGE and t.endswith('/depth'))
        wanted = [gt_topic, *estimates, *confidences, *depths]
        extra = [f'{ns}/left/occlusion_gt', f'{ns}/left/image_rect', f'{ns}/right/image_rect',
                 f'{ns}/left/image_rect_color',
                 f'{ns}/left/image_rect_gt', f'{ns}/right/image_rect_gt']
        if previews is not None or depths:
            extra.append(f'{ns}/left/depth_gt')
        if baselines:
            extra += [f'{ns}/{s}/{k}' for s in ('left', 'right')
                      for k in ('image_raw', 'image_raw/compressed', 'camera_info')]
        wanted += [t for t in extra if t in reader.topics]
        data = _load(reader, wanted)

    gt_frames = data[gt_topic]
    first = read_disparity(next(iter(gt_frames.values())))
    report = EvalReport(str(path), gt_topic, len(gt_frames), first.disparity.shape[::-1],
                        (np.inf, -np.inf), threshold)
    acc: dict[str, _Accumulator] = defaultdict(_Accumulator)
    grid_acc: dict[str, _Accumulator] = defaultdict(_Accumulator)
    matchers: dict[str, SgmMatcher] = {}
    conf_for = {c: _disparity_for(c, estimates) for c in confidences}
    occlusion_topic = f'{ns}/left/occlusion_gt'
    if occlusion_topic in data:
        report.nonocc_source = occlusion_topic
    visible_count = gt_count = 0
    for stamp in sorted(gt_frames):
        gt = read_disparity(gt_frames[stamp]).disparity
        finite = gt[np.isfinite(gt)]
        report.gt_range = (min(report.gt_range[0], float(finite.min())),
                           max(report.gt_range[1], float(finite.max())))
        occ_msg = data.get(occlusion_topic, {}).get(stamp)
        nonocc = image_to_array(occ_msg) == 0 if occ_msg is not None else np.isfinite(gt)
        visible_count += int(np.count_nonzero(nonocc & np.isfinite(gt)))
        gt_count += finite.size
        frame_out: dict[str, Array] = {'ground truth': gt}
        maps: dict[str, Array] = {}
        depth_msg = data.get(f'{ns}/left/depth_gt', {}).get(stamp)
        if depth_msg is not None:
            maps['depth_gt'] = image_to_array(depth_msg)
        for topic in estimates:
            msg = data[topic].get(stamp)
            est = read_disparity(msg).disparity if msg is not None else None
            conf_topic = next((c for c, d in conf_for.items() if d == topic), None)
            conf_msg = data.get(conf_topic, {}).get(stamp) if conf_topic else None
            conf = image_to_array(conf_msg) if conf_msg is not None else None
            raw = None
            raw_topic = topic.rsplit('/', 1)[0] + '/disparity'
            if conf is not None and raw_topic != topic and raw_topic in data:
                raw_msg = data[raw_topic].get(stamp)
                raw = (read_disparity(raw_msg).disparity if raw_msg is not None
                       else np.full(gt.shape, np.nan, np.float32))
            acc[topic].add(est, gt, nonocc, conf, raw)
            if conf is not None and conf_topic is not None:
                maps[conf_topic] = conf
            if est is not None:
                frame_out[topic] = est
        if baselines:
            left, right = rectified_pair(data, ns, stamp)
            drange = _baseline_range(data, estimates, stamp, gt)
            defaults = opencv_sgbm(left, right, STEREO_IMAGE_PROC_DEFAULTS,
                                   disparity_range=drange)
            acc[STEREO_IMAGE_PROC_DEFAULTS.label].add(defaults, gt, nonocc)
            frame_out[STEREO_IMAGE_PROC_DEFAULTS.label] = defaults
            for settings in SGBM_GRID:
                est = opencv_sgbm(left, right, settings, disparity_range=drange)
                grid_acc[settings.label].add(est, gt, nonocc)
        for cost in matching_costs:
            left, right = rectified_pair(data, ns, stamp)
            drange = _baseline_range(data, estimates, stamp, gt)
            if cost not in matchers:
                matchers[cost] = SgmMatcher(SgmParams(matching_cost=cost))
            matcher = matchers[cost]
            matcher.set_params(replace(matcher.params, disparity_range=drange))
            est = matcher.match(left, right).disparity
            acc[f'sgm matcher, matching_cost {cost}'].add(est.copy(), gt, nonocc)
        if previews is not None and stamp in sorted(gt_frames)[:preview_frames]:
            for topic in depths:  # the estimated depth too, in metres
                msg = data[topic].get(stamp)
                if msg is not None:
                    maps[topic] = depth_metres(image_to_array(msg), msg.encoding)
            write_views(Path(previews), stamp, _left_colour(data, ns, stamp),
                        scored_views(frame_out, maps, threshold))
    report.nonocc_fraction = visible_count / max(gt_count, 1)
    report.rows = [a.scores(m, threshold) for m, a in acc.items()]
    report.grid = [a.scores(m, threshold) for m, a in grid_acc.items()]
    if report.grid:
        for key, what in (('bad_dense', f'bad-{threshold:g}'),
                          ('bad1_dense_nonocc', 'nonocc bad-1')):
            best = report.opencv_best(key)
            report.rows.append(dataclasses.replace(
                best, method=f'opencv best of {len(report.grid)} by {what}: '
                             f'{best.method.removeprefix("opencv ")}'))
    report.rectification_mad = _rectification_mad(data, ns)
    if data.get(f'{ns}/left/depth_gt'):  # depth is scored only against a depth ground truth
        report.depth = {t: _depth_scores(data, t, f'{ns}/left/depth_gt') for t in depths}
    return report


def _depth_scores(data: dict[str, dict[int, Any]], topic: str, gt_topic: str) -> DepthScores:
    """A depth topic (32FC1 metres, or 16UC1 millimetres with 0 unknown) against the
    ground-truth depth, pooled over the frames both have; a missing frame counts as empty."""
    truth = data.get(gt_topic, {})
    est, gt = [], []
    for stamp in sorted(truth):
        z_gt = image_to_array(truth[stamp]).astype(np.float64)
        msg = data[topic].get(stamp)
        if msg is None:
            z = np.full(z_gt.shape, np.nan)
        elif msg.encoding == '16UC1':
            raw = image_to_array(msg).astype(np.float64)
            z = np.where(raw > 0, raw / 1000.0, np.nan)
        else:
            z = image_to_array(msg).astype(np.float64)
        est.append(z)
        gt.append(z_gt)
    return depth_errors(np.concatenate(est), np.concatenate(gt))


def _rectification_mad(data: dict[str, dict[int, Any]], ns: str) -> dict[str, float]:
    """Mean |rectified - rectified render| per side over all frames that have both."""
    out = {}
    for side in ('left', 'right'):
        rect, truth = data.get(f'{ns}/{side}/image_rect', {}), data.get(
            f'{ns}/{side}/image_rect_gt', {})
        diffs = []
        for stamp in sorted(set(rect) & set(truth)):
            a = gray_image(rect[stamp]).astype(np.float32)
            b = gray_image(truth[stamp]).astype(np.float32)
            if a.shape == b.shape:
                m = RECT_MARGIN
                diffs.append(float(np.abs(a - b)[m:-m, m:-m].mean()))
        if diffs:
            out[side] = float(np.mean(diffs))
    return out


def _baseline_range(data: dict[str, dict[int, Any]], estimates: list[str], stamp: int,
                    gt: Array) -> int:
    """OpenCV's disparity range: the widest one the estimated disparities searched (read
    from their DisparityImage), so both search the same window; without an estimate, the
    ground truth's maximum. Rounded up to a multiple of 16 (OpenCV's rule)."""
    top = float(np.nanmax(gt))
    for topic in estimates:
        msg = data[topic].get(stamp)
        if msg is not None:
            top = max(top, float(msg.max_disparity))
    return opencv_range(0, top)


def _disparity_for(confidence_topic: str, estimates: list[str]) -> str | None:
    """The disparity a confidence map belongs to: checked, else raw, in its namespace."""
    ns = confidence_topic.rsplit('/', 1)[0]
    for name in ('disparity_checked', 'disparity'):
        if f'{ns}/{name}' in estimates:
            return f'{ns}/{name}'
    return None


def _left_colour(data: dict[str, dict[int, Any]], ns: str, stamp: int) -> Array | None:
    """The left image of a frame as BGR for the previews: the colour one when the bag has
    it, else the mono rectified one."""
    for topic in (f'{ns}/left/image_rect_color', f'{ns}/left/image_rect'):
        msg = data.get(topic, {}).get(stamp)
        if msg is not None:
            return cv2.cvtColor(to_rgb8(*image_pixels(msg)), cv2.COLOR_RGB2BGR)
    return None
