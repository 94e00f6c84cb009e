"""Looking at a running graph, ``ros2``-style, from `depth-nodes` (the ``ros2`` command is
not on PyPI): ``node list``, ``topic list|echo|hz|bw`` and ``diag``.

Each command starts a hidden node (its name begins with ``_``, so listings leave it out)
on the environment's ``ROS_DOMAIN_ID`` and discovery range, waits for discovery, and reads
the graph or subscribes like any other node. ``echo`` prints a message as YAML-like text,
but an image, a point cloud or a disparity image as one summary line (its stamp, frame,
size, encoding and a few statistics), never its bytes. The commands that run until
stopped (``echo`` without ``--count``, ``hz``, ``bw``, ``diag``) end on Ctrl-C or
SIGTERM with status 0.
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, TextIO

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import try_shutdown

from depth_nodes.errors import ConfigError, DepthNodesError
from depth_nodes.ros.disparity import read_disparity
from depth_nodes.ros.image import image_to_array
from depth_nodes.tools.bags.io import message_class
from depth_nodes.tools.signals import stop_requested

#: Seconds of discovery before a listing is printed (at least; see :func:`settle`).
DISCOVERY_S = 2.0
#: Seconds the node list must stay the same before a listing is printed.
STABLE_S = 2.0
#: Elements of an array ``echo`` prints before it elides the rest.
MAX_ARRAY = 16
#: Seconds of diagnostics the ``diag`` view's rate is taken over.
RATE_WINDOW_S = 10.0


@contextmanager
def graph_node(kind: str) -> Iterator[tuple[Node, SingleThreadedExecutor]]:
    """A hidden node and its executor on a context of their own."""
    context = Context()
    # stopping is ours (tools/signals.py), as for play and record
    rclpy.init(args=[], context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = Node(f'_depth_nodes_{kind}_{os.getpid()}', context=context,
                start_parameter_services=False, enable_rosout=False)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield node, executor
    finally:
        executor.shutdown()
        node.destroy_node()
        try_shutdown(context=context)


def _spin_for(executor: SingleThreadedExecutor, seconds: float) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not stop_requested():
        executor.spin_once(timeout_sec=min(0.1, max(0.0, deadline - time.monotonic())))


def unnamed_endpoints(node: Node) -> bool:
    """True while some publisher's node is not known yet (rmw says _NODE_NAME_UNKNOWN_
    until the owner's participant has announced its nodes)."""
    for topic, _ in node.get_topic_names_and_types():
        for info in node.get_publishers_info_by_topic(topic):
            if info.node_name.startswith('_NODE_NAME_UNKNOWN'):
                return True
    return False


def settle(node: Node, executor: SingleThreadedExecutor, wait: float,
           limit: float = 10.0) -> None:
    """Spin for ``wait`` s, then on until every publisher's node is known and the node list
    has not changed for :data:`STABLE_S` s, at most ``limit`` s in all. Busy nodes announce
    themselves late: on this machine a graph at 10 Hz took 0.3 - 3 s to show all of its
    six nodes to a new process."""
    start = time.monotonic()
    _spin_for(executor, wait)
    seen, stable_since = visible_nodes(node), time.monotonic()
    while time.monotonic() - start < limit and not stop_requested():
        _spin_for(executor, 0.1)
        now = visible_nodes(node)
        if now != seen:
            seen, stable_since = now, time.monotonic()
        elif time.monotonic() - stable_since >= STABLE_S and not unnamed_endpoints(node):
            return


def visible_nodes(node: Node) -> list[str]:
    """Fully qualified names of the graph's nodes, hidden ones (``_...``) left out."""
    return sorted({f'{ns.rstrip("/")}/{name}' for name, ns in
                   node.get_node_names_and_namespaces() if not name.startswith('_')})


def list_nodes(*, wait: float = DISCOVERY_S) -> list[str]:
    """``ros2 node list``."""
    with graph_node('node_list') as (node, executor):
        settle(node, executor, wait)
        return visible_nodes(node)


def list_topics(*, wait: float = DISCOVERY_S) -> list[tuple[str, list[str]]]:
    """``ros2 topic list -t``: every topic and its types, sorted."""
    with graph_node('topic_list') as (node, executor):
        settle(node, executor, wait)
        return sorted((name, list(types)) for name, types in node.get_topic_names_and_types())


def topic_type(node: Node, executor: SingleThreadedExecutor, topic: str,
               timeout: float) -> str:
    """The type of ``topic`` once a publisher of it is seen.

    Raises:
        ConfigError: Not seen within ``timeout`` s (names the topics that are), or seen
            with several types.
    """
    deadline = time.monotonic() + timeout
    while True:
        types = dict(node.get_topic_names_and_types()).get(topic)
        if types:
            if len(types) > 1:
                raise ConfigError(f'topic {topic} has several types: {", ".join(types)}')
            return str(types[0])
        if time.monotonic() >= deadline or stop_requested():
            known = sorted(name for name, _ in node.get_topic_names_and_types())
            raise ConfigError(f'topic {topic} not found within {timeout:g} s'
                              + (f' (topics: {", ".join(known)})' if known else
                                 ' (no topics visible: is the graph running, on this '
                                 'ROS_DOMAIN_ID?)'))
        executor.spin_once(timeout_sec=0.1)


def _qos_for(node: Node, topic: str) -> QoSProfile:
    """Best effort (sensor data) unless every publisher is reliable (a best-effort reader
    matches both kinds of writer); transient local when every publisher is, so a latched
    message such as /tf_static's is received too."""
    publishers = node.get_publishers_info_by_topic(topic)
    if publishers and all(p.qos_profile.reliability == ReliabilityPolicy.RELIABLE
                          for p in publishers):
        qos = QoSProfile(depth=10)
    else:
        qos = QoSProfile(depth=qos_profile_sensor_data.depth,
                         reliability=ReliabilityPolicy.BEST_EFFORT)
    if publishers and all(p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                          for p in publishers):
        qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
    return qos


# -- echo -------------------------------------------------------------------------------------


def _stamp(msg: Any) -> str:
    header = getattr(msg, 'header', None)
    if header is None:
        return ''
    return f'stamp {header.stamp.sec}.{header.stamp.nanosec:09d} frame {header.frame_id!r} '


def _stats(values: np.ndarray) -> str:
    finite = values[np.isfinite(values)] if values.dtype.kind == 'f' else values.ravel()
    if not finite.size:
        return 'no finite value'
    return (f'min {float(finite.min()):.4g} max {float(finite.max()):.4g} '
            f'mean {float(finite.mean()):.4g}, {finite.size / max(values.size, 1):.1%} finite')


def summary(msg: Any) -> str | None:
    """One line for a message whose payload is a picture or a cloud; None for others."""
    name = type(msg).__name__
    try:
        if name == 'Image':
            pixels = image_to_array(msg)
            return (f'Image {_stamp(msg)}{msg.width}x{msg.height} {msg.encoding} '
                    f'{len(msg.data)} bytes: {_stats(pixels)}')
        if name == 'CompressedImage':
            return f'CompressedImage {_stamp(msg)}{msg.format!r} {len(msg.data)} bytes'
        if name == 'DisparityImage':
            frame = read_disparity(msg)
            return (f'DisparityImage {_stamp(msg)}{msg.image.width}x{msg.image.height} '
                    f'f {msg.f:.6g} t {msg.t:.6g} d {msg.min_disparity:g}..'
                    f'{msg.max_disparity:g}: {_stats(frame.disparity)}')
        if name == 'PointCloud2':
            fields = ', '.join(f.name for f in msg.fields)
            return (f'PointCloud2 {_stamp(msg)}{msg.width}x{msg.height} points ({fields}), '
                    f'point_step {msg.point_step}, {len(msg.data)} bytes, '
                    f'is_dense {msg.is_dense}')
    except DepthNodesError as exc:
        return f'{name} {_stamp(msg)}(unreadable: {exc})'
    return None


def to_text(msg: Any, indent: str = '') -> str:
    """A message as YAML-like lines, arrays longer than :data:`MAX_ARRAY` elided."""
    lines = []
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        if hasattr(value, 'get_fields_and_field_types'):
            lines.append(f'{indent}{name}:')
            lines.append(to_text(value, indent + '  '))
            continue
        if isinstance(value, (list, tuple, np.ndarray)) or type(value).__name__ == 'array':
            items = list(value[:MAX_ARRAY])
            if items and hasattr(items[0], 'get_fields_and_field_types'):
                lines.append(f'{indent}{name}:')
                for item in items:
                    lines.append(f'{indent}- ' + to_text(item, indent + '  ').lstrip())
            else:
                text = ', '.join(repr(v) if isinstance(v, str) else f'{v}' for v in items)
                more = f', ... ({len(value)} in all)' if len(value) > MAX_ARRAY else ''
                lines.append(f'{indent}{name}: [{text}{more}]')
            continue
        if isinstance(value, bytes) and len(value) > MAX_ARRAY:
            value = f'<{len(value)} bytes>'
        lines.append(f'{indent}{name}: {value!r}' if isinstance(value, str) else
                     f'{indent}{name}: {value}')
    return '\n'.join(lines)


def echo(topic: str, *, count: int | None = None, timeout: float = 10.0,
         out: TextIO = sys.stdout) -> int:
    """Print the messages of ``topic`` (``ros2 topic echo``) until ``count`` arrived or a
    signal; returns how many were printed."""
    if count is not None and count < 1:
        raise ConfigError(f'--count must be at least 1, got {count}')
    printed = [0]
    with graph_node('echo') as (node, executor):
        msgtype = topic_type(node, executor, topic, timeout)

        def on_message(msg: Any) -> None:
            if count is not None and printed[0] >= count:
                return
            line = summary(msg)
            out.write((line if line is not None else to_text(msg)) + '\n---\n')
            out.flush()
            printed[0] += 1

        node.create_subscription(message_class(msgtype), topic, on_message,
                                 _qos_for(node, topic))
        while not stop_requested() and (count is None or printed[0] < count):
            executor.spin_once(timeout_sec=0.1)
    return printed[0]


# -- hz and bw --------------------------------------------------------------------------------


@dataclass
class RateWindow:
    """Arrival times (and sizes) of the last ``window`` messages of a topic."""

    window: int = 100
    times: deque[float] = field(default_factory=deque)
    sizes: deque[int] = field(default_factory=deque)
    total: int = 0

    def add(self, when: float, size: int = 0) -> None:
        self.times.append(when)
        self.sizes.append(size)
        self.total += 1
        while len(self.times) > self.window:
            self.times.popleft()
            self.sizes.popleft()

    def hz_line(self) -> str:
        """``ros2 topic hz``'s report of the window."""
        if len(self.times) < 2:
            return 'no new messages' if not self.total else 'waiting for a second message'
        gaps = np.diff(np.asarray(self.times))
        rate = (len(gaps)) / float(self.times[-1] - self.times[0])
        std = statistics.pstdev(gaps.tolist()) if len(gaps) > 1 else 0.0
        return (f'average rate: {rate:.3f}\n\tmin: {gaps.min():.3f}s max: {gaps.max():.3f}s '
                f'std dev: {std:.5f}s window: {len(self.times)}')

    def bw_line(self, now: float) -> str:
        """``ros2 topic bw``'s report: bytes per second over the window."""
        if len(self.times) < 2:
            return 'no new messages' if not self.total else 'waiting for a second message'
        span = max(now - self.times[0], 1e-9)
        rate = sum(self.sizes) / span
        mean = statistics.fmean(self.sizes)
        return (f'{_bytes(rate)}/s from {len(self.sizes)} messages\n\tMessage size mean: '
                f'{_bytes(mean)} min: {_bytes(min(self.sizes))} max: {_bytes(max(self.sizes))}')


def _bytes(n: float) -> str:
    for unit in ('B', 'KB', 'MB'):
        if abs(n) < 1000 or unit == 'MB':
            return f'{n:.2f} {unit}'
        n /= 1000
    return f'{n:.2f} MB'


def measure(topic: str, kind: str, *, window: int = 100, timeout: float = 10.0,
            period: float = 1.0, duration: float | None = None,
            out: TextIO = sys.stdout) -> RateWindow:
    """``hz`` or ``bw`` of ``topic``: a report every ``period`` s until a signal (or for
    ``duration`` s); returns the window."""
    if window < 2:
        raise ConfigError(f'--window must be at least 2, got {window}')
    stats = RateWindow(window)
    with graph_node(kind) as (node, executor):
        msgtype = topic_type(node, executor, topic, timeout)

        def on_message(data: bytes) -> None:
            stats.add(time.monotonic(), len(data))

        node.create_subscription(message_class(msgtype), topic, on_message,
                                 _qos_for(node, topic), raw=True)
        start = next_report = time.monotonic()
        while not stop_requested() and (duration is None or
                                        time.monotonic() - start < duration):
            executor.spin_once(timeout_sec=0.05)
            now = time.monotonic()
            if now >= next_report + period:
                next_report = now
                out.write((stats.hz_line() if kind == 'hz' else stats.bw_line(now)) + '\n')
                out.flush()
    return stats


# -- diagnostics ------------------------------------------------------------------------------

_LEVELS = {0: 'OK', 1: 'WARN', 2: 'ERROR', 3: 'STALE'}


def _level(level: Any) -> str:
    """A DiagnosticStatus level (rclpy gives a byte as ``bytes``) as OK / WARN / ..."""
    code = level[0] if isinstance(level, (bytes, bytearray)) else int(level)
    return _LEVELS.get(code, '?')


def _output_total(status: Any) -> int | None:
    totals = [int(kv.value) for kv in status.values
              if kv.key.startswith('output ') and kv.key.endswith(' total')]
    return max(totals) if totals else None


def diag_table(statuses: dict[str, Any],
               history: dict[str, deque[tuple[float, int]]] | None = None) -> str:
    """The nodes' latest DiagnosticStatus as a table: level, rate, processing time, drops
    by reason. With ``history`` (per node, when each status came and its largest output
    total) the rate is the frames published over the last :data:`RATE_WINDOW_S` s, which
    does not swing with a one-second period's jitter as the node's own rate does."""
    if not statuses:
        return 'no diagnostics yet (nodes publish /diagnostics every diagnostics_period s)'
    lines = [f'{"node":<30} {"level":<5} {"frames/s":>8} {"ms/frame":>9} {"dropped":>7}  '
             'drops by reason / message']
    for name in sorted(statuses):
        status = statuses[name]
        values = {kv.key: kv.value for kv in status.values}
        rates = [float(v) for k, v in values.items()
                 if k.startswith('output ') and k.endswith('rate (Hz)')]
        ms = values.get('processing time mean (ms)', 'nan')
        reasons = ', '.join(f'{k[len("drops "):]} {v}' for k, v in sorted(values.items())
                            if k.startswith('drops ') and k != 'drops total')
        rate = f'{max(rates):.1f}' if rates else '-'
        seen = (history or {}).get(name)
        if seen and len(seen) > 1 and seen[-1][0] > seen[0][0]:
            rate = f'{(seen[-1][1] - seen[0][1]) / (seen[-1][0] - seen[0][0]):.1f}'
        ms_text = '-' if ms == 'nan' else f'{float(ms):.1f}'
        lines.append(f'{name:<30} {_level(status.level):<5} {rate:>8} {ms_text:>9} '
                     f'{values.get("drops total", "0"):>7}  {reasons or status.message}')
    return '\n'.join(lines)


def diagnostics_view(*, period: float = 2.0, once: bool = False, timeout: float = 10.0,
                     out: TextIO = sys.stdout,
                     clear: Callable[[], None] | None = None) -> dict[str, Any]:
    """Print :func:`diag_table` of ``/diagnostics`` every ``period`` s until a signal
    (``once``: the first table that has every node seen so far, after ``period`` s)."""
    if not period > 0:
        raise ConfigError(f'--period must be positive, got {period:g}')
    statuses: dict[str, Any] = {}
    history: dict[str, deque[tuple[float, int]]] = {}

    def on_array(array: Any) -> None:
        now = time.monotonic()
        for status in array.status:
            statuses[status.name] = status
            total = _output_total(status)
            if total is not None:
                seen = history.setdefault(status.name, deque())
                seen.append((now, total))
                while len(seen) > 2 and now - seen[1][0] >= RATE_WINDOW_S:
                    seen.popleft()

    with graph_node('diag') as (node, executor):
        node.create_subscription(DiagnosticArray, '/diagnostics', on_array, 50)
        start = time.monotonic()
        while not stop_requested():
            _spin_for(executor, period)
            if once and not statuses:
                if time.monotonic() - start < timeout:
                    continue
                raise ConfigError(f'no diagnostics within {timeout:g} s: is the graph '
                                  'running, on this ROS_DOMAIN_ID?')
            if clear is not None:
                clear()
            out.write(diag_table(statuses, history) + '\n')
            out.flush()
            if once:
                break
    return statuses
