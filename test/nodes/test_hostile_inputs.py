"""The package's structured hostile-input test: every node of the registry, present and
future, gets every hostile variant of each of its input messages, one at a time, in place
of the valid one.

Each case is a fresh node fed three frames through its own input callbacks, as the bag
harness does: a valid frame, the hostile frame (the valid messages of its kind, see
test/node_frames.py, with one message replaced by a variant of test/hostile_messages.py:
sizes 0x0 / 1xN / odd / another size than its partners, every encoding, NaN / inf /
negative / tiny / huge values, zero and non-finite camera matrices, stamps duplicated /
out of order / nanosec >= 1e9 / far off; or the whole frame restamped), then the next
valid frame. A pattern sequence is one frame; its last image is the one replaced. The
verdict, per case:

* no exception, caught or not: nothing escapes the callbacks and ``internal_error``
  stays 0 (the base class's last line of defence is never needed); a numpy
  RuntimeWarning counts as an exception;
* every drop counted with its reason: the hostile frame gives its output (never an empty
  image or cloud), or at least one drop is counted by the end of the stream, under a
  stable snake_case reason;
* the next valid frame's outputs are byte-identical to what the same frame gives in a
  fresh node that never saw the hostile one. For a node that ``keeps_state`` (its output
  depends on the frames before, as the multi-view node's filter and keyframes do), a
  hostile frame it accepted and answered legitimately changes that state: then the next
  valid frame must still be answered; a stamp far off makes it start over (its
  ``on_time_jump``), after which the next frame is a first one again (answered, or a
  counted drop); a frame it dropped must leave no trace, byte for byte.

The cases of a node run in one test and every failing case is reported with what went
wrong. A registry node whose inputs kind has no frame builder fails: adding a node of a
new kind is one entry in test/node_frames.py, and its messages of a new type get the
generic variants (every float NaN, inf and huge; every string empty and nonsense).
"""

from __future__ import annotations

import itertools
import re
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest
from hostile_messages import stamp_variants, variants
from node_frames import (
    PARAMETERS,
    STEP_NS,
    Kind,
    is_empty,
    kind_of,
    make_node,
    participant_kept,
)
from rclpy.context import Context
from rclpy.parameter import Parameter

from depth_nodes.graph.description import resolve_plugin
from depth_nodes.nodes.registry import NODES, NodeEntry
from depth_nodes.ros.serialized import Serialized
from depth_nodes.tools.bags.io import serialize

# a numpy RuntimeWarning (overflow, invalid value) in a node is an error here: a hostile
# value is handled, not warned about in the node's log
pytestmark = [pytest.mark.ros, pytest.mark.slow,
              pytest.mark.filterwarnings('error::RuntimeWarning')]

#: The valid frame, the hostile one, the next valid one (ns).
BEFORE, HOSTILE, AFTER = 10**9, 2 * 10**9, 3 * 10**9
#: A drop reason: a short stable key.
REASON = re.compile(r'[a-z][a-z0-9_]*')
#: Whole-frame stamp cases: every message of the hostile frame restamped.
FRAME_STAMPS = {'frame duplicated': BEFORE, 'frame out of order': BEFORE - 1_000_000,
                'frame nanosec 1e9': None}

Frame = list[dict[str, Any]]


def _stamp_ns(msg: Any) -> int | None:
    if isinstance(msg, Serialized):  # tsdf_fusion's MarkerArray, as CDR bytes
        return msg.stamp_ns
    header = getattr(msg, 'header', None)
    return None if header is None else header.stamp.sec * 10**9 + header.stamp.nanosec


def _restamped(frame: Frame, ns: int | None) -> Frame:
    for step, msgs in enumerate(frame):
        for msg in msgs.values():
            stamp = msg.stamp if not hasattr(msg, 'header') else msg.header.stamp
            if ns is None:
                stamp.nanosec = 10**9
            else:
                stamp.sec, stamp.nanosec = divmod(ns + step * STEP_NS, 10**9)
    return frame


def cases(kind: Kind) -> Iterator[tuple[str, Frame]]:
    """Every hostile frame of a kind: ``(case name, frame)``."""
    last = kind.steps - 1  # of a sequence, the image that completes it
    previous = BEFORE + last * STEP_NS
    for topic in sorted(kind.step(HOSTILE, last)):
        valid = kind.frame(HOSTILE)[last][topic]
        for name, variant in itertools.chain(variants(valid),
                                             stamp_variants(valid, previous)):
            frame = kind.frame(HOSTILE)
            frame[last][topic] = variant
            yield f'{topic}: {name}', frame
    for name, ns in FRAME_STAMPS.items():
        yield name, _restamped(kind.frame(HOSTILE), ns)


@dataclass
class Outcome:
    """What a node did with a hostile frame between two valid ones."""

    hostile: list[tuple[str, Any]]
    after: list[tuple[str, Any]]
    drops: Counter[str]
    #: Times the stamps jumped back and the node started over (its on_time_jump hook).
    time_jumps: int = 0


def _feed(node: Any, frame: Frame) -> list[tuple[str, Any]]:
    mark = len(node.outbox)
    for msgs in frame:
        for topic, msg in msgs.items():
            node.routes[topic](msg)  # an exception here fails the case: never expected
    return node.outbox[mark:]


def run(entry: NodeEntry, context: Context, frame: Frame | None) -> Outcome:
    """A fresh node fed a valid frame, ``frame`` (None: nothing), the next valid frame."""
    kind = kind_of(entry)
    node = make_node(entry, context)
    jumps = [0]
    hook = node.on_time_jump

    def counted() -> None:
        jumps[0] += 1
        hook()

    node.on_time_jump = counted
    try:
        _feed(node, kind.frame(BEFORE))
        hostile = _feed(node, frame) if frame is not None else []
        after = _feed(node, kind.frame(AFTER))
        node.finish_stream()
        return Outcome(hostile, after, Counter(node.drops), jumps[0])
    finally:
        node.destroy_node()


def _outputs(out: list[tuple[str, Any]]) -> list[tuple[str, bytes]]:
    """The next valid frame's outputs (those stamped with it), serialised."""
    return [(topic, msg.data if isinstance(msg, Serialized) else serialize(msg))
            for topic, msg in out if _stamp_ns(msg) == AFTER]


def verdict(kind: Kind, outcome: Outcome, expected: list[tuple[str, bytes]], *,
            keeps_state: bool = False) -> list[str]:
    """What is wrong with a case's outcome (nothing: an empty list)."""
    problems = []
    if outcome.drops.get('internal_error'):
        problems.append('internal_error: an exception reached the last line of defence')
    if any(is_empty(msg) for _, msg in outcome.hostile + outcome.after):
        problems.append('an empty image or cloud was published')
    answered = any(t == kind.output and not is_empty(m) for t, m in outcome.hostile)
    if not answered and not sum(outcome.drops.values()):
        problems.append('no output and no drop counted')
    if bad := [r for r in outcome.drops if not REASON.fullmatch(r)]:
        problems.append(f'drop reasons {bad} are not short keys')
    got = _outputs(outcome.after)
    if keeps_state and answered:  # the state took the hostile frame in, as it should
        if not any(t == kind.output for t, _ in got):
            problems.append('the next valid frame gave no output')
    elif keeps_state and outcome.time_jumps:  # a far stamp: the node started over, as a
        # stateful node must when time jumps; the next frame is then a first one again
        if not got and not outcome.drops:
            problems.append('the next valid frame gave no output and no drop')
    elif got != expected:
        problems.append(f'the next valid frame gave {[t for t, _ in got]}, not the fresh '
                        f'node\'s {[t for t, _ in expected]} byte for byte')
    return problems


WITH_INPUTS = [entry for entry in NODES if entry.inputs != 'none']


@pytest.mark.parametrize('entry', WITH_INPUTS, ids=lambda entry: entry.name)
def test_node_survives_every_hostile_input_and_counts_it(context: Context,
                                                         entry: NodeEntry) -> None:
    _campaign(context, entry)


#: Settings that take another path through a node than its defaults: each gets the whole
#: campaign too (the learned matching cost, the learned confidence).
VARIANTS = {
    'sgm_stereo': [Parameter('matching_cost', value='census+learned')],
    'cross_check': [Parameter('confidence_model', value='learned')],
}


@pytest.mark.parametrize('name', sorted(VARIANTS))
def test_the_learned_paths_survive_every_hostile_input(context: Context, name: str,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    entry = next(e for e in WITH_INPUTS if e.name == name)
    monkeypatch.setitem(PARAMETERS, name, [*PARAMETERS.get(name, []), *VARIANTS[name]])
    _campaign(context, entry)


def _campaign(context: Context, entry: NodeEntry) -> None:
    """Every hostile case of ``entry``'s inputs kind, each judged by :func:`verdict`."""
    kind = kind_of(entry)
    failures, reasons, count = [], Counter[str](), 0
    with participant_kept(context):
        expected = _outputs(run(entry, context, None).after)
        assert any(t == kind.output for t, _ in expected), (entry.name, expected)
        for name, frame in cases(kind):
            count += 1
            try:
                outcome = run(entry, context, frame)
            except Exception as exc:  # reported with the others, then the test fails
                failures.append(f'{name}: raised {type(exc).__name__}: {exc}')
                continue
            reasons.update(outcome.drops)
            keeps_state = bool(getattr(resolve_plugin(entry.name), 'keeps_state', False))
            failures += [f'{name}: {problem}' for problem in verdict(
                kind, outcome, expected, keeps_state=keeps_state)]
    print(f'{entry.name}: {count} cases, drops by reason {dict(sorted(reasons.items()))}')
    assert count >= 50, (entry.name, count)  # the catalog reached the node
    assert not failures, f'{entry.name}: {len(failures)} of {count} cases failed:\n' + (
        '\n'.join(failures))
