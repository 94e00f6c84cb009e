"""A graph description run as separate node processes, and a stereo frame feeder.

:class:`GraphProcesses` starts one process per node of a graph description (the node
module with ``--ros-args``, name, namespace, remappings and a generated ``--params-file``),
exactly what the launch files do on a full ROS install. :class:`StereoFeeder` publishes
stereo frames into such a graph and notes when each watched output of every frame arrives.
``bench live`` and the live-graph tests are built on both.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import yaml
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from stereo_msgs.msg import DisparityImage

from depth_nodes.core.stamps import stamp_ns, stamp_parts
from depth_nodes.errors import ConfigError
from depth_nodes.graph.description import GraphConfig, NodeSpec, parameters_for
from depth_nodes.nodes import NODE_PLUGINS
from depth_nodes.tools.bags.io import BagReader, header_stamp

#: Seconds a node process gets to exit after SIGINT before it is killed.
STOP_TIMEOUT_S = 15.0


def node_command(spec: NodeSpec, params_file: Path) -> list[str]:
    """The command that runs ``spec`` as its own process (its console script's ``main``,
    or a ``module:Class`` plugin's, through ``python -m depth_nodes.nodes.scripts``)."""
    if spec.plugin not in NODE_PLUGINS and ':' not in spec.plugin:
        raise ConfigError(f'node {spec.fully_qualified_name}: plugin {spec.plugin!r} has no '
                          'module to run as a process')
    command = [sys.executable, '-m', 'depth_nodes.nodes.scripts', spec.plugin, '--ros-args',
               '-r', f'__node:={spec.name}',
               '-r', f'__ns:={spec.namespace}', '--params-file', str(params_file)]
    for src, dst in spec.remappings.items():
        command += ['-r', f'{src}:={dst}']
    return command


def write_params_file(config: GraphConfig, path: Path,
                      overrides: dict[str, dict[str, Any]] | None = None) -> Path:
    """A ``--params-file`` with every node's parameters (config, then ``overrides`` in the
    ``load_params_file`` layout), keyed by fully qualified node name."""
    doc = {spec.fully_qualified_name: {
        'ros__parameters': parameters_for(spec, overrides or {})} for spec in config.nodes}
    path.write_text(yaml.safe_dump(doc, sort_keys=True))
    return path


def write_graph_file(config: GraphConfig, path: Path,
                     overrides: dict[str, dict[str, Any]] | None = None) -> Path:
    """``config`` as a graph YAML, each node's parameters merged with ``overrides``."""
    nodes = [{'name': spec.name, 'plugin': spec.plugin, 'namespace': spec.namespace,
              'parameters': parameters_for(spec, overrides or {}),
              'remappings': dict(spec.remappings)} for spec in config.nodes]
    path.write_text(yaml.safe_dump({'graph': {'name': config.name, 'nodes': nodes}},
                                   sort_keys=False))
    return path


class GraphProcesses:
    """Every node of ``config`` in its own process; a context manager that stops them.

    Args:
        config: The graph.
        workdir: Folder for the generated parameter file and each node's log.
        env: Environment of the processes (ROS_DOMAIN_ID, discovery range, ...).
        overrides: Extra parameters, ``{node key: {name: value}}`` as in a params file.
    """

    def __init__(self, config: GraphConfig, workdir: Path, *, env: dict[str, str] | None = None,
                 overrides: dict[str, dict[str, Any]] | None = None,
                 composed: bool = False) -> None:
        self.config = config
        self.composed = composed
        self.workdir = Path(workdir)
        self.env = dict(os.environ if env is None else env)
        # a node that hangs or crashes writes every thread's Python stack into its log
        # (see stop); the user's own setting wins
        self.env.setdefault('PYTHONFAULTHANDLER', '1')
        self.overrides = overrides or {}
        self.processes: dict[str, subprocess.Popen[bytes]] = {}
        self.exit_codes: dict[str, int] = {}

    def start(self) -> None:
        """Start every node (returns at once; see :meth:`StereoFeeder.wait_for_graph`); with
        ``composed``, all of them in one `depth-nodes pipeline` process named 'pipeline'."""
        self.workdir.mkdir(parents=True, exist_ok=True)
        if self.composed:
            graph = write_graph_file(self.config, self.workdir / 'graph.yaml', self.overrides)
            log = (self.workdir / 'pipeline.log').open('wb')
            self.processes['pipeline'] = subprocess.Popen(
                [sys.executable, '-m', 'depth_nodes.tools.cli', 'pipeline', '--config',
                 str(graph)], stdout=log, stderr=subprocess.STDOUT, env=self.env)
            log.close()
            return
        params = write_params_file(self.config, self.workdir / 'params.yaml', self.overrides)
        for spec in self.config.nodes:
            name = spec.fully_qualified_name
            log = (self.workdir / f'{name.strip("/").replace("/", "_")}.log').open('wb')
            self.processes[name] = subprocess.Popen(
                node_command(spec, params), stdout=log, stderr=subprocess.STDOUT, env=self.env)
            log.close()

    def log(self, name: str) -> str:
        """What node ``name`` (fully qualified) has printed so far."""
        path = self.workdir / f'{name.strip("/").replace("/", "_")}.log'
        return path.read_text(errors='replace') if path.is_file() else ''

    def exited(self) -> dict[str, int]:
        """Nodes whose process has ended, with their exit status."""
        return {name: code for name, proc in self.processes.items()
                if (code := proc.poll()) is not None}

    def cpu_seconds(self) -> dict[str, float]:
        """User + system CPU time of each running node process (Linux /proc), seconds."""
        ticks = os.sysconf('SC_CLK_TCK')
        out = {}
        for name, proc in self.processes.items():
            try:
                fields = Path(f'/proc/{proc.pid}/stat').read_text().rsplit(')', 1)[1].split()
            except OSError:
                continue
            out[name] = (int(fields[11]) + int(fields[12])) / ticks
        return out

    def stop(self) -> dict[str, int]:
        """SIGINT every node; one still running after :data:`STOP_TIMEOUT_S` gets SIGABRT,
        so that Python's fault handler writes where each of its threads hung into its log
        (:meth:`log`), and is killed if even that does not end it. Returns the exit
        statuses (-6 for a node that had to be aborted, -9 for a killed one)."""
        for proc in self.processes.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + STOP_TIMEOUT_S
        for name, proc in self.processes.items():
            try:
                self.exit_codes[name] = proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.send_signal(signal.SIGABRT)
                try:
                    self.exit_codes[name] = proc.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    self.exit_codes[name] = proc.wait()
        return self.exit_codes

    def __enter__(self) -> GraphProcesses:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _reliable(depth: int) -> QoSProfile:
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)


StereoFrame = tuple[Image, CameraInfo, Image, CameraInfo]


class StereoFeeder:
    """Publishes stereo frames under ``namespace`` and notes, per watched topic and stamp,
    when the output arrived (and its bytes).

    Args:
        node: The node to publish and subscribe with (spun by the caller).
        namespace: Where the raw topics go: ``<ns>/left/image_raw``, ``.../camera_info``.
        watch: Output topics (fully qualified) to subscribe to.
        keep_data: Keep each arrived message's bytes (for :meth:`message`).
    """

    def __init__(self, node: Node, namespace: str, watch: Sequence[str], *,
                 keep_data: bool = False) -> None:
        self.node = node
        self.keep_data = keep_data
        ns = namespace.rstrip('/')
        self.publishers = [
            node.create_publisher(Image, f'{ns}/left/image_raw', _reliable(10)),
            node.create_publisher(CameraInfo, f'{ns}/left/camera_info', _reliable(10)),
            node.create_publisher(Image, f'{ns}/right/image_raw', _reliable(10)),
            node.create_publisher(CameraInfo, f'{ns}/right/camera_info', _reliable(10)),
        ]
        self.sent: dict[int, float] = {}
        self.arrived: dict[str, dict[int, float]] = {topic: {} for topic in watch}
        self.data: dict[str, dict[int, bytes]] = {topic: {} for topic in watch}
        self.subscriptions = [
            node.create_subscription(_watched_type(topic), topic, self._on(topic),
                                     _reliable(50), raw=True)
            for topic in watch]

    def _on(self, topic: str) -> Callable[[bytes], None]:
        def on_message(data: bytes) -> None:
            stamp = header_stamp(data)
            self.arrived[topic][stamp] = time.monotonic()
            if self.keep_data:
                self.data[topic][stamp] = data
        return on_message

    def graph_ready(self) -> bool:
        """Every raw topic has a subscriber and every watched topic a publisher."""
        return (all(p.get_subscription_count() > 0 for p in self.publishers)
                and all(s.get_publisher_count() > 0 for s in self.subscriptions))

    def publish(self, frame: StereoFrame, stamp_ns: int) -> None:
        """Publish the four messages of ``frame`` with the stamp ``stamp_ns``."""
        sec, nanosec = stamp_parts(stamp_ns)
        for msg in frame:
            msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        self.sent[stamp_ns] = time.monotonic()
        for pub, msg in zip(self.publishers, frame, strict=True):
            pub.publish(msg)

    def complete(self, stamp_ns: int) -> bool:
        """Every watched topic has delivered the frame of ``stamp_ns``."""
        return all(stamp_ns in arrived for arrived in self.arrived.values())

    def message(self, topic: str, stamp_ns: int, msg_type: type) -> Any:
        """The message of ``topic`` for ``stamp_ns`` (needs ``keep_data``)."""
        return deserialize_message(self.data[topic][stamp_ns], msg_type)


def _watched_type(topic: str) -> type:
    """Message class of a watched output, by the stereo pipeline's topic names."""
    leaf = topic.rsplit('/', 1)[-1]
    watched: type = Image
    if leaf.startswith('disparity'):
        watched = DisparityImage
    elif leaf.startswith('points'):
        watched = PointCloud2
    return watched


def load_stereo_frames(bag: str | Path, namespace: str = '/stereo') -> list[StereoFrame]:
    """The raw stereo frames (left image, left info, right image, right info) of a bag."""
    ns = namespace.rstrip('/')
    topics = [f'{ns}/left/image_raw', f'{ns}/left/camera_info', f'{ns}/right/image_raw',
              f'{ns}/right/camera_info']
    by_stamp: dict[int, dict[str, Any]] = {}
    with BagReader(bag) as reader:
        for topic in topics:
            reader.require(topic)
        for bag_msg in reader.messages(topics):
            msg = bag_msg.deserialize()
            stamp = stamp_ns(msg)
            by_stamp.setdefault(stamp, {})[bag_msg.topic] = msg
    return [tuple(parts[t] for t in topics)  # type: ignore[misc,unused-ignore]
            for _, parts in sorted(by_stamp.items()) if len(parts) == len(topics)]
