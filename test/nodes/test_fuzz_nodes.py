"""Every node of the registry fed randomly mutated messages: it survives, and counts what
it loses.

The campaign iterates over the node registry (depth_nodes/nodes/registry.py): each node's
valid frames are built from its ``inputs`` kind (:data:`KINDS`: small simulated images,
their CameraInfos, the disparities the matcher makes of them, depth images, time-of-flight
correlation frames), and fed through the node's own input callbacks, as the bag harness
does; in most frames one field of one message is replaced by an extreme, non-finite, empty,
oversized or nonsensical value (any field, nested ones included: stamps, sizes, encodings,
data, calibration matrices, DisparityImage ranges, pattern tags). A registry node whose kind
has no frame builder fails, so no node is left out. Each node must:

* never let an exception out, and never need the last line of defence: every bad value is
  caught where messages are converted, so ``internal_error`` stays 0;
* account for every frame: never publish an empty image or cloud for a frame it cannot
  use, and a frame without output adds at least one counted drop (frames still held when
  the stream ends are counted by ``finish_stream``);
* keep producing output for the valid frames around the bad ones.

A node without input messages (kind ``none``: static_transform, which latches one
transform at start-up) has its parameters as its only input: hostile values must end its
start-up with a one-line error, or it latches one finite transform.

Fixed seeds, so a failure is reproducible; the mutation that broke a node is in the message.
Known failures are marked ``xfail(strict=True)`` with their issue, per node and seed: the
marker must go when the bug is fixed.
"""

from __future__ import annotations

import array
import copy
import importlib
import math
import random
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from helpers import Lazy
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.parameter import Parameter
from ros_helpers import header
from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.errors import DepthNodesError
from depth_nodes.graph.description import resolve_plugin
from depth_nodes.nodes.registry import NODES, NodeEntry
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image
from depth_nodes.sim import StereoSimConfig, simulate_stereo
from depth_nodes.sim.tof import ToFSimConfig, simulate_tof

pytestmark = [pytest.mark.ros, pytest.mark.slow]

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
TOF = Lazy(lambda: next(simulate_tof(ToFSimConfig(
               width=W, height=H, focal_px=50.0, supersample=1, emitter_step=8,
               multipath=False, n_frames=1))))
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


def _depth(stamp: int) -> Image:
    """The left view's depth, 32FC1 metres (NaN where the scene has none)."""
    return _image(FRAME.depth_gt.astype(np.float32), '32FC1', stamp)


def _millimetres(stamp: int) -> Image:
    depth = np.nan_to_num(FRAME.depth_gt * 1000.0, nan=0.0, posinf=0.0)
    return _image(np.clip(depth, 0, 65535).astype(np.uint16), '16UC1', stamp)


def _tof(stamp: int) -> Image:
    planes = TOF.samples
    return _image(planes.reshape(-1, planes.shape[-1]), '16UC1', stamp)


def _odometry(stamp: int) -> Odometry:
    """A camera moving sideways at 0.5 m/s (5 cm between two frames 0.1 s apart)."""
    msg = Odometry(header=header(stamp, 'world'), child_frame_id='camera')
    msg.pose.pose.position.x = 0.5 * stamp / 1e9
    msg.pose.pose.orientation.w = 1.0
    return msg


@dataclass(frozen=True)
class Kind:
    """An inputs kind of the registry: the valid messages of one frame by input topic
    suffix, and the output topic a frame produces."""

    frame: Callable[[int], dict[str, Any]]
    output: str


KINDS = {
    'camera': Kind(lambda t: {
        'image': _image(FRAME.left_raw, 'mono8', t),
        'camera_info': _info(FRAME.left_camera, t)}, '/image_rect'),
    'stereo_rect': Kind(lambda t: {
        'left/image_rect': _image(FRAME.left_rect_gt, 'mono8', t),
        'left/camera_info': _info(FRAME.left_camera, t),
        'right/image_rect': _image(FRAME.right_rect_gt, 'mono8', t),
        'right/camera_info': _info(FRAME.right_camera, t)}, '/disparity'),
    'disparity_pair': Kind(lambda t: {
        'disparity': _disparity(MATCH.disparity, t),
        'disparity_right': _disparity(MATCH.disparity_right, t),
        'cost_ratio': _image(MATCH.cost_ratio, '32FC1', t)}, '/disparity_checked'),
    'stereo_disparity': Kind(lambda t: {
        'disparity': _disparity(MATCH.disparity, t),
        'left/image_rect_color': _image(FRAME.left_rect_gt, 'mono8', t),
        'left/camera_info': _info(FRAME.left_camera, t),
        'right/camera_info': _info(FRAME.right_camera, t),
        'confidence': _image(np.full((H, W), 0.5, np.float32), '32FC1', t)}, '/points2'),
    'pattern_sequence': Kind(lambda t: {
        'image': _image(FRAME.left_rect_gt, 'mono8', t),
        'camera_info': _info(FRAME.left_camera, t),
        'pattern': header(t, f'{t // 10**9}:0/24'),
        'projector/camera_info': _info(FRAME.right_camera, t)}, '/depth'),
    'depth': Kind(lambda t: {
        'image_rect': _depth(t),
        'camera_info': _info(FRAME.left_camera, t)}, '/points'),
    'depth_colour': Kind(lambda t: {
        'depth_registered/image_rect': _depth(t),
        'rgb/image_rect_color': _image(FRAME.left_rect_gt, 'mono8', t),
        'rgb/camera_info': _info(FRAME.left_camera, t)}, '/points'),
    'depth_two_cameras': Kind(lambda t: {
        'depth/image_rect': _millimetres(t),
        'depth/camera_info': _info(FRAME.left_camera, t),
        'rgb/camera_info': _info(FRAME.right_camera, t)}, '/depth_registered/image_rect'),
    'depth_raw': Kind(lambda t: {'image_raw': _millimetres(t)}, '/image'),
    'depth_stereo': Kind(lambda t: {
        'left/image_rect': _depth(t),
        'right/camera_info': _info(FRAME.right_camera, t)}, '/left/disparity'),
    'tof_correlation': Kind(lambda t: {
        'correlation/image_raw': _tof(t),
        'camera_info': _info(TOF.camera, t)}, '/depth/image_rect'),
    'posed_camera': Kind(lambda t: {
        'image_rect': _image(FRAME.left_rect_gt, 'mono8', t),
        'camera_info': _info(FRAME.left_camera, t),
        'odom': _odometry(t)}, '/depth'),
}

#: Parameters a node runs with here (ranges that fit 64 x 48 images, its optional inputs
#: and checks on); the others run with their defaults.
PARAMETERS = {
    'sgm_stereo': [Parameter('disparity_range', value=RANGE), Parameter('paths', value=5),
                   Parameter('threads', value=1)],
    'cross_check': [Parameter('fill_holes', value=True), Parameter('median_size', value=5)],
    'point_cloud': [Parameter('use_confidence', value=True),
                    Parameter('min_confidence', value=0.05)],
    'structured_light': [Parameter('mode', value='gray'),
                         Parameter('sequence_timeout', value=0.0)],
    'register_depth': [Parameter('depth_in_rgb', value=[0.02, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])],
    'tof': [Parameter('threads', value=1)],
    'multiview_stereo': [Parameter('planes', value=RANGE), Parameter('paths', value=5),
                         Parameter('threads', value=1), Parameter('min_depth', value=0.5),
                         Parameter('max_depth', value=10.0)],
}


def _make(entry: NodeEntry, context: Context) -> Any:
    node_class = resolve_plugin(entry.name)
    return node_class(context=context, parameter_overrides=PARAMETERS.get(entry.name, []))


def _empty(msg: Any) -> bool:
    """An image, cloud or disparity with no pixels: no output for the frame."""
    holder = getattr(msg, 'image', msg)
    return getattr(holder, 'width', 1) * getattr(holder, 'height', 1) == 0


def _route(node: Any) -> dict[str, Callable[[Any], None]]:
    """Input callbacks by topic suffix (the node's topics are resolved: '/image', ...)."""
    return {spec.topic.lstrip('/'): spec.callback for spec in node.inputs}


_EMPTY_DEPTH = 'a depth image 0 pixels wide or high gives an empty {} instead of a counted drop'
#: Known failures, each an xfail(strict=True) of that node and seed: (node, seed) -> why.
KNOWN = {
    **{('point_cloud_xyz', seed): 'issue 33: ' + _EMPTY_DEPTH.format('cloud') for seed in SEEDS},
    **{('point_cloud_xyzrgb', seed): 'issue 33: a colour image 0 pixels wide or high raises '
       'IndexError (internal_error); ' + _EMPTY_DEPTH.format('cloud') for seed in SEEDS},
    **{('register_depth', seed): 'issue 33: a camera_info 2**31 pixels wide or high makes it '
       'allocate hundreds of GiB (MemoryError, internal_error)' for seed in SEEDS},
    **{('convert_metric', seed): 'issue 33: ' + _EMPTY_DEPTH.format('image') for seed in SEEDS},
    ('depth_disparity', 1): 'issue 33: a right camera_info whose focal length is 0 makes '
                            'depth_to_disparity raise ArgumentError (internal_error)',
    ('depth_disparity', 2): 'issue 33: ' + _EMPTY_DEPTH.format('disparity'),
}


def _cases(entries: list[NodeEntry]) -> list[Any]:
    return [pytest.param(entry, seed, id=f'{entry.name}-{seed}', marks=[
        pytest.mark.xfail(strict=True, reason=KNOWN[entry.name, seed])]
        if (entry.name, seed) in KNOWN else []) for entry in entries for seed in SEEDS]


WITH_INPUTS = [entry for entry in NODES if entry.inputs != 'none']
WITHOUT_INPUTS = [entry for entry in NODES if entry.inputs == 'none']


@pytest.mark.parametrize(('entry', 'seed'), _cases(WITH_INPUTS))
def test_node_survives_mutated_messages_and_counts_its_losses(
        context: Context, entry: NodeEntry, seed: int) -> None:
    name = entry.name
    assert entry.inputs in KINDS, (f'{name}: no frame builder for inputs kind '
                                   f'{entry.inputs!r}; add one to KINDS')
    kind = KINDS[entry.inputs]
    rng = random.Random(f'{name}-{seed}')
    done: list[str] = []
    produced = without_output = dropped = 0
    empty: list[str] = []
    node = None
    try:
        for i in range(FRAMES):
            if i % FRESH == 0:
                if node is not None:
                    node.finish_stream()
                    dropped += sum(node.drops.values())
                    assert node.drops.get('internal_error', 0) == 0, (name, done[-FRESH:])
                    node.destroy_node()
                node = _make(entry, context)
                outbox: list[tuple[str, Any]] = []
                node.sink = lambda topic, msg, box=outbox: box.append((topic, msg))
                routes = _route(node)
                assert set(kind.frame(1)) <= set(routes), (name, sorted(routes))
            stamp = (i + 1) * 100_000_000
            msgs = kind.frame(stamp)
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
            outputs = [m for t, m in outbox[before:] if t == kind.output]
            if any(_empty(m) for m in outputs):  # a frame lost without a word
                empty.append(what)
            if any(not _empty(m) for m in outputs):
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
    # an empty image or cloud is no output: the frame must be counted instead
    assert not empty, (name, empty)
    # every frame without output was counted, at least once
    assert dropped >= without_output, (name, produced, without_output, dropped)
    # and valid frames still come through around the bad ones
    if entry.inputs != 'pattern_sequence':  # a gray sequence needs 24 frames in a row
        assert produced >= FRAMES // 8, (name, produced, done)


#: Start-ups per node and seed of the parameter campaign.
START_UPS = 24


def _hostile_overrides(specs: list[Any], rng: random.Random) -> list[Parameter]:
    """One or two of a node's parameters (its module's ``PARAMETERS``) set to hostile
    values of their type (a string where the type is another: a parameter file can)."""
    out = []
    for spec in rng.sample(specs, rng.choice([1, 2])):
        if isinstance(spec.default, bool):
            value: Any = rng.choice([not spec.default, 'true', ''])
        elif isinstance(spec.default, float):
            value = rng.choice(FLOATS)
        else:
            value = rng.choice(STRINGS)
        out.append(Parameter(spec.name, value=value))
    return out


@pytest.mark.parametrize(('entry', 'seed'), _cases(WITHOUT_INPUTS))
def test_node_without_inputs_survives_hostile_parameters(
        context: Context, entry: NodeEntry, seed: int) -> None:
    """Its parameters are its only input: each start-up with hostile values either stops
    with a one-line error of the package's own (a DepthNodesError: never another exception)
    or latches what the node is for, once (static_transform: one transform with a finite
    translation and a unit rotation). Where tf2_msgs is missing (the PyPI wheels) a start-up
    whose values pass stops because of that, in one line too."""
    node_class = resolve_plugin(entry.name)
    specs = importlib.import_module(entry.module).PARAMETERS
    rng = random.Random(f'{entry.name}-{seed}')
    no_tf2 = f'{entry.name} needs tf2_msgs'
    outcomes = []
    for _ in range(START_UPS):
        overrides = _hostile_overrides(specs, rng)
        try:
            node = node_class(context=context, parameter_overrides=overrides)
        except DepthNodesError as exc:  # anything else fails the test
            error = str(exc)
        else:
            error = ''
        if error:
            assert '\n' not in error, (overrides, error)
            outcomes.append('no tf2_msgs' if error.startswith(no_tf2) else 'refused')
            continue
        try:
            assert set(node.outputs) == {'/tf_static'}, overrides
            (tf,) = node.message.transforms
            t, q = tf.transform.translation, tf.transform.rotation
            assert np.isfinite([t.x, t.y, t.z]).all(), overrides
            assert math.isclose(math.hypot(q.x, q.y, q.z, q.w), 1.0, rel_tol=1e-9), overrides
            outcomes.append('latched')
        finally:
            node.destroy_node()
    assert 'refused' in outcomes, outcomes  # the hostile values reached the checks
    assert len(set(outcomes)) == 2, outcomes  # and some passed them
