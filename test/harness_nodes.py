"""Small nodes used to test the node base class (hooks for state of a node's own, lazy
outputs) and the bag harness, and :func:`want_only`, which picks the outputs wanted."""

from __future__ import annotations

import time
from collections import Counter
from typing import Any

import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from sensor_msgs.msg import Image

from depth_nodes.errors import MessageError
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.ros.node import DepthNode, Output


class InvertNode(DepthNode):
    """Publishes 255 - image for mono8 images on `image`; drops anything else."""

    def __init__(self, node_name: str = 'invert', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.declare_parameter('offset', 0)
        self.add_input(Image, 'image', self.on_image)
        self.out = self.add_output(Image, 'image_inverted')

    def on_image(self, msg: Image) -> None:
        if msg.encoding != 'mono8':
            self.drop('unsupported_encoding', f'expected mono8, got {msg.encoding}')
            return
        try:
            pixels = image_to_array(msg)
        except MessageError as exc:
            self.drop('malformed_image', str(exc))
            return
        offset = self.get_parameter('offset').value
        inverted = (255 - pixels.astype(np.int32) + offset).clip(0, 255).astype(np.uint8)
        self.out.publish(array_to_image(inverted, 'mono8', msg.header))


class RestoreNode(DepthNode):
    """Inverts `image_inverted` back (tests node-to-node chaining in the harness)."""

    def __init__(self, node_name: str = 'restore', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.add_input(Image, 'image_inverted', self.on_image)
        self.out = self.add_output(Image, 'image_restored')

    def on_image(self, msg: Image) -> None:
        pixels = image_to_array(msg)
        self.out.publish(array_to_image(255 - pixels, 'mono8', msg.header))


class RunningMeanNode(DepthNode):
    """A temporal filter: publishes on `image_mean` the mean of every mono8 image on
    `image` since the start, or since the stamps last jumped back (its state of its own)."""

    keeps_state = True

    def __init__(self, node_name: str = 'running_mean', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.add_input(Image, 'image', self.on_image)
        self.out = self.add_output(Image, 'image_mean')
        self.total: np.ndarray | None = None
        self.seen = 0
        self.time_jumps = 0

    def on_image(self, msg: Image) -> None:
        pixels = image_to_array(msg).astype(np.float64)
        self.total = pixels if self.total is None else self.total + pixels
        self.seen += 1
        mean = np.rint(self.total / self.seen).astype(np.uint8)
        self.out.publish(array_to_image(mean, 'mono8', msg.header))

    def on_time_jump(self) -> None:
        self.time_jumps += 1
        self.total, self.seen = None, 0


class PairMeanNode(DepthNode):
    """Publishes on `image_pair` the mean of each pair of images matched on `a` and `b`
    and then of each two such pairs: it holds the first pair of two (state of its own,
    which `holds_input` and `finish_stream` report)."""

    def __init__(self, node_name: str = 'pair_mean', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.add_synced_inputs([(Image, 'a'), (Image, 'b')], self.on_pair, queue_size=5)
        self.out = self.add_output(Image, 'image_pair')
        self.held: np.ndarray | None = None

    def on_pair(self, a: Image, b: Image) -> None:
        pixels = image_to_array(a).astype(np.float64) + image_to_array(b)
        if self.held is None:
            self.held = pixels
            return
        mean = np.rint((self.held + pixels) / 4).astype(np.uint8)
        self.held = None
        self.out.publish(array_to_image(mean, 'mono8', a.header))

    def on_time_jump(self) -> None:
        if self.held is not None:
            self.drop('time_jump', 'a pair waiting for its second when the stamps jumped back')
            self.held = None

    def holds_input(self) -> bool:
        return super().holds_input() or self.held is not None

    def finish_stream(self) -> None:
        super().finish_stream()
        if self.held is not None:
            self.drop('stream_ended', 'a pair waiting for its second when the stream ended')
            self.held = None


class SplitNode(DepthNode):
    """Publishes a mono8 image's top half on `top` and its bottom half on `bottom`, each
    only while it is wanted (lazy outputs); notes the halves it computed."""

    def __init__(self, node_name: str = 'split', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.add_input(Image, 'image', self.on_image)
        self.top = self.add_output(Image, 'top')
        self.bottom = self.add_output(Image, 'bottom')
        self.computed: list[str] = []

    def on_image(self, msg: Image) -> None:
        want_top, want_bottom = self.top.wanted, self.bottom.wanted
        if self.skip_unwanted(want_top, want_bottom):
            return
        pixels = image_to_array(msg)
        half = pixels.shape[0] // 2
        if want_top:
            self.computed.append('top')
            self.top.publish(array_to_image(pixels[:half].copy(), 'mono8', msg.header))
        if want_bottom:
            self.computed.append('bottom')
            self.bottom.publish(array_to_image(pixels[half:].copy(), 'mono8', msg.header))


def count_calls(monkeypatch: Any, owner: Any, *names: str) -> Counter[str]:
    """Count the calls of the functions ``names`` of ``owner`` (a module or class) from
    now on; they still do their work."""
    calls: Counter[str] = Counter()
    for name in names:
        real = getattr(owner, name)

        def spy(*args: Any, _real: Any = real, _name: str = name, **kwargs: Any) -> Any:
            calls[_name] += 1
            return _real(*args, **kwargs)

        monkeypatch.setattr(owner, name, spy)
    return calls


def want_only(monkeypatch: Any, *topics: str) -> None:
    """Make every node's outputs wanted only on ``topics`` (resolved names), whatever
    subscribes and whether a sink is installed, so a test can see which outputs a node
    computes and still capture them with a sink."""
    monkeypatch.setattr(Output, 'wanted', property(lambda out: out.topic in topics))


class Listener:
    """A peer node that subscribes to outputs over DDS, as a user's subscriber does."""

    def __init__(self, context: Any) -> None:
        self.peer = rclpy.create_node('listener', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.peer)

    def subscribe(self, output: Output, msg_type: type) -> list[Any]:
        """Subscribe to ``output``'s topic; return the list its messages arrive in, once
        the node sees the subscription (``output.wanted``)."""
        box: list[Any] = []
        self.peer.create_subscription(msg_type, output.topic, box.append, 10)
        deadline = time.monotonic() + 30
        while not output.wanted and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)
        assert output.wanted, f'{output.topic}: the subscription was not matched within 30 s'
        return box

    def wait(self, box: list[Any], count: int) -> list[Any]:
        """Spin until ``box`` holds ``count`` messages (at most 30 s)."""
        deadline = time.monotonic() + 30
        while len(box) < count and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)
        return box

    def close(self) -> None:
        self.executor.shutdown()
        self.peer.destroy_node()
