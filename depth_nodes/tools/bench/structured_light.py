"""`depth-nodes bench structured_light`: decoding one sequence of a structured-light bag,
the core functions and the node's whole callback path, beside OpenCV's GrayCodePattern.

The methods are those ``eval`` scores on a structured-light bag
(tools/evaluation/structured_light.py); times are medians over repeated runs after one
warm-up run, OpenCV's one run (its per-pixel ``getProjPixel`` is slow).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from std_msgs.msg import Header

from depth_nodes.core.stamps import stamp_parts
from depth_nodes.core.structured_light import (
    PatternSet,
    ProjectorGeometry,
    SpeckleMatcher,
    camera_rays,
    shift_range,
    speckle_depth,
)
from depth_nodes.core.structured_light.reconstruct import reconstruct
from depth_nodes.errors import BagError
from depth_nodes.nodes.structured_light import StructuredLightNode
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.image import array_to_image
from depth_nodes.tools.bags.structured_light import read_structured_light_bag
from depth_nodes.tools.bench.timing import median_ms
from depth_nodes.tools.evaluation.structured_light import (
    SPECKLE_DEPTH_RANGE,
    SPECKLE_WINDOW,
    opencv_available,
    opencv_gray_columns,
)


@dataclass
class SLBench:
    """Per-sequence decode times at the bag's resolution (medians)."""

    size: tuple[int, int]
    frames: int
    repeats: int
    times_ms: dict[str, float]
    notes: dict[str, str] = field(default_factory=dict)

    def format(self) -> str:
        """The printed report."""
        lines = [f'structured light: {self.size[0]}x{self.size[1]}, sequences of '
                 f'{self.frames} frames, median of {self.repeats} runs, OpenCV threads '
                 f'{cv2.getNumThreads()}']
        for name, ms in self.times_ms.items():
            rate = f'  {1000 / ms:6.1f} frames/s' if name.startswith('speckle') else ''
            lines.append(f'  {name:<58}{ms:9.1f} ms{rate}')
        for name, note in self.notes.items():
            lines.append(f'  {name:<58}{note}')
        return '\n'.join(lines)


def bench_structured_light(path: str | Path, *, repeats: int = 10) -> SLBench:
    """Time decoding one sequence of the bag: core functions, the whole node callback path
    (messages in, depth / points2 / confidence out), speckle, and OpenCV's GrayCodePattern
    (one run: its per-pixel ``getProjPixel`` is slow).

    Raises:
        BagError: As :func:`read_structured_light_bag`.
    """
    bag = read_structured_light_bag(path)
    if not bag.sequences:
        raise BagError(f'{path}: no complete sequence to time')
    cfg, seq = bag.config, bag.sequences[0]
    ps = cfg.pattern_set
    gray = PatternSet('gray', ps.width, ps.height, ps.axes)
    geometry = ProjectorGeometry.from_models(bag.camera, bag.projector)
    rays = camera_rays(bag.camera)
    fns: dict[str, Any] = {
        f'{ps.mode} decode + triangulate (core, {ps.count} frames)':
            lambda: reconstruct(seq.images, ps, geometry, rays=rays),
        f'gray decode + triangulate (core, {gray.count} frames)':
            lambda: reconstruct(seq.images[:gray.count], gray, geometry, rays=rays),
    }
    node_fn, close = _node_runner(bag, seq)
    fns['node: messages in -> depth, points2, confidence out'] = node_fn
    if bag.speckle and bag.reference is not None:
        ref = bag.reference
        matcher = SpeckleMatcher()
        lo, hi = shift_range(bag.camera.K[0, 0], float(geometry.centre[0]),
                             cfg.reference_depth, *SPECKLE_DEPTH_RANGE)
        fns[f'speckle (core, one image, window {SPECKLE_WINDOW}, {hi - lo + 1} shifts)'] = \
            lambda: speckle_depth(
                bag.speckle[0], ref, focal=bag.camera.K[0, 0],
                baseline=float(geometry.centre[0]), reference_depth=cfg.reference_depth,
                depth_min=SPECKLE_DEPTH_RANGE[0], depth_max=SPECKLE_DEPTH_RANGE[1],
                window=SPECKLE_WINDOW, matcher=matcher)
    try:
        times = median_ms(fns, repeats)
    finally:
        close()
    out = SLBench((bag.camera.width, bag.camera.height), ps.count, repeats, times)
    name = f'opencv GrayCodePattern.getProjPixel ({gray.count} frames, one run)'
    if opencv_available():
        start = time.perf_counter()
        opencv_gray_columns(seq.images[:gray.count], ps.width)
        out.times_ms[name] = (time.perf_counter() - start) * 1e3
    else:
        out.notes[name] = 'unavailable: cv2.structured_light needs the opencv-contrib wheel'
    return out


def _node_runner(bag: Any, seq: Any) -> tuple[Any, Any]:
    """A function feeding one sequence through a StructuredLightNode, and its cleanup."""
    cfg = bag.config
    context = Context()
    rclpy.init(args=[], context=context)
    node = StructuredLightNode(context=context, parameter_overrides=[
        Parameter('mode', value=cfg.mode), Parameter('axes', value=cfg.axes),
        Parameter('phase_steps', value=cfg.steps),
        Parameter('phase_period', value=float(cfg.period))])
    published: list[str] = []
    node.sink = lambda topic, msg: published.append(topic)
    cb = {spec.topic: spec.callback for spec in node.inputs}
    node.on_projector_info(model_to_camera_info(bag.projector))
    msgs = [(array_to_image(image, 'mono8', header_at(0, bag.camera.frame_id)),
             model_to_camera_info(bag.camera, header_at(0, bag.camera.frame_id)))
            for image in seq.images]
    topics = {name: _topic(cb, name) for name in ('image', 'camera_info', 'pattern')}
    runs = [0]

    def run() -> None:  # fresh stamps and sequence number every run
        runs[0] += 1
        for k, (image, info) in enumerate(msgs):
            stamp = (runs[0] * 10**9 + k) * 1000
            for header in (image.header, info.header):
                header.stamp.sec, header.stamp.nanosec = divmod(stamp, 10**9)
            cb[topics['image']](image)
            cb[topics['camera_info']](info)
            cb[topics['pattern']](header_at(stamp, f'{runs[0]}:{k}/{len(msgs)}'))
        if len(published) != 3 * runs[0]:
            raise RuntimeError(f'the node dropped the benchmark sequence: {dict(node.drops)}')

    def close() -> None:
        node.destroy_node()
        rclpy.shutdown(context=context)

    return run, close


def _topic(cb: dict[str, Any], name: str) -> str:
    return next(t for t in cb if t.rsplit('/', 1)[-1] == name)


def header_at(stamp_ns: int, frame_id: str) -> Header:
    """A header with ``frame_id`` stamped ``stamp_ns``."""
    header = Header(frame_id=frame_id)
    header.stamp.sec, header.stamp.nanosec = stamp_parts(stamp_ns)
    return header
