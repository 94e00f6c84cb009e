"""The base class of every depth_nodes node.

It adds three things to ``rclpy.node.Node``, all of which the offline bag harness relies on:

* inputs and outputs are declared through :meth:`DepthNode.add_input` and
  :meth:`DepthNode.add_output`, so a harness can see which topics a node consumes and can
  route its published messages directly (no DDS) while the live path is unchanged;
* QoS follows REP 2003 (sensor-data subscriptions, reliable publishers) and both can be
  overridden with ``qos_overrides`` parameters;
* a frame that produces no output is never lost silently: :meth:`DepthNode.drop` counts it
  by reason and logs a throttled warning naming the reason.
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions

from depth_nodes.core.camera import StereoModel
from depth_nodes.errors import CalibrationError, DepthNodesError, MessageError, UncalibratedError
from depth_nodes.ros.camera_info import StereoInfoCache
from depth_nodes.ros.image import image_to_array
from depth_nodes.ros.sync import ApproximateTimeSynchronizer, ExactTimeSynchronizer

#: Publishers keep this many messages by default (reliable, volatile).
PUBLISHER_DEPTH = 10
#: Seconds between two warnings for the same drop reason.
DROP_LOG_PERIOD_S = 5.0

Sink = Callable[[str, Any], None]


@dataclass(frozen=True)
class InputSpec:
    """One subscription: fully resolved topic, message class and callback."""

    topic: str
    msg_type: type
    callback: Callable[[Any], None]


class Output:
    """A publisher that the offline harness can redirect.

    Live, :meth:`publish` publishes over DDS; with a sink installed on its node (the bag
    harness does that) the message goes to the sink instead.
    """

    def __init__(self, node: DepthNode, publisher: Any) -> None:
        self._node = node
        self._publisher = publisher
        self.topic: str = publisher.topic_name
        self.count = 0

    def publish(self, msg: Any) -> None:
        """Publish ``msg`` (or hand it to the harness sink)."""
        self.count += 1
        sink = self._node.sink
        if sink is None:
            self._publisher.publish(msg)
        else:
            sink(self.topic, msg)


class DepthNode(Node):
    """Base class: declared inputs/outputs, REP 2003 QoS, counted drops.

    Args:
        node_name: Default node name (remappable with ``__node``).
        **kwargs: Passed to ``rclpy.node.Node`` (namespace, context, parameter_overrides,
            cli_args, ...).
    """

    def __init__(self, node_name: str, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.inputs: list[InputSpec] = []
        self.outputs: dict[str, Output] = {}
        self.drops: Counter[str] = Counter()
        self.sink: Sink | None = None
        self._last_drop_log: dict[str, float] = {}
        self._stereo_cache: StereoInfoCache | None = None

    def add_input(
        self,
        msg_type: type,
        topic: str,
        callback: Callable[[Any], None],
        *,
        qos: QoSProfile | int | None = None,
    ) -> str:
        """Subscribe ``callback`` to ``topic`` with sensor-data QoS unless told otherwise.

        Returns:
            The fully resolved topic name (after namespace and remapping).
        """
        sub = self.create_subscription(
            msg_type,
            topic,
            callback,
            qos if qos is not None else qos_profile_sensor_data,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        self.inputs.append(InputSpec(sub.topic_name, msg_type, callback))
        return str(sub.topic_name)

    def add_output(
        self, msg_type: type, topic: str, *, qos: QoSProfile | int | None = None
    ) -> Output:
        """Create a reliable publisher on ``topic`` (depth :data:`PUBLISHER_DEPTH`)."""
        pub = self.create_publisher(
            msg_type,
            topic,
            qos if qos is not None else PUBLISHER_DEPTH,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        out = Output(self, pub)
        self.outputs[out.topic] = out
        return out

    def add_synced_inputs(
        self,
        inputs: list[tuple[type, str]],
        callback: Callable[..., None],
        *,
        queue_size: int,
        approximate: bool = False,
        max_interval: float | None = None,
    ) -> ExactTimeSynchronizer | ApproximateTimeSynchronizer:
        """Subscribe to several topics and call ``callback(*msgs)`` for each matched set.

        Matching is by header stamp, exact or (``approximate``) by the ApproximateTime
        policy. Messages the synchroniser discards are counted as drops with the reason
        ``sync_<why>`` (``sync_unmatched``, ``sync_queue_full``, ...), so an image that never
        found its camera_info is not lost silently.
        """
        if approximate:
            sync: ExactTimeSynchronizer | ApproximateTimeSynchronizer = (
                ApproximateTimeSynchronizer(len(inputs), callback, queue_size=queue_size,
                                            max_interval=max_interval))
        else:
            sync = ExactTimeSynchronizer(len(inputs), callback, queue_size=queue_size)
        seen: Counter[str] = Counter()
        topics: list[str] = []

        def feed(index: int) -> Callable[[Any], None]:
            def on_message(msg: Any) -> None:
                sync.add(index, msg)
                for why, count in sync.dropped.items():
                    if count > seen[why]:
                        self.drop(f'sync_{why}', f'{count - seen[why]} message(s) from '
                                  f'{", ".join(topics)} could not be matched by stamp ({why})')
                        seen[why] = count
            return on_message

        for index, (msg_type, topic) in enumerate(inputs):
            topics.append(self.add_input(msg_type, topic, feed(index)))
        return sync

    def frame_image(self, msg: Any, what: str, shape: tuple[int, ...],
                    encodings: tuple[str, ...]) -> Any:
        """The pixels of an input image that must fit the frame being processed.

        Returns:
            The array (see ``image_to_array``), or None after counting the drop:
            ``unsupported_encoding`` (not one of ``encodings``), ``size_mismatch`` (not
            ``shape`` = (height, width)) or ``malformed_image``.
        """
        if msg.encoding not in encodings:
            self.drop('unsupported_encoding', f'{what} encoding {msg.encoding!r} is not '
                      f'{" or ".join(encodings)}')
            return None
        if (msg.height, msg.width) != tuple(shape[:2]):
            self.drop('size_mismatch', f'{what} is {msg.width}x{msg.height}, the frame '
                      f'{shape[1]}x{shape[0]}')
            return None
        try:
            return image_to_array(msg)
        except MessageError as exc:
            self.drop('malformed_image', f'{what}: {exc}')
            return None

    def stereo_model(self, left_info: Any, right_info: Any) -> StereoModel | None:
        """The stereo geometry of a CameraInfo pair (converted again only when one changes),
        or None after counting the drop: ``uncalibrated`` (a K all zero) or
        ``bad_calibration`` (anything else unusable)."""
        if self._stereo_cache is None:
            self._stereo_cache = StereoInfoCache()
        try:
            return self._stereo_cache.model(left_info, right_info)
        except UncalibratedError as exc:
            self.drop('uncalibrated', str(exc))
        except CalibrationError as exc:
            self.drop('bad_calibration', f'camera_info unusable: {exc}')
        return None

    def drop(self, reason: str, detail: str) -> None:
        """Count a frame that produced no output, and log why (throttled per reason).

        Args:
            reason: A short stable key, e.g. ``size_mismatch``; the counter's key.
            detail: The human-readable explanation, e.g. the sizes that disagreed.
        """
        self.drops[reason] += 1
        now = time.monotonic()
        last = self._last_drop_log.get(reason)
        if last is None or now - last >= DROP_LOG_PERIOD_S:
            self._last_drop_log[reason] = now
            self.get_logger().warning(
                f'dropped frame ({reason}, {self.drops[reason]} so far): {detail}'
            )


def run_node(node_class: type[DepthNode], args: list[str] | None = None) -> int:
    """Run one node until Ctrl-C: the body of every node's console script ``main``.

    Returns:
        The process exit status: 0, or 1 when the node could not start (bad parameters).
    """
    rclpy.init(args=args)
    node = None
    try:
        node = node_class()
        rclpy.spin(node)
    except DepthNodesError as exc:
        print(f'{node_class.__name__}: error: {exc}', file=sys.stderr)
        return 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
