"""`depth-nodes bench depth_filter`: the depth filter's stages, timed at 640x480 on one
core, beside librealsense's filters (pyrealsense2, the ``realsense`` extra) on the same
frames, and the node's whole frame callback.

Two chains, each stage's time the median over the frames (``--frames`` rounds of a short
simulated sequence of a moving camera, cycled): the full-size chain (flying pixels,
spatial, temporal moved with the camera's motion, hole filling farthest_from_around:
librealsense's has no flying-pixel stage and no motion), and the decimated one (decimation
by 2 first, then the same at 320x240, librealsense's recommended order). With ``busy``,
everything again with that many cores kept busy (a robot computer's other work).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import cv2
import numba
import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

from depth_nodes.core.depth_filter import DepthFilter, DepthFilterParams, stereo_sigma
from depth_nodes.core.depth_image import from_metres
from depth_nodes.nodes.depth_filter import DepthFilterNode
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.image import array_to_image
from depth_nodes.sim.depth_sequence import DepthFrame, DepthSequenceConfig, simulate_depth_sequence
from depth_nodes.tools.bags.depth_filter import FRAME_ID
from depth_nodes.tools.bags.multiview import camera_model, odometry_message
from depth_nodes.tools.bags.simulated import stamped_header
from depth_nodes.tools.bench.sgm import busy_loops
from depth_nodes.tools.evaluation import librealsense as rs

#: The stages in the order they run, as the core names them.
STAGES = ('decimation', 'flying', 'spatial', 'temporal', 'hole_filling')
#: Frames of the simulated sequence (cycled).
SEQUENCE_FRAMES = 4


@dataclass
class ChainTimes:
    """Median ms of each stage and of the whole chain, ours and librealsense's."""

    ours: dict[str, float]
    theirs: dict[str, float]


@dataclass
class DepthFilterBench:
    """The report (see the module notes)."""

    width: int
    height: int
    repeats: int
    full: ChainTimes
    decimated: ChainTimes
    node_ms: float
    busy: int = 0
    busy_full: ChainTimes | None = None
    busy_node_ms: float = float('nan')
    notes: list[str] = field(default_factory=list)

    def format(self) -> str:
        """The report as printed."""
        lines = [f'depth_filter: {self.width}x{self.height}, one core (numba and OpenCV 1 '
                 f'thread; librealsense runs on the calling thread), median of '
                 f'{self.repeats} frames of a moving camera']
        for title, times in (('full size: flying, spatial, temporal (with motion), holes',
                              self.full),
                             ('decimation 2 first, the rest at half size', self.decimated)):
            lines.append(f'  {title}')
            lines.append(f'    {"stage":14s} {"ours":>9s} {"librealsense":>13s}')
            for stage in (*STAGES, 'chain'):
                if stage not in times.ours:
                    continue
                theirs = times.theirs.get(stage)
                other = f'{theirs:10.2f} ms' if theirs is not None else '  (no such filter)'
                lines.append(f'    {stage:14s} {times.ours[stage]:6.2f} ms {other}')
        lines.append(f'  node frame callback (16UC1 in, depth, camera_info, filled, sigma '
                     f'out; odometry poses): {self.node_ms:.2f} ms')
        if self.busy_full is not None:
            lines.append(f'  with {self.busy} busy core(s): full-size chain '
                         f'{self.busy_full.ours["chain"]:.2f} ms (librealsense '
                         f'{self.busy_full.theirs["chain"]:.2f} ms), node '
                         f'{self.busy_node_ms:.2f} ms')
        lines.extend(self.notes)
        return '\n'.join(lines)


def _frames(width: int, height: int) -> list[DepthFrame]:
    config = DepthSequenceConfig(kind='moving_camera', width=width, height=height,
                                 n_frames=SEQUENCE_FRAMES, supersample=2)
    return list(simulate_depth_sequence(config))


def _chain(frames: list[DepthFrame], repeats: int, decimation: int) -> ChainTimes:
    params = DepthFilterParams(decimation=decimation, hole_filling='farthest_from_around')
    camera = frames[0].camera
    sim = DepthSequenceConfig()  # the noise the frames were made with
    theirs_settings = rs.RealsenseSettings(decimation=decimation, spatial=True, temporal=True,
                                           disparity=True, hole_filling=1)
    rs_camera = rs.Camera(camera.width, camera.height, camera.fx, camera.fy, camera.cx,
                          camera.cy, sim.baseline_m)
    filt = DepthFilter()
    ours: dict[str, list[float]] = {}
    theirs: dict[str, list[float]] = {}
    sigmas = [stereo_sigma(f.depth, f.camera.fx, sim.baseline_m, sim.disparity_sigma)
              for f in frames]
    with rs.RealsenseChain(theirs_settings, rs_camera) as chain:
        for k in range(repeats + 2):  # two rounds of warm-up (compilation, memory)
            frame = frames[k % len(frames)]
            start = time.perf_counter()
            result = filt.process(frame.depth, frame.camera, params, sigma=sigmas[k % len(frames)],
                                  pose=frame.pose)
            total = time.perf_counter() - start
            start = time.perf_counter()
            filtered = chain.process(np.nan_to_num(frame.depth, nan=0.0))
            their_total = time.perf_counter() - start
            if k < 2:
                continue
            for stage, seconds in result.times.items():
                ours.setdefault(stage, []).append(seconds)
            ours.setdefault('chain', []).append(total)
            for stage, seconds in filtered.seconds.items():
                theirs.setdefault(stage, []).append(seconds)
            theirs.setdefault('chain', []).append(their_total)
    mine = {k: 1000 * float(np.median(v)) for k, v in ours.items()}
    if decimation == 1:
        mine.pop('decimation', None)
    other = {k: 1000 * float(np.median(v)) for k, v in theirs.items()}
    # librealsense's domain changes belong to its spatial and temporal stages
    other['spatial'] = other.get('spatial', 0.0) + other.pop('depth_to_disparity', 0.0)
    other['temporal'] = other.get('temporal', 0.0) + other.pop('disparity_to_depth', 0.0)
    return ChainTimes(mine, other)


@contextlib.contextmanager
def _node() -> Iterator[Any]:
    context = Context()
    rclpy.init(args=[], context=context)
    node = DepthFilterNode(context=context, parameter_overrides=[
        Parameter('pose_source', value='odometry'), Parameter('noise_model', value='stereo'),
        Parameter('stereo_baseline', value=0.08), Parameter('threads', value=1),
        Parameter('hole_filling', value='farthest_from_around')])
    node.sink = lambda topic, msg: None
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def _node_ms(frames: list[DepthFrame], repeats: int) -> float:
    messages = []
    for frame in frames:
        header = stamped_header(frame.stamp_ns, FRAME_ID)
        messages.append((array_to_image(from_metres(frame.depth, '16UC1'), '16UC1', header),
                         model_to_camera_info(camera_model(frame.camera, FRAME_ID), header)))
    times = []
    step = frames[1].stamp_ns - frames[0].stamp_ns
    with _node() as node:
        for k in range(repeats + 2):
            frame = frames[k % len(frames)]
            lap = k // len(frames)  # stamps keep going forward round after round
            stamp = frame.stamp_ns + lap * len(frames) * step
            depth, info = messages[k % len(frames)]
            depth.header.stamp.sec, depth.header.stamp.nanosec = divmod(stamp, 10**9)
            info.header = depth.header
            node.poses.on_odometry(odometry_message(frame.pose, stamp, FRAME_ID))
            start = time.perf_counter()
            node.on_frame(depth, info)
            if k >= 2:
                times.append(time.perf_counter() - start)
        drops = dict(node.drops)
    if drops:
        raise RuntimeError(f'the depth_filter node dropped frames: {drops}')
    return 1000 * float(np.median(times))


def bench_depth_filter(*, size: tuple[int, int] = (640, 480), repeats: int = 20,
                       busy: int = 0) -> DepthFilterBench:
    """Time the chains and the node (see the module notes) on one thread."""
    numba.set_num_threads(1)
    cv2.setNumThreads(1)
    frames = _frames(*size)
    full = _chain(frames, repeats, 1)
    decimated = _chain(frames, repeats, 2)
    node_ms = _node_ms(frames, repeats)
    report = DepthFilterBench(size[0], size[1], repeats, full, decimated, node_ms, busy)
    if busy:
        loops = busy_loops(busy)
        try:
            time.sleep(0.5)
            report.busy_full = _chain(frames, repeats, 1)
            report.busy_node_ms = _node_ms(frames, repeats)
        finally:
            for loop in loops:
                loop.terminate()
                loop.wait()
    return report
