"""DepthNode live: real DDS publishing, sensor-data subscriptions, counted throttled drops."""

from __future__ import annotations

import time

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import ReliabilityPolicy
from sensor_msgs.msg import Image

from depth_nodes.ros.image import array_to_image, image_to_array
from harness_nodes import InvertNode

pytestmark = pytest.mark.ros



def test_live_publish_over_dds_with_rep2003_qos(context: Context) -> None:
    node = InvertNode(context=context, namespace='/cam')
    peer = rclpy.create_node('peer', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(peer)
    received: list[Image] = []
    peer.create_subscription(Image, '/cam/image_inverted', received.append, 10)
    pub = peer.create_publisher(Image, '/cam/image', 10)  # reliable meets best effort
    try:
        (sub_info,) = peer.get_subscriptions_info_by_topic('/cam/image')
        assert sub_info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
        (pub_info,) = peer.get_publishers_info_by_topic('/cam/image_inverted')
        assert pub_info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        pixels = np.arange(12, dtype=np.uint8).reshape(3, 4)
        deadline = time.monotonic() + 30
        while not received and time.monotonic() < deadline:
            pub.publish(array_to_image(pixels, 'mono8'))
            executor.spin_once(timeout_sec=0.1)
        assert received, 'no inverted image arrived within 30 s'
        np.testing.assert_array_equal(image_to_array(received[0]), 255 - pixels)
        assert node.out.count >= 1
    finally:
        executor.shutdown()
        node.destroy_node()
        peer.destroy_node()


class _Logger:
    def __init__(self) -> None:
        self.warnings: list[str] = []

    def warning(self, text: str) -> None:
        self.warnings.append(text)


def test_drops_are_counted_and_logged_once_per_period(context: Context,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    node = InvertNode(context=context)
    logger = _Logger()
    monkeypatch.setattr(node, 'get_logger', lambda: logger)
    try:
        rgb = array_to_image(np.zeros((2, 2, 3), np.uint8), 'rgb8')
        for _ in range(3):
            node.on_image(rgb)
        broken = array_to_image(np.zeros((2, 2), np.uint8), 'mono8')
        broken.step = 1
        node.on_image(broken)
        assert node.drops == {'unsupported_encoding': 3, 'malformed_image': 1}
        assert logger.warnings == [
            'dropped frame (unsupported_encoding, 1 so far): expected mono8, got rgb8',
            'dropped frame (malformed_image, 1 so far): Image step 1 is smaller than a row: '
            'width 2 x 1 channel(s) x 1 byte(s) (mono8) = 2',
        ]
    finally:
        node.destroy_node()
