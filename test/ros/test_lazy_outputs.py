"""Lazy outputs: a node computes an output only while something subscribes to it, or
always while the offline harness's sink is installed; a frame nobody wants is skipped,
counted in the diagnostics and not as a drop."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.context import Context
from ros_helpers import capture
from sensor_msgs.msg import Image

from depth_nodes.ros.diagnostics import SKIPPED_KEY
from depth_nodes.ros.image import array_to_image, image_to_array
from harness_nodes import Listener, SplitNode

pytestmark = pytest.mark.ros

PIXELS = np.arange(24, dtype=np.uint8).reshape(4, 6)


def _image(sec: int) -> Image:
    msg = array_to_image(PIXELS, 'mono8')
    msg.header.stamp.sec = sec
    return msg


def _values(status: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def test_only_the_subscribed_output_is_computed_and_a_later_subscriber_gets_its_own(
        context: Context) -> None:
    node = SplitNode(context=context, namespace='/cam')
    listener = Listener(context)
    (spec,) = node.inputs
    try:
        assert (node.top.wanted, node.bottom.wanted) == (False, False)
        top = listener.subscribe(node.top, Image)
        assert not node.bottom.wanted
        spec.callback(_image(1))
        listener.wait(top, 1)
        np.testing.assert_array_equal(image_to_array(top[0]), PIXELS[:2])
        assert (node.top.count, node.bottom.count) == (1, 0)
        assert node.computed == ['top']
        bottom = listener.subscribe(node.bottom, Image)
        spec.callback(_image(2))
        listener.wait(bottom, 1)
        listener.wait(top, 2)
        np.testing.assert_array_equal(image_to_array(bottom[0]), PIXELS[2:])
        assert bottom[0].header.stamp.sec == 2
        assert node.computed == ['top', 'top', 'bottom']
        assert node.drops == {}
        assert node.accounting.skipped == 0
    finally:
        listener.close()
        node.destroy_node()


class _Logger:
    def __init__(self) -> None:
        self.lines: list[str] = []

    def warning(self, text: str) -> None:
        self.lines.append(text)

    info = error = warning


def test_a_frame_nobody_wants_is_skipped_counted_and_not_a_drop(
        context: Context, monkeypatch: pytest.MonkeyPatch) -> None:
    node = SplitNode(context=context, namespace='/cam')
    logger = _Logger()
    monkeypatch.setattr(node, 'get_logger', lambda: logger)
    (spec,) = node.inputs
    try:
        node.diagnostics()  # a fresh period
        for sec in range(3):
            spec.callback(_image(sec))
        assert node.computed == []
        assert (node.top.count, node.bottom.count) == (0, 0)
        assert node.drops == {}
        assert logger.lines == []
        status = node.diagnostics()
        values = _values(status)
        assert values[SKIPPED_KEY] == '3'
        assert values['frames processed'] == '0'
        assert values['drops total'] == '0'
        assert values['input /cam/image total'] == '3'
        assert status.level == DiagnosticStatus.OK
        assert status.message.endswith(', 3 skipped (no subscriber)')
        assert node.accounting.skipped == 3
        assert _values(node.diagnostics())[SKIPPED_KEY] == '0'  # per period
    finally:
        node.destroy_node()


def test_offline_every_output_is_wanted(context: Context) -> None:
    node = capture(SplitNode(context=context, namespace='/cam'))
    try:
        assert (node.top.wanted, node.bottom.wanted) == (True, True)  # the sink; no subscriber
        node.inputs[0].callback(_image(1))
        assert set(node.outbox) == {'/cam/top', '/cam/bottom'}
        assert node.computed == ['top', 'bottom']
        assert node.accounting.skipped == 0
    finally:
        node.destroy_node()
