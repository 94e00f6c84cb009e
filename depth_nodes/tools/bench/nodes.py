"""`depth-nodes bench cross_check` and `bench point_cloud`: a node's whole frame beside the
census SGM time on the same pair, in the same run.

One synthetic 640x480 frame (the simulator's rectified renders); every round runs the
node's frame callback with its messages in and its outputs caught by the harness sink
(nothing goes through the middleware), the node's core function alone, and SGM (128
disparities) on the same pair.

* cross_check: SGM's two DisparityImages and the cost ratio in, ``disparity_checked`` and
  ``confidence`` out; the core ``cross_check`` also with hole filling.
* point_cloud: the ground-truth DisparityImage (right cx offset 2 px), both CameraInfos
  and an rgb8 image in; a padded 32-byte colour cloud and a 32FC1 depth image out.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import cv2
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

from depth_nodes.core.camera import StereoModel
from depth_nodes.core.cross_check import cross_check
from depth_nodes.core.reproject import reproject_disparity
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.nodes.cross_check import CrossCheckNode
from depth_nodes.nodes.point_cloud import PointCloudNode
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image, to_gray
from depth_nodes.sim import StereoSimConfig, simulate_stereo
from depth_nodes.tools.bench.timing import median_ms


@dataclass
class NodeBench:
    """Median per-frame times of a node, of its core and of census SGM on the same pair."""

    width: int
    height: int
    repeats: int
    node_ms: float
    sgm_ms: float

    def _lines(self, title: str, setup: str, node: str,
               core: list[tuple[str, float]]) -> list[str]:
        rows = [(f'node, per frame ({node})', self.node_ms), *core,
                ('census SGM on the same pair (128 disp.)', self.sgm_ms)]
        width = max(len(label) for label, _ in rows) + 2
        lines = [f'{title}: {self.width}x{self.height} {setup}, median of {self.repeats} '
                 'interleaved rounds']
        lines += [f'  {label:<{width}}{ms:8.2f} ms' for label, ms in rows]
        lines[-1] += f'   node / SGM = {self.node_ms / self.sgm_ms:5.3f}'
        return lines


@dataclass
class CrossCheckBench(NodeBench):
    """The cross-check node (speckle_size 100) and its core, with and without filling."""

    core_ms: float
    core_fill_ms: float
    learned_ms: float

    def format(self) -> str:
        """The printed report."""
        lines = self._lines(
            'cross_check', 'speckle_size 100', 'disparity_checked + confidence', [
            ('node, confidence_model learned', self.learned_ms),
            ('core cross_check only', self.core_ms),
            ('core cross_check with fill_holes', self.core_fill_ms)])
        lines[2] += f'   learned / hand-made = {self.learned_ms / self.node_ms:5.2f}'
        return '\n'.join(lines)


@dataclass
class PointCloudBench(NodeBench):
    """The point-cloud node (rgb8, padded points, 32FC1 depth) and the reprojection."""

    reproject_ms: float
    cloud_bytes: int
    point_step: int
    depth_bytes: int

    def format(self) -> str:
        """The printed report."""
        sizes = (f'  points2 {self.cloud_bytes / 1e6:.2f} MB ({self.point_step} bytes x '
                 f'{self.width * self.height} points), depth {self.depth_bytes / 1e6:.2f} MB')
        return '\n'.join([*self._lines(
            'point_cloud', 'rgb8, padded points, 32FC1 depth', 'points2 + depth', [
            ('core reproject_disparity only', self.reproject_ms)]), sizes])


@contextlib.contextmanager
def node_on_bench(node_class: Callable[..., Any], **parameters: Any
                  ) -> Iterator[tuple[Any, dict[str, Any]]]:
    """A node on a context of its own, with OpenCV's threads as the caller set them (the
    node applies its ``threads`` every frame) and ``parameters``; yields the node and the
    dict its outputs land in (topic -> last message)."""
    context = Context()
    rclpy.init(args=[], context=context)
    try:
        node = node_class(context=context, parameter_overrides=[
            Parameter('threads', value=cv2.getNumThreads()),
            *(Parameter(name, value=value) for name, value in parameters.items())])
        out: dict[str, Any] = {}
        node.sink = out.__setitem__
        try:
            yield node, out
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def bench_cross_check(repeats: int = 20) -> CrossCheckBench:
    """Time the cross-check of a 640x480 SGM result, beside SGM in the same run."""
    frame = next(simulate_stereo(StereoSimConfig(width=640, height=480, n_frames=1, seed=1)))
    h, w = frame.disparity_gt.shape
    stereo = StereoModel(frame.left_camera, frame.right_camera)
    matcher = SgmMatcher(SgmParams(disparity_range=128))
    left, right = frame.left_rect_gt, frame.right_rect_gt
    result = matcher.match(left, right)
    common: dict[str, Any] = {
        'focal': stereo.focal, 'baseline': stereo.baseline, 'min_disparity': 0.0,
        'max_disparity': 127.0, 'delta_d': 1 / 32, 'valid_window': (0, 0, w, h)}
    msgs = [build_disparity(result.disparity, None, **common),
            build_disparity(result.disparity_right, None, **common),
            array_to_image(result.cost_ratio, '32FC1')]
    disparity, disparity_right, ratio = (result.disparity.copy(),
                                         result.disparity_right.copy(),
                                         result.cost_ratio.copy())
    with node_on_bench(CrossCheckNode) as (node, out), \
            node_on_bench(CrossCheckNode, confidence_model='learned') as (learned, _):
        ms = median_ms({
            'node': lambda: node.on_frame(*msgs),
            'learned': lambda: learned.on_frame(*msgs),
            'core': lambda: cross_check(disparity, disparity_right, ratio),
            'fill': lambda: cross_check(disparity, disparity_right, ratio, fill=True),
            'sgm': lambda: matcher.match(left, right),
        }, repeats, settle=0.05)
    assert set(out) == {'/disparity_checked', '/confidence'}
    return CrossCheckBench(w, h, repeats, node_ms=ms['node'], sgm_ms=ms['sgm'],
                           core_ms=ms['core'], core_fill_ms=ms['fill'],
                           learned_ms=ms['learned'])


def bench_point_cloud(repeats: int = 20) -> PointCloudBench:
    """Time building a 640x480 colour cloud + depth image, beside SGM in the same run."""
    frame = next(simulate_stereo(StereoSimConfig(width=640, height=480, n_frames=1, seed=1,
                                                 colour=True, right_cx_offset=2.0)))
    h, w = frame.disparity_gt.shape
    stereo = StereoModel(frame.left_camera, frame.right_camera)
    image = array_to_image(frame.left_rect_gt, 'rgb8')
    disparity = build_disparity(frame.disparity_gt, image.header, focal=stereo.focal,
                                baseline=stereo.baseline, min_disparity=-8.0,
                                max_disparity=127.0, delta_d=1 / 32)
    infos = [model_to_camera_info(m) for m in (frame.left_camera, frame.right_camera)]
    left, right = (to_gray(a, 'rgb8') for a in (frame.left_rect_gt, frame.right_rect_gt))
    matcher = SgmMatcher(SgmParams(disparity_range=128))
    with node_on_bench(PointCloudNode) as (node, out):
        ms = median_ms({
            'node': lambda: node.on_frame(disparity, *infos, image=image),
            'reproject': lambda: reproject_disparity(frame.disparity_gt, stereo),
            'sgm': lambda: matcher.match(left, right),
        }, repeats, settle=0.05)
    cloud, depth = out['/points2'], out['/depth']
    return PointCloudBench(w, h, repeats, node_ms=ms['node'], sgm_ms=ms['sgm'],
                           reproject_ms=ms['reproject'], cloud_bytes=len(cloud.data),
                           point_step=int(cloud.point_step), depth_bytes=len(depth.data))
