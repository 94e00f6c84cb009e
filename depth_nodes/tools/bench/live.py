"""`depth-nodes bench live`: the stereo pipeline over DDS, one process per node.

The graph of config/stereo_pipeline.yaml (rectify x2 -> sgm_stereo -> cross_check ->
point_cloud) runs as five processes; this process publishes 640x480 frames of the bundled
stereo_vga bag at a fixed rate and subscribes to every stage's output, so it sees when each
frame leaves each stage. Printed: the sustained output rate, frames lost, per-stage
latency (median and 95th percentile), each process's CPU load, and drops the nodes
reported on /diagnostics. The same is then measured for the graph stereo_image_proc users
run, OpenCV's StereoSGBM (MODE_HH) in the SGM node and no cross-check, on the same frames.

With ``watch='points2'`` this process subscribes to the final output only, as a robot's
consumer of the point cloud would (a node that computes an output only while something
subscribes to it then skips what nobody reads): the report gives the end-to-end latency,
raw frame published to points2, instead of the per-stage ones.
"""

from __future__ import annotations

import copy
import os
import statistics
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.utilities import try_shutdown

from depth_nodes.core.stamps import NS_PER_S
from depth_nodes.errors import ConfigError
from depth_nodes.graph.description import GraphConfig, load_graph_config
from depth_nodes.nodes.sgm_stereo import CENSUS_DEFAULTS
from depth_nodes.tools.live.processes import (
    GraphProcesses,
    StereoFeeder,
    StereoFrame,
    load_stereo_frames,
)

REPO = Path(__file__).resolve().parents[3]
NS = '/stereo'
LEFT_RECT, RIGHT_RECT = f'{NS}/left/image_rect', f'{NS}/right/image_rect'
DISPARITY, CHECKED, POINTS = f'{NS}/disparity', f'{NS}/disparity_checked', f'{NS}/points2'
#: Seconds the first (warm-up) frame may take: processes start, numba loads its cache.
FIRST_FRAME_TIMEOUT_S = 300.0
#: Seconds to wait for the last frame's outputs after it was published.
DRAIN_S = 10.0
#: Seconds after which an unanswered warm-up frame is followed by another.
RETRY_S = 5.0
#: Seconds without a new output after which the remaining frames count as lost.
QUIET_S = 2.0

#: A stage: its name, the topics it consumes ('' = the published raw frame) and produces.
Stage = tuple[str, tuple[str, ...], tuple[str, ...]]
OURS_STAGES: list[Stage] = [
    ('rectify', ('',), (LEFT_RECT, RIGHT_RECT)),
    ('sgm_stereo', (LEFT_RECT, RIGHT_RECT), (DISPARITY,)),
    ('cross_check', (DISPARITY,), (CHECKED,)),
    ('point_cloud', (CHECKED,), (POINTS,)),
]
OPENCV_STAGES: list[Stage] = [
    ('rectify', ('',), (LEFT_RECT, RIGHT_RECT)),
    ('sgm_stereo (opencv)', (LEFT_RECT, RIGHT_RECT), (DISPARITY,)),
    ('point_cloud', (DISPARITY,), (POINTS,)),
]
#: What the bench subscribes to: every stage's output, or the final one (points2) only.
Watch = Literal['all', 'points2']
WATCH: tuple[Watch, ...] = ('all', 'points2')


@dataclass
class LiveRun:
    """Figures of one graph at one rate."""

    label: str
    rate: float
    sent: int
    received: int
    fps: float
    latency_ms: dict[str, tuple[float, float]]
    cpu_percent: dict[str, float]
    node_drops: dict[str, int] = field(default_factory=dict)
    #: Mean processing time per frame of each node (from /diagnostics), ms.
    processing_ms: dict[str, float] = field(default_factory=dict)
    #: CPU load of this process (publishing the frames, receiving every output).
    bench_cpu_percent: float = 0.0

    def format(self) -> str:
        lost = self.sent - self.received
        lines = [f'{self.label}: {self.sent} frames sent at {self.rate:g} Hz, '
                 f'{self.received} point clouds back ({lost} lost), sustained '
                 f'{self.fps:.2f} Hz']
        for stage, (median, p95) in self.latency_ms.items():
            lines.append(f'  latency {stage:<22} median {median:7.1f} ms   p95 {p95:7.1f} ms')
        load = ', '.join(f'{name.rsplit("/", 1)[-1]} {pct:.0f}%'
                         for name, pct in self.cpu_percent.items())
        lines.append(f'  CPU (100% = one core): {load}; total '
                     f'{sum(self.cpu_percent.values()):.0f}% of 200%, and this bench '
                     f'process (publisher, subscribers) {self.bench_cpu_percent:.0f}%')
        if self.processing_ms:
            times = ', '.join(f'{name.rsplit("/", 1)[-1]} {ms:.1f}'
                              for name, ms in self.processing_ms.items())
            lines.append(f'  processing per frame (ms, from /diagnostics): {times}')
        drops = ', '.join(f'{n} {c}' for n, c in self.node_drops.items() if c) or 'none'
        lines.append(f'  drops reported on /diagnostics: {drops}')
        return '\n'.join(lines)


@dataclass
class LiveBench:
    """Ours and the OpenCV graph, measured one after the other in one run."""

    ours: LiveRun
    opencv: LiveRun | None
    target_hz: float = 10.0
    threads: int = 0
    paths: int = 8
    composed: bool = False
    watch: Watch = 'all'

    def format(self) -> str:
        threads = f'{self.threads} thread(s)' if self.threads else 'every core'
        layout = ('every node in one `depth-nodes pipeline` process' if self.composed else
                  'one process per node')
        lines = [f'live: 640x480, 128 disparities, {self.paths} paths, {layout} over DDS '
                 f'(Fast DDS, localhost), SGM node on {threads}', self.ours.format()]
        if self.watch == 'points2':
            lines[0] += ('; the bench subscribed to points2 only (latency: raw frame '
                         'published -> points2)')
        met = self.ours.fps >= 0.95 * self.target_hz and self.ours.received == self.ours.sent
        lines.append(f'  target {self.target_hz:g} Hz with nothing lost: '
                     f'{"met" if met else "NOT met"}')
        if self.opencv is not None:
            lines.append(self.opencv.format())
            lines.append(f'  ours / OpenCV graph, sustained rate: '
                         f'{self.ours.fps / max(self.opencv.fps, 1e-9):.2f}')
        return '\n'.join(lines)


def opencv_mode(paths: int) -> str:
    """The StereoSGBM mode with the directions closest to ``paths``: MODE_SGBM (5, one
    pass; stereo_image_proc's default) for 4 and 5 paths, MODE_HH (8) otherwise."""
    return 'MODE_SGBM' if paths <= 5 else 'MODE_HH'


def opencv_graph(config: GraphConfig, paths: int = 8) -> GraphConfig:
    """``config`` as stereo_image_proc users run it: StereoSGBM in the SGM node (the mode
    of :func:`opencv_mode`), no cross-check, the point cloud straight from the disparity.
    It searches the census matcher's disparity range: with stereo_algorithm 1 the node
    would otherwise take stereo_image_proc's default range (64), half the work."""
    graph = copy.deepcopy(config)
    graph.nodes = [n for n in graph.nodes if n.plugin != 'cross_check']
    for node in graph.nodes:
        if node.plugin == 'sgm_stereo':
            # StereoSGBM with its usual tuning of the shared filters (the census
            # matcher's own values in the config are not the OpenCV user's)
            node.parameters.update(
                disparity_range=node.parameters.get('disparity_range',
                                                    CENSUS_DEFAULTS['disparity_range']),
                stereo_algorithm=1, sgbm_mode=1 if opencv_mode(paths) == 'MODE_HH' else 0,
                right_view=False,
                correlation_window_size=5, P1=200.0, P2=800.0, uniqueness_ratio=10.0,
                prefilter_cap=63, disp12_max_diff=1, speckle_size=100, speckle_range=2)
        if node.plugin == 'point_cloud':
            node.parameters['use_confidence'] = False
            node.parameters.pop('min_confidence', None)
            node.remappings.pop('disparity', None)
    graph.name = f'{config.name} (opencv)'
    return graph


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def watched(stages: list[Stage], watch: Watch) -> list[str]:
    """The topics the bench subscribes to: every stage's outputs, or the last stage's."""
    if watch == 'points2':
        return list(stages[-1][2])
    return sorted({t for _, _, outs in stages for t in outs})


def latencies(stages: list[Stage], sent: dict[int, float],
              arrived: dict[str, dict[int, float]],
              timed: list[int]) -> dict[str, tuple[float, float]]:
    """Median and 95th percentile (ms) of each stage whose topics were all watched, and end
    to end (raw frame published -> the last stage's output), over the frames of ``timed``
    (stamps) that arrived.

    Args:
        stages: The graph's stages, in order.
        sent: Stamp -> time the raw frame was published (s).
        arrived: Watched topic -> stamp -> time its message arrived (s).
        timed: The stamps of the timed frames.
    """
    out = {}
    for name, inputs, outputs in [*stages, ('end to end', ('',), stages[-1][2])]:
        if not all(t == '' or t in arrived for t in (*inputs, *outputs)):
            continue  # a stage between topics this bench did not subscribe to
        values = []
        for s in timed:
            if not all(s in arrived[t] for t in outputs):
                continue
            start = max(sent[s] if t == '' else arrived[t][s] for t in inputs)
            values.append(1e3 * (max(arrived[t][s] for t in outputs) - start))
        if values:
            out[name] = (statistics.median(values), _percentile(values, 0.95))
    return out


def run_live(config: GraphConfig, stages: list[Stage], frames: list[StereoFrame], *,
             rate: float, count: int, warmup: int, label: str, workdir: Path,
             env: dict[str, str], threads: int | None = None,
             paths: int | None = None, composed: bool = False,
             watch: Watch = 'all') -> LiveRun:
    """Run ``config`` as processes, feed ``warmup`` frames one at a time, then ``count``
    frames at ``rate`` Hz, and measure (subscribed to the outputs :func:`watched` names)."""
    context = Context()
    rclpy.init(args=[], context=context)
    node = rclpy.create_node('depth_nodes_bench_live', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    feeder = StereoFeeder(node, NS, watched(stages, watch))
    last_status: dict[str, int] = {}
    timing = threading.Event()  # set while the timed frames are in flight
    processing: dict[str, list[tuple[int, float]]] = {}  # (frames, mean ms) per period

    def on_diagnostics(array: DiagnosticArray) -> None:
        for status in array.status:
            values = {kv.key: kv.value for kv in status.values}
            if 'drops total' in values:
                last_status[status.name] = int(values['drops total'])
            frames = int(values.get('frames processed', '0'))
            if timing.is_set() and frames:
                processing.setdefault(status.name, []).append(
                    (frames, float(values['processing time mean (ms)'])))

    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 50)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    sgm: dict[str, int] = {} if threads is None else {'threads': threads}
    if paths is not None:
        sgm['paths'] = paths
    graph = GraphProcesses(config, workdir, env=env, overrides={'sgm_stereo': sgm} if sgm
                           else {}, composed=composed)
    try:
        graph.start()
        wait_until(feeder.graph_ready, FIRST_FRAME_TIMEOUT_S, graph, 'the graph to connect')
        stamp = warm_up(feeder, frames, graph, warmup)
        time.sleep(1.5)  # a diagnostics period: the drops so far are the warm-up's
        drops_before = dict(last_status)
        cpu_start, wall_start = graph.cpu_seconds(), time.monotonic()
        own_cpu_start = time.process_time()
        timing.set()
        timed = []
        for i in range(count):
            stamp += 100_000_000
            delay = wall_start + i / rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            feeder.publish(frames[i % len(frames)], stamp)
            timed.append(stamp)
        final_topic = stages[-1][2][0]
        deadline = time.monotonic() + DRAIN_S
        while time.monotonic() < deadline and not all(feeder.complete(s) for s in timed):
            last = max(feeder.arrived[final_topic].values(), default=wall_start)
            if time.monotonic() - last > QUIET_S:
                break  # the graph has gone quiet: the rest was lost
            time.sleep(0.05)
        cpu_end = graph.cpu_seconds()
        own_cpu = time.process_time() - own_cpu_start
        timing.clear()
        # CPU load over the time frames were in flight (publishing to the last output)
        wall = max(max(feeder.arrived[final_topic].values(), default=0.0),
                   wall_start + (count - 1) / rate) - wall_start
        time.sleep(1.5)  # one more diagnostics period
    finally:
        graph.stop()
        executor.shutdown()
        node.destroy_node()
        try_shutdown(context=context)
        spinner.join(timeout=5)
    done = sorted(feeder.arrived[final_topic][s] for s in timed
                  if s in feeder.arrived[final_topic])
    fps = (len(done) - 1) / (done[-1] - done[0]) if len(done) > 1 else 0.0
    latency = latencies(stages, feeder.sent, feeder.arrived, timed)
    cpu = {n: 100 * (cpu_end[n] - cpu_start.get(n, 0.0)) / wall for n in cpu_end}
    drops = {n: c - drops_before.get(n, 0) for n, c in last_status.items()}
    mean_ms = {n: sum(f * ms for f, ms in periods) / sum(f for f, _ in periods)
               for n, periods in sorted(processing.items())}
    return LiveRun(label, rate, count, len(done), fps, latency, cpu, drops, mean_ms,
                   100 * own_cpu / wall)


def warm_up(feeder: StereoFeeder, frames: list[StereoFrame], graph: GraphProcesses,
            count: int) -> int:
    """Publish frames one at a time until ``count`` have come out of every stage; returns
    the last stamp used.

    A frame published just after the graph connected can still be lost (DDS matches the
    two ends of a connection one after the other), and the first frame waits for numba to
    load its kernels, so an unanswered frame is followed by another every few seconds.
    """
    stamp, done = NS_PER_S, 0
    deadline = time.monotonic() + FIRST_FRAME_TIMEOUT_S
    while done < count:
        stamp += 100_000_000
        feeder.publish(frames[done % len(frames)], stamp)
        retry = time.monotonic() + RETRY_S
        while not feeder.complete(stamp) and time.monotonic() < retry:
            _check_alive(graph)
            time.sleep(0.02)
        if feeder.complete(stamp):
            done += 1
        elif time.monotonic() > deadline:
            raise ConfigError(f'no frame came out of the graph within '
                              f'{FIRST_FRAME_TIMEOUT_S:g} s')
    return stamp


def _check_alive(graph: GraphProcesses) -> None:
    exited = graph.exited()
    if exited:
        name, code = next(iter(exited.items()))
        raise ConfigError(f'node {name} exited with status {code}:\n'
                          f'{graph.log(name)[-2000:]}')


def wait_until(done: Callable[[], bool], timeout: float, graph: GraphProcesses,
               what: str) -> None:
    """Wait until ``done()`` is true.

    Raises:
        ConfigError: A node of ``graph`` exited, or ``timeout`` s passed (``what`` says
            what was waited for).
    """
    deadline = time.monotonic() + timeout
    while not done():
        _check_alive(graph)
        if time.monotonic() > deadline:
            raise ConfigError(f'timed out after {timeout:g} s waiting for {what}')
        time.sleep(0.02)


def bench_live(*, rate: float = 10.0, count: int = 50, warmup: int = 3,
               threads: int | None = None, opencv: bool = True,
               bag: str | Path | None = None, paths: int | None = None,
               composed: bool = False, watch: Watch = 'all') -> LiveBench:
    """Measure the stereo pipeline (and the OpenCV graph) as separate processes, the SGM
    node of both with ``threads`` threads (0: every core; None: as the config says), ours
    with ``paths`` aggregation paths (None: as the config says) and OpenCV in the mode of
    :func:`opencv_mode`; subscribed to every stage's output or (``watch='points2'``) to
    the point cloud only.

    Runs in its own ROS domain (derived from the process id, discovery on localhost) so it
    neither disturbs nor hears another graph.
    """
    if rate <= 0 or count < 2 or warmup < 1:
        raise ConfigError('bench live needs --rate > 0, at least 2 frames and 1 warm-up')
    if watch not in WATCH:
        raise ConfigError(f'--watch must be one of {", ".join(WATCH)}, got {watch!r}')
    env = dict(os.environ, ROS_DOMAIN_ID=str(1 + os.getpid() % 100),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    os.environ.update(ROS_DOMAIN_ID=env['ROS_DOMAIN_ID'],
                      ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    frames = load_stereo_frames(bag or REPO / 'bags' / 'stereo_vga', NS)
    if not frames:
        raise ConfigError(f'no complete stereo frame under {NS} in {bag}')
    config = load_graph_config(REPO / 'config' / 'stereo_pipeline.yaml')
    sgm = next(n for n in config.nodes if n.plugin == 'sgm_stereo')
    used_paths = int(sgm.parameters.get('paths', 8)) if paths is None else paths
    with tempfile.TemporaryDirectory(prefix='depth_nodes_live_') as tmp:
        ours = run_live(config, OURS_STAGES, frames, rate=rate, count=count, warmup=warmup,
                        label='depth_nodes graph (census SGM + cross-check)',
                        workdir=Path(tmp) / 'ours', env=env, threads=threads, paths=paths,
                        composed=composed, watch=watch)
        theirs = None
        if opencv:
            mode = opencv_mode(used_paths)
            theirs = run_live(opencv_graph(config, used_paths), OPENCV_STAGES, frames,
                              rate=rate, count=count, warmup=warmup,
                              label=f'OpenCV graph (StereoSGBM {mode}, no cross-check)',
                              workdir=Path(tmp) / 'opencv', env=env, threads=threads,
                              composed=composed, watch=watch)
    used = sgm.parameters.get('threads', 0) if threads is None else threads
    return LiveBench(ours, theirs, target_hz=rate, threads=used, paths=used_paths,
                     composed=composed, watch=watch)
