"""`process` on several workers: the bag cut into time segments, each run by a fresh copy of
the graph in another process (spawned, or a Ray actor), the results stitched back into the
output the one-worker run writes, byte for byte.

A graph holds state from one message to the next: synchronisers wait for partners, the
structured-light node gathers a sequence, camera_info caches hold the last calibration. A
copy of the graph that starts in the middle of the bag starts without that state, so its
first outputs may differ. Two things make the stitched result exact:

* **Hand-over at a common idle point.** Every worker records after which messages its graph
  held nothing (no message waiting in a synchroniser or a sequence: ``holds_input``) once
  every dense input has delivered a message since it started. The worker of segment k runs
  on past its end until it has seen :data:`HANDOVER_POINTS` idle points in the next segment.
  The output takes segment k's results up to the first message after which both workers'
  graphs were idle, and the next worker's from there on: from a point where both hold
  nothing and have seen the same latest message on every input, they compute the same thing.
* **Primed sparse inputs.** A topic with at most :data:`SPARSE_MESSAGES` messages in the
  whole bag (a camera_info recorded once, latched) is fed to a worker first with its last
  message before the segment, as the one-worker run would hold it.

When no common idle point exists (a graph that never empties, e.g. a sequence longer than
the hand-over), the run stops with an error that says to use one worker rather than write
something else than one worker would. The main process checks every message the workers
report against its own reading of the bag, so a different message order cannot go unnoticed.

The workers run segments (:mod:`~depth_nodes.tools.bags.segments`) on an engine
(:mod:`~depth_nodes.tools.bags.engines`); their results are stitched
(:mod:`~depth_nodes.tools.bags.stitching`) and written here, in the main process. A node
that keeps state of its own from frame to frame (``keeps_state``), beyond what
``holds_input`` reports, cannot be cut this way: such a graph is refused up front.
"""

from __future__ import annotations

import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any, TextIO

from depth_nodes.errors import BagError, ConfigError
from depth_nodes.graph.description import GraphConfig
from depth_nodes.tools.bags.engines import Engine
from depth_nodes.tools.bags.harness import Routes
from depth_nodes.tools.bags.io import BagReader, BagWriter
from depth_nodes.tools.bags.report import ProcessReport, Progress
from depth_nodes.tools.bags.segments import END, SegmentJob, segments
from depth_nodes.tools.bags.stitching import Stitched, stitch
from depth_nodes.tools.signals import stop_requested

#: A topic with at most this many messages in the bag is primed (see the module notes).
SPARSE_MESSAGES = 4
#: Segments per worker: enough that workers finish together, few enough that the
#: hand-over (about two frames per segment) and each segment's start cost little.
SEGMENTS_PER_WORKER = 4


def refuse_stateful_nodes(nodes: list[Any], how: str) -> None:
    """Stop before a run on several workers (``how``: the option that asked for them) of a
    graph with a node that keeps state from frame to frame: a worker starting mid-bag would
    lack it, and the output would differ from one worker's.

    Raises:
        ConfigError: A node's ``keeps_state`` is true.
    """
    for node in nodes:
        if getattr(node, 'keeps_state', False):
            raise ConfigError(f'{how}: node {node.get_fully_qualified_name()} keeps state from '
                              'frame to frame, which a bag split between workers would lose; '
                              'use one worker (--workers 1, without --ray)')


def run_parallel(
    reader: BagReader,
    writer: BagWriter,
    nodes: list[Any],
    config: GraphConfig,
    params: dict[str, dict[str, Any]],
    engine: Engine,
    routes: Routes,
    produced: set[str],
    report: ProcessReport,
    progress: TextIO | None,
    in_bag: str | Path,
) -> None:
    """:func:`~depth_nodes.tools.bags.harness.run_graph` with the graph on ``engine``'s
    workers, segment by segment: this process reads the bag, checks each message against
    what the worker handled, and writes the stitched output.

    Raises:
        BagError: The bag cannot be read or the output written, two segments have no
            common idle point, or a worker failed.
    """
    consumed = sorted(t for t in routes if t in reader.topics and t not in produced)
    sparse = tuple(t for t in consumed if reader.counts[t] <= SPARSE_MESSAGES)
    dense = tuple(t for t in consumed if t not in sparse)
    start_ns, end_ns = reader.time_range
    # workers on this machine hand their outputs over in files beside the output bag
    spill = None if engine.remote else tempfile.TemporaryDirectory(
        prefix='.depth-nodes-', dir=writer.path.parent)
    jobs = [SegmentJob(str(Path(in_bag).resolve()), config, params, segment, sparse, dense,
                       spill.name if spill else None)
            for segment in segments(start_ns, end_ns, engine.workers * SEGMENTS_PER_WORKER)]
    try:
        stitch_into(writer, reader, stitch(engine.map(jobs, stop_requested)), nodes,
                     routes, produced, report, progress)
    finally:
        if spill is not None:
            spill.cleanup()


def stitch_into(writer: BagWriter, reader: BagReader, stitched: Iterator[Stitched],
                 nodes: list[Any], routes: Routes, produced: set[str],
                 report: ProcessReport, progress: TextIO | None) -> None:
    """Write the input messages and the workers' stitched outputs in the bag's order."""
    by_name = {node.get_fully_qualified_name(): node for node in nodes}
    bar = Progress(reader.counts[report.frame_topic], progress or sys.stderr)
    report.total = reader.message_count
    messages = enumerate(reader.messages())
    last_stamp = 0
    for item in stitched:
        if item.index != END:
            index, bag_msg = next(messages)
            if index != item.index or (bag_msg.topic, bag_msg.timestamp) != item.seen:
                raise BagError(f'a worker read message {item.index} as {item.seen}, this '
                               f'process message {index} as {bag_msg.topic} at '
                               f'{bag_msg.timestamp}: use --workers 1')
            report.done = index + 1
            last_stamp = bag_msg.timestamp
            if bag_msg.topic not in produced:
                writer.write(bag_msg.topic, bag_msg.data, bag_msg.timestamp, bag_msg.msgtype,
                             qos=reader.qos.get(bag_msg.topic, ()))
                report.copied[bag_msg.topic] += 1
            if routes.get(bag_msg.topic) and bag_msg.topic not in produced:
                report.consumed[bag_msg.topic] += 1
            report.frames += bag_msg.topic == report.frame_topic
        for topic, msgtype, data in item.outputs:
            writer.write(topic, data, last_stamp, msgtype)
            report.published[topic] += 1
        for name, reason, count in item.drops:
            by_name[name].drops[reason] += count
        bar.update(report.frames)
    if report.done < report.total:
        report.interrupted = True
    bar.update(report.frames, force=True)
    bar.close()
