"""A node's outputs: publishers the offline harness can redirect, that count what they
publish, give every header the node's ``frame_id`` when it is set, and say whether anyone
wants them (lazy outputs).

Outputs are lazy, as image_pipeline's nodes: a node computes an output only while it is
:attr:`Output.wanted`: while a subscription matches its publisher, or always while the
offline harness's sink is installed (offline, every output is written).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from rclpy.qos import QoSProfile
from std_msgs.msg import Header

from depth_nodes.ros.accounting import Accounting
from depth_nodes.ros.serialized import Serialized

#: Publishers keep this many messages by default (reliable, volatile).
PUBLISHER_DEPTH = 10

#: Where the offline harness routes a node's messages: ``sink(topic, msg)``.
Sink = Callable[[str, Any], None]


class OutputHost(Protocol):
    """What an output needs of its node."""

    #: The offline harness's sink; None live.
    sink: Sink | None
    #: The ``frame_id`` parameter: the frame of every output's header (empty: the input's).
    frame_override: str
    accounting: Accounting

    @property
    def stopping(self) -> bool:
        """True once the node's context is shut down."""


def set_frame(msg: Any, frame: str) -> None:
    """Give ``msg``'s header (and a DisparityImage's image header) the frame ``frame``, on a
    new Header: a header the message shares with an input is left alone."""
    for holder in (msg, getattr(msg, 'image', None)):
        header = getattr(holder, 'header', None)
        if holder is not None and header is not None:
            holder.header = Header(stamp=header.stamp, frame_id=frame)


class Output:
    """A publisher that the offline harness can redirect.

    Live, :meth:`publish` publishes over DDS; with a sink installed on its node (the bag
    harness does that) the message goes to the sink instead.

    Args:
        node: The node publishing (its sink, ``frame_id`` and counters).
        publisher: The rclpy publisher.
    """

    def __init__(self, node: OutputHost, publisher: Any) -> None:
        self._node = node
        self._publisher = publisher
        self.topic: str = publisher.topic_name

    @property
    def wanted(self) -> bool:
        """True when the output is worth computing: the offline harness's sink is installed
        (every output is written offline), or a subscription matches the publisher. Cheap
        (0.2 us with the sink, 1.3 to 3.5 us live: one rcl call), so a node asks once per
        frame, before the work."""
        return self._node.sink is not None or self._publisher.get_subscription_count() > 0

    @property
    def count(self) -> int:
        """Messages published so far."""
        return self._node.accounting.published[self.topic]

    def publish(self, msg: Any) -> None:
        """Publish ``msg`` (or hand it to the harness sink); callable from any thread.
        ``msg`` may be a :class:`~depth_nodes.ros.serialized.Serialized` message. With
        the node's ``frame_id`` parameter set, the message's header (and a DisparityImage's
        image header) get that frame, on a copy: the input's header is left alone."""
        if self._node.stopping:  # the run is over: nothing can be sent any more
            return
        frame = self._node.frame_override
        if frame and not isinstance(msg, Serialized):  # bytes carry the node's own frame
            set_frame(msg, frame)
        self._node.accounting.count_output(self.topic)
        sink = self._node.sink
        if sink is None:
            self._publisher.publish(msg.data if isinstance(msg, Serialized) else msg)
        else:
            sink(self.topic, msg)

    @property
    def qos_profile(self) -> QoSProfile:
        """The publisher's QoS (after ``qos_overrides``)."""
        return self._publisher.qos_profile  # type: ignore[no-any-return]
