"""Every node fed randomly mutated messages: it survives, and counts what it loses.

For each node, frames of valid messages (small simulated images, their CameraInfos, the
disparities the matcher makes of them) are fed through the node's own input callbacks, as
the bag harness does; in most frames one field of one message is replaced by an extreme,
non-finite, empty, oversized or nonsensical value (any field, nested ones included: stamps,
sizes, encodings, data, calibration matrices, DisparityImage ranges, pattern tags). Each
node must:

* never let an exception out, and never need the last line of defence: every bad value is
  caught where messages are converted, so ``internal_error`` stays 0;
* account for every frame: a frame without output adds at least one counted drop (frames
  still held when the stream ends are counted by ``finish_stream``);
* keep producing output for the valid frames around the bad ones.

Fixed seeds, so a failure is reproducible; the mutation that broke a node is in the message.
"""

from __future__ import annotations

import array
import copy
import math
import random
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from helpers import Lazy
from rclpy.context import Context
from rclpy.parameter import Parameter
from ros_helpers import header
from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.nodes.cross_check import CrossCheckNode
from depth_nodes.nodes.point_cloud import PointCloudNode
from depth_nodes.nodes.rectify import RectifyNode
from depth_nodes.nodes.sgm_stereo import SgmStereoNode
from depth_nodes.nodes.structured_light import StructuredLightNode
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image
from depth_nodes.sim import StereoSimConfig, simulate_stereo

pytestmark = pytest.mark.ros

#: Frames per node and seed; a fresh node every FRESH frames (a mutated stamp far in the
#: future would otherwise make every later frame out of order).
FRAMES, FRESH = 120, 12
SEEDS = (1, 2)
W, H, RANGE = 64, 48, 16

FRAME = Lazy(lambda: next(simulate_stereo(StereoSimConfig(
                 width=W, height=H, n_frames=1, seed=9, distortion_scale=0.0, rotation_deg=0.0,
                 noise_sigma=1.0, focal_px=60.0))))
MATCH = Lazy(lambda: SgmMatcher(SgmParams(disparity_range=RANGE, paths=5)).match(FRAME.left_rect_gt,
                                                                                 FRAME.right_rect_gt))
DISPARITY_COMMON = {'focal': 60.0, 'baseline': 0.1, 'min_disparity': 0.0,
                    'max_disparity': RANGE - 1.0, 'delta_d': 1 / 32}

INT_LIMITS = {'int8': (-2**7, 2**7 - 1), 'uint8': (0, 2**8 - 1), 'int16': (-2**15, 2**15 - 1),
              'uint16': (0, 2**16 - 1), 'int32': (-2**31, 2**31 - 1),
              'uint32': (0, 2**32 - 1), 'int64': (-2**63, 2**63 - 1),
              'uint64': (0, 2**64 - 1), 'octet': (0, 255)}
FLOATS = (math.nan, math.inf, -math.inf, 0.0, -1.0, 1e30, -1e30, 1e-30)
STRINGS = ('', 'x' * 300, 'mono8', 'rgb8', '32FC1', 'bayer_rggb8', 'yuv422', 'mono16',
           '16UC1', 'nonsense', '\x00', '0:0/1', '7:3/2', '1:0/1000000', '-1:0/5',
           'plumb_bob', 'equidistant', 'rational_polynomial')


def _mutations(msg: Any, prefix: str = '') -> list[tuple[str, Any, str]]:
    """Every (path, owner, field) of ``msg`` that can be mutated, nested ones included."""
    out = []
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        if hasattr(value, 'get_fields_and_field_types'):
            out += _mutations(value, f'{prefix}{name}.')
        else:
            out.append((f'{prefix}{name}', msg, name))
    return out


def _mutate(msg: Any, rng: random.Random) -> str:
    """Replace one random field of ``msg`` with a hostile value; returns what was done."""
    path, owner, name = rng.choice(_mutations(msg))
    kind = owner.get_fields_and_field_types()[name]
    current = getattr(owner, name)
    if kind in INT_LIMITS:
        low, high = INT_LIMITS[kind]
        value: Any = rng.choice([low, high, 0, 1, high // 2 + 1, rng.randint(low, high)])
    elif kind in ('float', 'double'):
        value = rng.choice(FLOATS)
    elif kind == 'boolean':
        value = not current
    elif kind == 'string':
        value = rng.choice(STRINGS)
    elif kind.startswith('sequence<uint8') or kind.startswith('uint8['):
        size = len(current)
        choice = rng.choice(['empty', 'short', 'long', 'noise'])
        if kind.startswith('uint8['):  # fixed size: new values, same length
            value = [rng.randint(0, 255) for _ in range(size)]
        elif choice == 'empty':
            value = b''
        elif choice == 'short':
            value = bytes(current)[:max(0, size // 2 - 1)]
        elif choice == 'long':
            value = bytes(current) + bytes(rng.randint(1, 64))
        else:
            value = bytes(rng.getrandbits(8) for _ in range(size))
    elif 'double' in kind or 'float' in kind:  # fixed arrays (K, R, P) or sequences (D)
        items = list(current)
        if kind.startswith('sequence') and rng.random() < 0.4:
            value = [rng.choice(FLOATS) for _ in range(rng.choice([0, 1, 3, 100]))]
        else:
            if items:
                items[rng.randrange(len(items))] = rng.choice(FLOATS)
            value = array.array('d', items) if isinstance(current, array.array) else items
    else:
        return f'{path}: left as is ({kind})'
    try:
        setattr(owner, name, value)
    except (AssertionError, TypeError, ValueError):  # rclpy refuses it: no message to send
        return f'{path}: refused by rclpy'
    shown = repr(value) if not isinstance(value, (bytes, list, array.array)) else (
        f'{type(value).__name__} of {len(value)}')
    return f'{path} = {shown}'


def _info(model: Any, stamp: int) -> CameraInfo:
    return model_to_camera_info(model, header(stamp))


def _image(pixels: Any, encoding: str, stamp: int) -> Image:
    return array_to_image(np.ascontiguousarray(pixels), encoding, header(stamp))


def _disparity(values: Any, stamp: int) -> Any:
    return build_disparity(values, header(stamp), **DISPARITY_COMMON)


@dataclass
class Case:
    """How to build a node and the valid messages of one frame, by input topic suffix."""

    make: Callable[[Context], Any]
    frame: Callable[[int], dict[str, Any]]
    output: str


def _rectify(context: Context) -> Any:
    return RectifyNode(context=context)


def _sgm(context: Context) -> Any:
    return SgmStereoNode(context=context, parameter_overrides=[
        Parameter('disparity_range', value=RANGE), Parameter('paths', value=5),
        Parameter('threads', value=1)])


def _cross(context: Context) -> Any:
    return CrossCheckNode(context=context, parameter_overrides=[
        Parameter('fill_holes', value=True), Parameter('median_size', value=5)])


def _cloud(context: Context) -> Any:
    return PointCloudNode(context=context, parameter_overrides=[
        Parameter('use_confidence', value=True), Parameter('min_confidence', value=0.05)])


def _light(context: Context) -> Any:
    return StructuredLightNode(context=context, parameter_overrides=[
        Parameter('mode', value='gray'), Parameter('sequence_timeout', value=0.0)])


CASES = {
    'rectify': Case(_rectify, lambda t: {
        'image': _image(FRAME.left_raw, 'mono8', t),
        'camera_info': _info(FRAME.left_camera, t)}, '/image_rect'),
    'sgm_stereo': Case(_sgm, lambda t: {
        'left/image_rect': _image(FRAME.left_rect_gt, 'mono8', t),
        'left/camera_info': _info(FRAME.left_camera, t),
        'right/image_rect': _image(FRAME.right_rect_gt, 'mono8', t),
        'right/camera_info': _info(FRAME.right_camera, t)}, '/disparity'),
    'cross_check': Case(_cross, lambda t: {
        'disparity': _disparity(MATCH.disparity, t),
        'disparity_right': _disparity(MATCH.disparity_right, t),
        'cost_ratio': _image(MATCH.cost_ratio, '32FC1', t)}, '/disparity_checked'),
    'point_cloud': Case(_cloud, lambda t: {
        'disparity': _disparity(MATCH.disparity, t),
        'left/image_rect_color': _image(FRAME.left_rect_gt, 'mono8', t),
        'left/camera_info': _info(FRAME.left_camera, t),
        'right/camera_info': _info(FRAME.right_camera, t),
        'confidence': _image(np.full((H, W), 0.5, np.float32), '32FC1', t)}, '/points2'),
    'structured_light': Case(_light, lambda t: {
        'image': _image(FRAME.left_rect_gt, 'mono8', t),
        'camera_info': _info(FRAME.left_camera, t),
        'pattern': header(t, f'{t // 10**9}:0/24'),
        'projector/camera_info': _info(FRAME.right_camera, t)}, '/depth'),
}


def _route(node: Any) -> dict[str, Callable[[Any], None]]:
    """Input callbacks by topic suffix (the node's topics are resolved: '/image', ...)."""
    return {spec.topic.lstrip('/'): spec.callback for spec in node.inputs}


@pytest.mark.parametrize('seed', SEEDS)
@pytest.mark.parametrize('name', sorted(CASES))
def test_node_survives_mutated_messages_and_counts_its_losses(
        context: Context, name: str, seed: int) -> None:
    case = CASES[name]
    rng = random.Random(f'{name}-{seed}')
    done: list[str] = []
    produced = without_output = dropped = 0
    node = None
    try:
        for i in range(FRAMES):
            if i % FRESH == 0:
                if node is not None:
                    node.finish_stream()
                    dropped += sum(node.drops.values())
                    assert node.drops.get('internal_error', 0) == 0, (name, done[-FRESH:])
                    node.destroy_node()
                node = case.make(context)
                outbox: list[tuple[str, Any]] = []
                node.sink = lambda topic, msg, box=outbox: box.append((topic, msg))
                routes = _route(node)
            stamp = (i + 1) * 100_000_000
            msgs = case.frame(stamp)
            what = 'valid frame'
            if rng.random() < 0.75:
                target = rng.choice(sorted(msgs))
                msgs[target] = copy.deepcopy(msgs[target])
                what = f'{target}: {_mutate(msgs[target], rng)}'
            done.append(what)
            before = len(outbox)
            order = sorted(msgs)
            rng.shuffle(order)
            for topic in order:
                routes[topic](msgs[topic])  # an exception here fails the test: never expected
            if any(t == case.output for t, _ in outbox[before:]):
                produced += 1
            else:
                without_output += 1
        assert node is not None
        node.finish_stream()
        dropped += sum(node.drops.values())
        assert node.drops.get('internal_error', 0) == 0, (name, done[-FRESH:])
    finally:
        if node is not None:
            node.destroy_node()
    # every frame without output was counted, at least once
    assert dropped >= without_output, (name, produced, without_output, dropped)
    # and valid frames still come through around the bad ones
    if name != 'structured_light':  # a gray sequence needs 24 frames in a row
        assert produced >= FRAMES // 8, (name, produced, done)
