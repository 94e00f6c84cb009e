"""Graph descriptions and ROS 2 parameter files: parsing, precedence and every error."""

from __future__ import annotations

from pathlib import Path

import pytest

from depth_nodes.errors import ConfigError
from depth_nodes.graph.description import (
    GraphConfig,
    NodeSpec,
    addressed_parameters,
    camera_readers,
    load_graph_config,
    load_params_file,
    parameters_for,
    resolve_plugin,
)
from depth_nodes.tools.bags.process import default_config_path, select_nodes

GOOD = """
graph:
  name: demo
  nodes:
    - name: invert
      plugin: harness_nodes:InvertNode
      namespace: /stereo/left
      parameters: {offset: 3}
      remappings: {image: image_raw}
    - name: restore
      plugin: harness_nodes:RestoreNode
      namespace: /stereo/left
"""


def _write(tmp_path: Path, text: str, name: str = 'g.yaml') -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_load_good_config(tmp_path: Path) -> None:
    config = load_graph_config(_write(tmp_path, GOOD))
    assert config.name == 'demo'
    assert [n.fully_qualified_name for n in config.nodes] == [
        '/stereo/left/invert', '/stereo/left/restore']
    assert config.nodes[0].parameters == {'offset': 3}
    assert config.nodes[0].remappings == {'image': 'image_raw'}
    assert [n.name for n in select_nodes(config, ['restore']).nodes] == ['restore']
    with pytest.raises(ConfigError, match=r'--nodes: not in demo graph: nope \(nodes: invert'):
        select_nodes(config, ['nope'])


def test_default_config_is_valid() -> None:
    config = load_graph_config(default_config_path())
    assert config.name == 'stereo'
    for spec in config.nodes:
        assert resolve_plugin(spec.plugin)


def test_camera_readers_are_the_registrys(tmp_path: Path) -> None:
    """The nodes an image_transport choice applies to: registry nodes marked camera_reader,
    named by plugin name or by their module:Class; no other class."""
    config = load_graph_config(default_config_path())
    assert camera_readers(config) == ['/stereo/left/rectify_left', '/stereo/right/rectify_right']
    graph = GraphConfig('g', [
        NodeSpec('tof', 'tof', '/cam'),
        NodeSpec('sl', 'depth_nodes.nodes.structured_light:StructuredLightNode', '/cam'),
        NodeSpec('cloud', 'point_cloud_xyz', '/cam'),
        NodeSpec('invert', 'harness_nodes:InvertNode', '/cam')])
    assert camera_readers(graph) == ['/cam/tof', '/cam/sl']


@pytest.mark.parametrize(('text', 'message'), [
    ('just a string', 'needs a top-level "graph:" mapping'),
    ('graph: {nodes: 3}', '"nodes" must be a list'),
    ('graph: {nodes: [3]}', 'node #1: expected a mapping'),
    ('graph: {nodes: [{name: a}]}', 'node #1: "plugin" must be a non-empty string'),
    ('graph: {nodes: [{name: a, plugin: p, colour: red}]}', r"unknown keys \['colour'\]"),
    ('graph: {nodes: [{name: a, plugin: p, namespace: rel}]}', 'must be absolute'),
    ('graph: {nodes: [{name: a, plugin: p, parameters: [1]}]}', 'must be mappings'),
    ('graph: {nodes: [{name: a, plugin: p}, {name: a, plugin: q}]}', 'used twice: /a'),
    ('graph: [unclosed', 'is not valid YAML'),
])
def test_bad_configs(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_graph_config(_write(tmp_path, text))


def test_missing_config(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match='graph config not found'):
        load_graph_config(tmp_path / 'missing.yaml')


def test_params_file_precedence(tmp_path: Path) -> None:
    params = load_params_file(_write(tmp_path, """
/**:
  ros__parameters: {queue_size: 5, offset: 1}
invert:
  ros__parameters: {offset: 2}
stereo:
  left:
    invert:
      ros__parameters: {offset: 7}
""", 'p.yaml'))
    assert params['/**'] == {'queue_size': 5, 'offset': 1}
    assert params['stereo/left/invert'] == {'offset': 7}
    spec = NodeSpec('invert', 'x:Y', '/stereo/left', {'offset': 0, 'own': True})
    assert parameters_for(spec, params) == {'offset': 7, 'queue_size': 5, 'own': True}
    other = NodeSpec('restore', 'x:Y', '/stereo/left')
    assert parameters_for(other, params) == {'queue_size': 5, 'offset': 1}
    # only names addressed to a node in particular must exist on it; /** ones may not
    assert addressed_parameters(spec, params) == {'offset', 'own'}
    assert addressed_parameters(other, params) == set()


@pytest.mark.parametrize(('text', 'message'), [
    ('[1, 2]', 'must be a mapping of node names'),
    ('node: {ros__parameters: 3}', 'ros__parameters of node must be a mapping'),
    ('node: {offset: 3}', 'missing ros__parameters'),
    ('{}', 'sets no ros__parameters'),
])
def test_bad_params_files(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_params_file(_write(tmp_path, text, 'p.yaml'))


def test_resolve_plugin_errors() -> None:
    with pytest.raises(ConfigError, match="unknown node plugin 'nonsense'"):
        resolve_plugin('nonsense')
    with pytest.raises(ConfigError, match='cannot import node plugin'):
        resolve_plugin('no_such_module_xyz:Node')
    with pytest.raises(ConfigError, match='has no class Missing'):
        resolve_plugin('harness_nodes:Missing')
    assert resolve_plugin('harness_nodes:InvertNode').__name__ == 'InvertNode'


def test_unknown_parameter_is_an_error(tmp_path: Path, ros_env: dict[str, str]) -> None:
    import rclpy
    from rclpy.context import Context

    from depth_nodes.graph.description import instantiate

    ctx = Context()
    rclpy.init(args=[], context=ctx)
    try:
        spec = NodeSpec('invert', 'harness_nodes:InvertNode', '/cam', {'ofset': 3})
        with pytest.raises(ConfigError, match=r"/cam/invert .* has no parameter ofset "
                                              r"\(parameters: diagnostics_period, frame_id, "
                                              r"offset"):
            instantiate(spec, spec.parameters, context=ctx)
        node = instantiate(NodeSpec('invert', 'harness_nodes:InvertNode', '/cam'),
                           {'offset': 3}, context=ctx)
        assert node.get_parameter('offset').value == 3
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


def test_nested_parameter_names_are_flattened(tmp_path: Path) -> None:
    """What a parameter dump writes: qos_overrides as nested maps, read as ROS reads them."""
    params = load_params_file(_write(tmp_path, """
/stereo/sgm_stereo:
  ros__parameters:
    P2: 300.0
    qos_overrides:
      /stereo/disparity:
        publisher: {depth: 5, reliability: reliable}
""", 'dump.yaml'))
    assert params == {'/stereo/sgm_stereo': {
        'P2': 300.0, 'qos_overrides./stereo/disparity.publisher.depth': 5,
        'qos_overrides./stereo/disparity.publisher.reliability': 'reliable'}}
