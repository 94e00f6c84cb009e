"""Offline bag harness: drive a bag's messages through the live node classes.

Every message of the input bag is copied to the output bag (like ``ros2 bag record -a``
during a replay would), and so is its custom metadata (a generated bag's simulator
settings), and every message a node publishes is written at the timestamp of
the input message that caused it and handed, synchronously and in order, to every node that
subscribes to its topic. Nothing goes over DDS and nothing can be lost to queue depths, so a
run is deterministic.
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import rclpy
from rclpy.context import Context
from sensor_msgs.msg import Image

from depth_nodes.errors import BagError, ConfigError
from depth_nodes.graph.description import (
    GraphConfig,
    camera_readers,
    checked_name,
    checked_namespace,
    create_nodes,
    load_graph_config,
    load_params_file,
    root_namespace,
    unmatched_entries,
    with_transport,
)
from depth_nodes.tools.bags.io import BagReader, BagWriter, message_type_name, remove_bag
from depth_nodes.tools.signals import stop_requested

COMPRESSED = 'sensor_msgs/msg/CompressedImage'
IMAGE_TYPE = 'sensor_msgs/msg/Image'
#: The default graph: the stereo pipeline under /stereo.
DEFAULT_CONFIG = Path(__file__).resolve().parents[3] / 'config' / 'stereo_pipeline.yaml'


def default_config_path() -> Path:
    """The stereo pipeline config: the source tree's, else an installed share folder's.

    Looks in the source checkout, then ``<sys.prefix>/share/depth_nodes/config`` (where pip
    puts the package's data files), then the ament index (a colcon install space).
    """
    installed = Path(sys.prefix) / 'share' / 'depth_nodes' / 'config' / DEFAULT_CONFIG.name
    for candidate in (DEFAULT_CONFIG, installed):
        if candidate.is_file():
            return candidate
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory('depth_nodes')) / 'config' / DEFAULT_CONFIG.name
    except Exception:  # no ament index either: the source path, which then fails clearly
        return DEFAULT_CONFIG


@dataclass
class ProcessReport:
    """What went in, what came out, and what nodes dropped, by reason."""

    nodes: list[str] = field(default_factory=list)
    consumed: Counter[str] = field(default_factory=Counter)
    copied: Counter[str] = field(default_factory=Counter)
    published: Counter[str] = field(default_factory=Counter)
    drops: dict[str, Counter[str]] = field(default_factory=dict)
    shadowed: list[str] = field(default_factory=list)
    unfed: list[str] = field(default_factory=list)
    #: Nodes switched to a compressed transport because the bag holds only that.
    transports: dict[str, str] = field(default_factory=dict)
    #: What the command line could say instead, when the bag holds the missing inputs
    #: elsewhere (e.g. ``--namespace /camera``).
    suggestions: list[str] = field(default_factory=list)
    #: Parameter-file entries that address no node (rclpy would ignore them).
    unmatched_params: list[str] = field(default_factory=list)
    #: Input messages handled, of ``total`` in the bag.
    done: int = 0
    total: int = 0
    #: True when a SIGINT / SIGTERM stopped the run (the output holds what was done).
    interrupted: bool = False
    #: The input topic whose messages count as frames (the most frequent one the graph
    #: consumes), frames done and the run's wall-clock seconds.
    frame_topic: str = ''
    frames: int = 0
    seconds: float = 0.0
    workers: int = 1
    engine: str = ''

    def summary(self) -> str:
        """One line: frames, messages, time, rate."""
        rate = self.frames / self.seconds if self.seconds > 0 else 0.0
        how = f'{self.workers} worker{"s" * (self.workers != 1)}'
        if self.engine:
            how += f' on {self.engine}'
        return (f'processed {self.frames} frames ({self.done} of {self.total} messages) in '
                f'{self.seconds:.1f} s: {rate:.2f} frames/s, {how}')

    def format(self) -> str:
        """A plain-text summary for the terminal."""
        lines = [f'nodes: {", ".join(self.nodes) or "none"}']
        lines.append('in:')
        for topic in sorted(self.copied):
            use = f'  -> {self.consumed[topic]} consumed' if self.consumed[topic] else ''
            lines.append(f'  {topic:<40} {self.copied[topic]:>6}{use}')
        lines.append('out:')
        for topic in sorted(self.published) or ['(nothing published)']:
            count = f'{self.published[topic]:>6}' if topic in self.published else ''
            lines.append(f'  {topic:<40} {count}')
        total_drops = sum(sum(c.values()) for c in self.drops.values())
        lines.append(f'dropped: {total_drops}')
        for node, counter in sorted(self.drops.items()):
            for reason, n in sorted(counter.items()):
                lines.append(f'  {node:<30} {reason:<28} {n:>6}')
        for topic in self.shadowed:
            lines.append(f'note: input topic {topic} is also published by a node; '
                         'only the node output was written')
        for node, transport in sorted(self.transports.items()):
            lines.append(f'note: {node} reads its images with image_transport {transport} '
                         '(the bag holds no raw ones)')
        for topic in self.unfed:
            lines.append(f'note: {topic} is subscribed but neither in the bag nor published')
        return '\n'.join(lines)

    def nothing_published(self) -> str:
        """Why a run published nothing, for the one-line error."""
        if not self.unfed:
            return 'the graph published nothing (see the drops above)'
        hint = ''
        if self.suggestions:
            hint = '; try ' + ' or '.join(self.suggestions)
        return (f'the graph published nothing: its inputs {", ".join(self.unfed)} are not in '
                f'the bag{hint}')


class _Progress:
    """A one-line progress display on a terminal (frames done, frames/s, ETA); silent
    otherwise (the summary line says it all at the end)."""

    def __init__(self, total_frames: int, stream: TextIO) -> None:
        self.total = max(total_frames, 1)
        self.stream = stream
        self.enabled = stream.isatty()
        self.start = time.monotonic()
        self._shown = -1.0

    def update(self, frames: int, *, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._shown < 0.25:
            return
        self._shown = now
        elapsed = now - self.start
        rate = frames / elapsed if elapsed > 0 else 0.0
        eta = f'{(self.total - frames) / rate:.0f} s' if rate > 0 else '?'
        percent = min(frames * 100 // self.total, 100)
        bar = '#' * (percent // 4)
        self.stream.write(f'\r[{bar:<25}] {percent:3d}% {frames}/{self.total} frames, '
                          f'{rate:.2f} frames/s, ETA {eta}   ')
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write('\n')
            self.stream.flush()


def select_nodes(config: GraphConfig, names: list[str] | None) -> GraphConfig:
    """Keep only the named nodes (by name or full name) of ``config``.

    Raises:
        ConfigError: A name is not in the config.
    """
    if not names:
        return config
    index = {n.name: n for n in config.nodes} | {n.fully_qualified_name: n for n in config.nodes}
    missing = [n for n in names if n not in index]
    if missing:
        known = ', '.join(n.name for n in config.nodes) or 'none'
        raise ConfigError(f'--nodes: not in {config.name} graph: {", ".join(missing)} '
                          f'(nodes: {known})')
    return GraphConfig(config.name, [index[n] for n in names], config.source)


def process_bag(
    in_bag: str | Path,
    out_bag: str | Path,
    *,
    config: GraphConfig | None = None,
    params_file: str | Path | None = None,
    overwrite: bool = False,
    progress: TextIO | None = None,
    image_transport: str | None = None,
    workers: int = 1,
    ray: bool = False,
    ray_address: str | None = None,
) -> ProcessReport:
    """Run ``config``'s nodes over ``in_bag`` and write everything to ``out_bag``.

    Args:
        in_bag: Input bag folder.
        out_bag: Output bag folder (created).
        config: The graph to run; the default stereo pipeline when None.
        params_file: A ROS 2 parameter file overriding node parameters.
        overwrite: Replace an existing ``out_bag``.
        progress: Stream for a progress bar (shown only when it is a terminal).
        image_transport: How the nodes that read the bag's camera images take them
            (``raw``, ``compressed``, ``compressedDepth``); by default raw, or compressed
            where the bag holds only ``<topic>/compressed``.
        workers: Graph copies running segments of the bag at once (see
            :mod:`depth_nodes.tools.bags.parallel`); the output is the same as with one.
        ray: Run the workers as Ray actors: on a local cluster started for the run, or on
            the one at ``ray_address``.

    Returns:
        The counts of what went in, came out and was dropped.

    Raises:
        BagError: The input bag is missing/corrupt, or the output exists.
        ConfigError: The graph or parameter file is invalid.
    """
    if Path(in_bag).resolve() == Path(out_bag).resolve():
        raise BagError(f'output bag {out_bag} is the input bag: choose another folder')
    config = config or load_graph_config(default_config_path())
    params = load_params_file(params_file) if params_file else {}
    report = ProcessReport()
    report.unmatched_params = unmatched_entries(config, params)
    if image_transport is not None:
        params = with_transport(params, camera_readers(config), image_transport)
    reader = BagReader(in_bag)
    if reader.message_count == 0:
        reader.close()
        raise BagError(f'{in_bag} holds no messages: nothing to process')
    context = Context()
    rclpy.init(args=[], context=context)
    nodes: list[Any] = []
    try:
        nodes = create_nodes(config, params, context=context)
        report.nodes = [n.get_fully_qualified_name() for n in nodes]
        routes, produced = routes_of(nodes)
        report.shadowed = sorted(produced & set(reader.topics))
        switch = {} if image_transport is not None else _compressed_inputs(nodes, reader,
                                                                           produced)
        if switch:  # raw was asked for nothing, and the bag holds only compressed images
            for node in nodes:
                node.destroy_node()
            nodes = []
            for name, transport in switch.items():
                params = with_transport(params, [name], transport)
            report.transports = switch
            nodes = create_nodes(config, params, context=context)
            routes, produced = routes_of(nodes)
        _check_types(reader, routes)
        report.unfed = sorted(set(routes) - set(reader.topics) - produced)
        report.suggestions = _suggestions(report.unfed, config, reader,
                                          {n.get_fully_qualified_name(): n.get_parameter(
                                              'image_transport').value for n in nodes
                                           if n.has_parameter('image_transport')})
        report.frame_topic = _frame_topic(reader, routes, produced)
        report.workers = workers
        report.engine = ('Ray at ' + ray_address if ray_address else 'Ray') if ray else ''
        started = time.monotonic()
        engine = None
        try:
            if workers > 1 or ray:
                from depth_nodes.tools.bags.parallel import LocalEngine, RayEngine

                engine = RayEngine(workers, ray_address) if ray else LocalEngine(workers)
            writer = BagWriter(out_bag, overwrite=overwrite)
            try:
                with writer:
                    for key, value in reader.custom_data.items():  # the simulator's settings
                        writer.set_custom_data(key, value)
                    if engine is None:
                        _run(reader, writer, nodes, routes, produced, report, progress)
                    else:
                        _run_parallel(reader, writer, nodes, config, params, engine, routes,
                                      produced, report, progress, in_bag)
            except BagError as exc:  # e.g. the input is corrupt part-way, or the disk is
                # full: no partial output
                writer.discard()
                raise BagError(f'{exc}; {out_bag} not written') from None
        finally:
            report.seconds = time.monotonic() - started
            if engine is not None:
                engine.close()
        if not report.published and not report.interrupted:
            remove_bag(out_bag)  # a run that produced nothing leaves nothing behind
    finally:
        for node in nodes:
            report.drops[node.get_fully_qualified_name()] = Counter(node.drops)
            node.destroy_node()
        rclpy.shutdown(context=context)
        reader.close()
    return report


def routes_of(nodes: list[Any]) -> tuple[dict[str, list[Any]], set[str]]:
    """Which node inputs each topic feeds, and the topics the nodes publish."""
    routes: dict[str, list[Any]] = {}
    produced: set[str] = set()
    for node in nodes:
        for spec_in in node.inputs:
            routes.setdefault(spec_in.topic, []).append(spec_in)
        produced.update(node.outputs)
    return routes, produced


def _compressed_inputs(nodes: list[Any], reader: BagReader, produced: set[str]
                       ) -> dict[str, str]:
    """Nodes whose raw image inputs the bag lacks but holds as ``<topic>/compressed`` (or
    ``compressedDepth``): ``{node: transport}``."""
    switch: dict[str, str] = {}
    for node in nodes:
        if not node.has_parameter('image_transport') or \
                node.get_parameter('image_transport').value != 'raw':
            continue
        for spec_in in node.inputs:
            if spec_in.msg_type is not Image or spec_in.topic in reader.topics or \
                    spec_in.topic in produced:
                continue
            for transport in ('compressed', 'compressedDepth'):
                if reader.topics.get(f'{spec_in.topic}/{transport}') == COMPRESSED:
                    switch[node.get_fully_qualified_name()] = transport
                    break
    return switch


def _suggestions(unfed: list[str], config: GraphConfig, reader: BagReader,
                 transports: dict[str, str]) -> list[str]:
    """Command-line options under which the bag would feed the graph: another namespace
    that holds the missing inputs (raw or compressed), the compressed transport where a
    raw one was asked for, or, for a camera whose sides are not left / right (a
    RealSense's infra1 / infra2), the namespace, side and image names of its two
    camera_infos."""
    root = root_namespace(config).rstrip('/')
    found: set[str] = set()
    for topic in unfed:
        if not topic.startswith(root + '/'):
            continue
        tail = topic[len(root):]
        for bag_topic in reader.topics:
            for suffix in ('', '/compressed'):
                if bag_topic.endswith(tail + suffix):
                    found.add(bag_topic[:len(bag_topic) - len(tail + suffix)] or '/')
    out = []
    for namespace in sorted(found):
        if namespace.rstrip('/') == root:  # here already: only as compressed images
            out.append('--image-transport compressed (the bag holds the images as '
                       '<topic>/compressed)' if any(t == 'raw' for t in transports.values())
                       else '')
            continue
        try:
            checked_namespace(namespace)
        except ConfigError:
            continue  # a name the options could not take
        out.append(f'--namespace {namespace}')
    if not found:
        out += _camera_pairs(reader)
    return [s for s in out if s]


def _camera_pairs(reader: BagReader) -> list[str]:
    """``--namespace P --left A --right B --image I`` for two cameras P/A and P/B that
    each have a camera_info and an image (raw or compressed)."""
    parents: dict[str, list[str]] = {}
    for topic in reader.topics:
        if topic.endswith('/camera_info') and topic.count('/') >= 3:
            camera = topic[:-len('/camera_info')]
            parent, _, side = camera.rpartition('/')
            parents.setdefault(parent, []).append(side)
    out = []
    for parent, sides in sorted(parents.items()):
        if len(sides) != 2:
            continue
        left, right = sorted(sides, key=lambda s: ('left' not in s, s))
        images = sorted(t[len(f'{parent}/{left}/'):].removesuffix('/compressed')
                        for t, kind in reader.topics.items()
                        if t.startswith(f'{parent}/{left}/') and kind in (
                            IMAGE_TYPE, COMPRESSED))
        if not images:
            continue
        # image_raw if there is one, else a camera image (not a ground truth render)
        image = min(images, key=lambda n: (n != 'image_raw', n.endswith('_gt'),
                                           not n.startswith('image'), n))
        try:
            checked_namespace(parent)
            for name in (left, right, image):
                checked_name(name, 'name')
        except ConfigError:
            continue
        out.append(f'--namespace {parent} --left {left} --right {right} --image {image}')
    return out


def _check_types(reader: BagReader, routes: dict[str, list[Any]]) -> None:
    for topic, specs in routes.items():
        if topic not in reader.topics:
            continue
        for spec_in in specs:
            wanted = message_type_name(spec_in.msg_type)
            if reader.topics[topic] != wanted:
                raise BagError(f'topic {topic} in {reader.path} has type '
                               f'{reader.topics[topic]}, but a node subscribes to it as {wanted}')


def _run(
    reader: BagReader,
    writer: BagWriter,
    nodes: list[Any],
    routes: dict[str, list[Any]],
    produced: set[str],
    report: ProcessReport,
    progress: TextIO | None,
) -> None:
    now = [0]
    failed: list[BagError] = []

    def sink(topic: str, msg: Any) -> None:
        # a node's publish calls this: a write that fails (a full disk) ends the run below,
        # instead of being taken by the node for a failure of its own frame
        if failed:
            return
        try:
            writer.write(topic, msg, now[0])
        except BagError as exc:
            failed.append(exc)
            return
        report.published[topic] += 1
        for spec_in in routes.get(topic, ()):
            spec_in.callback(msg)

    for node in nodes:
        node.sink = sink
    bar = _Progress(reader.counts[report.frame_topic], progress or sys.stderr)
    report.total = reader.message_count
    for done, bag_msg in enumerate(reader.messages(), start=1):
        if stop_requested():  # SIGINT / SIGTERM: close the bag with what is done
            report.interrupted = True
            break
        report.done = done
        now[0] = bag_msg.timestamp
        if bag_msg.topic not in produced:
            writer.write(bag_msg.topic, bag_msg.data, bag_msg.timestamp, bag_msg.msgtype,
                         qos=reader.qos.get(bag_msg.topic, ()))
            report.copied[bag_msg.topic] += 1
        subscribers = routes.get(bag_msg.topic)
        if subscribers and bag_msg.topic not in produced:
            msg = bag_msg.deserialize()
            report.consumed[bag_msg.topic] += 1
            for spec_in in subscribers:
                spec_in.callback(msg)
            if failed:
                raise failed[0]
        report.frames += bag_msg.topic == report.frame_topic
        bar.update(report.frames)
    bar.update(report.frames, force=True)
    bar.close()
    for node in nodes:  # what the nodes still hold can never complete: count it
        node.finish_stream()
    if failed:
        raise failed[0]


def _frame_topic(reader: BagReader, routes: dict[str, list[Any]], produced: set[str]) -> str:
    """The consumed input topic with the most messages: its messages count as frames."""
    consumed = [t for t in routes if t in reader.topics and t not in produced]
    return min(consumed, key=lambda t: (-reader.counts[t], t)) if consumed else ''


def _run_parallel(
    reader: BagReader,
    writer: BagWriter,
    nodes: list[Any],
    config: GraphConfig,
    params: dict[str, dict[str, Any]],
    engine: Any,
    routes: dict[str, list[Any]],
    produced: set[str],
    report: ProcessReport,
    progress: TextIO | None,
    in_bag: str | Path,
) -> None:
    """:func:`_run` with the graph on ``engine``'s workers, segment by segment (see
    :mod:`depth_nodes.tools.bags.parallel`); the main process reads the bag, checks each
    message against what the worker handled, and writes the stitched output."""
    from depth_nodes.tools.bags.parallel import (
        SEGMENTS_PER_WORKER,
        SPARSE_MESSAGES,
        SegmentJob,
        segments,
        stitch,
    )

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
        _stitch_into(writer, reader, stitch(engine.map(jobs, stop_requested)), nodes,
                     routes, produced, report, progress)
    finally:
        if spill is not None:
            spill.cleanup()


def _stitch_into(writer: BagWriter, reader: BagReader, stitched: Iterator[Any],
                 nodes: list[Any], routes: dict[str, list[Any]], produced: set[str],
                 report: ProcessReport, progress: TextIO | None) -> None:
    """Write the input messages and the workers' stitched outputs in the bag's order."""
    from depth_nodes.tools.bags.parallel import END

    by_name = {node.get_fully_qualified_name(): node for node in nodes}
    bar = _Progress(reader.counts[report.frame_topic], progress or sys.stderr)
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
