"""The core of the offline bag harness: a graph's nodes driven by a bag's messages.

Each message a node subscribes to is handed to the node's input callbacks; each message a
node publishes goes to a :class:`Sink` (written to the output bag, or kept by a worker) and
then, synchronously and in order, to every node that subscribes to its topic. Nothing goes
over DDS and nothing can be lost to queue depths, so a run is deterministic. One process
runs the whole bag with :func:`run_graph`; several workers run segments of it with the same
pieces (:mod:`depth_nodes.tools.bags.segments`).
"""

from __future__ import annotations

import sys
from typing import Any, TextIO

from depth_nodes.errors import BagError
from depth_nodes.ros.serialized import Serialized
from depth_nodes.tools.bags.io import BagMessage, BagReader, BagWriter, message_type_name
from depth_nodes.tools.bags.report import ProcessReport, Progress
from depth_nodes.tools.signals import stop_requested

#: Topic -> the node inputs (``InputSpec``) it feeds.
Routes = dict[str, list[Any]]


def routes_of(nodes: list[Any]) -> tuple[Routes, set[str]]:
    """Which node inputs each topic feeds, and the topics the nodes publish."""
    routes: Routes = {}
    produced: set[str] = set()
    for node in nodes:
        for spec_in in node.inputs:
            routes.setdefault(spec_in.topic, []).append(spec_in)
        produced.update(node.outputs)
    return routes, produced


class Sink:
    """Where the nodes' published messages go (it becomes every node's ``sink``): first to
    :meth:`handle` (write it somewhere), then to every node input subscribed to its topic.

    A :class:`BagError` out of :meth:`handle` (a full disk) is kept and raised by
    :meth:`check` after the message that caused it, instead of being taken by the
    publishing node for a failure of its own frame; nothing is handled after it.
    """

    def __init__(self, nodes: list[Any], routes: Routes) -> None:
        self.routes = routes
        self.error: BagError | None = None
        for node in nodes:
            node.sink = self

    def handle(self, topic: str, msg: Any) -> None:
        """Keep one published message (subclasses write it)."""
        raise NotImplementedError

    def __call__(self, topic: str, msg: Any) -> None:
        if self.error is not None:
            return
        try:
            self.handle(topic, msg)
        except BagError as exc:
            self.error = exc
            return
        subscribers = self.routes.get(topic, ())
        if subscribers and isinstance(msg, Serialized):
            msg = msg.message()
        for spec_in in subscribers:
            spec_in.callback(msg)

    def check(self) -> None:
        """Raise the error that stopped the sink, if one did."""
        if self.error is not None:
            raise self.error


def feed(routes: Routes, produced: set[str], bag_msg: BagMessage) -> bool:
    """Hand a bag message to the node inputs subscribed to its topic (none for a topic a
    node publishes: the node's output stands for it). Returns whether any took it.

    Raises:
        BagError: The message cannot be deserialised.
    """
    subscribers = routes.get(bag_msg.topic)
    if not subscribers or bag_msg.topic in produced:
        return False
    msg = bag_msg.deserialize()
    for spec_in in subscribers:
        spec_in.callback(msg)
    return True


def check_types(reader: BagReader, routes: Routes) -> None:
    """Every consumed topic of the bag has the type its subscribers take.

    Raises:
        BagError: A topic's type in the bag is not the one a node subscribes to.
    """
    for topic, specs in routes.items():
        if topic not in reader.topics:
            continue
        for spec_in in specs:
            wanted = message_type_name(spec_in.msg_type)
            if reader.topics[topic] != wanted:
                raise BagError(f'topic {topic} in {reader.path} has type '
                               f'{reader.topics[topic]}, but a node subscribes to it as {wanted}')


def frame_topic(reader: BagReader, routes: Routes, produced: set[str]) -> str:
    """The consumed input topic with the most messages: its messages count as frames."""
    consumed = [t for t in routes if t in reader.topics and t not in produced]
    return min(consumed, key=lambda t: (-reader.counts[t], t)) if consumed else ''


def drop_counts(nodes: list[Any]) -> dict[tuple[str, str], int]:
    """Every node's drops so far: ``{(node, reason): count}``."""
    return {(node.get_fully_qualified_name(), reason): count
            for node in nodes for reason, count in node.drops.items()}


class _BagSink(Sink):
    """Writes each published message at the timestamp of the input message that caused it."""

    def __init__(self, nodes: list[Any], routes: Routes, writer: BagWriter,
                 report: ProcessReport) -> None:
        super().__init__(nodes, routes)
        self.writer = writer
        self.report = report
        self.stamp = 0

    def handle(self, topic: str, msg: Any) -> None:
        if isinstance(msg, Serialized):
            self.writer.write(topic, msg.data, self.stamp, msgtype=msg.msgtype)
        else:
            self.writer.write(topic, msg, self.stamp)
        self.report.published[topic] += 1


def run_graph(reader: BagReader, writer: BagWriter, nodes: list[Any], routes: Routes,
              produced: set[str], report: ProcessReport, progress: TextIO | None) -> None:
    """Run ``nodes`` over the whole bag in this process: every input message copied to
    ``writer`` (but those of topics a node publishes), every output written at the
    timestamp of the message that caused it; at the end, what the nodes still hold is
    counted (``finish_stream``). A stop request (SIGINT / SIGTERM) ends the run with what
    is done.

    Raises:
        BagError: The bag cannot be read, or the output cannot be written.
    """
    sink = _BagSink(nodes, routes, writer, report)
    bar = Progress(reader.counts[report.frame_topic], progress or sys.stderr)
    report.total = reader.message_count
    for done, bag_msg in enumerate(reader.messages(), start=1):
        if stop_requested():  # SIGINT / SIGTERM: close the bag with what is done
            report.interrupted = True
            break
        report.done = done
        sink.stamp = bag_msg.timestamp
        if bag_msg.topic not in produced:
            writer.write(bag_msg.topic, bag_msg.data, bag_msg.timestamp, bag_msg.msgtype,
                         qos=reader.qos.get(bag_msg.topic, ()))
            report.copied[bag_msg.topic] += 1
        if feed(routes, produced, bag_msg):
            report.consumed[bag_msg.topic] += 1
            sink.check()
        report.frames += bag_msg.topic == report.frame_topic
        bar.update(report.frames)
    bar.update(report.frames, force=True)
    bar.close()
    for node in nodes:  # what the nodes still hold can never complete: count it
        node.finish_stream()
    sink.check()
