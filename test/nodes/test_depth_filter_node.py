"""The depth_filter node: simulated depth-camera frames (depth_nodes.sim.depth_sequence) in
as a driver sends them, the filtered depth, its camera_info, the filled mask and sigma out,
checked against the exact depth and against the core filter run on the same frames; its
parameters, poses and every drop reason.

Tolerances: the node's depth equals the core's to float32 (32FC1) or to the millimetre it
rounds to (16UC1); accuracy targets as in test/core/test_depth_filter.py.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from helpers import Lazy
from rclpy.context import Context
from rclpy.parameter import Parameter
from ros_helpers import capture, header, tuner

from depth_nodes.core.depth_filter import DepthFilter, DepthFilterParams, stereo_sigma
from depth_nodes.core.depth_image import from_metres
from depth_nodes.nodes.depth_filter import DepthFilterNode
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.sim.depth_sequence import DepthSequenceConfig, simulate_depth_sequence
from depth_nodes.tools.bags.multiview import camera_model, odometry_message
from harness_nodes import want_only

pytestmark = pytest.mark.ros

CONFIG = DepthSequenceConfig(kind='moving_camera', width=96, height=72, n_frames=6,
                             supersample=2)
SEQ = Lazy(lambda: SimpleNamespace(frames=list(simulate_depth_sequence(CONFIG))))
FRAME_ID = 'depth_optical'


def _inputs(frame: Any, encoding: str = '32FC1', stamp: int | None = None
            ) -> tuple[Any, Any]:
    h = header(frame.stamp_ns if stamp is None else stamp, FRAME_ID)
    depth = from_metres(frame.depth, encoding)
    return (array_to_image(depth, encoding, h),
            model_to_camera_info(camera_model(frame.camera, FRAME_ID), h))


def _make(context: Context, **params: Any) -> Any:
    return capture(DepthFilterNode(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()]), history=True)


def _published(node: Any, topic: str) -> list[Any]:
    return [msg for t, msg in node.outbox if t.endswith(topic)]


def _core(frames: list[Any], params: DepthFilterParams, *, poses: bool,
          sigma: bool = False) -> list[Any]:
    filt = DepthFilter()
    out = []
    for f in frames:
        s = stereo_sigma(f.depth, f.camera.fx, 0.08, 0.1) if sigma else None
        out.append(filt.process(f.depth, f.camera, params, sigma=s,
                                pose=f.pose if poses else None))
    return out


def test_the_node_publishes_what_the_core_computes(context: Context) -> None:
    node = _make(context)
    for f in SEQ.frames:
        node.on_frame(*_inputs(f))
    want = _core(SEQ.frames, DepthFilterParams(), poses=False)
    got = [image_to_array(m) for m in _published(node, 'filtered/image_rect')]
    assert len(got) == len(SEQ.frames)
    assert node.drops == {}
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w.depth)
    masks = [image_to_array(m) for m in _published(node, 'filtered/filled')]
    np.testing.assert_array_equal(masks[-1] == 255, want[-1].filled)
    assert not _published(node, 'filtered/sigma')  # noise_model none: no sigma
    node.destroy_node()


def test_odometry_moves_the_temporal_memory_with_the_camera(context: Context) -> None:
    node = _make(context, pose_source='odometry', noise_model='stereo', stereo_baseline=0.08)
    for f in SEQ.frames:
        node.poses.on_odometry(odometry_message(f.pose, f.stamp_ns, FRAME_ID))
        node.on_frame(*_inputs(f))
    want = _core(SEQ.frames, DepthFilterParams(), poses=True, sigma=True)
    got = [image_to_array(m) for m in _published(node, 'filtered/image_rect')]
    np.testing.assert_array_equal(got[-1], want[-1].depth)
    sigma = image_to_array(_published(node, 'filtered/sigma')[-1])
    np.testing.assert_array_equal(sigma, want[-1].sigma)
    # and the compensation matters: without poses the last frame differs
    still = _core(SEQ.frames, DepthFilterParams(), poses=False)
    assert not np.array_equal(np.nan_to_num(still[-1].depth), np.nan_to_num(got[-1]))
    node.destroy_node()


def test_a_frame_waits_for_its_pose_and_is_dropped_when_none_comes(context: Context) -> None:
    node = _make(context, pose_source='odometry', pose_wait=0.05)
    first, second = SEQ.frames[0], SEQ.frames[1]
    node.on_frame(*_inputs(first))
    assert not _published(node, 'filtered/image_rect')
    assert node.holds_input()
    node.poses.on_odometry(odometry_message(first.pose, first.stamp_ns, FRAME_ID))
    assert len(_published(node, 'filtered/image_rect')) == 1
    node.on_frame(*_inputs(second))
    node.on_frame(*_inputs(SEQ.frames[5]))  # 0.13 s later: the second's pose is given up on
    assert node.drops['pose_timeout'] == 1
    node.finish_stream()
    assert node.drops['stream_ended'] == 1
    node.destroy_node()


def test_16uc1_in_16uc1_out_and_decimation_scales_the_camera(context: Context) -> None:
    node = _make(context, decimation=2)
    node.on_frame(*_inputs(SEQ.frames[0], '16UC1'))
    out = _published(node, 'filtered/image_rect')[0]
    info = _published(node, 'filtered/camera_info')[0]
    assert out.encoding == '16UC1'
    assert (out.width, out.height) == (48, 36)
    assert (info.width, info.height) == (48, 36)
    cam = SEQ.frames[0].camera
    assert info.k[0] == pytest.approx(cam.fx / 2)
    assert info.k[2] == pytest.approx((cam.cx + 0.5) / 2 - 0.5)
    assert info.p[0] == pytest.approx(cam.fx / 2)
    assert out.header.stamp == info.header.stamp
    node.destroy_node()


def test_bad_inputs_are_counted_drops(context: Context) -> None:
    node = _make(context, decimation=4, noise_model='sigma')
    f = SEQ.frames[0]
    depth, info = _inputs(f)
    h = header(f.stamp_ns, FRAME_ID)
    sigma = array_to_image(np.full((10, 10), 0.01, np.float32), '32FC1', h)
    node.on_frame(depth, info, sigma)
    assert node.drops == {'size_mismatch': 1}
    mono = array_to_image(np.zeros((72, 96), np.uint8), 'mono8', h)
    node.on_frame(mono, info, sigma)
    assert node.drops['unsupported_encoding'] == 1
    tiny = array_to_image(np.ones((3, 3), np.float32), '32FC1', h)
    tiny_info = model_to_camera_info(camera_model(
        type(f.camera)(3.0, 3.0, 1.0, 1.0, 3, 3), FRAME_ID), h)
    node.on_frame(tiny, tiny_info, array_to_image(np.ones((3, 3), np.float32), '32FC1', h))
    assert node.drops['too_small'] == 1
    uncalibrated = model_to_camera_info(camera_model(f.camera, FRAME_ID), h)
    uncalibrated.k = [0.0] * 9
    uncalibrated.p = [0.0] * 12
    node.on_frame(depth, uncalibrated, sigma)
    assert node.drops['uncalibrated'] == 1
    assert not _published(node, 'filtered/image_rect')
    node.destroy_node()


def test_nan_negative_and_infinite_depth_is_unknown(context: Context) -> None:
    node = _make(context, spatial=False, temporal=False, flying_gap=0.0)
    depth = np.full((72, 96), 2.0, np.float32)
    depth[0, :4] = [np.nan, -1.0, np.inf, 0.0]
    h = header(SEQ.frames[0].stamp_ns, FRAME_ID)
    node.on_frame(array_to_image(depth, '32FC1', h),
                  model_to_camera_info(camera_model(SEQ.frames[0].camera, FRAME_ID), h))
    out = image_to_array(_published(node, 'filtered/image_rect')[0])
    assert np.isnan(out[0, :4]).all()
    assert (out[0, 4:] == 2.0).all()
    node.destroy_node()


def test_a_size_change_and_a_time_jump_start_the_memory_over(context: Context) -> None:
    node = _make(context)
    for f in SEQ.frames[:3]:
        node.on_frame(*_inputs(f))
    assert node.filter.state is not None
    node.set_parameters([Parameter('decimation', value=2)])
    node.on_frame(*_inputs(SEQ.frames[3]))
    assert node.resets == 1
    assert node.filter.state.values.shape == (36, 48)
    node.on_time_jump()
    assert node.filter.state is None
    assert node.resets == 2
    assert len(_published(node, 'filtered/image_rect')) == 4
    assert node.drops == {}
    node.destroy_node()


def test_parameters_are_checked_by_the_core_rules(context: Context) -> None:
    node = _make(context)
    with tuner(node, context) as set_params:
        refused = set_params(spatial_alpha=0.1)
        assert not refused[0].successful
        assert 'spatial_alpha' in refused[0].reason
        refused = set_params(hole_filling='everywhere')
        assert not refused[0].successful
        assert set_params(temporal_persistence=8)[0].successful
    assert node.params.values['temporal_persistence'] == 8
    node.destroy_node()


def test_only_the_wanted_outputs_are_published(context: Context, monkeypatch: Any) -> None:
    node = _make(context)
    want_only(monkeypatch, '/filtered/filled')
    node.on_frame(*_inputs(SEQ.frames[0]))
    assert [t for t, _ in node.outbox] == ['/filtered/filled']
    want_only(monkeypatch)
    node.on_frame(*_inputs(SEQ.frames[1]))
    assert node.filter.state is None  # nobody listens: the memory is forgotten
    # without a noise model sigma is never published: wanting only it filters nothing
    want_only(monkeypatch, '/filtered/sigma')
    node.on_frame(*_inputs(SEQ.frames[2]))
    assert node.outbox[-1][0] == '/filtered/filled'
    assert node.accounting.skipped == 2
    node.destroy_node()
