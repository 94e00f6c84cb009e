"""One segment of a bag run by a fresh copy of the graph: the worker's side of `process` on
several workers (:mod:`depth_nodes.tools.bags.parallel` explains the hand-over).

A worker records, by the local index of the message that caused them (from the segment's
start), the outputs of its graph (their bytes in a spill file beside the output bag when the
worker runs on this machine), the drops, and the messages after which its graph held
nothing: its idle points.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import IO, Any

import rclpy
from rclpy.context import Context
from rclpy.impl.logging_severity import LoggingSeverity

from depth_nodes.errors import BagError
from depth_nodes.graph.description import GraphConfig, create_nodes
from depth_nodes.ros.dds import PROFILE, PROFILE_VARIABLES
from depth_nodes.ros.serialized import Serialized
from depth_nodes.tools.bags.harness import Routes, Sink, drop_counts, feed, routes_of
from depth_nodes.tools.bags.io import BagReader, message_type_name, serialize

#: Idle points a worker records past its segment's end, for the hand-over.
HANDOVER_POINTS = 2
#: Causes of the outputs and drops that come after the last message (``finish_stream``).
END = -1


@dataclass(frozen=True)
class Segment:
    """The messages with timestamps in ``[start_ns, stop_ns)``; ``stop_ns`` None: to the end."""

    index: int
    start_ns: int | None
    stop_ns: int | None

    @property
    def last(self) -> bool:
        return self.stop_ns is None


@dataclass(frozen=True)
class SegmentJob:
    """What a worker needs: the bag, the graph with its parameters, the segment."""

    in_bag: str
    config: GraphConfig
    params: dict[str, dict[str, Any]]
    segment: Segment
    #: Consumed topics to prime, and the dense ones that must have delivered a message
    #: before an idle point counts.
    sparse: tuple[str, ...]
    dense: tuple[str, ...]
    #: Folder for the outputs' bytes (workers on this machine); None: in the result.
    spill_dir: str | None = None


@dataclass
class SegmentResult:
    """A worker's outputs, drops and idle points, by the local index of the message (from
    the segment's start) that caused them."""

    index: int
    #: (topic, timestamp) of each message handled, in order.
    seen: list[tuple[str, int]] = field(default_factory=list)
    #: Local index of the first message past the segment's end (``len(seen)`` if none).
    own_end: int = 0
    idle: set[int] = field(default_factory=set)
    #: (topic, msgtype, CDR bytes, or their (offset, length) in ``spill``).
    outputs: dict[int, list[tuple[str, str, bytes | tuple[int, int]]]] = field(
        default_factory=dict)
    drops: dict[int, list[tuple[str, str, int]]] = field(default_factory=dict)
    #: The file holding the outputs' bytes, when the job gave a folder.
    spill: str | None = None


def segments(start_ns: int, end_ns: int, count: int) -> list[Segment]:
    """``count`` segments of equal duration covering ``[start_ns, end_ns]``.

    (Measured on the 200-frame VGA bag with two workers: a short first and last segment,
    or a big first one, were slower; so was nothing gained by running the workers nicer
    than the main process.)
    """
    span = end_ns - start_ns + 1
    count = max(1, min(count, span))
    cuts = [start_ns + span * k // count for k in range(1, count)]
    bounds: list[int | None] = [None, *cuts, None]
    return [Segment(k, bounds[k], bounds[k + 1]) for k in range(count)]


def run_segment(job: SegmentJob) -> SegmentResult:
    """Run the graph over one segment (in a worker process or actor).

    Raises:
        BagError: The bag cannot be read, or the outputs cannot be written to the spill
            file.
    """
    worker_environment()
    result = SegmentResult(job.segment.index)
    spill = None
    if job.spill_dir is not None:  # bytes through a file: no pickling of the clouds
        result.spill = spill_path(job)
        # a file an earlier segment used is written over, not truncated (claim_spill);
        # closed in the finally below
        mode = 'r+b' if os.path.exists(result.spill) else 'wb'
        spill = open(result.spill, mode)  # noqa: SIM115
    context = Context()
    rclpy.init(args=[], context=context)
    nodes: list[Any] = []
    try:
        with BagReader(job.in_bag) as reader:
            nodes = create_nodes(job.config, job.params, context=context)
            for node in nodes:  # warnings about the discarded start would mislead: the
                # report's drop table counts what the stitched output lost
                node.get_logger().set_level(LoggingSeverity.ERROR)
            routes, produced = routes_of(nodes)
            sink = _SegmentSink(nodes, routes, result, spill, job.spill_dir)
            if job.segment.start_ns is not None:  # what a one-worker run would hold already
                for topic in job.sparse:
                    latest = None
                    for bag_msg in reader.messages([topic], stop=job.segment.start_ns):
                        latest = bag_msg
                    if latest is not None:
                        feed(routes, produced, latest)
            sink.keep = True
            _run(job, reader, nodes, routes, produced, sink, result)
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.shutdown(context=context)
        if spill is not None:
            spill.close()
    return result


class _SegmentSink(Sink):
    """Keeps the outputs (once ``keep`` is set) by the local index of the message that
    caused them (``cause``): serialised, their bytes in ``spill`` if there is one."""

    def __init__(self, nodes: list[Any], routes: Routes, result: SegmentResult,
                 spill: IO[bytes] | None, spill_dir: str | None) -> None:
        super().__init__(nodes, routes)
        self.result = result
        self.spill = spill
        self.spill_dir = spill_dir
        self.keep = False
        self.cause = END

    def handle(self, topic: str, msg: Any) -> None:
        if not self.keep:
            return
        if isinstance(msg, Serialized):
            msgtype, data = msg.msgtype, msg.data
        else:
            msgtype = message_type_name(msg)
            data = serialize(msg, msgtype)
        kept: bytes | tuple[int, int] = data
        if self.spill is not None:
            try:
                kept = (self.spill.tell(), self.spill.write(data))
            except OSError as exc:
                raise BagError(f"cannot write a worker's outputs to {self.spill_dir}: "
                               f'{exc.strerror or exc}') from None
        self.result.outputs.setdefault(self.cause, []).append((topic, msgtype, kept))


def _run(job: SegmentJob, reader: BagReader, nodes: list[Any], routes: Routes,
         produced: set[str], sink: _SegmentSink, result: SegmentResult) -> None:
    """Feed the segment's messages, and those past its end until :data:`HANDOVER_POINTS`
    idle points were seen there (or the bag ends), recording into ``result``."""
    segment = job.segment
    before = drop_counts(nodes)
    waiting = set(job.dense)
    handover = 0
    result.own_end = -1
    for local, bag_msg in enumerate(reader.messages(start=segment.start_ns)):
        past = segment.stop_ns is not None and bag_msg.timestamp >= segment.stop_ns
        if past and result.own_end < 0:
            result.own_end = local
        result.seen.append((bag_msg.topic, bag_msg.timestamp))
        sink.cause = local
        feed(routes, produced, bag_msg)
        sink.check()
        waiting.discard(bag_msg.topic)
        after = drop_counts(nodes)
        delta = _new_drops(before, after)
        if delta:
            result.drops[local] = delta
        before = after
        if not waiting and not any(node.holds_input() for node in nodes):
            result.idle.add(local)
            if past:
                handover += 1
                if handover >= HANDOVER_POINTS:
                    break
    else:  # the end of the bag (the last segment, or a hand-over that ran into it): what
        # the graph still holds can never complete
        sink.cause = END
        for node in nodes:
            node.finish_stream()
        sink.check()
        result.drops[END] = _new_drops(before, drop_counts(nodes))
    if result.own_end < 0:
        result.own_end = len(result.seen)


def _new_drops(before: dict[tuple[str, str], int], after: dict[tuple[str, str], int]
               ) -> list[tuple[str, str, int]]:
    return [(node, reason, count - before.get((node, reason), 0))
            for (node, reason), count in after.items() if count != before.get((node, reason), 0)]


def worker_environment() -> None:
    """A worker routes its messages in-process: its participant discovers no other one and
    has no shared-memory transport, whatever the caller's environment says.

    * Discovery: with the caller's LOCALHOST (as in the tests) the workers' participants
      found each other, and one worker once hung for good at its end: Fast DDS's
      set_listener spinning while a discovery thread (a participant that went away) waited
      on the lock it held.
    * Shared memory: a participant's 64 MiB segment, a file in /dev/shm, is removed only
      when it exits cleanly; each worker killed when a run was stopped (SIGINT, SIGTERM) or
      failed left 70 MB behind, for good. The package's own large-message profile is
      dropped for the worker (a profile of the user's is kept) and the builtin transports
      are UDP only (with discovery off, localhost mode would add shared memory back).

    Set before the worker's first participant (``rclpy.init``).
    """
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'OFF'
    os.environ.pop('ROS_STATIC_PEERS', None)
    for name in PROFILE_VARIABLES:
        if os.environ.get(name) == str(PROFILE):
            del os.environ[name]
    os.environ['FASTDDS_BUILTIN_TRANSPORTS'] = 'UDPv4'


def spill_path(job: SegmentJob) -> str:
    """The file a local worker writes the outputs' bytes of ``job`` to."""
    assert job.spill_dir is not None
    return os.path.join(job.spill_dir, f'segment-{job.segment.index}')


#: Name prefix of a spill file whose segment was written out, kept for the next segment.
FREE_PREFIX = 'free-'


def claim_spill(job: SegmentJob) -> None:
    """Give ``job`` the spill file of a segment already written out, if one is free.

    Writing over a file's pages costs a tenth of writing new ones (500 MB: 0.1 s against
    1.56 s of system time on this machine's ext4, 0.32 s on tmpfs): with a new file per
    segment, two workers spent about 10 s more in the kernel than one worker on the
    200-frame VGA bag, mostly copying into fresh page-cache pages. The main process renames
    files, so nothing else touches them meanwhile.
    """
    if job.spill_dir is None:
        return
    free = sorted(f for f in os.listdir(job.spill_dir) if f.startswith(FREE_PREFIX))
    if free:
        os.rename(os.path.join(job.spill_dir, free[0]), spill_path(job))


def release_spill(path: str | None) -> None:
    """Mark a segment's spill file free for the next segment (:func:`claim_spill`)."""
    if path and os.path.exists(path):
        head, tail = os.path.split(path)
        os.rename(path, os.path.join(head, FREE_PREFIX + tail))
