"""`depth-nodes play` and `depth-nodes record`: bags into and out of a live ROS graph.

``ros2 bag`` is not on PyPI. These publish and record the serialised CDR bytes untouched,
so a recorded message is byte-for-byte the one that was played.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import rclpy
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.signals import SignalHandlerOptions

from depth_nodes.errors import BagError, ConfigError
from depth_nodes.tools.bagio import BagReader, BagWriter, message_class
from depth_nodes.tools.signals import STOP, stop_requested

#: Queue depth of the player's publishers and the recorder's subscriptions.
QUEUE_DEPTH = 1000


def _reliable(depth: int = QUEUE_DEPTH) -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


@dataclass
class PlayOptions:
    """How to play a bag.

    Attributes:
        rate: Playback speed factor (2.0 plays twice as fast).
        loop: Start again at the end, until interrupted.
        clock: Publish rosgraph_msgs/Clock on /clock with the bag time.
        topics: Only these topics (all when None).
        wait_for_subscribers: Seconds to wait, before the first message, for every topic
            to have a subscriber.
        delay: Seconds to wait after that, before the first message. A publisher sees a
            subscription a moment before the subscription is ready for data, and a
            best-effort subscription loses what comes in between.
        linger: Seconds to stay after the last message, once reliable subscriptions have
            acknowledged everything, before the player's publishers go away. A
            best-effort subscription (sensor-data QoS: every node's input) acknowledges
            nothing, and a message still on its way to it when its publisher is destroyed
            is lost: the campaign test lost its last frame that way, at a different node
            each time.
    """

    rate: float = 1.0
    loop: bool = False
    clock: bool = False
    topics: list[str] | None = None
    wait_for_subscribers: float = 0.0
    delay: float = 0.0
    linger: float = 1.0

    def validate(self) -> None:
        """Raises ConfigError for a non-positive rate or a negative wait, delay or linger."""
        if not self.rate > 0:
            raise ConfigError(f'--rate must be positive, got {self.rate}')
        if self.delay < 0:
            raise ConfigError(f'--delay must be >= 0, got {self.delay}')
        if self.linger < 0:
            raise ConfigError(f'--linger must be >= 0, got {self.linger}')
        if self.wait_for_subscribers < 0:
            raise ConfigError(f'--wait-for-subscribers must be >= 0, got '
                              f'{self.wait_for_subscribers}')


def play_bag(path: str | Path, options: PlayOptions | None = None,
             log: TextIO | None = None) -> int:
    """Publish the bag at ``path`` with its original timing; returns messages published.

    Raises:
        BagError: Missing/corrupt bag or unknown topic.
        ConfigError: Invalid options.
    """
    options = options or PlayOptions()
    options.validate()
    reader = BagReader(path)
    if reader.message_count == 0:
        reader.close()
        raise BagError(f'{path} holds no messages: nothing to play')
    topics = options.topics or sorted(reader.topics)
    for topic in topics:
        reader.require(topic)
    # Stopping is ours (tools/signals.py): rclpy's handler would shut the context down
    # under a publish() in progress ("rcl_shutdown already called").
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = Node('depth_nodes_player')
    try:
        pubs = {t: node.create_publisher(message_class(reader.topics[t]), t, _reliable())
                for t in topics}
        clock_pub = None
        if options.clock:
            from rosgraph_msgs.msg import Clock

            clock_pub = node.create_publisher(Clock, '/clock', _reliable())
        waited = {**pubs, '/clock': clock_pub} if clock_pub is not None else pubs
        _wait_for_subscribers(waited, options.wait_for_subscribers)
        STOP.wait(options.delay)
        if log:
            log.write(f'playing {reader.message_count} messages on {len(topics)} topics\n')
            log.flush()
        published = 0
        while not stop_requested():
            published += _play_once(reader, topics, pubs, clock_pub, options.rate)
            if not options.loop:
                break
        if stop_requested():
            if log:
                log.write(f'interrupted after {published} messages\n')
            return published
        for pub in waited.values():
            pub.wait_for_all_acked(Duration(seconds=5.0))
        STOP.wait(options.linger)
        return published
    finally:
        node.destroy_node()
        rclpy.shutdown()
        reader.close()


def _wait_for_subscribers(pubs: dict[str, Any], timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not stop_requested():
        if all(p.get_subscription_count() > 0 for p in pubs.values()):
            return
        STOP.wait(0.02)


def _play_once(reader: BagReader, topics: list[str], pubs: dict[str, Any],
               clock_pub: Any, rate: float) -> int:
    start_wall = time.monotonic()
    start_bag: int | None = None
    count = 0
    for bag_msg in reader.messages(topics):
        if start_bag is None:
            start_bag = bag_msg.timestamp
        delay = start_wall + (bag_msg.timestamp - start_bag) / 1e9 / rate - time.monotonic()
        if (delay > 0 and STOP.wait(delay)) or stop_requested():
            break
        if clock_pub is not None:
            from rosgraph_msgs.msg import Clock

            clock = Clock()
            clock.clock.sec, clock.clock.nanosec = divmod(bag_msg.timestamp, 1_000_000_000)
            clock_pub.publish(clock)
        pubs[bag_msg.topic].publish(bag_msg.data)
        count += 1
    return count


class Recorder:
    """Subscribe to ``topics`` as they appear and write every message's bytes to a bag.

    A subscription is reliable when every publisher of the topic is, best effort
    otherwise (as rosbag2 does), so it matches any publisher.
    """

    def __init__(self, path: str | Path, topics: Iterable[str], *, overwrite: bool = False) -> None:
        self.topics = sorted(set(topics))
        if not self.topics:
            raise ConfigError('record needs at least one topic (--topics)')
        for topic in self.topics:
            if not topic.startswith('/'):
                raise ConfigError(f'record: topic names must be absolute, got {topic!r}')
        self.writer = BagWriter(path, overwrite=overwrite)
        self.node = Node('depth_nodes_recorder')
        self.count = 0
        self._lock = threading.Lock()
        self._subs: dict[str, Any] = {}

    def poll_topics(self) -> list[str]:
        """Subscribe to requested topics that have appeared; returns those still missing."""
        types = dict(self.node.get_topic_names_and_types())
        for topic in self.topics:
            if topic in self._subs or topic not in types:
                continue
            if len(types[topic]) != 1:
                raise BagError(f'topic {topic} is published with several types: {types[topic]}')
            msgtype = types[topic][0]
            infos = self.node.get_publishers_info_by_topic(topic)
            qos = _reliable()
            if not infos or any(i.qos_profile.reliability != ReliabilityPolicy.RELIABLE
                                for i in infos):
                qos.reliability = ReliabilityPolicy.BEST_EFFORT
            self._subs[topic] = self.node.create_subscription(
                message_class(msgtype), topic, self._callback(topic, msgtype), qos, raw=True)
        return [t for t in self.topics if t not in self._subs]

    def _callback(self, topic: str, msgtype: str) -> Any:
        def on_message(data: bytes) -> None:
            stamp = self.node.get_clock().now().nanoseconds
            with self._lock:
                self.writer.write(topic, data, stamp, msgtype)
                self.count += 1
        return on_message

    def close(self) -> None:
        """Finish the bag and the node."""
        self.node.destroy_node()
        self.writer.close()


def record_bag(path: str | Path, topics: Iterable[str], *, duration: float | None = None,
               max_messages: int | None = None, overwrite: bool = False,
               log: TextIO | None = None) -> int:
    """Record ``topics`` until ``duration`` s, ``max_messages`` or Ctrl-C; returns the count.

    Raises:
        BagError: The output exists, or a topic has several types.
        ConfigError: No or relative topic names, or a non-positive limit.
    """
    if duration is not None and duration <= 0:
        raise ConfigError(f'--duration must be positive, got {duration}')
    if max_messages is not None and max_messages <= 0:
        raise ConfigError(f'--max-messages must be positive, got {max_messages}')
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)  # stopping is ours (play)
    recorder = None
    try:
        recorder = Recorder(path, topics, overwrite=overwrite)
        executor = SingleThreadedExecutor()
        executor.add_node(recorder.node)
        deadline = None if duration is None else time.monotonic() + duration
        announced = False
        while (deadline is None or time.monotonic() < deadline) and not stop_requested():
            missing = recorder.poll_topics()
            if not missing and not announced and log:
                log.write(f'recording {len(recorder.topics)} topics\n')
                log.flush()
                announced = True
            executor.spin_once(timeout_sec=0.05)
            if max_messages is not None and recorder.count >= max_messages:
                break
    except KeyboardInterrupt:
        pass
    finally:
        count = recorder.count if recorder else 0
        if recorder is not None:
            recorder.close()
        rclpy.try_shutdown()
    return count
