"""`depth-nodes bench tof`: the tof node's frame callback and its core decoding, timed on
the first frame of a ToF bag (the bundled tof_vga by default)."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from std_msgs.msg import Header

from depth_nodes.core.stamps import stamp_parts
from depth_nodes.core.tof import ToFDecoder, ToFParams
from depth_nodes.errors import BagError
from depth_nodes.nodes.tof import ToFNode
from depth_nodes.ros.camera_info import camera_info_to_model, model_to_camera_info
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.tools.bags.tof import NAMESPACE, read_topics


@dataclass
class ToFBench:
    """Per-frame times of the tof node and of its core decoding, 640x480."""

    width: int
    height: int
    planes: int
    threads: int
    repeats: int
    node_ms: float
    core_ms: float

    def format(self) -> str:
        """The report as printed."""
        return '\n'.join([
            f'tof: {self.width}x{self.height}, {self.planes} correlation planes, '
            f'{self.threads} thread(s), median of {self.repeats} frames',
            f'  node, per frame (decode, rectify, publish depth, amplitude, confidence, '
            f'points)  {self.node_ms:7.1f} ms  {1000 / self.node_ms:6.1f} frames/s',
            f'  core decoding alone (tof.decode_tof)                                     '
            f'{self.core_ms:7.1f} ms  {1000 / self.core_ms:6.1f} frames/s',
        ])


@contextlib.contextmanager
def _node() -> Iterator[Any]:
    """A tof node on a context of its own, its outputs dropped."""
    context = Context()
    rclpy.init(args=[], context=context)
    node = ToFNode(context=context)
    node.sink = lambda topic, msg: None
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def bench_tof(path: str | Path, *, repeats: int = 20, threads: int = 2) -> ToFBench:
    """Time the node's frame callback and the core decoding on the first frame of a ToF bag.

    Raises:
        BagError: Not a ToF bag.
    """
    raw, info_topic = f'{NAMESPACE}/correlation/image_raw', f'{NAMESPACE}/camera_info'
    config, found = read_topics(path, [raw, info_topic])
    if not found[raw]:
        raise BagError(f'{path}: no {raw} messages')
    stamp = min(found[raw])
    image, info = found[raw][stamp], found[info_topic][stamp]
    camera = camera_info_to_model(info)
    samples = image_to_array(image).reshape(-1, camera.height, camera.width)
    decoder = ToFDecoder()
    params = ToFParams(phase_steps=config.phase_steps)
    decoder.decode(samples, camera, config.frequencies_mhz, params)  # compile, maps
    core = []
    for _ in range(repeats):
        start = time.perf_counter()
        decoder.decode(samples, camera, config.frequencies_mhz, params)
        core.append(time.perf_counter() - start)
    header = Header(frame_id=camera.frame_id)
    header.stamp.sec, header.stamp.nanosec = stamp_parts(stamp)
    node_times = []
    with _node() as node:
        node.set_parameters([Parameter('modulation_frequencies',
                                       value=list(config.frequencies_mhz)),
                             Parameter('phase_steps', value=config.phase_steps),
                             Parameter('threads', value=threads)])
        msg = array_to_image(image_to_array(image), image.encoding, header)
        info_msg = model_to_camera_info(camera, header)
        node.on_frame(msg, info_msg)
        for _ in range(repeats):
            start = time.perf_counter()
            node.on_frame(msg, info_msg)
            node_times.append(time.perf_counter() - start)
        if node.drops:
            raise BagError(f'{path}: the tof node dropped the frame: {dict(node.drops)}')
    return ToFBench(camera.width, camera.height, samples.shape[0], threads, repeats,
                    float(np.median(node_times) * 1000), float(np.median(core) * 1000))
