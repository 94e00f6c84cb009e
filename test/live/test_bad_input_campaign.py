"""The bad-input campaign replayed into the stereo graph of separate processes.

Five node processes (as the launch file starts them), `depth-nodes play` and
`depth-nodes record` in their own processes, all over DDS. The campaign bag
(depth_nodes.tools.bags.bad_inputs) puts a hostile stamp between every two good frames. Checked
(the drops each case must cause: test/campaign.py):
no node dies; each hostile message is counted under its reason by the node that first
sees it (read from the /diagnostics the nodes published, recorded in the bag) and logged;
every good frame, and no hostile one, comes out as disparity, checked disparity, depth and
point cloud.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import rclpy
from campaign import expected_drops
from diagnostic_msgs.msg import DiagnosticArray
from helpers import REPO, run_cli
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from depth_nodes.graph.description import load_graph_config
from depth_nodes.tools.bags.bad_inputs import START_NS, Campaign, write_bad_input_bag
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bench.live import warm_up
from depth_nodes.tools.live.processes import GraphProcesses, StereoFeeder, load_stereo_frames

pytestmark = [pytest.mark.ros, pytest.mark.slow]

OUTPUTS = ['/stereo/disparity', '/stereo/disparity_checked', '/stereo/depth',
           '/stereo/points2']


class _Replay:
    """Results of one campaign replay (run once for all tests of this module)."""

    def __init__(self, campaign: Campaign, graph: GraphProcesses, recorded: Path,
                 crashed: dict[str, int], baseline: dict[str, dict[str, int]]) -> None:
        self.campaign = campaign
        self.graph = graph
        self.recorded = recorded
        self.crashed = crashed
        self.baseline = baseline  # drops by node and reason after the warm-up


def _wait_for_line(stream: Any, text: str, timeout: float) -> str:
    lines: list[str] = []

    def read() -> None:
        for line in stream:
            lines.append(line)
            if text in line:
                return

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(timeout)
    return ''.join(lines)


@pytest.fixture(scope='module')
def replay(tmp_path_factory: pytest.TempPathFactory) -> Iterator[_Replay]:
    from helpers import next_domain

    tmp = tmp_path_factory.mktemp('campaign')
    patch = pytest.MonkeyPatch()  # this process's graph too: its own domain, localhost
    patch.setenv('ROS_DOMAIN_ID', str(next_domain()))
    patch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    patch.delenv('ROS_STATIC_PEERS', raising=False)
    env = dict(os.environ)
    campaign = write_bad_input_bag(tmp / 'bad', REPO / 'bags' / 'stereo_vga')
    config = load_graph_config(REPO / 'config' / 'stereo_pipeline.yaml')
    graph = GraphProcesses(config, tmp / 'graph', env=env,
                           overrides={'/**': {'diagnostics_period': 0.5}})
    context = Context()
    rclpy.init(args=[], context=context)
    node = rclpy.create_node('campaign_feeder', context=context)
    drops: dict[str, dict[str, int]] = {}

    def on_diagnostics(array: DiagnosticArray) -> None:
        for status in array.status:
            drops[status.name] = _drops(status)

    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 50)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    feeder = StereoFeeder(node, '/stereo', ['/stereo/points2'])
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    recorder = None
    try:
        graph.start()
        recorder = subprocess.Popen(
            [sys.executable, '-m', 'depth_nodes.tools.cli', 'record', str(tmp / 'rec'),
             '--topics', *OUTPUTS, '/diagnostics'],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=REPO)
        started = _wait_for_line(recorder.stdout, 'recording 5 topics', 120)
        assert 'recording 5 topics' in started, started
        # Warm up (numba may still be compiling on a fresh clone) with stamps before the
        # campaign's, so the campaign meets a graph that keeps up and a recorder whose
        # subscriptions had the warm-up's time to match their publishers (a publisher
        # does not deliver to a subscription it has not matched yet).
        deadline = time.monotonic() + 300
        while not feeder.graph_ready() and time.monotonic() < deadline:
            time.sleep(0.05)
        warm_up(feeder, load_stereo_frames(REPO / 'bags' / 'stereo_vga'), graph, 3)
        time.sleep(1.5)  # three diagnostics periods: the warm-up's drops are in
        baseline = {name: dict(counts) for name, counts in drops.items()}
        played = run_cli(['play', str(tmp / 'bad'), '--wait-for-subscribers', '60',
                          '--delay', '3'], env=env, timeout=300)
        assert played.returncode == 0, played.stderr
        last_good = max(campaign.good)
        deadline = time.monotonic() + 120
        while last_good not in feeder.arrived['/stereo/points2'] and (
                time.monotonic() < deadline):
            time.sleep(0.1)
        time.sleep(2.0)  # the nodes' last diagnostics after the last frame
        crashed = graph.exited()
        recorder.send_signal(signal.SIGINT)
        recorder.communicate(timeout=60)
        yield _Replay(campaign, graph, tmp / 'rec', crashed, baseline)
    finally:
        if recorder is not None and recorder.poll() is None:
            recorder.kill()
        graph.stop()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        patch.undo()


def _drops(status: Any) -> dict[str, int]:
    """{reason: count} of a node's DiagnosticStatus."""
    return {kv.key.removeprefix('drops '): int(kv.value) for kv in status.values
            if kv.key.startswith('drops ') and kv.key != 'drops total'}


def _recorded(replay: _Replay) -> dict[str, list[Any]]:
    out: dict[str, list[Any]] = {}
    with BagReader(replay.recorded) as reader:
        for bag_msg in reader.messages():
            out.setdefault(bag_msg.topic, []).append(bag_msg.deserialize())
    return out


def _stamp(msg: Any) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_no_node_crashes_and_all_stop_cleanly(replay: _Replay) -> None:
    assert replay.crashed == {}
    codes = replay.graph.stop()
    hung = {name: replay.graph.log(name)[-4000:] for name, code in codes.items() if code}
    assert codes == dict.fromkeys(codes, 0), (codes, hung)  # with where a hung node stood


def test_every_good_frame_and_no_hostile_one_comes_out(replay: _Replay) -> None:
    recorded = _recorded(replay)
    good = set(replay.campaign.good)
    for topic in OUTPUTS:  # the warm-up frames before the campaign are recorded too
        stamps = [_stamp(m) for m in recorded.get(topic, []) if _stamp(m) >= START_NS]
        assert sorted(stamps) == sorted(good), topic


def _campaign_drops(replay: _Replay) -> dict[str, dict[str, int]]:
    """Drops during the campaign, {node: {reason: count}}: the last diagnostics each node
    published (recorded in the bag) minus those after the warm-up."""
    final: dict[str, dict[str, int]] = {}
    for array in _recorded(replay)['/diagnostics']:
        for status in array.status:
            final[status.name] = _drops(status)
    out = {}
    for name, counts in final.items():
        before = replay.baseline.get(name, {})
        out[name] = {r: c - before.get(r, 0) for r, c in counts.items() if c > before.get(r, 0)}
    return out


def test_each_hostile_message_is_counted_by_reason(replay: _Replay) -> None:
    final = _campaign_drops(replay)
    assert len(final) == 5
    for node, expected in expected_drops(replay.campaign).items():
        for reason, count in expected.items():
            assert final[node].get(reason) == count, (node, reason, final[node])
    # The first stage rejects nothing but what the campaign says, except that a lead-in
    # frame may lose a message to a subscription that had not matched the player yet.
    lead_in = len(replay.campaign.lead_in)
    for node in ('/stereo/left/rectify_left', '/stereo/right/rectify_right'):
        counts = dict(final[node])
        assert counts.pop('sync_unmatched', 0) <= lead_in, final[node]
        assert counts == dict(expected_drops(replay.campaign).get(node, {})), final[node]
    # the unpaired frames and the frames the rectifiers refused never complete a set
    assert final['/stereo/sgm_stereo'].get('sync_unmatched', 0) >= 1
    assert final['/stereo/point_cloud'].get('sync_unmatched', 0) >= 1
    assert final['/stereo/cross_check'] == {}


def test_each_drop_reason_is_logged_with_a_clear_reason(replay: _Replay) -> None:
    for node, expected in expected_drops(replay.campaign).items():
        log = replay.graph.log(node)
        for reason in expected:
            assert f'dropped frame ({reason}, 1 so far): ' in log, (node, reason, log[-3000:])
    assert 'Traceback' not in ''.join(replay.graph.log(n) for n in replay.graph.processes)
