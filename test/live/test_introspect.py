"""Looking at a running graph from a shell, as a user would: `node list`, `topic
list|echo|hz|bw`, `diag`, `param list` of every node, a wrong node name that fails fast;
and `play --loop` of a bundled bag, whose every repeat a node processes.

One rectifier process fed by `depth-nodes play --loop` (both in the background, on the
module's own ROS_DOMAIN_ID) serves the module; it is stopped with SIGINT and SIGTERM at
the end and must exit 0. The node's outputs are lazy: a `topic hz` on image_rect, in the
background too, keeps it rectifying every frame (without a subscriber it would count the
frames as skipped and publish nothing)."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import pytest
from helpers import REPO, START_TIMEOUT, graph_env, interrupt, run_cli
from std_msgs.msg import Header

from depth_nodes.tools.live.introspect import RateWindow, diag_table, summary, to_text

pytestmark = [pytest.mark.ros, pytest.mark.slow]

BAG = REPO / 'bags' / 'stereo_vga'
NODE = '/stereo/left/rectify_left'


@pytest.fixture(scope='module')
def graph() -> Iterator[dict[str, str]]:
    env = graph_env()
    node = subprocess.Popen(
        [sys.executable, '-m', 'depth_nodes.nodes.scripts', 'rectify', '--ros-args', '-r',
         '__ns:=/stereo/left', '-r', 'image:=image_raw', '-r', '__node:=rectify_left'],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=REPO)
    player = subprocess.Popen(
        [sys.executable, '-m', 'depth_nodes.tools.cli', 'play', str(BAG), '--loop',
         '--wait-for-subscribers', str(START_TIMEOUT), '--topics', '/stereo/left/image_raw',
         '/stereo/left/camera_info'],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=REPO)
    listener = subprocess.Popen(
        [sys.executable, '-m', 'depth_nodes.tools.cli', 'topic', 'hz',
         f'{NODE.rsplit("/", 1)[0]}/image_rect', '--timeout', str(START_TIMEOUT)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env, cwd=REPO)
    try:
        deadline = time.monotonic() + START_TIMEOUT
        while time.monotonic() < deadline:
            result = run_cli(['topic', 'echo', f'{NODE.rsplit("/", 1)[0]}/image_rect',
                              '--once', '--timeout', '5'], env=env)
            if result.returncode == 0:
                break
        else:
            raise AssertionError('the rectifier published nothing')
        yield env
    finally:
        listener.send_signal(signal.SIGINT)
        _, heard = listener.communicate(timeout=30)
        player.send_signal(signal.SIGTERM)  # what systemd and docker send
        played, _ = player.communicate(timeout=30)
        output = interrupt(node)
    assert listener.returncode == 0, heard
    assert player.returncode == 0, played
    assert re.search(r'played \d+ messages', played), played
    assert node.returncode == 0, output


def test_node_and_topic_lists(graph: dict[str, str]) -> None:
    nodes = run_cli(['node', 'list'], env=graph)
    assert nodes.returncode == 0, nodes.stderr
    assert NODE in nodes.stdout.split()
    assert 'depth_nodes_player' in nodes.stdout
    assert '_depth_nodes' not in nodes.stdout  # the command's own node is hidden
    topics = run_cli(['topic', 'list', '-t'], env=graph)
    assert '/stereo/left/image_rect [sensor_msgs/msg/Image]' in topics.stdout.splitlines()
    assert '/diagnostics [diagnostic_msgs/msg/DiagnosticArray]' in topics.stdout.splitlines()


def test_echo_summarises_images_and_prints_other_messages(graph: dict[str, str]) -> None:
    image = run_cli(['topic', 'echo', '/stereo/left/image_rect', '--count', '2'], env=graph)
    assert image.returncode == 0, image.stderr
    lines = [line for line in image.stdout.splitlines() if line != '---']
    assert len(lines) == 2
    for line in lines:
        assert re.fullmatch(r"Image stamp \d+\.\d{9} frame 'left_camera_optical_frame' "
                            r'640x480 mono8 307200 bytes: min \d+ max \d+ mean [\d.]+, '
                            r'100.0% finite', line), line
    info = run_cli(['topic', 'echo', '/stereo/left/camera_info', '--once'], env=graph)
    assert "distortion_model: 'plumb_bob'" in info.stdout
    assert re.search(r'^k: \[[-\d.e, ]+\]$', info.stdout, re.MULTILINE), info.stdout


def _report_over(verb: str, count: str, env: dict[str, str], messages: int = 60) -> str:
    """Run ``topic hz|bw`` until a report covers ``messages`` messages (``count`` finds
    their number in a line; at most 90 s), then stop it with SIGINT; its whole output. A
    short window measures a burst rather than the stream: under load the player publishes
    late frames back to back (CI once saw 17 frames in 1.1 s, 4.6 MB/s)."""
    proc = subprocess.Popen(
        [sys.executable, '-m', 'depth_nodes.tools.cli', 'topic', verb, '/stereo/left/image_rect'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=REPO)
    assert proc.stdout is not None
    lines: list[str] = []
    covered = threading.Event()

    def read() -> None:
        for line in proc.stdout:
            lines.append(line)
            found = re.search(count, line)
            if found and int(found.group(1)) >= messages:
                covered.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    covered.wait(90)
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=30)
    reader.join(timeout=30)
    assert proc.stderr is not None
    err = proc.stderr.read()
    out = ''.join(lines)
    assert proc.returncode == 0, err
    assert 'Traceback' not in err
    assert covered.is_set(), out
    return out


def test_hz_and_bw_measure_the_stream(graph: dict[str, str]) -> None:
    hz = _report_over('hz', r'window: (\d+)', graph)
    # the bag's 10 Hz, looped
    rate = float(re.findall(r'average rate: ([\d.]+)', hz)[-1])
    assert 7.0 < rate < 13.0, hz
    bw = _report_over('bw', r'from (\d+) messages', graph)
    # 307 kB a frame at ~10 Hz
    assert 2.0 < float(re.findall(r'([\d.]+) MB/s from', bw)[-1]) < 4.0, bw


def test_diag_shows_every_node_and_its_drops(graph: dict[str, str]) -> None:
    table = run_cli(['diag', '--once', '--period', '3'], env=graph)
    assert table.returncode == 0, table.stderr
    row = next(line for line in table.stdout.splitlines() if line.startswith(NODE))
    assert re.match(rf'{NODE}\s+OK\s+[\d.]+\s+[\d.]+\s+0\s', row), row


def test_play_loop_gives_every_repeat_to_the_node(graph: dict[str, str]) -> None:
    """The bag lasts 0.1 s: repeats with its own stamps were all dropped as out of order;
    re-stamped, the rectifier's output keeps pace with the loop and drops nothing."""
    first = _output_total(graph)
    time.sleep(3)
    second = _output_total(graph)
    assert second - first >= 15  # ~10 Hz
    table = run_cli(['diag', '--once'], env=graph)
    assert 'stamp_out_of_order' not in table.stdout


def _output_total(env: dict[str, str]) -> int:
    echo = run_cli(['topic', 'echo', '/diagnostics', '--once'], env=env)
    match = re.search(r"key: 'output /stereo/left/image_rect total'\s*\n\s*value: '(\d+)'",
                      echo.stdout)
    assert match, echo.stdout
    return int(match.group(1))


def test_param_list_of_every_node_and_a_wrong_name(graph: dict[str, str]) -> None:
    listing = run_cli(['param', 'list'], env=graph)
    assert listing.returncode == 0, listing.stderr
    assert f'{NODE}:\n' in listing.stdout
    assert '  interpolation\n' in listing.stdout
    # the player publishes in a loop of its own and never spins parameter services: it has
    # none, so the listing says so instead of waiting for an answer that cannot come
    assert '/depth_nodes_player:\n  (no parameter services)\n' in listing.stdout
    assert 'no answer' not in listing.stdout
    wrong = run_cli(['param', 'get', '/stereo/left/rectfy_left', 'interpolation'], env=graph)
    assert wrong.returncode == 1
    assert wrong.stderr.count('\n') == 1
    # the node list settled without it: said as 'not in the graph', before the timeout
    assert ('error: node /stereo/left/rectfy_left not found (not in the graph); did you mean '
            f'{NODE}?') in wrong.stderr


def test_report_helpers_on_hand_made_values() -> None:
    window = RateWindow(window=4)
    for i, t in enumerate((0.0, 0.1, 0.2, 0.3, 0.5)):
        window.add(t, 1000 * (i + 1))
    assert list(window.times) == [0.1, 0.2, 0.3, 0.5]  # the window keeps the last four
    assert window.hz_line().startswith('average rate: 7.500\n\tmin: 0.100s max: 0.200s')
    assert window.bw_line(0.6).startswith('28.00 KB/s from 4 messages')
    header = Header(frame_id='cam')
    text = to_text(header)
    assert text == "stamp:\n  sec: 0\n  nanosec: 0\nframe_id: 'cam'"
    assert summary(header) is None
    assert diag_table({}).startswith('no diagnostics yet')
    from collections import deque

    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

    status = DiagnosticStatus(name='/n', level=DiagnosticStatus.WARN, message='x', values=[
        KeyValue(key='output /t rate (Hz)', value='7.0'), KeyValue(key='output /t total',
                                                                    value='100'),
        KeyValue(key='processing time mean (ms)', value='12.5'),
        KeyValue(key='drops total', value='3'), KeyValue(key='drops sync_unmatched',
                                                         value='3')])
    row = diag_table({'/n': status}).splitlines()[1]
    assert row.split() == ['/n', 'WARN', '7.0', '12.5', '3', 'sync_unmatched', '3']
    # with the totals seen over time, the rate is frames per second over that window
    steady = diag_table({'/n': status}, {'/n': deque([(0.0, 0), (10.0, 99)])})
    assert steady.splitlines()[1].split()[2] == '9.9'


def test_diag_once_without_a_graph_is_an_error() -> None:
    from helpers import graph_env

    result = run_cli(['diag', '--once', '--timeout', '2'], env=graph_env())
    assert result.returncode == 1
    assert 'error: no diagnostics within 2 s: is the graph running' in result.stderr
