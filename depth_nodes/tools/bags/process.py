"""`depth-nodes process`: a graph's nodes run over a bag offline, everything written to a
new bag.

Every message of the input bag is copied to the output bag (like ``ros2 bag record -a``
during a replay would), and so is its custom metadata (a generated bag's simulator
settings); every message a node publishes is written at the timestamp of the input message
that caused it and handed, synchronously and in order, to every node that subscribes to its
topic (:mod:`~depth_nodes.tools.bags.harness`). Nothing goes over DDS and nothing can be
lost to queue depths, so a run is deterministic, on one worker or on several
(:mod:`~depth_nodes.tools.bags.parallel`, the same output). This module sets the run up:
the graph and its parameters, the transports the bag's images need, what the bag lacks.
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any, TextIO

import rclpy
from ament_index_python.packages import get_package_share_directory
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
from depth_nodes.tools.bags.engines import Engine, LocalEngine, RayEngine
from depth_nodes.tools.bags.harness import check_types, frame_topic, routes_of, run_graph
from depth_nodes.tools.bags.io import BagReader, BagWriter, remove_bag
from depth_nodes.tools.bags.parallel import refuse_stateful_nodes, run_parallel
from depth_nodes.tools.bags.report import ProcessReport

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
        return Path(get_package_share_directory('depth_nodes')) / 'config' / DEFAULT_CONFIG.name
    except Exception:  # no ament index either: the source path, which then fails clearly
        return DEFAULT_CONFIG


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
            A graph with a node that keeps state of its own (``keeps_state``) is refused.
        ray: Run the workers as Ray actors: on a local cluster started for the run, or on
            the one at ``ray_address``.

    Returns:
        The counts of what went in, came out and was dropped.

    Raises:
        BagError: The input bag is missing/corrupt, or the output exists.
        ConfigError: The graph or parameter file is invalid, or a node that keeps state
            would run on several workers.
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
        check_types(reader, routes)
        report.unfed = sorted(set(routes) - set(reader.topics) - produced)
        report.suggestions = _suggestions(report.unfed, config, reader,
                                          {n.get_fully_qualified_name(): n.get_parameter(
                                              'image_transport').value for n in nodes
                                           if n.has_parameter('image_transport')})
        report.frame_topic = frame_topic(reader, routes, produced)
        report.workers = workers
        report.engine = ('Ray at ' + ray_address if ray_address else 'Ray') if ray else ''
        if workers > 1 or ray:
            refuse_stateful_nodes(nodes, '--ray' if ray else f'--workers {workers}')
        started = time.monotonic()
        engine: Engine | None = None
        try:
            if workers > 1 or ray:
                engine = RayEngine(workers, ray_address) if ray else LocalEngine(workers)
            writer = BagWriter(out_bag, overwrite=overwrite)
            try:
                with writer:
                    for key, value in reader.custom_data.items():  # the simulator's settings
                        writer.set_custom_data(key, value)
                    if engine is None:
                        run_graph(reader, writer, nodes, routes, produced, report, progress)
                    else:
                        run_parallel(reader, writer, nodes, config, params, engine, routes,
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
