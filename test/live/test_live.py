"""play / record over real DDS between separate processes: every message, byte for byte."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from helpers import REPO, run_cli
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import qos_profile_sensor_data
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

from depth_nodes.ros.image import array_to_image
from depth_nodes.tools.bags.io import BagReader, BagWriter

pytestmark = [pytest.mark.ros, pytest.mark.slow]

N_FRAMES = 12
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def _bag(path: Path) -> None:
    rng = np.random.default_rng(3)
    with BagWriter(path) as writer:
        for i in range(N_FRAMES):
            header = Header()
            header.stamp.sec, header.stamp.nanosec = 50, i * 20_000_000
            header.frame_id = 'cam'
            stamp = 50_000_000_000 + i * 20_000_000
            image = rng.integers(0, 256, (48, 64), dtype=np.uint8)
            writer.write('/cam/image_raw', array_to_image(image, 'mono8', header), stamp)
            info = CameraInfo(header=header, width=64, height=48)
            info.k = [float(i), 0.0, 32.0, 0.0, 60.0, 24.0, 0.0, 0.0, 1.0]
            writer.write('/cam/camera_info', info, stamp)


def _payloads(bag: Path) -> dict[str, list[bytes]]:
    out: dict[str, list[bytes]] = {}
    with BagReader(bag) as reader:
        for m in reader.messages():
            out.setdefault(m.topic, []).append(m.data)
    return out


def test_play_into_record_is_lossless_and_byte_exact(tmp_path: Path,
                                                     ros_env: dict[str, str]) -> None:
    _bag(tmp_path / 'in')
    recorder = subprocess.Popen(
        [sys.executable, '-m', 'depth_nodes.tools.cli', 'record', str(tmp_path / 'rec'),
         '--topics', '/cam/image_raw', '/cam/camera_info', '/clock',
         '--max-messages', str(4 * N_FRAMES), '--duration', '120'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ros_env, cwd=REPO)
    try:
        played = run_cli(['play', str(tmp_path / 'in'), '--rate', '4', '--clock',
                          '--wait-for-subscribers', '60'], env=ros_env, timeout=180)
        assert played.returncode == 0, played.stderr
        assert f'played {2 * N_FRAMES} messages' in played.stdout
        out, err = recorder.communicate(timeout=180)
    finally:
        recorder.kill()
    assert recorder.returncode == 0, err
    assert f'recorded {4 * N_FRAMES} messages' in out
    recorded, played_bytes = _payloads(tmp_path / 'rec'), _payloads(tmp_path / 'in')
    # one /clock message, carrying the bag time, before every played message
    clock_ns = [TYPESTORE.deserialize_cdr(c, 'rosgraph_msgs/msg/Clock').clock
                for c in recorded.pop('/clock')]
    with BagReader(tmp_path / 'in') as reader:
        bag_times = [m.timestamp for m in reader.messages()]
    assert [c.sec * 10**9 + c.nanosec for c in clock_ns] == bag_times
    assert recorded.keys() == played_bytes.keys()
    for topic, originals in played_bytes.items():
        assert len(recorded[topic]) == len(originals), topic
        for got, sent in zip(recorded[topic], originals, strict=True):
            # Byte for byte, plus the zero padding the DDS transport adds to bring a
            # serialized payload to a multiple of 4 bytes (rosbag2 records it too).
            assert got[: len(sent)] == sent
            assert got[len(sent):] == b'\0' * ((-len(sent)) % 4)


def test_a_best_effort_subscription_receives_the_last_message(
        tmp_path: Path, context: Context) -> None:
    """Every node's inputs are best effort, which acknowledges nothing: the player stays
    (--linger, 1 s by default) after its last message so that one arrives too."""
    _bag(tmp_path / 'in')
    node = rclpy.create_node('best_effort_listener', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    stamps: list[int] = []
    node.create_subscription(Image, '/cam/image_raw',
                             lambda msg: stamps.append(msg.header.stamp.nanosec),
                             qos_profile_sensor_data)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        played = run_cli(['play', str(tmp_path / 'in'), '--topics', '/cam/image_raw',
                          '--wait-for-subscribers', '60', '--delay', '1'],
                         env=dict(os.environ), timeout=180)
    finally:
        executor.shutdown()
        node.destroy_node()
    assert played.returncode == 0, played.stderr
    assert stamps == [i * 20_000_000 for i in range(N_FRAMES)]


def test_play_unknown_topic_and_bad_rate(tmp_path: Path, ros_env: dict[str, str]) -> None:
    _bag(tmp_path / 'in')
    result = run_cli(['play', str(tmp_path / 'in'), '--topics', '/nope'], env=ros_env)
    assert result.returncode == 1
    assert result.stderr.strip().startswith('depth-nodes play: error: topic /nope is not in')
    result = run_cli(['play', str(tmp_path / 'in'), '--rate', '0'], env=ros_env)
    assert result.returncode == 1
    assert 'rate must be positive' in result.stderr
    result = run_cli(['play', str(tmp_path / 'in'), '--linger', '-1'], env=ros_env)
    assert result.returncode == 1
    assert '--linger must be >= 0, got -1.0' in result.stderr
    assert 'Traceback' not in result.stderr


def test_record_rejects_relative_topics_and_existing_output(tmp_path: Path,
                                                            ros_env: dict[str, str]) -> None:
    result = run_cli(['record', str(tmp_path / 'rec'), '--topics', 'relative', '--duration', '1'],
                     env=ros_env)
    assert result.returncode == 1
    assert 'topic names must be absolute' in result.stderr
    _bag(tmp_path / 'exists')
    result = run_cli(['record', str(tmp_path / 'exists'), '--topics', '/a', '--duration', '1'],
                     env=ros_env)
    assert result.returncode == 1
    assert 'exists already' in result.stderr


def test_a_node_that_ignores_ctrl_c_is_aborted_with_its_stacks_in_its_log(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """GraphProcesses.stop: a process still running after the grace period gets SIGABRT,
    and Python's fault handler (switched on for every node) writes where it stood."""
    from depth_nodes.graph.description import GraphConfig
    from depth_nodes.tools.live import processes as live_graph

    monkeypatch.setattr(live_graph, 'STOP_TIMEOUT_S', 1.0)
    graph = live_graph.GraphProcesses(GraphConfig('hang', []), tmp_path)
    assert graph.env['PYTHONFAULTHANDLER'] == '1'
    script = ('import signal, sys, time\n'
              'signal.signal(signal.SIGINT, signal.SIG_IGN)\n'
              'print("ready", flush=True)\n'
              'def wait_forever():\n'
              '    while True:\n'
              '        time.sleep(0.1)\n'
              'wait_forever()\n')
    with (tmp_path / 'hang.log').open('wb') as log:
        proc = subprocess.Popen([sys.executable, '-c', script], stdout=log,
                                stderr=subprocess.STDOUT, env=graph.env)
    graph.processes['/hang'] = proc
    while 'ready' not in graph.log('/hang'):
        assert proc.poll() is None, graph.log('/hang')
        time.sleep(0.01)
    assert graph.stop() == {'/hang': -6}  # SIGABRT, not a kill
    assert 'in wait_forever' in graph.log('/hang')


def test_transient_local_topics_keep_their_qos_through_record_and_play(
        tmp_path: Path, context: Context) -> None:
    """`record` stores the offered QoS in the bag's metadata (as rosbag2 does) and `play`
    offers it again: a subscriber that comes after the message was played still gets a
    transient-local (latched, like /tf_static) one; remapped with --remap."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node = rclpy.create_node('latched_talker', context=context)
    publisher = node.create_publisher(Header, '/calibration', latched)
    publisher.publish(Header(frame_id='once'))
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        recorded = run_cli(['record', str(tmp_path / 'rec'), '--topics', '/calibration',
                            '--max-messages', '1', '--duration', '60'],
                           env=dict(os.environ), timeout=120)
        assert recorded.returncode == 0, recorded.stderr
        with BagReader(tmp_path / 'rec') as reader:
            offered = reader.qos['/calibration']
        assert [q.durability.name for q in offered] == ['TRANSIENT_LOCAL']
        assert [q.reliability.name for q in offered] == ['RELIABLE']
        player = subprocess.Popen(
            [sys.executable, '-m', 'depth_nodes.tools.cli', 'play', str(tmp_path / 'rec'),
             '--remap', '/calibration:=/calibration_played', '--linger', '30'],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ),
            cwd=REPO)
        try:
            time.sleep(5)  # the message has been published, to nobody
            got: list[str] = []
            node.create_subscription(Header, '/calibration_played',
                                     lambda msg: got.append(msg.frame_id), latched)
            deadline = time.monotonic() + 20
            while not got and time.monotonic() < deadline:
                time.sleep(0.1)
            assert got == ['once']
        finally:
            player.send_signal(subprocess.signal.SIGINT)
            _, err = player.communicate(timeout=30)
        assert player.returncode == 0, err
    finally:
        executor.shutdown()
        node.destroy_node()
