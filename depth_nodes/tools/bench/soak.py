"""`depth-nodes bench soak`: the stereo graph fed for a long time, tuned while it runs.

The graph of config/stereo_pipeline.yaml runs as node processes (or, with ``composed``, as
one `depth-nodes pipeline` process); this process publishes the bundled 640x480 frames at a
fixed rate with ever increasing stamps for ``duration`` seconds, changes the matcher's P2
through its parameter service every ``tune_every`` seconds (timing each answer), samples
every node process's resident memory, and at the end reads every node's totals from
/diagnostics. Printed:

* frames sent, point clouds back, and where the others went: drops the nodes counted (by
  node and reason) and messages the middleware did not deliver (an upstream node's output
  total minus the downstream node's input total, per topic). A frame that is lost and
  appears in neither is lost uncounted;
* resident memory of each process: at the first sample, at the run's middle and at the
  end, its largest, its growth over the second half, and a timeline every 5 minutes
  (what "flat" is judged by: the first half includes allocations made once, such as a
  second matcher's buffers, and a step that does not repeat, such as the middleware's
  history of large messages filling up, is bounded where a steady climb is not); every
  sample also goes to ``memory_log`` (CSV) when given;
* the parameter service's answer times.
"""

from __future__ import annotations

import contextlib
import os
import statistics
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.utilities import try_shutdown

from depth_nodes.errors import ConfigError
from depth_nodes.graph.description import load_graph_config
from depth_nodes.tools.bench.live import (
    FIRST_FRAME_TIMEOUT_S,
    NS,
    POINTS,
    REPO,
    wait_until,
    warm_up,
)
from depth_nodes.tools.live.processes import GraphProcesses, StereoFeeder, load_stereo_frames
from depth_nodes.tools.signals import STOP, graceful, stop_requested

SGM = f'{NS}/sgm_stereo'
#: Seconds between two memory samples.
MEMORY_PERIOD_S = 30.0
#: Spacing of the memory timeline in the report.
TIMELINE_S = 300.0
#: Seconds to wait for the last frames once publishing stopped.
DRAIN_S = 5.0
#: The two values of P2 the soak alternates between.
P2_VALUES = (220.0, 230.0)


@dataclass
class SoakReport:
    """What a soak measured (see the module notes)."""

    duration_s: float
    rate: float
    composed: bool
    sent: int = 0
    back: int = 0
    drops: dict[str, dict[str, int]] = field(default_factory=dict)
    middleware_lost: dict[str, int] = field(default_factory=dict)
    memory_mb: dict[str, list[float]] = field(default_factory=dict)
    answers_ms: list[float] = field(default_factory=list)
    refused: int = 0
    interrupted: bool = False

    def format(self) -> str:
        layout = 'one pipeline process' if self.composed else 'one process per node'
        counted = sum(sum(c.values()) for c in self.drops.values())
        mw = sum(self.middleware_lost.values())
        lost = self.sent - self.back
        lines = [f'soak: {self.duration_s:.0f} s at {self.rate:g} Hz, 640x480, {layout}'
                 f'{" (interrupted)" if self.interrupted else ""}',
                 f'  frames sent {self.sent}, point clouds back {self.back}, lost {lost}']
        for node, reasons in sorted(self.drops.items()):
            if reasons:
                lines.append(f'  counted by {node}: ' + ', '.join(
                    f'{r} {c}' for r, c in sorted(reasons.items())))
        for topic, count in sorted(self.middleware_lost.items()):
            if count:
                lines.append(f'  not delivered by the middleware on {topic}: {count}')
        verdict = 'nothing lost uncounted' if lost <= counted + mw else 'SOME LOST UNCOUNTED'
        lines.append(f'  lost frames {lost}; counted by nodes {counted}, middleware {mw}: '
                     f'{verdict}')
        for name, samples in sorted(self.memory_mb.items()):
            if samples:
                mid = samples[len(samples) // 2]
                lines.append(f'  memory {name.rsplit("/", 1)[-1]:<14} first {samples[0]:7.1f} MB'
                             f'  middle {mid:7.1f} MB  last {samples[-1]:7.1f} MB  max '
                             f'{max(samples):7.1f} MB  second half {samples[-1] - mid:+.1f} MB'
                             f'  ({len(samples)} samples)')
                lines.append(f'    every {TIMELINE_S / 60:g} min: '
                             f'{timeline(samples, round(TIMELINE_S / MEMORY_PERIOD_S))} MB')
        if self.answers_ms:
            lines.append(f'  parameter service ({len(self.answers_ms)} sets of P2): answer '
                         f'median {statistics.median(self.answers_ms):.0f} ms, max '
                         f'{max(self.answers_ms):.0f} ms, refused {self.refused}')
        return '\n'.join(lines)


def timeline(samples: list[float], every: int) -> str:
    """Every ``every``-th sample and the last, rounded to MB: steps and trends show."""
    picked = samples[::every]
    if (len(samples) - 1) % every:
        picked.append(samples[-1])
    return ' '.join(f'{v:.0f}' for v in picked)


def _rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def soak(*, duration: float = 1800.0, rate: float = 10.0, tune_every: float = 10.0,
         composed: bool = False, memory_log: str | Path | None = None) -> SoakReport:
    """Run the soak (see the module notes); a SIGINT / SIGTERM ends it early, reported.

    Raises:
        ConfigError: Bad durations or rate, or the graph did not come up.
    """
    if duration <= 0 or rate <= 0 or tune_every <= 0:
        raise ConfigError('bench soak needs --duration, --rate and --tune-every > 0')
    env = dict(os.environ, ROS_DOMAIN_ID=str(1 + os.getpid() % 100),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    os.environ.update(ROS_DOMAIN_ID=env['ROS_DOMAIN_ID'],
                      ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    frames = load_stereo_frames(REPO / 'bags' / 'stereo_vga', NS)
    config = load_graph_config(REPO / 'config' / 'stereo_pipeline.yaml')
    report = SoakReport(duration, rate, composed)
    totals: dict[str, dict[str, str]] = {}

    def on_diagnostics(array: DiagnosticArray) -> None:
        for status in array.status:
            totals[status.name] = {kv.key: kv.value for kv in status.values}

    context = Context()
    rclpy.init(args=[], context=context)
    node = rclpy.create_node('depth_nodes_soak', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    feeder = StereoFeeder(node, NS, [POINTS])
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 50)
    client = node.create_client(SetParameters, f'{SGM}/set_parameters')
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    with tempfile.TemporaryDirectory(prefix='depth_nodes_soak_') as tmp, graceful(), \
            contextlib.ExitStack() as stack:
        log = None
        if memory_log is not None:
            try:
                log = stack.enter_context(open(memory_log, 'w', encoding='utf-8'))
            except OSError as exc:
                raise ConfigError(f'--memory-log {memory_log}: {exc.strerror}') from None
            log.write('seconds,process,rss_mb\n')
        graph = GraphProcesses(config, Path(tmp), env=env, composed=composed)
        try:
            graph.start()
            wait_until(feeder.graph_ready, FIRST_FRAME_TIMEOUT_S, graph, 'the graph to connect')
            stamp = warm_up(feeder, frames, graph, 3)
            warm = len(feeder.arrived[POINTS])
            start = time.monotonic()
            next_tune, next_sample, tune = start + tune_every, start, 0
            i = 0
            while time.monotonic() - start < duration and not stop_requested():
                now = time.monotonic()
                if now >= next_sample:
                    for name, proc in graph.processes.items():
                        mb = _rss_mb(proc.pid)
                        if mb is not None:
                            report.memory_mb.setdefault(name, []).append(mb)
                            if log is not None:
                                log.write(f'{now - start:.1f},{name},{mb:.2f}\n')
                                log.flush()
                    next_sample += MEMORY_PERIOD_S
                if now >= next_tune:
                    tune += 1
                    _tune(client, P2_VALUES[tune % 2], report)
                    next_tune += tune_every
                stamp += 100_000_000
                feeder.publish(frames[i % len(frames)], stamp)
                report.sent += 1
                i += 1
                STOP.wait(max(0.0, start + i / rate - time.monotonic()))
            report.interrupted = stop_requested()
            STOP.clear()  # drain even after a signal
            time.sleep(DRAIN_S)
            report.back = len(feeder.arrived[POINTS]) - warm
            report.duration_s = time.monotonic() - start - DRAIN_S
        finally:
            graph.stop()
            executor.shutdown()
            node.destroy_node()
            try_shutdown(context=context)
            spinner.join(timeout=5)
    report.drops = {name: {k[len('drops '):]: int(v) for k, v in values.items()
                           if k.startswith('drops ') and k != 'drops total'}
                    for name, values in totals.items()}
    report.middleware_lost = middleware_losses(totals)
    return report


def _tune(client: object, value: float, report: SoakReport) -> None:
    """Set P2 through the matcher's parameter service and time the answer."""
    request = SetParameters.Request()
    request.parameters = [Parameter('P2', value=value).to_parameter_msg()]
    start = time.monotonic()
    future = client.call_async(request)  # type: ignore[attr-defined]
    deadline = start + 30
    while not future.done() and time.monotonic() < deadline:
        time.sleep(0.005)
    if not future.done() or not all(r.successful for r in future.result().results):
        report.refused += 1
        return
    report.answers_ms.append(1e3 * (time.monotonic() - start))


def middleware_losses(totals: dict[str, dict[str, str]]) -> dict[str, int]:
    """Per topic: the publishing node's output total minus each subscribing node's input
    total (messages that left one node and never reached the next)."""
    published: dict[str, int] = {}
    received: dict[str, list[int]] = {}
    for values in totals.values():
        for key, value in values.items():
            if key.startswith('output ') and key.endswith(' total'):
                published[key[len('output '):-len(' total')]] = int(value)
            elif key.startswith('input ') and key.endswith(' total'):
                received.setdefault(key[len('input '):-len(' total')], []).append(int(value))
    return {topic: sum(max(0, published[topic] - got) for got in counts)
            for topic, counts in received.items() if topic in published}
