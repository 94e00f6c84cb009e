"""The tof node: raw correlation frames of the simulator (depth_nodes.sim.tof) in as a
driver would send them, depth, amplitude, confidence and points out, checked against the
exact ground truth; the message convention, parameters and every drop reason.

Tolerance: the depth within 1 % of Z at the median (the target; measured 0.3 %
at VGA), points equal to the published depth's back-projection to float precision.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from helpers import Lazy
from rclpy.context import Context
from rclpy.parameter import Parameter
from ros_helpers import capture, header, tuner

from depth_nodes.errors import ConfigError
from depth_nodes.nodes import tof
from depth_nodes.nodes.tof import ToFNode
from depth_nodes.ros.camera_info import camera_info_to_model, model_to_camera_info
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.ros.pointcloud import read_pointcloud
from depth_nodes.sim.tof import ToFSimConfig, simulate_tof
from harness_nodes import count_calls, want_only

pytestmark = pytest.mark.ros

CONFIG = ToFSimConfig(width=160, height=120, focal_px=125.0, supersample=2, emitter_step=8,
                      n_frames=1)
FRAME = Lazy(lambda: next(simulate_tof(CONFIG)))
STAMP = 1700 * 10**9 + 77


def _inputs(samples: np.ndarray | None = None, encoding: str = '16UC1') -> tuple[Any, Any]:
    planes = FRAME.samples if samples is None else samples
    h = header(STAMP, 'tof_optical_frame')
    stacked = np.ascontiguousarray(planes.reshape(-1, planes.shape[-1]))
    if encoding == '32FC1':
        stacked = stacked.astype(np.float32)
    return array_to_image(stacked, encoding, h), model_to_camera_info(FRAME.camera, h)


def _make(context: Context, **params: Any) -> Any:
    return capture(ToFNode(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()]))


@pytest.fixture
def node(context: Context) -> Any:
    n = _make(context)
    yield n
    n.destroy_node()


@pytest.mark.parametrize('encoding', ['16UC1', 'mono16', '32FC1'])
def test_depth_meets_the_accuracy_target(context: Context, encoding: str) -> None:
    n = _make(context)
    try:
        n.on_frame(*_inputs(encoding=encoding))
        assert n.drops == {}
        depth_msg = n.outbox['/depth/image_rect']
        assert (depth_msg.encoding, depth_msg.width, depth_msg.height) == ('32FC1', 160, 120)
        assert depth_msg.header.frame_id == 'tof_optical_frame'
        depth = image_to_array(depth_msg)
        truth = FRAME.depth_gt
        est = np.isfinite(depth)
        assert est[(FRAME.flags_gt == 0) & np.isfinite(truth)].mean() > 0.85
        assert np.median(np.abs(depth[est] - truth[est]) / truth[est]) < 0.01
    finally:
        n.destroy_node()


def test_outputs_fit_together(node: Any) -> None:
    node.on_frame(*_inputs())
    depth = image_to_array(node.outbox['/depth/image_rect'])
    info = node.outbox['/depth/camera_info']
    camera = camera_info_to_model(info)
    assert not camera.is_distorted
    np.testing.assert_array_equal(camera.P, FRAME.camera.P)
    np.testing.assert_array_equal(camera.K, FRAME.camera.P[:, :3])
    assert info.header.stamp == node.outbox['/depth/image_rect'].header.stamp
    amplitude = image_to_array(node.outbox['/amplitude/image_rect'])
    confidence = image_to_array(node.outbox['/confidence/image_rect'])
    assert amplitude.shape == confidence.shape == depth.shape
    assert amplitude.dtype == confidence.dtype == np.float32
    assert confidence.min() >= 0.0
    assert confidence.max() <= 1.0
    assert (confidence[np.isfinite(depth)] >= 0.5).all()  # min_confidence
    fields = read_pointcloud(node.outbox['/points'])
    assert set(fields) == {'x', 'y', 'z', 'intensity'}
    np.testing.assert_array_equal(fields['z'], depth)
    np.testing.assert_array_equal(fields['intensity'], amplitude)
    P = FRAME.camera.P
    u = np.arange(160)[None, :]
    with np.errstate(invalid='ignore'):
        np.testing.assert_allclose(fields['x'], (u - P[0, 2]) / P[0, 0] * depth, rtol=1e-6,
                                   atol=1e-7)


def test_depth_in_millimetres(context: Context) -> None:
    n = _make(context, depth_encoding='16UC1')
    try:
        n.on_frame(*_inputs())
        msg = n.outbox['/depth/image_rect']
        assert msg.encoding == '16UC1'
        mm = image_to_array(msg).astype(np.float64)
        known = mm > 0
        truth = FRAME.depth_gt[known] * 1000
        assert np.median(np.abs(mm[known] - truth) / truth) < 0.01
    finally:
        n.destroy_node()


def test_one_frequency_and_three_steps(context: Context) -> None:
    config = dataclasses.replace(CONFIG, frequencies_mhz=(20.0,), phase_steps=3)
    frame = next(simulate_tof(config))
    # 20 MHz alone is five times noisier than 100 MHz: a looser confidence reference
    n = _make(context, modulation_frequencies=[20.0], phase_steps=3, noise_reference=0.05)
    try:
        n.on_frame(*_inputs(frame.samples))
        depth = image_to_array(n.outbox['/depth/image_rect'])
        est = np.isfinite(depth)
        assert est.mean() > 0.5
        assert np.median(np.abs(depth[est] - frame.depth_gt[est]) / frame.depth_gt[est]) < 0.03
    finally:
        n.destroy_node()


def test_drops_are_counted_with_their_reason(node: Any) -> None:
    image, info = _inputs()
    image.encoding = 'rgb8'
    node.on_frame(image, info)
    node.on_frame(*_inputs(FRAME.samples[:6]))  # 6 planes, not 2 x 4
    image, info = _inputs()
    info.k = np.zeros(9)
    node.on_frame(image, info)
    image, info = _inputs()
    image.step = 7  # does not fit the width
    node.on_frame(image, info)
    assert node.drops == {'unsupported_encoding': 1, 'size_mismatch': 1, 'uncalibrated': 1,
                          'malformed_image': 1}
    assert '/depth/image_rect' not in node.outbox


def test_parameters_change_at_runtime_and_bad_ones_are_refused(node: Any,
                                                               context: Context) -> None:
    with tuner(node, context) as tune:
        assert tune(phase_steps=5)[0].successful
        node.on_frame(*_inputs())
        assert node.drops == {'size_mismatch': 1}  # 8 planes are not 2 x 5
        assert tune(phase_steps=4, min_confidence=0.9)[0].successful
        node.on_frame(*_inputs())
        confident = image_to_array(node.outbox['/depth/image_rect'])
        refused = tune(modulation_frequencies=[80.0, 80.0])[0]
        assert not refused.successful
        assert 'must differ' in refused.reason
        first, refused = tune(depth_min=3.0, depth_max=2.0)  # set one after the other
        assert first.successful
        assert not refused.successful
        assert 'depth_max (2) must be greater than depth_min (3)' in refused.reason
    assert node.params.values['modulation_frequencies'] == [80.0, 100.0]
    assert node.params.values['depth_max'] == 0.0
    assert np.isfinite(confident).mean() < np.isfinite(
        image_to_array(_run_default(context))).mean()


def _run_default(context: Context) -> Any:
    n = _make(context)
    try:
        n.on_frame(*_inputs())
        return n.outbox['/depth/image_rect']
    finally:
        n.destroy_node()


@pytest.mark.parametrize(('name', 'value', 'message'), [
    ('modulation_frequencies', [80.0, 100.0, 120.0, 140.0], 'one to three'),
    ('phase_steps', 2, 'phase_steps'),
    ('depth_encoding', 'mono8', 'must be one of 32FC1, 16UC1'),
])
def test_bad_start_up_values_are_one_line_errors(context: Context, name: str, value: Any,
                                                 message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        ToFNode(context=context, parameter_overrides=[Parameter(name, value=value)])


ALL = ('/depth/image_rect', '/depth/camera_info', '/amplitude/image_rect',
       '/confidence/image_rect', '/points')


@pytest.mark.parametrize(('wanted', 'work'), [
    (ALL, {'decode': 1, 'depth_to_points': 1, 'array_to_image': 3}),
    (('/depth/image_rect',), {'decode': 1, 'array_to_image': 1}),
    (('/points',), {'decode': 1, 'depth_to_points': 1}),
    (('/depth/camera_info',), {}),  # the rectified camera needs no decoding
    ((), {}),
])
def test_only_the_outputs_wanted_are_computed(node: Any, monkeypatch: pytest.MonkeyPatch,
                                              wanted: tuple[str, ...],
                                              work: dict[str, int]) -> None:
    node.on_frame(*_inputs())
    everything = dict(node.outbox)
    node.outbox.clear()
    decoded = count_calls(monkeypatch, node.decoder, 'decode')
    built = count_calls(monkeypatch, tof, 'depth_to_points', 'array_to_image')
    want_only(monkeypatch, *wanted)
    node.on_frame(*_inputs())
    assert node.outbox == {topic: everything[topic] for topic in wanted}
    assert decoded + built == work
    assert node.drops == {}
    assert node.accounting.skipped == (0 if wanted else 1)
