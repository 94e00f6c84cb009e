"""`depth-nodes bench rectify`: the rectify node's frame beside cv2.remap and cv2.undistort.

Times are medians over repeated runs on the same synthetic frame, after one warm-up run;
OpenCV uses the thread count the caller set (``cv2.getNumThreads()``), printed with the
figures.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from std_msgs.msg import Header

from depth_nodes.core.rectify import interpolation_flag
from depth_nodes.nodes.rectify import RectifyNode
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.image import array_to_image
from depth_nodes.sim import StereoSimConfig, simulate_stereo
from depth_nodes.tools.bench.timing import median_ms


@dataclass
class RectifyBench:
    """Per-frame times of the rectify node and of OpenCV on the same frame."""

    width: int
    height: int
    encoding: str
    interpolation: str
    repeats: int
    threads: int
    first_frame_ms: float
    node_ms: float
    remap_ms: float
    messages_ms: float
    undistort_ms: float

    def format(self) -> str:
        """The printed report."""
        return '\n'.join([
            f'rectify: {self.width}x{self.height} {self.encoding}, {self.interpolation}, '
            f'median of {self.repeats} frames, OpenCV threads {self.threads}',
            f'  first frame (builds the maps)                  {self.first_frame_ms:8.2f} ms',
            f'  node, per frame (image_rect_color + image_rect) {self.node_ms:7.2f} ms',
            f'  cv2.remap with the cached maps                 {self.remap_ms:8.2f} ms'
            f'   node / remap     = {self.node_ms / self.remap_ms:5.2f}',
            f'  node part: building the two Image messages     {self.messages_ms:8.2f} ms'
            f'   (pixels copied into rclpy messages, mono conversion included)',
            f'  cv2.undistort (no R, no P; maps every call)    {self.undistort_ms:8.2f} ms'
            f'   node / undistort = {self.node_ms / self.undistort_ms:5.2f}',
        ])


def bench_rectify(*, width: int = 640, height: int = 480, repeats: int = 200,
                  interpolation: str = 'linear') -> RectifyBench:
    """Time the rectify node's frame callback against cv2.remap and cv2.undistort."""
    frame = next(simulate_stereo(StereoSimConfig(width=width, height=height, n_frames=1,
                                                 colour=True, seed=21)))
    camera = frame.left_camera
    header = Header(frame_id=camera.frame_id)
    image_msg = array_to_image(frame.left_raw, 'rgb8', header)
    info_msg = model_to_camera_info(camera, header)
    context = Context()
    rclpy.init(args=[], context=context)
    # the node's threads as the caller set OpenCV's (the node applies them every frame)
    node = RectifyNode(context=context, parameter_overrides=[
        Parameter('interpolation', value=interpolation),
        Parameter('threads', value=cv2.getNumThreads())])
    try:
        published: list[str] = []
        node.sink = lambda topic, msg: published.append(topic)  # keep no pixels
        start = time.perf_counter()
        node.on_frame(image_msg, info_msg)
        first_ms = (time.perf_counter() - start) * 1e3
        if len(published) != 2:
            raise RuntimeError(f'rectify node dropped the benchmark frame: {dict(node.drops)}')
        map1, map2 = node.rectifier.maps(camera)
        flag = interpolation_flag(interpolation)
        rect = cv2.remap(frame.left_raw, map1, map2, flag)
        ms = median_ms({
            'node': lambda: node.on_frame(image_msg, info_msg),
            'remap': lambda: cv2.remap(frame.left_raw, map1, map2, flag),
            'messages': lambda: (
                array_to_image(rect, 'rgb8', header),
                array_to_image(cv2.cvtColor(rect, cv2.COLOR_RGB2GRAY), 'mono8', header)),
            'undistort': lambda: cv2.undistort(frame.left_raw, camera.K, camera.D),
        }, repeats)
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
    return RectifyBench(width, height, 'rgb8', interpolation, repeats, cv2.getNumThreads(),
                        first_ms, ms['node'], ms['remap'], ms['messages'], ms['undistort'])
