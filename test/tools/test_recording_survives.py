"""A `depth-nodes record` killed mid-write (SIGKILL: what a power loss does to the
process; the data it had handed to the disk is all that is left) loses at most its last
second: `reindex` gives back every message published more than a second before the
kill, bit for bit. And `play` refuses a bag whose messages are not of their topic's type
instead of publishing them."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from helpers import REPO, SHM, START_TIMEOUT, fast_dds_files, orphaned, run_cli
from rclpy.context import Context
from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.ros.image import array_to_image
from depth_nodes.tools.bags.io import BagReader, BagWriter, serialize
from depth_nodes.tools.bags.live import FLUSH_AGE_S
from depth_nodes.tools.bags.recover import reindex_bag

pytestmark = [pytest.mark.ros, pytest.mark.slow]

#: Publishing rate (Hz) and how long the recording runs before it is killed (s).
RATE, RUN_S = 20.0, 4.0


def _wait(condition: object, proc: subprocess.Popen[bytes], log: Path) -> None:
    deadline = time.monotonic() + START_TIMEOUT
    while not condition():  # type: ignore[operator]
        assert proc.poll() is None, log.read_text()
        assert time.monotonic() < deadline, log.read_text()
        time.sleep(0.05)


def test_a_killed_recording_loses_at_most_its_last_second(tmp_path: Path,
                                                          context: Context) -> None:
    assert 2 * FLUSH_AGE_S < 1.0
    node = rclpy.create_node('talker', context=context)
    images = node.create_publisher(Image, '/cam/image_raw', 100)
    infos = node.create_publisher(CameraInfo, '/cam/camera_info', 100)
    log = tmp_path / 'record.log'
    segments = fast_dds_files()
    with log.open('wb') as out:
        recorder = subprocess.Popen(
            [sys.executable, '-m', 'depth_nodes.tools.cli', 'record', str(tmp_path / 'rec'),
             '--topics', '/cam/image_raw', '/cam/camera_info'],
            stdout=out, stderr=subprocess.STDOUT, env=dict(os.environ), cwd=REPO)
    rng = np.random.default_rng(5)
    sent: list[tuple[float, bytes]] = []
    info_times: list[float] = []
    try:
        _wait(lambda: 'recording 2 topics' in log.read_text(), recorder, log)
        _wait(lambda: images.get_subscription_count() and infos.get_subscription_count(),
              recorder, log)
        start = time.monotonic()
        for i in range(int(RUN_S * RATE)):
            # the first half with 77 kB images of noise (chunks fill up and close), the
            # second with camera_infos alone: a chunk of those closes only by the flushes
            if i < RUN_S * RATE / 2:
                image = array_to_image(rng.integers(0, 256, (240, 320), dtype=np.uint8),
                                       'mono8')
                image.header.stamp.sec = i
                images.publish(image)
                sent.append((time.monotonic(), serialize(image)))
            infos.publish(CameraInfo(width=i))
            info_times.append(time.monotonic())
            time.sleep(max(0.0, start + (i + 1) / RATE - time.monotonic()))
        killed = time.monotonic()
        recorder.send_signal(signal.SIGKILL)
        recorder.wait(timeout=30)
    finally:
        if recorder.poll() is None:
            recorder.kill()
            recorder.wait(timeout=30)
        node.destroy_node()
        # a killed process cannot remove its Fast DDS segment (70 MB in /dev/shm) nor its
        # ports: what came with the recorder goes with it (the segments and ports nobody
        # holds any more, their lock files and mutexes; not another test worker's)
        for name in orphaned(fast_dds_files() - segments):
            for left in (name, f'{name}_el', f'{name}_sl', f'sem.{name}_mutex'):
                (SHM / left).unlink(missing_ok=True)
    assert recorder.returncode == -signal.SIGKILL
    bag = tmp_path / 'rec'
    assert not (bag / 'metadata.yaml').exists()
    result = reindex_bag(bag)
    with BagReader(bag) as reader:
        got = [m.data for m in reader.messages(['/cam/image_raw'])]
        widths = [reader_msg.deserialize().width
                  for reader_msg in reader.messages(['/cam/camera_info'])]
    # every image (all published 2 s before the kill), in order, byte for byte (plus the
    # zero padding DDS adds to a multiple of 4 bytes, recorded as rosbag2 does)
    assert len(got) == len(sent), result.format()
    for recorded, (_, published) in zip(got, sent, strict=True):
        assert recorded[:len(published)] == published
        assert recorded[len(published):] == b'\0' * (-len(published) % 4)
    # every camera_info published a second before the kill, in order
    older = sum(at < killed - 1.0 for at in info_times)
    assert widths[:older] == list(range(older)), (older, widths, result.format())
    assert not result.scans[0][1].complete  # it was cut: no summary was written


def _mislabelled(bag: Path) -> None:
    """A CameraInfo's bytes on an Image topic, and the reverse."""
    image = array_to_image(np.zeros((4, 6), np.uint8), 'mono8')
    with BagWriter(bag) as writer:
        writer.write('/cam/image_raw', image, 1)
        writer.write('/cam/camera_info', CameraInfo(width=6, height=4), 1)
        writer.write('/cam/image_raw', serialize(CameraInfo()), 2, 'sensor_msgs/msg/Image')
        writer.write('/cam/camera_info', serialize(image), 2, 'sensor_msgs/msg/CameraInfo')


def test_play_refuses_messages_not_of_their_topic_type(tmp_path: Path,
                                                       ros_env: dict[str, str]) -> None:
    """It exited 0 ("played 4 messages") and published another type's bytes as an Image."""
    _mislabelled(tmp_path / 'bag')
    result = run_cli(['play', str(tmp_path / 'bag'), '--rate', '100', '--linger', '0'],
                     env=ros_env)
    assert result.returncode == 1, result.stdout
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith('depth-nodes play: error: the message on /cam/')
    assert 'at t=2 is not a sensor_msgs/msg/' in line
    assert 'size mismatch' in line
    assert 'played' not in result.stdout
