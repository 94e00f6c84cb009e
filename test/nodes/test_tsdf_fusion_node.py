"""The tsdf_fusion node: simulated depth-camera frames and their odometry in as a driver and
a VIO send them, the mesh (MarkerArray, block by block), surface points and distance slice
out, checked against the core volume run on the same frames; its parameters, services,
poses and every drop reason.

Tolerances: the node's mesh is the core's, triangle for triangle (the same float32
arithmetic); the surface is checked against the exact depth in test/core/test_fusion.py.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import rclpy
from helpers import Lazy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from ros_helpers import capture, header, tuner
from std_srvs.srv import Trigger

from depth_nodes.core.depth_image import from_metres
from depth_nodes.core.fusion import TsdfParams, TsdfVolume
from depth_nodes.core.fusion.layer import MeshLayer
from depth_nodes.core.fusion.ply import read_ply
from depth_nodes.core.geometry import Pose
from depth_nodes.nodes.tsdf_fusion import TsdfFusionNode
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.image import array_to_image
from depth_nodes.ros.pointcloud import read_pointcloud
from depth_nodes.ros.serialized import DELETEALL, Serialized, read_marker_array
from depth_nodes.sim.depth_sequence import DepthSequenceConfig, simulate_depth_sequence
from depth_nodes.tools.bags.multiview import camera_model, odometry_message

pytestmark = pytest.mark.ros

CONFIG = DepthSequenceConfig(kind='moving_camera', width=96, height=72, n_frames=6,
                             supersample=2)
SEQ = Lazy(lambda: SimpleNamespace(frames=list(simulate_depth_sequence(CONFIG))))
FRAME_ID = 'depth_optical'
VOXEL = 0.05


def _inputs(frame: Any, encoding: str = '32FC1', stamp: int | None = None) -> tuple[Any, Any]:
    h = header(frame.stamp_ns if stamp is None else stamp, FRAME_ID)
    return (array_to_image(from_metres(frame.depth, encoding), encoding, h),
            model_to_camera_info(camera_model(frame.camera, FRAME_ID), h))


def _make(context: Context, **params: Any) -> Any:
    params = {'voxel_size': VOXEL, 'esdf_slice_axis': 'y', **params}
    return capture(TsdfFusionNode(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()]), history=True)


def _feed(node: Any, frames: list[Any], noise: Any = None) -> None:
    for f in frames:
        node.poses.on_odometry(odometry_message(f.pose, f.stamp_ns, FRAME_ID))
        node.on_frame(*_inputs(f), *(() if noise is None else (noise(f),)))


def _published(node: Any, topic: str) -> list[Any]:
    return [msg for t, msg in node.outbox if t.endswith(topic)]


def _drawn(node: Any) -> dict[int, np.ndarray]:
    """The mesh a viewer shows after every MarkerArray the node sent."""
    drawn: dict[int, np.ndarray] = {}
    for message in _published(node, '/mesh'):
        assert isinstance(message, Serialized)
        for marker in read_marker_array(message.data):
            if marker.action == DELETEALL:
                drawn.clear()
            elif marker.action == 2:
                drawn.pop(marker.id, None)
            else:
                drawn[marker.id] = marker.points
    return drawn


def test_the_mesh_drawn_is_the_core_s_mesh_of_the_same_frames(context: Context) -> None:
    node = _make(context, mesh_rate_hz=10.0)
    _feed(node, SEQ.frames)
    node.finish_stream()
    assert node.drops == {}
    volume, layer = TsdfVolume(TsdfParams(voxel_size=VOXEL)), MeshLayer()
    for f in SEQ.frames:
        volume.integrate(f.depth, f.camera, f.pose)
    layer.update(volume)
    drawn = _drawn(node)
    assert len(drawn) == len(layer.blocks) > 10
    got = np.sort(np.concatenate(list(drawn.values())).astype(np.float32), axis=0)
    np.testing.assert_array_equal(got, np.sort(layer.soup(), axis=0))
    first = read_marker_array(_published(node, '/mesh')[0].data)
    assert first[0].action == DELETEALL  # a viewer forgets an earlier run's mesh
    # 6 frames over 0.17 s at 10 Hz: the first frame, one 0.1 s later, and the end
    assert len(_published(node, '/mesh')) == 3
    message = _published(node, '/mesh')[-1].message()  # rclpy reads the bytes
    assert message.markers[0].header.frame_id == 'world'  # the odometry's frame
    points = read_pointcloud(_published(node, '/surface_points')[-1])
    assert len(points['x'].ravel()) > 100
    cut = read_pointcloud(_published(node, '/esdf_slice')[-1])
    assert np.isfinite(cut['distance']).all()
    assert np.abs(cut['y']).max() < VOXEL / 2  # the plane y = 0
    node.destroy_node()


def test_sigma_weighting_reads_the_sigma_input_and_checks_its_size(context: Context) -> None:
    node = _make(context, weighting_mode='sigma')
    assert any(spec.topic.endswith('/sigma') for spec in node.inputs)
    h = header(SEQ.frames[0].stamp_ns, FRAME_ID)
    small = array_to_image(np.full((10, 10), 0.01, np.float32), '32FC1', h)
    _feed(node, SEQ.frames[:1], noise=lambda f: small)
    assert node.drops == {'size_mismatch': 1}
    _feed(node, SEQ.frames[1:2], noise=lambda f: array_to_image(
        np.full(f.depth.shape, 0.01, np.float32), '32FC1', header(f.stamp_ns, FRAME_ID)))
    assert node.volume.block_count > 0
    # weighted by (voxel / sigma)^2 = 25 per observation
    assert node.volume.weight.max() == pytest.approx(25.0)
    node.destroy_node()


def test_frames_that_cannot_be_fused_are_counted_with_their_reason(context: Context) -> None:
    node = _make(context, pose_wait=0.05)
    f = SEQ.frames[0]
    depth, info = _inputs(f)
    nothing = array_to_image(np.full(f.depth.shape, np.nan, np.float32), '32FC1', depth.header)
    node.on_frame(nothing, info)
    negative = array_to_image(np.full(f.depth.shape, -1.0, np.float32), '32FC1', depth.header)
    node.on_frame(negative, info)
    assert node.drops == {'no_depth': 2}
    mono = array_to_image(np.zeros(f.depth.shape, np.uint8), 'mono8', depth.header)
    node.on_frame(mono, info)
    assert node.drops['unsupported_encoding'] == 1
    uncalibrated = _inputs(f)[1]
    uncalibrated.k = [0.0] * 9
    uncalibrated.p = [0.0] * 12
    node.on_frame(depth, uncalibrated)
    assert node.drops['uncalibrated'] == 1
    # a frame whose pose never comes
    node.on_frame(*_inputs(SEQ.frames[1]))
    node.on_frame(*_inputs(SEQ.frames[5]))
    assert node.drops['pose_timeout'] == 1
    # a wild pose: held, then dropped when the next pose shows it was wrong; its frame
    # is not fused at it
    node2 = _make(context)
    _feed(node2, SEQ.frames[:2])
    wild = SEQ.frames[2]
    far = Pose(wild.pose.rotation, wild.pose.position + 100.0)
    node2.poses.on_odometry(odometry_message(far, wild.stamp_ns, FRAME_ID))
    node2.on_frame(*_inputs(wild))
    _feed(node2, SEQ.frames[3:4])
    assert node2.drops.get('bad_pose') == 1
    centres = node2.volume.block_centres(node2.volume.slots())
    assert np.abs(centres).max() < 20  # nothing 100 m away
    node.destroy_node()
    node2.destroy_node()


def test_stamps_that_jump_back_start_the_map_over(context: Context) -> None:
    node = _make(context)
    _feed(node, SEQ.frames[:3])
    assert node.volume.block_count > 0
    node.on_time_jump()
    assert node.volume.block_count == 0
    assert node.resets == 1
    _feed(node, SEQ.frames[:2])
    assert node.volume.block_count > 0
    node.destroy_node()


def test_runtime_parameters_follow_the_core_s_rules(context: Context) -> None:
    node = _make(context)
    _feed(node, SEQ.frames[:2])
    with tuner(node, context) as tune:
        refused = tune(truncation_distance=0.2)[0]
        assert not refused.successful
        assert 'truncation_distance' in refused.reason
        refused = tune(weighting_mode='sigma')[0]
        assert not refused.successful
        assert 'needs the sigma input' in refused.reason
        assert tune(weighting_mode='inverse_square')[0].successful
        assert tune(voxel_size=0.08)[0].successful
    _feed(node, SEQ.frames[2:3])
    assert node.resets == 1  # a new voxel size starts the map over
    assert node.volume.params.voxel_size == 0.08
    assert node.volume.params.weighting_mode == 'inverse_square'
    with pytest.raises(Exception, match='weighting_mode'):
        _make(context, weighting_mode='loud')
    node.destroy_node()


def test_the_services_save_the_mesh_and_clear_the_map(context: Context, tmp_path: Path) -> None:
    path = tmp_path / 'mesh.ply'
    node = _make(context, mesh_path=str(path))
    _feed(node, SEQ.frames)
    peer = rclpy.create_node('caller', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(peer)

    def call(name: str) -> Any:
        client = peer.create_client(Trigger, f'/tsdf_fusion/{name}')
        assert client.wait_for_service(timeout_sec=30)
        future = client.call_async(Trigger.Request())
        executor.spin_until_future_complete(future, timeout_sec=30)
        return future.result()

    try:
        saved = call('save_mesh')
        assert saved.success, saved.message
        _, faces, _ = read_ply(path)
        assert len(faces) > 100
        assert f'{len(faces)} triangles' in saved.message
        cleared = call('clear')
        assert cleared.success
        assert node.volume.block_count == 0
        _feed(node, SEQ.frames[:1])
        node.finish_stream()
        last = read_marker_array(_published(node, '/mesh')[-1].data)
        assert last[0].action == DELETEALL  # after a clear, a viewer starts over
        node.set_parameters([Parameter('mesh_path', value=str(tmp_path / 'no' / 'x.ply'))])
        failed = call('save_mesh')
        assert not failed.success
        assert 'cannot write' in failed.message
    finally:
        executor.shutdown()
        peer.destroy_node()
        node.destroy_node()
