"""`depth-nodes play` and `depth-nodes record`: bags into and out of a live ROS graph.

``ros2 bag`` is not on PyPI. These publish and record the serialised CDR bytes untouched,
so a recorded message is byte-for-byte the one that was played (but for ``play --loop``'s
repeats, whose header stamps move on; see :class:`PlayOptions`).

QoS as rosbag2: ``record`` stores the QoS profiles each topic's publishers offered in the
bag's metadata, and ``play`` offers them again: a transient-local topic such as
``/tf_static`` stays transient-local (a node that starts later still gets it), a topic
recorded best effort is played best effort; others are reliable.
"""

from __future__ import annotations

import itertools
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
from rclpy.serialization import serialize_message
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import try_shutdown
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosgraph_msgs.msg import Clock

from depth_nodes.core.stamps import NS_PER_S, stamp_ns, stamp_parts
from depth_nodes.errors import BagError, ConfigError
from depth_nodes.graph.description import checked_namespace
from depth_nodes.tools.bags.io import BagReader, BagWriter, message_class
from depth_nodes.tools.signals import STOP, stop_requested

#: Queue depth of the player's publishers and the recorder's subscriptions.
QUEUE_DEPTH = 1000
#: Seconds: a recording's chunk is closed once its first message is this old, and the
#: file fsynced at most this often (:meth:`BagWriter.flush`, every pass of the loop), so a
#: SIGKILL or a power loss takes at most the last second with it (the rest is recovered
#: by `depth-nodes reindex`).
FLUSH_AGE_S = 0.4


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
        restamp: With ``loop``, move the header stamps of every repeat on by the bag's
            length plus one message period, so the repeats read as a stream that goes on
            (the nodes drop a stamp that is not newer than the last: a 0.1 s bag looped
            as it is gave two frames, then only drops). False keeps the recorded stamps.
        remap: Publish topic ``FROM`` as ``TO`` (``--remap FROM:=TO``).
    """

    rate: float = 1.0
    loop: bool = False
    clock: bool = False
    topics: list[str] | None = None
    wait_for_subscribers: float = 0.0
    delay: float = 0.0
    linger: float = 1.0
    restamp: bool = True
    remap: dict[str, str] | None = None

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
        for source, target in (self.remap or {}).items():
            if not source.startswith('/') or not target.startswith('/'):
                raise ConfigError(f'--remap {source}:={target}: both names must be absolute')
            checked_namespace(target, '--remap target')


def play_bag(path: str | Path, options: PlayOptions | None = None,
             log: TextIO | None = None) -> int:
    """Publish the bag at ``path`` with its original timing; returns messages published.

    Raises:
        BagError: Missing/corrupt bag or unknown topic, or a message whose bytes are not
            of its topic's type (found when its turn comes: the messages before it went
            out).
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
    remap = options.remap or {}
    for source in remap:
        if source not in topics:
            reader.close()
            raise BagError(f'--remap {source}: no such topic played from {path}')
    # Stopping is ours (tools/signals.py): rclpy's handler would shut the context down
    # under a publish() in progress ("rcl_shutdown already called"). No arguments: rcl
    # would read --remap's FROM:=TO in the command line as ROS remappings of its own, with
    # a deprecation warning for each.
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    # no parameter services: the loop below publishes and never spins them, so a
    # `param list` of the graph would wait for an answer that cannot come
    node = Node('depth_nodes_player', start_parameter_services=False)
    try:
        pubs = {t: node.create_publisher(message_class(reader.topics[t]), remap.get(t, t),
                                         _offered(reader.qos.get(t, [])))
                for t in topics}
        clock_pub = None
        if options.clock:
            clock_pub = node.create_publisher(Clock, '/clock', _reliable())
        waited = {**pubs, '/clock': clock_pub} if clock_pub is not None else pubs
        _wait_for_subscribers(waited, options.wait_for_subscribers, log)
        STOP.wait(options.delay)
        if log:
            count = sum(reader.counts[t] for t in topics)
            log.write(f'playing {count} messages on {len(topics)} topics'
                      f'{", again and again" if options.loop else ""}\n')
            log.flush()
        published = 0
        shift = 0
        step, period = _loop_step(reader, topics) if options.loop else (0, 0)
        while not stop_requested():
            published += _play_once(reader, topics, pubs, clock_pub, options.rate, shift)
            if not options.loop:
                break
            STOP.wait(period / NS_PER_S / options.rate)  # the next repeat a period later
            if options.restamp:
                shift += step
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


def _offered(profiles: list[Any]) -> QoSProfile:
    """The QoS to play a topic with, from the profiles its publishers offered when it was
    recorded (rosbag2's rule): transient local when every one was, best effort when any
    was, else reliable and volatile."""
    qos = _reliable()
    if not profiles:
        return qos
    if all(p.durability.name == 'TRANSIENT_LOCAL' for p in profiles):
        qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
        qos.depth = max(1, max(p.depth for p in profiles))
    if any(p.reliability.name == 'BEST_EFFORT' for p in profiles):
        qos.reliability = ReliabilityPolicy.BEST_EFFORT
    return qos


def _loop_step(reader: BagReader, topics: list[str]) -> tuple[int, int]:
    """Nanoseconds to move the stamps on per repeat (the bag's length plus one period),
    and that period: the median one of the busiest topic (0.1 s for a single message)."""
    times: dict[str, list[int]] = {}
    for bag_msg in reader.messages(topics):
        times.setdefault(bag_msg.topic, []).append(bag_msg.timestamp)
    if not times:
        raise BagError(f'{reader.path}: the topics to play hold no messages')
    first = min(t[0] for t in times.values())
    last = max(t[-1] for t in times.values())
    busiest = max(times.values(), key=len)
    gaps = sorted(b - a for a, b in itertools.pairwise(busiest) if b > a)
    period = gaps[len(gaps) // 2] if gaps else 100_000_000
    return last - first + period, period


def _restamped(bag_msg: Any, shift: int) -> bytes:
    """The message with every std_msgs/Header stamp in it moved on by ``shift`` ns.

    Raises:
        BagError: The message cannot be deserialised.
    """
    msg = bag_msg.deserialize()
    if not _shift_stamps(msg, shift):
        return bytes(bag_msg.data)
    return bytes(serialize_message(msg))


def _shift_stamps(msg: Any, shift: int) -> bool:
    """Move every Header stamp inside ``msg`` (nested and in arrays) on; False when none."""
    found = False
    for name, kind in msg.get_fields_and_field_types().items():
        value = getattr(msg, name)
        if kind == 'std_msgs/Header':
            value.stamp.sec, value.stamp.nanosec = stamp_parts(stamp_ns(value) + shift)
            found = True
        elif hasattr(value, 'get_fields_and_field_types'):
            found |= _shift_stamps(value, shift)
        elif '/' in kind and isinstance(value, (list, tuple)):  # sequences, fixed arrays
            for item in value:
                found |= _shift_stamps(item, shift)
    return found


def _wait_for_subscribers(pubs: dict[str, Any], timeout: float,
                          log: TextIO | None = None) -> None:
    """Wait up to ``timeout`` s for every topic to have a subscriber, saying every second
    which ones are still without."""
    start = time.monotonic()
    said = start
    while time.monotonic() - start < timeout and not stop_requested():
        missing = [p.topic_name for p in pubs.values() if p.get_subscription_count() == 0]
        if not missing:
            return
        if log is not None and time.monotonic() - said >= 1.0:
            said = time.monotonic()
            log.write(f'waiting for subscribers ({said - start:.0f} of {timeout:g} s): '
                      f'{len(pubs) - len(missing)} of {len(pubs)} topics have one; none on '
                      f'{", ".join(missing[:4])}{" ..." if len(missing) > 4 else ""}\n')
            log.flush()
        STOP.wait(0.02)


def _play_once(reader: BagReader, topics: list[str], pubs: dict[str, Any],
               clock_pub: Any, rate: float, shift: int = 0) -> int:
    start_wall = time.monotonic()
    start_bag: int | None = None
    count = 0
    for bag_msg in reader.messages(topics):
        if start_bag is None:
            start_bag = bag_msg.timestamp
        delay = start_wall + (bag_msg.timestamp - start_bag) / NS_PER_S / rate - time.monotonic()
        if (delay > 0 and STOP.wait(delay)) or stop_requested():
            break
        if clock_pub is not None:
            clock = Clock()
            clock.clock.sec, clock.clock.nanosec = stamp_parts(bag_msg.timestamp + shift)
            clock_pub.publish(clock)
        bag_msg.check()  # the bytes a subscriber gets must be its topic's type
        data = _restamped(bag_msg, shift) if shift else bag_msg.data
        pubs[bag_msg.topic].publish(data)
        count += 1
    return count


def _to_bag_qos(profile: QoSProfile) -> Any:
    """An rclpy QoS profile as rosbags' Qos tuple (what rosbag2 writes to metadata)."""

    def when(duration: Any) -> Any:
        sec, nsec = stamp_parts(duration.nanoseconds)
        return QosTime(min(sec, 2 ** 31 - 1), nsec)

    return Qos(QosHistory(int(profile.history)), int(profile.depth),
               QosReliability(int(profile.reliability)),
               QosDurability(int(profile.durability)), when(profile.deadline),
               when(profile.lifespan), QosLiveliness(int(profile.liveliness)),
               when(profile.liveliness_lease_duration),
               bool(profile.avoid_ros_namespace_conventions))


class Recorder:
    """Subscribe to ``topics`` as they appear and write every message's bytes to a bag.

    A subscription is reliable when every publisher of the topic is, best effort
    otherwise, and transient local when every publisher is (as rosbag2 does), so it
    matches any publisher and gets a latched message published before it started.
    What is recorded reaches the disk within about a second (:meth:`flush`).
    """

    def __init__(self, path: str | Path, topics: Iterable[str], *, overwrite: bool = False) -> None:
        self.topics = sorted(set(topics))
        if not self.topics:
            raise ConfigError('record needs at least one topic (--topics)')
        for topic in self.topics:
            if not topic.startswith('/'):
                raise ConfigError(f'record: topic names must be absolute, got {topic!r}')
        # a full disk leaves what was recorded, without its index (not readable as it is)
        self.writer = BagWriter(path, overwrite=overwrite, keep_partial=True)
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
            if infos and all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                             for i in infos):  # latched (/tf_static): get what came before
                qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
            self._subs[topic] = self.node.create_subscription(
                message_class(msgtype), topic,
                self._callback(topic, msgtype, [_to_bag_qos(i.qos_profile) for i in infos]),
                qos, raw=True)
        return [t for t in self.topics if t not in self._subs]

    def _callback(self, topic: str, msgtype: str, offered: list[Any]) -> Any:
        def on_message(data: bytes) -> None:
            stamp = self.node.get_clock().now().nanoseconds
            with self._lock:
                self.writer.write(topic, data, stamp, msgtype, qos=offered)
                self.count += 1
        return on_message

    def flush(self) -> None:
        """Put what was recorded on the disk, once it is :data:`FLUSH_AGE_S` old."""
        with self._lock:
            self.writer.flush(FLUSH_AGE_S)

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
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)  # as play
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
            recorder.flush()
            if max_messages is not None and recorder.count >= max_messages:
                break
    except KeyboardInterrupt:
        pass
    finally:
        count = recorder.count if recorder else 0
        if recorder is not None:
            recorder.close()
        try_shutdown()
    return count
