"""`depth-nodes bench cross_check`: the cross-check node's time beside the SGM time.

One synthetic 640x480 frame (the simulator's rectified renders); census SGM (128
disparities) gives the node's three inputs once, then every round runs the node's whole
frame callback (two DisparityImages and the cost ratio in; ``disparity_checked`` and
``confidence`` out, through the harness sink), the core ``cross_check`` alone, the core
with hole filling, and SGM on the same pair.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from depth_nodes.sim import StereoSimConfig, simulate_stereo
from depth_nodes.tools.bench.sgm import median_ms


@dataclass
class CrossCheckBench:
    """Median per-frame times of the cross-check node, its core, and census SGM."""

    width: int
    height: int
    repeats: int
    node_ms: float
    core_ms: float
    core_fill_ms: float
    sgm_ms: float

    def format(self) -> str:
        """The printed report."""
        return '\n'.join([
            f'cross_check: {self.width}x{self.height}, 128 disparities, speckle_size 100, '
            f'median of {self.repeats} interleaved rounds',
            f'  node, per frame (disparity_checked + confidence)  {self.node_ms:8.2f} ms',
            f'  core cross_check only                             {self.core_ms:8.2f} ms',
            f'  core cross_check with fill_holes                  {self.core_fill_ms:8.2f} ms',
            f'  census SGM on the same pair                       {self.sgm_ms:8.2f} ms'
            f'   node / SGM = {self.node_ms / self.sgm_ms:5.3f}',
        ])


def bench_cross_check(repeats: int = 20) -> CrossCheckBench:
    """Time the cross-check of a 640x480 SGM result, beside SGM in the same run."""
    import cv2
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from depth_nodes.core.camera import StereoModel
    from depth_nodes.core.cross_check import cross_check
    from depth_nodes.core.sgm import SgmMatcher, SgmParams
    from depth_nodes.nodes.cross_check import CrossCheckNode
    from depth_nodes.ros.disparity import build_disparity
    from depth_nodes.ros.image import array_to_image

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
    context = Context()
    rclpy.init(args=[], context=context)
    try:
        # the node's threads as the caller set OpenCV's (the node applies them every frame)
        node = CrossCheckNode(context=context, parameter_overrides=[
            Parameter('threads', value=cv2.getNumThreads())])
        out: dict[str, Any] = {}
        node.sink = out.__setitem__
        try:
            ms = median_ms({
                'node': lambda: node.on_frame(*msgs),
                'core': lambda: cross_check(disparity, disparity_right, ratio),
                'fill': lambda: cross_check(disparity, disparity_right, ratio, fill=True),
                'sgm': lambda: matcher.match(left, right),
            }, repeats, settle=0.05)
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    assert set(out) == {'/disparity_checked', '/confidence'}
    return CrossCheckBench(w, h, repeats, ms['node'], ms['core'], ms['fill'], ms['sgm'])
