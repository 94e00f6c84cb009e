"""A node's inputs: subscriptions with REP 2003 QoS, counted messages, checked stamps,
synchronised sets with counted losses, and starting over when the stamps jump back.

Every input message is counted and its stamp checked before the node's callback sees it:
a stamp with ``nanosec`` of 1e9 or more is dropped as ``bad_stamp``; a message not newer
than the last one on its topic as ``stamp_out_of_order``, unless the stamps jumped back by
:data:`STAMP_RESET_S` or more, as when a bag loops: the node then starts over (every
topic's stamp history and every synchroniser are reset, what they held counted as
``time_jump`` drops) and calls its ``on_time_jump`` hook.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import Image

from depth_nodes.core.stamps import NS_PER_S, STAMP_RESET_S, stamp_ns
from depth_nodes.ros.accounting import Accounting
from depth_nodes.ros.sync import ApproximateTimeSynchronizer, ExactTimeSynchronizer
from depth_nodes.ros.transport import transport_topic, transport_type

Synchronizer = ExactTimeSynchronizer | ApproximateTimeSynchronizer


@dataclass(frozen=True)
class InputSpec:
    """One subscription: fully resolved topic, message class and callback."""

    topic: str
    msg_type: type
    callback: Callable[[Any], None]


class InputSet:
    """The inputs of one node.

    Args:
        node: The node subscribing (topic resolution, subscriptions, its logger).
        accounting: The node's counters (messages received, drops, frame times).
        on_time_jump: Called with the new stamp (ns) after the stamps jumped back and the
            inputs started over.
    """

    def __init__(self, node: Node, accounting: Accounting,
                 on_time_jump: Callable[[int | None], None]) -> None:
        self._node = node
        self._accounting = accounting
        self._on_time_jump = on_time_jump
        #: Every subscription, in the order they were made (the offline harness feeds them).
        self.specs: list[InputSpec] = []
        #: The time a callback spends when it publishes is the frame's processing time.
        #: False for a node that publishes from worker threads (it records its own times).
        self.callback_is_frame_time = True
        self._last_stamp: dict[str, int] = {}
        self._syncs: list[tuple[Synchronizer, Counter[str]]] = []

    def add(self, msg_type: type, topic: str, callback: Callable[[Any], None], *,
            qos: QoSProfile | int | None = None, check_stamps: bool = True,
            transport: str = 'raw') -> str:
        """Subscribe ``callback`` to ``topic``: see :meth:`DepthNode.add_input`.

        Returns:
            The fully resolved topic name (after namespace and remapping).
        """
        resolved = self._node.resolve_topic_name(topic)
        if transport != 'raw' and msg_type is Image:
            msg_type = transport_type(transport)
            resolved = topic = transport_topic(resolved, transport)
        accounting = self._accounting

        def on_message(msg: Any) -> None:
            accounting.count_input(resolved)
            if not self._stamp_valid(resolved, msg):
                return
            if check_stamps and not self._stamp_in_order(resolved, msg):
                return
            if not self.callback_is_frame_time:  # workers may be publishing meanwhile
                accounting.guarded(callback, msg, where=resolved)
                return
            published = sum(accounting.published.values())
            start = time.perf_counter()
            accounting.guarded(callback, msg, where=resolved)
            if sum(accounting.published.values()) > published:
                accounting.record_frame_time(time.perf_counter() - start)

        sub = self._node.create_subscription(
            msg_type,
            topic,
            on_message,
            qos if qos is not None else qos_profile_sensor_data,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        self.specs.append(InputSpec(sub.topic_name, msg_type, on_message))
        return str(sub.topic_name)

    def add_synced(self, inputs: Sequence[tuple[Any, ...]], callback: Callable[..., None], *,
                   queue_size: int, approximate: bool = False,
                   max_interval: float | None = None,
                   qos: QoSProfile | int | None = None) -> Synchronizer:
        """Subscribe to several topics matched by stamp: see
        :meth:`DepthNode.add_synced_inputs`."""
        sync: Synchronizer
        if approximate:
            sync = ApproximateTimeSynchronizer(len(inputs), callback, queue_size=queue_size,
                                               max_interval=max_interval)
        else:
            sync = ExactTimeSynchronizer(len(inputs), callback, queue_size=queue_size)
        seen: Counter[str] = Counter()
        topics: list[str] = []
        self._syncs.append((sync, seen))

        def feed(index: int) -> Callable[[Any], None]:
            def on_message(msg: Any) -> None:
                try:
                    sync.add(index, msg)
                finally:  # also when the set's callback raised: the losses stand
                    for why, count in list(sync.lost_frames.items()):
                        if count > seen[why]:
                            self._accounting.drop(
                                f'sync_{why}', f'{count - seen[why]} frame(s) of '
                                f'{", ".join(topics)} could not be matched by stamp ({why})',
                                count=count - seen[why])
                            seen[why] = count
            return on_message

        for index, (msg_type, topic, *transport) in enumerate(inputs):
            topics.append(self.add(msg_type, topic, feed(index), qos=qos,
                                   transport=transport[0] if transport else 'raw'))
        return sync

    def start_over(self, stamp: int | None = None) -> None:
        """Forget every input's stamp history and what the synchronisers hold (counted as
        ``time_jump`` drops), so the inputs can be matched again from the new stamps on.

        Args:
            stamp: The stamp (ns) that jumped back. What a synchroniser holds stamped no
                later belongs to the new timeline (the image of a frame whose camera_info
                came second), and is offered to it again instead of being discarded.
        """
        self._last_stamp.clear()
        for sync, seen in self._syncs:
            kept = sorted(((s, i, m) for i, s, m in sync.held()
                           if stamp is not None and s <= stamp), key=lambda k: k[:2])
            frames = sync.queued_frames
            sync.reset()
            seen.clear()
            for _, index, msg in kept:
                sync.add(index, msg)
            lost = (frames - sync.queued_frames - sync.emitted
                    - sum(sync.lost_frames.values()))  # those are counted as sync_*
            if lost > 0:
                self._accounting.drop(
                    'time_jump', f'{lost} frame(s) waiting for their partners were '
                    'discarded when the stamps jumped back', count=lost)

    def restart(self, stamp: int | None, why: str) -> None:
        """Start the node over from ``stamp`` (ns): log ``why``, :meth:`start_over`, then
        call the node's time-jump handler. Used when an input's stamps jump back, and by a
        pose input whose poses do."""
        self._node.get_logger().info(f'{why}: starting over')
        self.start_over(stamp)
        self._accounting.guarded(self._on_time_jump, stamp, where='on_time_jump')

    def holds(self) -> bool:
        """True while a message waits for its partners in a synchroniser."""
        return any(sync.queued for sync, _ in self._syncs)

    def finish(self) -> None:
        """The stream ended: count what the synchronisers hold as ``stream_ended`` drops
        and empty them."""
        for sync, _ in self._syncs:
            if sync.queued_frames:
                self._accounting.drop(
                    'stream_ended', f'{sync.queued_frames} frame(s) still waiting for their '
                    'partners when the stream ended', count=sync.queued_frames)
            sync.reset()
        for _, seen in self._syncs:
            seen.clear()

    def _stamp_valid(self, topic: str, msg: Any) -> bool:
        """False (after counting a ``bad_stamp`` drop) for a header stamp that is not a
        time: ``nanosec`` must be below 1e9 (builtin_interfaces/Time)."""
        header = getattr(msg, 'header', None)
        stamp = getattr(header, 'stamp', None) if header is not None else getattr(
            msg, 'stamp', None)  # std_msgs/Header itself
        if stamp is None:
            return True
        if not 0 <= stamp.nanosec < NS_PER_S:
            self._accounting.drop('bad_stamp', f'{topic}: stamp nanosec {stamp.nanosec} is '
                                  f'not below 1e9 (sec {stamp.sec}): not a valid time')
            return False
        return True

    def _stamp_in_order(self, topic: str, msg: Any) -> bool:
        """True for a stamp newer than the last on ``topic``, or one that jumped back by
        :data:`STAMP_RESET_S` or more (after starting over); else False after counting a
        ``stamp_out_of_order`` drop."""
        header = getattr(msg, 'header', None)
        if header is None:
            return True
        stamp = stamp_ns(header)
        last = self._last_stamp.get(topic)
        self._last_stamp[topic] = stamp if last is None else max(stamp, last)
        if last is None or stamp > last:
            return True
        if last - stamp >= STAMP_RESET_S * NS_PER_S:
            self.restart(stamp, f'{topic}: stamps jumped back by {(last - stamp) / NS_PER_S:.3f}'
                         ' s (a looping bag or a restarted source)')
            self._last_stamp[topic] = stamp
            return True
        self._accounting.drop('stamp_out_of_order', f'{topic}: stamp {stamp / NS_PER_S:.9f} s is '
                              f'not newer than the last one, {last / NS_PER_S:.9f} s')
        return False
