"""`depth-nodes bench point_cloud`: the point-cloud node's time beside the SGM time.

One synthetic 640x480 colour frame (the simulator's rectified renders, ground-truth
disparity, right cx offset 2 px); every round runs the node's whole frame callback
(DisparityImage, both CameraInfos and an rgb8 image in; a padded 32-byte colour cloud
and a 32FC1 depth image out, through the harness sink) and census SGM on the same pair.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from depth_nodes.sim import StereoSimConfig, simulate_stereo
from depth_nodes.tools.bench.sgm import median_ms


@dataclass
class PointCloudBench:
    """Median per-frame times of the point-cloud node and of census SGM."""

    width: int
    height: int
    repeats: int
    node_ms: float
    reproject_ms: float
    sgm_ms: float
    cloud_bytes: int
    point_step: int
    depth_bytes: int

    def format(self) -> str:
        """The printed report."""
        return '\n'.join([
            f'point_cloud: {self.width}x{self.height} rgb8, padded points, 32FC1 depth, '
            f'median of {self.repeats} interleaved rounds',
            f'  node, per frame (points2 + depth)        {self.node_ms:8.2f} ms',
            f'  core reproject_disparity only            {self.reproject_ms:8.2f} ms',
            f'  census SGM on the same pair (128 disp.)  {self.sgm_ms:8.2f} ms'
            f'   node / SGM = {self.node_ms / self.sgm_ms:5.3f}',
            f'  points2 {self.cloud_bytes / 1e6:.2f} MB ({self.point_step} bytes x '
            f'{self.width * self.height} points), depth {self.depth_bytes / 1e6:.2f} MB',
        ])


def bench_point_cloud(repeats: int = 20) -> PointCloudBench:
    """Time building a 640x480 colour cloud + depth image, beside SGM in the same run."""
    import cv2
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from depth_nodes.core.camera import StereoModel
    from depth_nodes.core.reproject import reproject_disparity
    from depth_nodes.core.sgm import SgmMatcher, SgmParams
    from depth_nodes.nodes.point_cloud import PointCloudNode
    from depth_nodes.ros.camera_info import model_to_camera_info
    from depth_nodes.ros.disparity import build_disparity
    from depth_nodes.ros.image import array_to_image, to_gray

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
    context = Context()
    rclpy.init(args=[], context=context)
    try:
        # the node's threads as the caller set OpenCV's (the node applies them every frame)
        node = PointCloudNode(context=context, parameter_overrides=[
            Parameter('threads', value=cv2.getNumThreads())])
        out: dict[str, Any] = {}
        node.sink = out.__setitem__
        try:
            ms = median_ms({
                'node': lambda: node.on_frame(disparity, *infos, image=image),
                'reproject': lambda: reproject_disparity(frame.disparity_gt, stereo),
                'sgm': lambda: matcher.match(left, right),
            }, repeats, settle=0.05)
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    cloud, depth = out['/points2'], out['/depth']
    return PointCloudBench(w, h, repeats, ms['node'], ms['reproject'], ms['sgm'],
                           len(cloud.data), int(cloud.point_step), len(depth.data))
