"""`depth-nodes eval` on multi-view output: the depth the multiview_stereo node published,
scored against the simulator's exact depth, or, for real images without depth ground
truth, against itself across views and against the object's bounding box.

With ground truth (a bag from ``depth-nodes generate --preset mvs_*``, processed), per frame
of the published ``depth`` and over the frames from ``--skip`` on (after the filter has had
that many frames to converge):

* **median |dZ|/Z** over the pixels with a depth, and the share of the ground-truth pixels
  whose depth is within 1 % and 2 % of Z (a pixel without a depth counts as outside);
* **coverage**: the share of ground-truth pixels with a depth;
* **within 1 sigma**: the share of the depths whose error is at most the published
  standard deviation (honest when about 68 %);
* a rig bag also holds the two-view stereo graph's inputs for the middle camera and the
  one to its right: when the processed bag has the stereo graph's ``/stereo/depth`` too,
  both are scored as disparities at the stereo baseline (bad-1 and bad-2, dense), over the
  whole image and over the pixels the right camera does not see (occluded in one view).

Without depth ground truth (``depth-nodes import-views``): per view, the share of its
depths that a neighbouring view's depth confirms within 1 % (carried across with the known
cameras: :mod:`depth_nodes.core.mvs.consistency`; among the depths that land where a
neighbour has one), the share of all its depths whose points
lie inside the bounding box given to import-views (a depth on the background is outside),
and the object's coverage (pixels brighter than
``--object-threshold``, the share of them with a depth).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.depth_image import to_metres
from depth_nodes.core.geometry import Intrinsics, Pose, intrinsics
from depth_nodes.core.mvs.consistency import consistency
from depth_nodes.core.stamps import stamp_ns
from depth_nodes.errors import BagError
from depth_nodes.ros.camera_info import camera_info_to_model
from depth_nodes.ros.image import image_to_array
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bags.multiview import CONFIG_KEY, STEREO, config_from_metadata, namespace
from depth_nodes.tools.bags.views import VIEWS_KEY, ViewsInfo, views_info

F32 = NDArray[np.float32]
#: The targets the scores are read against (docs/multiview.md, Accuracy).
TARGET_MEDIAN, TARGET_WITHIN_2 = 0.01, 0.90
SIGMA_BAND = (0.60, 0.76)


@dataclass
class RelativeDepthScores:
    """Scores of one depth image by its error relative to the true Z (see the module
    notes); :class:`depth_nodes.core.metrics.DepthScores` holds the absolute errors in
    metres that the stereo report gives."""

    median_rel: float
    within_1: float
    within_2: float
    coverage: float
    within_sigma: float


def score_depth(depth: F32, truth: F32, sigma: F32 | None = None) -> RelativeDepthScores:
    """Score one depth image (NaN: no depth) against the true Z (NaN: no surface)."""
    has_truth = np.isfinite(truth) & (truth > 0)
    est = has_truth & np.isfinite(depth)
    total = max(int(has_truth.sum()), 1)
    rel = np.abs(depth[est] - truth[est]) / truth[est]
    median = float(np.median(rel)) if rel.size else float('nan')
    within_sigma = float('nan')
    if sigma is not None:
        ok = est & np.isfinite(sigma) & (sigma > 0)
        if ok.any():
            within_sigma = float(np.mean(np.abs(depth[ok] - truth[ok]) <= sigma[ok]))
    return RelativeDepthScores(median, float(np.sum(rel <= 0.01)) / total,
                               float(np.sum(rel <= 0.02)) / total, float(est.sum()) / total,
                               within_sigma)


@dataclass
class StereoComparison:
    """Multi-view against two-view stereo at the stereo baseline (dense bad-N: a pixel
    without an estimate counts as bad), over all pixels and over those occluded in the
    right view."""

    frames: int
    mvs_bad1: float
    mvs_bad2: float
    stereo_bad1: float
    stereo_bad2: float
    mvs_bad1_occluded: float
    stereo_bad1_occluded: float
    occluded_share: float


@dataclass
class MultiviewReport:
    """Per-frame scores and their summary."""

    bag: str
    motion: str
    skip: int
    frames: list[tuple[int, RelativeDepthScores]] = field(default_factory=list)
    stereo: StereoComparison | None = None

    def summary(self) -> RelativeDepthScores:
        """The mean of the scores of the frames from ``skip`` on."""
        kept = [s for _, s in self.frames[self.skip:]] or [s for _, s in self.frames]
        if not kept:
            return RelativeDepthScores(*(float('nan'),) * 5)
        return RelativeDepthScores(*(float(np.nanmean([getattr(s, f) for s in kept]))
                                     for f in ('median_rel', 'within_1', 'within_2',
                                               'coverage', 'within_sigma')))

    def format(self) -> str:
        """The printed report."""
        lines = [f'{self.bag}: multi-view depth, {self.motion} sequence, '
                 f'{len(self.frames)} frames with depth',
                 f'  {"frame":>5} {"median |dZ|/Z":>14} {"within 1 %":>11} {"within 2 %":>11} '
                 f'{"coverage":>9} {"within 1 sigma":>15}']
        for index, s in self.frames:
            lines.append(f'  {index:>5} {100 * s.median_rel:13.2f}% {100 * s.within_1:10.1f}% '
                         f'{100 * s.within_2:10.1f}% {100 * s.coverage:8.1f}% '
                         f'{100 * s.within_sigma:14.1f}%')
        m = self.summary()
        lines.append(f'  from frame {self.skip} on: median |dZ|/Z {100 * m.median_rel:.2f} % '
                     f'(target <= {100 * TARGET_MEDIAN:g} %), within 2 % '
                     f'{100 * m.within_2:.1f} % (target >= {100 * TARGET_WITHIN_2:g} %), '
                     f'within 1 sigma {100 * m.within_sigma:.1f} % (honest: '
                     f'{100 * SIGMA_BAND[0]:g} - {100 * SIGMA_BAND[1]:g} %)')
        if self.stereo is not None:
            c = self.stereo
            lines += [f'  against two-view stereo at its baseline ({c.frames} frames, dense '
                      'bad-N as disparities):',
                      f'    {"":24} {"bad-1":>7} {"bad-2":>7} {"bad-1 occluded in one view":>27}',
                      f'    {"multi-view":24} {100 * c.mvs_bad1:6.2f}% {100 * c.mvs_bad2:6.2f}% '
                      f'{100 * c.mvs_bad1_occluded:26.2f}%',
                      f'    {"stereo graph":24} {100 * c.stereo_bad1:6.2f}% '
                      f'{100 * c.stereo_bad2:6.2f}% {100 * c.stereo_bad1_occluded:26.2f}%',
                      f'    ({100 * c.occluded_share:.1f} % of the pixels are occluded in the '
                      'right view)']
        return '\n'.join(lines)


def is_multiview_bag(path: str | Path) -> bool:
    """Whether ``path`` is a simulated sequence bag (or one processed from it)."""
    with BagReader(Path(path)) as reader:
        return CONFIG_KEY in reader.custom_data


def _stamp(msg: Any) -> int:
    """A message's header stamp, ns: outputs are matched to their inputs by it (a node
    with ``delay`` publishes a frame's depth when a later frame arrives, so the bag's
    receive times do not pair them)."""
    return stamp_ns(msg)


def _depth_of(msg: Any) -> F32:
    return to_metres(image_to_array(msg), msg.encoding)


def evaluate_multiview_bag(path: str | Path, *, skip: int = 10,
                           depth_topic: str | None = None) -> MultiviewReport:
    """Score the multi-view depth of a processed sequence bag (see the module notes).

    Raises:
        BagError: Not a sequence bag, or it holds no multi-view depth.
    """
    with BagReader(Path(path)) as reader:
        config = config_from_metadata(dict(reader.custom_data), path)
        ns = namespace(config)
        camera_ns = f'{ns}/cam{config.rig_cameras // 2}' if config.motion == 'rig' else ns
        depth_topic = depth_topic or f'{ns}/depth'
        if depth_topic not in reader.topics:
            raise BagError(f'{path} holds no {depth_topic}: process the bag with '
                           'config/multiview_pipeline.yaml first')
        sigma_topic = depth_topic.rsplit('/', 1)[0] + '/sigma'
        right_ns = f'{ns}/cam{config.rig_cameras // 2 + 1}'
        topics = [t for t in (depth_topic, sigma_topic, f'{camera_ns}/depth_gt',
                              f'{STEREO}/depth', f'{right_ns}/depth_gt',
                              f'{camera_ns}/camera_info') if t in reader.topics]
        found: dict[str, dict[int, Any]] = {t: {} for t in topics}
        for m in reader.messages(topics):
            msg = m.deserialize()
            found[m.topic][_stamp(msg)] = msg
    report = MultiviewReport(str(path), config.motion, skip)
    truth = found[f'{camera_ns}/depth_gt']
    rows = []
    for index, (stamp, msg) in enumerate(sorted(found[depth_topic].items())):
        if stamp not in truth:
            continue
        sigma = found.get(sigma_topic, {}).get(stamp)
        report.frames.append((index, score_depth(_depth_of(msg), _depth_of(truth[stamp]),
                                                 None if sigma is None else _depth_of(sigma))))
        rows.append(stamp)
    if not report.frames:
        raise BagError(f'{path}: no {depth_topic} message has a ground truth of its stamp')
    if config.motion == 'rig' and f'{STEREO}/depth' in found and found[f'{STEREO}/depth']:
        report.stereo = _compare_stereo(found, depth_topic, camera_ns, right_ns,
                                        config.rig_baseline_m, rows[skip:] or rows)
    return report


def _compare_stereo(found: dict[str, dict[int, Any]], depth_topic: str, camera_ns: str,
                    right_ns: str, baseline: float, stamps: list[int]) -> StereoComparison:
    """Both estimates as disparities at the stereo baseline, against the truth's."""
    info = next(iter(found[f'{camera_ns}/camera_info'].values()))
    camera = intrinsics(camera_info_to_model(info))
    fb = camera.fx * baseline
    sums = np.zeros(6)
    frames = 0
    occluded_total = 0.0
    for stamp in stamps:
        stereo = found[f'{STEREO}/depth'].get(stamp)
        right = found[f'{right_ns}/depth_gt'].get(stamp)
        if stereo is None or right is None:
            continue
        truth = _depth_of(found[f'{camera_ns}/depth_gt'][stamp])
        occluded = hidden_in(truth, _depth_of(right), camera, baseline)
        has = np.isfinite(truth)
        gt_disp = fb / truth
        values = []
        for depth in (_depth_of(found[depth_topic][stamp]), _depth_of(stereo)):
            err = np.abs(fb / depth - gt_disp)
            bad1 = ~(err <= 1.0)
            bad2 = ~(err <= 2.0)
            values.append((bad1[has].mean(), bad2[has].mean(),
                           bad1[has & occluded].mean() if (has & occluded).any() else 0.0))
        (m1, m2, mo), (s1, s2, so) = values
        sums += [m1, m2, s1, s2, mo, so]
        occluded_total += float((has & occluded).sum()) / max(int(has.sum()), 1)
        frames += 1
    if not frames:
        return StereoComparison(0, *(float('nan'),) * 7)
    m1, m2, s1, s2, mo, so = sums / frames
    return StereoComparison(frames, m1, m2, s1, s2, mo, so, occluded_total / frames)


def hidden_in(depth: F32, right_depth: F32, camera: Intrinsics, baseline: float,
              tolerance: float = 0.01) -> NDArray[np.bool_]:
    """Pixels of a view whose point the camera ``baseline`` to its right does not see:
    outside its image, or behind a nearer surface there (its true depth)."""
    h, w = depth.shape
    ys, xs = np.mgrid[0:h, 0:w]
    with np.errstate(divide='ignore', invalid='ignore'):
        u = xs - camera.fx * baseline / depth
    ui = np.floor(u + 0.5)
    inside = np.isfinite(u) & (ui >= 0) & (ui <= w - 1)
    out = ~inside & np.isfinite(depth)
    idx = np.where(inside, ui, 0).astype(int)
    seen_depth = right_depth[ys, idx]
    out |= inside & (seen_depth < depth * (1.0 - tolerance))
    result: NDArray[np.bool_] = out
    return result


# ----------------------------------------------------------------- real images
@dataclass
class ViewsReport:
    """Consistency, bounding box and coverage of the depth of imported real views."""

    bag: str
    rows: list[tuple[str, float, float, float]] = field(default_factory=list)

    def format(self) -> str:
        """The printed report."""
        lines = [f'{self.bag}: multi-view depth of real views (no depth ground truth)',
                 f'  {"view":24} {"agrees with a neighbour":>24} {"inside the box":>15} '
                 f'{"object coverage":>16}']
        for name, agree, inside, coverage in self.rows:
            lines.append(f'  {name:24} {100 * agree:23.1f}% {100 * inside:14.1f}% '
                         f'{100 * coverage:15.1f}%')
        if self.rows:
            mean = np.nanmean(np.array([r[1:] for r in self.rows]), axis=0)
            lines.append(f'  {"mean":24} {100 * mean[0]:23.1f}% {100 * mean[1]:14.1f}% '
                         f'{100 * mean[2]:15.1f}%')
        return '\n'.join(lines)


def is_views_bag(path: str | Path) -> bool:
    """Whether ``path`` was written by import-views (or processed from such a bag)."""
    with BagReader(Path(path)) as reader:
        return VIEWS_KEY in reader.custom_data


def evaluate_views_bag(path: str | Path, *, depth_topic: str = '/views/depth',
                       agree: float = 0.01, object_threshold: float = 20.0) -> ViewsReport:
    """Score the depth of imported real views (see the module notes).

    Raises:
        BagError: Not an imported-views bag, or no depth in it.
    """
    with BagReader(Path(path)) as reader:
        info: ViewsInfo = views_info(dict(reader.custom_data), path)
        if depth_topic not in reader.topics:
            raise BagError(f'{path} holds no {depth_topic}: process the bag with '
                           'config/multiview_pipeline.yaml and --namespace /views first')
        topics = [depth_topic, info.image_topic, info.camera_info_topic, info.pose_topic]
        found: dict[str, dict[int, Any]] = {t: {} for t in topics}
        for m in reader.messages(topics):
            msg = m.deserialize()
            found[m.topic][_stamp(msg)] = msg
    report = ViewsReport(str(path))
    depths = found[depth_topic]
    stamps = sorted(depths)
    views = {}
    for stamp in stamps:
        pose_msg = found[info.pose_topic].get(stamp)
        info_msg = found[info.camera_info_topic].get(stamp)
        if pose_msg is None or info_msg is None:
            continue
        p = pose_msg.pose
        pose = Pose.from_quaternion((p.position.x, p.position.y, p.position.z),
                                    (p.orientation.x, p.orientation.y, p.orientation.z,
                                     p.orientation.w))
        model: CameraModel = camera_info_to_model(info_msg)
        views[stamp] = (_depth_of(depths[stamp]), intrinsics(model), pose)
    ordered = sorted(views)
    names = {stamp: info.names[i] if i < len(info.names) else str(stamp)
             for i, stamp in enumerate(sorted(found[info.image_topic]))}
    for i, stamp in enumerate(ordered):
        depth, camera, pose = views[stamp]
        neighbours = [views[s] for s in ordered[max(0, i - 1):i + 2] if s != stamp]
        others = [(d, c.matrix, pose.relative_to(q)) for d, c, q in neighbours]
        checked, agreed = consistency(depth, camera.matrix, others, max_px=1.0,
                                      max_relative=agree)
        has = np.isfinite(depth)
        seen = has & (checked > 0)  # a neighbour has a depth where the point lands
        agree_share = float((agreed > 0)[seen].mean()) if seen.any() else float('nan')
        inside = _inside_box(depth, camera, pose, info.bbox) if info.bbox else float('nan')
        image = image_to_array(found[info.image_topic][stamp]).astype(np.float32)
        grey = image.mean(axis=2) if image.ndim == 3 else image
        obj = grey > object_threshold
        coverage = float(has[obj].mean()) if obj.any() else float('nan')
        report.rows.append((names.get(stamp, str(stamp)), agree_share, inside, coverage))
    return report


def _inside_box(depth: F32, camera: Intrinsics, pose: Pose,
                box: tuple[float, ...]) -> float:
    """The share of the depths whose world point lies inside ``box`` (min xyz, max xyz)."""
    h, w = depth.shape
    ys, xs = np.mgrid[0:h, 0:w]
    has = np.isfinite(depth)
    if not has.any():
        return float('nan')
    z = depth[has].astype(np.float64)
    x = (xs[has] - camera.cx) / camera.fx * z
    y = (ys[has] - camera.cy) / camera.fy * z
    world = np.stack([x, y, z], axis=1) @ pose.rotation.T + pose.position
    lo, hi = np.asarray(box[:3]), np.asarray(box[3:])
    return float(np.all((world >= lo) & (world <= hi), axis=1).mean())
