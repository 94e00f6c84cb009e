"""Helpers of the tests that talk to nodes in this process (rclpy): message headers,
a node whose publications are kept instead of sent, setting parameters through the
node's service as ``ros2 param set`` does."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

import rclpy
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from std_msgs.msg import Header


def header(stamp_ns: int, frame_id: str = 'cam') -> Header:
    """A std_msgs/Header at ``stamp_ns`` nanoseconds in ``frame_id``."""
    msg = Header(frame_id=frame_id)
    msg.stamp.sec, msg.stamp.nanosec = divmod(stamp_ns, 10**9)
    return msg


def capture(node: Any, *, history: bool = False) -> Any:
    """Keep what ``node`` publishes instead of sending it: ``node.outbox`` maps each topic
    to its last message, or (``history``) lists every (topic, message) in order."""
    if history:
        node.outbox = []
        node.sink = lambda topic, msg: node.outbox.append((topic, msg))
    else:
        node.outbox = {}
        node.sink = lambda topic, msg: node.outbox.__setitem__(topic, msg)
    return node


def set_parameters(peer: Any, executor: Any, node: str, **values: Any) -> list[SetParametersResult]:
    """Set parameters of ``node`` through its standard set_parameters service, as
    `ros2 param set` does, spinning ``executor`` until the answer arrives."""
    client = peer.create_client(SetParameters, f'{node}/set_parameters')
    assert client.wait_for_service(timeout_sec=30)
    request = SetParameters.Request()
    request.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
    future = client.call_async(request)
    executor.spin_until_future_complete(future, timeout_sec=30)
    assert future.done(), f'{node}/set_parameters did not answer'
    return list(future.result().results)


@contextlib.contextmanager
def tuner(node: Any, context: Context) -> Iterator[Callable[..., list[SetParametersResult]]]:
    """A peer node and executor around ``node``; yields ``tune(**values)``, which sets
    ``node``'s parameters through its set_parameters service (see :func:`set_parameters`)."""
    peer = rclpy.create_node('tuner', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(peer)
    try:
        yield lambda **values: set_parameters(peer, executor,
                                              node.get_fully_qualified_name(), **values)
    finally:
        executor.shutdown()
        peer.destroy_node()
