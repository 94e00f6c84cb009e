"""DepthNode's hooks for a node with state of its own: on_time_jump, holds_input,
finish_stream, keeps_state."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from rclpy.context import Context
from ros_helpers import capture
from sensor_msgs.msg import Image

from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.ros.node import DepthNode
from harness_nodes import PairMeanNode, RunningMeanNode

pytestmark = pytest.mark.ros


def _image(value: int, sec: int, nanosec: int = 0) -> Image:
    msg = array_to_image(np.full((2, 3), value, np.uint8), 'mono8')
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    return msg


def _values(node: Any) -> list[int]:
    return [int(image_to_array(msg)[0, 0]) for _, msg in node.outbox]


def test_on_time_jump_is_called_when_the_stamps_go_back_2_s(context: Context) -> None:
    node = capture(RunningMeanNode(context=context), history=True)
    try:
        (spec,) = node.inputs
        for value, sec in [(10, 100), (20, 101), (200, 99), (100, 100)]:
            spec.callback(_image(value, sec))
        assert node.time_jumps == 1
        assert _values(node) == [10, 15, 200, 150]  # the mean started over at 99 s
        assert node.drops == {}
    finally:
        node.destroy_node()


def test_a_stamp_less_than_stamp_reset_s_back_is_out_of_order_not_a_jump(
        context: Context) -> None:
    node = capture(RunningMeanNode(context=context), history=True)
    try:
        (spec,) = node.inputs
        for value, sec, nanosec in [(10, 100, 0), (20, 101, 0), (30, 100, 500_000_000)]:
            spec.callback(_image(value, sec, nanosec))
        assert node.time_jumps == 0
        assert node.drops == {'stamp_out_of_order': 1}
        assert _values(node) == [10, 15]
    finally:
        node.destroy_node()


class _Recording(PairMeanNode):
    """Notes, at each time jump, whether the base class still held anything."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.base_held: list[bool] = []

    def on_time_jump(self) -> None:
        self.base_held.append(self.input_set.holds())
        super().on_time_jump()


def test_on_time_jump_comes_after_the_base_class_started_over(context: Context) -> None:
    node = capture(_Recording(context=context), history=True)
    try:
        feed_a, feed_b = (spec.callback for spec in node.inputs)
        feed_a(_image(10, 10))
        feed_b(_image(30, 10))  # a pair: held by the node, waiting for its second
        feed_a(_image(10, 11))  # held by the synchroniser, waiting for its b
        assert node.holds_input()
        feed_a(_image(50, 5))   # 6 s back: a looping bag
        # the base class counted and discarded the synchroniser's a; the hook the node's pair
        assert node.base_held == [False]
        assert node.drops == {'time_jump': 2}
        feed_b(_image(70, 5))
        feed_a(_image(10, 6))
        feed_b(_image(30, 6))
        assert _values(node) == [40]  # (50 + 70 + 10 + 30) / 4: both pairs after the jump
        assert not node.holds_input()
    finally:
        node.destroy_node()


class _Failing(RunningMeanNode):
    def on_time_jump(self) -> None:
        raise RuntimeError('the filter could not reset')


def test_a_failing_on_time_jump_is_an_internal_error_and_the_frame_goes_on(
        context: Context) -> None:
    node = capture(_Failing(context=context), history=True)
    try:
        (spec,) = node.inputs
        for value, sec in [(10, 100), (20, 98)]:
            spec.callback(_image(value, sec))
        assert node.drops == {'internal_error': 1}
        assert _values(node) == [10, 15]  # this node's state was not reset
    finally:
        node.destroy_node()


def test_holds_input_and_finish_stream_extended_by_a_node(context: Context) -> None:
    node = capture(PairMeanNode(context=context), history=True)
    try:
        feed_a, feed_b = (spec.callback for spec in node.inputs)
        assert not node.holds_input()
        feed_a(_image(10, 1))
        assert node.holds_input()  # the synchroniser holds a
        feed_b(_image(30, 1))
        assert node.holds_input()  # the node holds the pair
        feed_a(_image(50, 2))
        feed_b(_image(70, 2))
        assert not node.holds_input()
        assert _values(node) == [40]
        feed_a(_image(1, 3))
        feed_b(_image(1, 3))
        feed_a(_image(1, 4))
        node.finish_stream()  # the node's pair and the synchroniser's a can never complete
        assert node.drops == {'stream_ended': 2}
        assert not node.holds_input()
    finally:
        node.destroy_node()


def test_keeps_state_is_true_only_where_a_node_says_so() -> None:
    assert DepthNode.keeps_state is False
    assert PairMeanNode.keeps_state is False  # what it holds, holds_input reports
    assert RunningMeanNode.keeps_state is True
