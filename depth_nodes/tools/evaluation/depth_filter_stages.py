"""`depth-nodes eval` on a depth_* bag (or `eval-depth-filter`): its frames through this
package's depth filter and, stage by stage, through librealsense's own filters
(pyrealsense2, the ``realsense`` extra), every version scored against the truth
(:mod:`depth_nodes.tools.evaluation.depth_filter`).

Each stage runs alone with both libraries' defaults for it, on the same frames: decimation
by 2, flying pixels (librealsense has no such filter: its row is the input), spatial,
temporal (in the disparity domain, librealsense's recommendation; this package's with the
bag's poses, librealsense's has none), hole filling (each of the three modes), and the
chains: this package's defaults against librealsense's recommended spatial + temporal;
with a moving camera, this package's chain also without the poses (the ghosts they
prevent).
A decimated version is scored against the truth's block medians.

A processed bag (``depth-nodes process BAG OUT --config config/depth_filter_pipeline.yaml``)
also has the node's own output, ``/camera/filtered/image_rect``, scored beside.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.depth_filter import DepthFilter, DepthFilterParams, stereo_sigma
from depth_nodes.core.depth_filter.decimate import decimate
from depth_nodes.core.depth_image import to_metres
from depth_nodes.core.geometry import Intrinsics, Pose, intrinsics
from depth_nodes.errors import BagError
from depth_nodes.ros.camera_info import camera_info_to_model
from depth_nodes.ros.image import image_to_array
from depth_nodes.sim.depth_sequence import DepthSequenceConfig
from depth_nodes.tools.bags.depth_filter import NAMESPACE, read_topics
from depth_nodes.tools.evaluation import librealsense as rs
from depth_nodes.tools.evaluation.depth_filter import Scores, Version, format_table, score

F32 = NDArray[np.float32]
DEPTH = f'{NAMESPACE}/depth/image_rect_raw'
INFO = f'{NAMESPACE}/depth/camera_info'
ODOM = f'{NAMESPACE}/odom'
TRUTH = f'{NAMESPACE}/depth_gt'
LABELS = f'{NAMESPACE}/labels_gt'
FILTERED = f'{NAMESPACE}/filtered/image_rect'
FILLED = f'{NAMESPACE}/filtered/filled'
#: Every stage off (decimation and hole filling are by default).
_OFF = DepthFilterParams(flying_gap=0.0, spatial=False, temporal=False)


@dataclass
class Sequence:
    """A depth bag's frames: measured depth, truth, labels, camera, poses, and the
    per-pixel noise of the simulated camera."""

    config: DepthSequenceConfig
    depth: list[F32]
    truth: list[F32]
    labels: list[NDArray[np.uint8]]
    camera: Intrinsics
    poses: list[Pose | None]
    filtered: Version | None

    def sigma(self, depth: F32) -> F32:
        """The camera's noise at ``depth`` (what the node's noise_model gives)."""
        if self.config.noise == 'tof':
            return (self.config.tof_noise * depth).astype(np.float32)
        return stereo_sigma(depth, self.camera.fx, self.config.baseline_m,
                            self.config.disparity_sigma)


def read_sequence(path: str | Path) -> Sequence:
    """The frames of a depth bag (generated, or processed: then with the node's output).

    Raises:
        BagError: Not a depth bag, or a topic missing.
    """
    config, found = read_topics(path, [DEPTH, INFO, ODOM, TRUTH, LABELS, FILTERED, FILLED],
                                optional=(ODOM, FILTERED, FILLED))
    stamps = sorted(found[DEPTH])
    if not stamps:
        raise BagError(f'{path}: no depth frames on {DEPTH}')
    info = found[INFO][stamps[0]]
    camera = intrinsics(camera_info_to_model(info))
    depth = [to_metres(image_to_array(found[DEPTH][s]), found[DEPTH][s].encoding)
             for s in stamps]
    truth = [np.asarray(image_to_array(found[TRUTH][s]), np.float32) for s in stamps]
    labels = [np.asarray(image_to_array(found[LABELS][s]), np.uint8) for s in stamps]
    poses: list[Pose | None] = []
    for s in stamps:
        odom = found[ODOM].get(s)
        if odom is None:
            poses.append(None)
            continue
        p, q = odom.pose.pose.position, odom.pose.pose.orientation
        poses.append(Pose.from_quaternion((p.x, p.y, p.z), (q.x, q.y, q.z, q.w)))
    filtered = None
    if found[FILTERED]:
        if set(found[FILTERED]) != set(stamps):
            raise BagError(f'{path}: {FILTERED} has {len(found[FILTERED])} frames for the '
                           f'{len(stamps)} depth frames (a node dropped some: see `process`)')
        filtered = Version('depth_filter node (bag)', [
            to_metres(image_to_array(found[FILTERED][s]), found[FILTERED][s].encoding)
            for s in stamps])
        if found[FILLED]:
            filtered.filled = [np.asarray(image_to_array(found[FILLED][s])) == 255
                               for s in stamps]
    return Sequence(config, depth, truth, labels, camera, poses, filtered)


@dataclass(frozen=True)
class Stage:
    """One comparison: this package's settings and librealsense's (keyword arguments of
    :class:`~depth_nodes.tools.evaluation.librealsense.RealsenseSettings`; None: it has no
    such filter)."""

    name: str
    ours: DepthFilterParams
    theirs: dict[str, Any] | None
    decimation: int = 1
    #: Also this package's filter without the poses (the ghosts the motion prevents).
    without_poses: bool = False


STAGES = (
    Stage('decimation 2', replace(_OFF, decimation=2), {'decimation': 2}, 2),
    Stage('flying pixels', DepthFilterParams(spatial=False, temporal=False), None),
    Stage('spatial', DepthFilterParams(flying_gap=0.0, temporal=False),
          {'spatial': True, 'disparity': True}),
    Stage('temporal', DepthFilterParams(flying_gap=0.0, spatial=False),
          {'temporal': True, 'disparity': True}),
    Stage('holes: fill_from_left', replace(_OFF, hole_filling='fill_from_left'),
          {'hole_filling': 0}),
    Stage('holes: farthest_from_around', replace(_OFF, hole_filling='farthest_from_around'),
          {'hole_filling': 1}),
    Stage('holes: nearest_from_around', replace(_OFF, hole_filling='nearest_from_around'),
          {'hole_filling': 2}),
    Stage('chain (defaults)', DepthFilterParams(),
          {'spatial': True, 'temporal': True, 'disparity': True}, without_poses=True),
)


def _ours(seq: Sequence, stage: Stage, *, poses: bool = True) -> Version:
    filt = DepthFilter()
    out = Version('depth_filter' if poses else 'depth_filter, without poses', [], [], [])
    assert out.filled is not None
    for depth, pose in zip(seq.depth, seq.poses if poses else [None] * len(seq.depth),
                           strict=True):
        start = time.perf_counter()
        result = filt.process(depth, seq.camera, stage.ours, sigma=seq.sigma(depth),
                              pose=pose)
        out.seconds.append(time.perf_counter() - start)
        out.depths.append(result.depth)
        out.filled.append(result.filled)
    return out


def _theirs(seq: Sequence, stage: Stage) -> Version:
    if stage.theirs is None:
        return Version('librealsense: no such filter', list(seq.depth))
    camera = rs.Camera(seq.camera.width, seq.camera.height, seq.camera.fx, seq.camera.fy,
                       seq.camera.cx, seq.camera.cy, seq.config.baseline_m)
    out = Version('librealsense', [])
    h, w = seq.camera.height // stage.decimation, seq.camera.width // stage.decimation
    with rs.RealsenseChain(rs.RealsenseSettings(**stage.theirs), camera) as chain:
        for depth in seq.depth:
            start = time.perf_counter()
            result = chain.process(np.nan_to_num(depth, nan=0.0))
            out.seconds.append(time.perf_counter() - start)
            out.depths.append(result.depth[:h, :w])  # its decimation pads to 4 pixels
    return out


def _on_grid(seq: Sequence, factor: int) -> tuple[list[F32], list[F32], list[Any]]:
    """Truth, measured depth and labels on the decimated grid (block medians; a label bit
    set anywhere in the block)."""
    if factor == 1:
        return seq.truth, seq.depth, seq.labels
    truth = [decimate(t, factor)[0] for t in seq.truth]
    measured = [decimate(d, factor)[0] for d in seq.depth]
    labels = []
    for lab in seq.labels:
        h, w = lab.shape[0] // factor, lab.shape[1] // factor
        blocks = lab[:h * factor, :w * factor].reshape(h, factor, w, factor)
        labels.append(np.bitwise_or.reduce(np.bitwise_or.reduce(blocks, axis=3), axis=1))
    return truth, measured, labels


def compare(seq: Sequence, *, librealsense: bool, skip: int, persistence: int,
            on_stage: Callable[[str], None] = lambda name: None) -> str:
    """The tables: the input and the node's output, then each stage's versions."""
    still = seq.config.kind != 'moving_camera'

    def rows(versions: list[Version], factor: int) -> list[Scores]:
        truth, measured, labels = _on_grid(seq, factor)
        return [score(v, truth, measured, labels, skip=skip, still=still,
                      persistence=persistence) for v in versions]

    head = [Version('input (the camera)', list(seq.depth))]
    if seq.filtered is not None:
        head.append(seq.filtered)
    tables = [format_table(rows(head, 1), f'{seq.config.kind}, {seq.config.noise} noise, '
                           f'{seq.camera.width}x{seq.camera.height}, {len(seq.depth)} frames '
                           f'(scored from frame {skip})')]
    for stage in STAGES:
        on_stage(stage.name)
        versions = [_ours(seq, stage)]
        if stage.without_poses and any(pose is not None for pose in seq.poses) and not still:
            versions.append(_ours(seq, stage, poses=False))
        if librealsense:
            versions.append(_theirs(seq, stage))
        tables.append(format_table(rows(versions, stage.decimation), stage.name))
    return '\n\n'.join(tables)
