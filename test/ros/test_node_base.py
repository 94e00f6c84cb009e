"""DepthNode live: real DDS publishing, sensor-data subscriptions, counted throttled drops."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.ros.node import DepthNode
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


def _image(pixels: np.ndarray, sec: int, nanosec: int = 0) -> Image:
    msg = array_to_image(pixels, 'mono8')
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    return msg


def test_stamps_out_of_order_are_dropped_and_a_large_jump_starts_over(
        context: Context) -> None:
    node = InvertNode(context=context)
    try:
        (spec,) = node.inputs
        pixels = np.zeros((2, 2), np.uint8)
        for sec, nanosec in [(10, 0), (10, 100), (10, 50), (10, 100), (9, 0), (10, 200)]:
            spec.callback(_image(pixels, sec, nanosec))
        # 10.00000005 is older and 10.0000001 a repeat: dropped; 9 s is 1 s back: a restart
        assert node.drops == {'stamp_out_of_order': 2}
        assert node.out.count == 4
        assert node.received[spec.topic] == 6
    finally:
        node.destroy_node()


def _values(status: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def test_diagnostics_report_rates_processing_time_and_drops(context: Context) -> None:
    node = InvertNode(context=context, namespace='/cam')
    try:
        (spec,) = node.inputs
        first = node.diagnostics()  # starts a fresh period
        assert first.level == DiagnosticStatus.OK
        assert first.message == 'waiting for input'
        for i in range(5):
            spec.callback(_image(np.full((4, 4), i, np.uint8), 1, i))
        spec.callback(array_to_image(np.zeros((2, 2, 3), np.uint8), 'rgb8'))
        status = node.diagnostics()
        values = _values(status)
        assert status.name == '/cam/invert'
        assert status.level == DiagnosticStatus.WARN
        assert 'unsupported_encoding 1' in status.message
        assert values['input /cam/image total'] == '6'
        assert values['output /cam/image_inverted total'] == '5'
        assert values['frames processed'] == '5'
        assert values['drops unsupported_encoding'] == '1'
        assert values['drops total'] == '1'
        assert float(values['input /cam/image rate (Hz)']) > 0
        assert 0 < float(values['processing time mean (ms)']) <= float(
            values['processing time max (ms)'])
        # a new period: totals stay, rates and the level start over
        quiet = node.diagnostics()
        assert quiet.level == DiagnosticStatus.OK
        assert _values(quiet)['input /cam/image rate (Hz)'] == '0.00'
        assert _values(quiet)['drops unsupported_encoding'] == '1'
    finally:
        node.destroy_node()


def test_diagnostics_are_published_on_slash_diagnostics(context: Context) -> None:
    node = InvertNode(context=context, namespace='/cam', parameter_overrides=[
        Parameter('diagnostics_period', value=0.1)])
    peer = rclpy.create_node('peer', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(peer)
    arrays: list[DiagnosticArray] = []
    peer.create_subscription(DiagnosticArray, '/diagnostics', arrays.append, 10)
    try:
        deadline = time.monotonic() + 30
        while not arrays and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        assert arrays, 'no DiagnosticArray on /diagnostics within 30 s'
        assert [s.name for s in arrays[0].status] == ['/cam/invert']
        assert 'input /cam/image total' in _values(arrays[0].status[0])
    finally:
        executor.shutdown()
        node.destroy_node()
        peer.destroy_node()


def _exchange(context: Context, node: Any, publisher_qos: QoSProfile) -> tuple[int, bool]:
    """Publish 5 images with ``publisher_qos`` to ``node``; (images it received, whether
    the subscription and publisher matched)."""
    peer = rclpy.create_node('peer', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(peer)
    pub = peer.create_publisher(Image, '/cam/image', publisher_qos)
    try:
        deadline = time.monotonic() + 10
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        matched = pub.get_subscription_count() > 0
        for i in range(5):
            pub.publish(_image(np.zeros((2, 2), np.uint8), 1, i))
        deadline = time.monotonic() + (10 if matched else 1)
        while node.out.count < 5 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        return node.out.count, matched
    finally:
        executor.shutdown()
        peer.destroy_node()


@pytest.mark.parametrize('reliability', [ReliabilityPolicy.BEST_EFFORT,
                                         ReliabilityPolicy.RELIABLE])
def test_sensor_data_subscription_takes_best_effort_and_reliable_publishers(
        context: Context, reliability: ReliabilityPolicy) -> None:
    node = InvertNode(context=context, namespace='/cam')
    try:
        received, matched = _exchange(context, node, QoSProfile(depth=10,
                                                                reliability=reliability))
        assert matched
        assert received == 5
    finally:
        node.destroy_node()


@pytest.mark.slow  # 11 s (the subscription matches slowly over DDS)
def test_qos_overrides_make_the_subscription_reliable(context: Context) -> None:
    node = InvertNode(context=context, namespace='/cam', parameter_overrides=[
        Parameter('qos_overrides./cam/image.subscription.reliability', value='reliable')])
    try:
        (info,) = node.get_subscriptions_info_by_topic('/cam/image')
        assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        # a reliable subscription does not match a best-effort publisher (REP 2003's reason
        # for best-effort sensor subscriptions) ...
        received, matched = _exchange(context, node, QoSProfile(
            depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        assert not matched
        assert received == 0
        # ... and does match a reliable one
        received, matched = _exchange(context, node, QoSProfile(
            depth=10, reliability=ReliabilityPolicy.RELIABLE))
        assert matched
        assert received == 5
    finally:
        node.destroy_node()


def test_qos_overrides_change_an_output_to_best_effort(context: Context) -> None:
    node = InvertNode(context=context, namespace='/cam', parameter_overrides=[
        Parameter('qos_overrides./cam/image_inverted.publisher.reliability',
                  value='best_effort'),
        Parameter('qos_overrides./cam/image_inverted.publisher.depth', value=2)])
    try:
        (info,) = node.get_publishers_info_by_topic('/cam/image_inverted')
        assert info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
        assert node.outputs['/cam/image_inverted'].qos_profile.depth == 2
    finally:
        node.destroy_node()


class _PairNode(DepthNode):
    """Counts matched (a, b) image pairs."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('pair', **kwargs)
        self.pairs: list[int] = []
        self.add_synced_inputs([(Image, 'a'), (Image, 'b')], self.on_pair, queue_size=5)

    def on_pair(self, a: Image, b: Image) -> None:
        self.pairs.append(a.header.stamp.sec)


def test_a_jump_back_in_time_restarts_the_synchroniser_and_counts_what_it_held(
        context: Context) -> None:
    node = _PairNode(context=context)
    try:
        feed_a, feed_b = (spec.callback for spec in node.inputs)
        pixels = np.zeros((2, 2), np.uint8)
        feed_a(_image(pixels, 10))
        feed_b(_image(pixels, 10))
        feed_a(_image(pixels, 11))  # its partner never comes: held by the synchroniser
        feed_b(_image(pixels, 10))  # a repeat: out of order
        feed_a(_image(pixels, 5))   # the bag loops: 6 s back
        feed_b(_image(pixels, 5))
        assert node.pairs == [10, 5]
        assert node.drops == {'stamp_out_of_order': 1, 'time_jump': 1}
    finally:
        node.destroy_node()
