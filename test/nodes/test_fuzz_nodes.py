"""Every node of the registry fed randomly mutated messages: it survives, and counts what
it loses.

The campaign iterates over the node registry (depth_nodes/nodes/registry.py): each node's
valid frames are built from its ``inputs`` kind (``KINDS`` of test/node_frames.py, shared
with the structured hostile-input test: small simulated images, their CameraInfos, the
disparities the matcher makes of them, depth images, time-of-flight correlation frames,
pattern images), and fed through the node's own input callbacks, as the bag harness
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
"""

from __future__ import annotations

import array
import copy
import importlib
import math
import random
from typing import Any

import numpy as np
import pytest
from node_frames import is_empty, kind_of, make_node, participant_kept
from rclpy.context import Context
from rclpy.parameter import Parameter

from depth_nodes.errors import DepthNodesError
from depth_nodes.graph.description import resolve_plugin
from depth_nodes.nodes.registry import NODES, NodeEntry

pytestmark = [pytest.mark.ros, pytest.mark.slow]

#: Frames per node and seed; a fresh node every FRESH frames (a mutated stamp far in the
#: future would otherwise make every later frame out of order).
FRAMES, FRESH = 120, 12
SEEDS = (1, 2)

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


def _cases(entries: list[NodeEntry]) -> list[Any]:
    return [pytest.param(entry, seed, id=f'{entry.name}-{seed}') for entry in entries
            for seed in SEEDS]


WITH_INPUTS = [entry for entry in NODES if entry.inputs != 'none']
WITHOUT_INPUTS = [entry for entry in NODES if entry.inputs == 'none']


@pytest.mark.parametrize(('entry', 'seed'), _cases(WITH_INPUTS))
def test_node_survives_mutated_messages_and_counts_its_losses(
        context: Context, entry: NodeEntry, seed: int) -> None:
    name = entry.name
    kind = kind_of(entry)
    rng = random.Random(f'{name}-{seed}')
    done: list[str] = []
    produced = without_output = dropped = 0
    empty: list[str] = []
    node = None
    with participant_kept(context):
        try:
            for i in range(FRAMES):
                if i % FRESH == 0:
                    if node is not None:
                        node.finish_stream()
                        dropped += sum(node.drops.values())
                        assert node.drops.get('internal_error', 0) == 0, (name, done[-FRESH:])
                        node.destroy_node()
                    node = make_node(entry, context)
                    outbox, routes = node.outbox, node.routes
                    assert set(kind.step(1, 0)) <= set(routes), (name, sorted(routes))
                stamp = (i + 1) * 100_000_000
                msgs = kind.step(stamp, 0)
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
                if any(is_empty(m) for m in outputs):  # a frame lost without a word
                    empty.append(what)
                if any(not is_empty(m) for m in outputs):
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
    if kind.steps == 1:  # a pattern sequence needs all its frames in a row
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
