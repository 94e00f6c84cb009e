"""image_pipeline's executable names: a launch file written for image_proc,
stereo_image_proc or depth_image_proc runs these nodes when only its ``package`` is
changed. Each executable starts its node under upstream's default node name, with at least
upstream's topics (ros-perception/image_pipeline, the packages' doc/components.rst) and
parameters."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest
from launch_checks import check_launch_file, source_prefix
from rclpy.context import Context
from rclpy.parameter import Parameter

from depth_nodes.nodes import NODE_PLUGINS, UPSTREAM_EXECUTABLES, scripts

pytestmark = pytest.mark.ros

#: executable -> (subscribed topics, published topics, parameters), as upstream documents
#: them (relative names, resolved in the root namespace here).
UPSTREAM = {
    'rectify_node': ({'image', 'camera_info'}, {'image_rect'}, {'queue_size', 'interpolation'}),
    'disparity_node': ({'left/image_rect', 'left/camera_info', 'right/image_rect',
                        'right/camera_info'}, {'disparity'},
                       {'queue_size', 'approximate_sync', 'stereo_algorithm',
                        'prefilter_size', 'correlation_window_size', 'min_disparity',
                        'disparity_range', 'uniqueness_ratio', 'speckle_size',
                        'speckle_range', 'P1', 'P2', 'disp12_max_diff'}),
    'point_cloud_node': ({'left/camera_info', 'right/camera_info', 'left/image_rect_color',
                          'disparity'}, {'points2'},
                         {'queue_size', 'approximate_sync', 'use_color',
                          'avoid_point_cloud_padding'}),
    'convert_metric_node': ({'image_raw'}, {'image'}, {'image_transport'}),
    'point_cloud_xyz_node': ({'image_rect', 'camera_info'}, {'points'}, {'queue_size'}),
    'point_cloud_xyzrgb_node': ({'depth_registered/image_rect', 'rgb/image_rect_color',
                                 'rgb/camera_info'}, {'points'},
                                {'queue_size', 'exact_sync', 'image_transport',
                                 'depth_image_transport', 'invalid_depth'}),
    'register_node': ({'depth/image_rect', 'depth/camera_info', 'rgb/camera_info'},
                      {'depth_registered/image_rect', 'depth_registered/camera_info'},
                      {'queue_size', 'depth_image_transport'}),
    # not upstream's name, which stereo_image_proc's matcher has here: same topics
    'depth_disparity_node': ({'left/image_rect', 'right/camera_info'}, {'left/disparity'},
                             {'queue_size', 'delta_d', 'min_range', 'max_range',
                              'image_transport'}),
}


def test_every_upstream_executable_is_described() -> None:
    assert set(UPSTREAM) == set(UPSTREAM_EXECUTABLES)
    for name in UPSTREAM_EXECUTABLES:
        assert callable(getattr(scripts, name)), name


@pytest.mark.parametrize('executable', sorted(UPSTREAM))
def test_upstream_executable_has_upstream_name_topics_and_parameters(
        context: Context, executable: str) -> None:
    _, plugin, node_name = UPSTREAM_EXECUTABLES[executable]
    module, _, cls = NODE_PLUGINS[plugin].partition(':')
    node_class = getattr(importlib.import_module(module), cls)
    overrides = [Parameter('depth_in_rgb', value=[0.0] * 6 + [1.0])] \
        if plugin == 'register_depth' else []
    node = node_class(node_name, context=context, parameter_overrides=overrides)
    try:
        assert node.get_name() == node_name
        inputs, outputs, params = UPSTREAM[executable]
        assert {f'/{t}' for t in inputs} <= {s.topic for s in node.inputs}
        assert {f'/{t}' for t in outputs} <= set(node.outputs)
        missing = {p for p in params if not node.has_parameter(p)}
        assert not missing, f'{executable} lacks {sorted(missing)}'
    finally:
        node.destroy_node()


def test_a_users_depth_image_proc_launch_file_runs_with_the_package_changed(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A launch file as a user writes it for a depth camera, with ``package`` changed from
    depth_image_proc / stereo_image_proc / image_proc to depth_nodes: every executable it
    names is a console script here."""
    launch = tmp_path / 'rgbd.launch.py'
    launch.write_text('''
from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description():
    remap = [('rgb/camera_info', '/camera/color/camera_info'),
             ('rgb/image_rect_color', '/camera/color/image_raw'),
             ('depth_registered/image_rect', '/camera/aligned_depth/image_raw'),
             ('points', '/camera/points')]
    return LaunchDescription([
        Node(package='depth_nodes', executable='point_cloud_xyzrgb_node',
             name='depth_to_cloud', remappings=remap, parameters=[{'exact_sync': True}]),
        Node(package='depth_nodes', executable='register_node',
             parameters=[{'depth_in_rgb': [0.015, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]}]),
        Node(package='depth_nodes', executable='convert_metric_node'),
        Node(package='depth_nodes', executable='point_cloud_xyz_node'),
        Node(package='depth_nodes', executable='depth_disparity_node'),
        Node(package='depth_nodes', executable='disparity_node'),
        Node(package='depth_nodes', executable='point_cloud_node'),
        Node(package='depth_nodes', executable='rectify_node', namespace='left'),
    ])
''')
    check_launch_file(launch, source_prefix(tmp_path), monkeypatch)

