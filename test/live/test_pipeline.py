"""`depth-nodes pipeline`'s composition: every shipped graph builds in one process."""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers import REPO
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor

from depth_nodes.errors import ConfigError
from depth_nodes.graph.description import create_nodes, load_graph_config, load_params_file

pytestmark = [pytest.mark.ros, pytest.mark.slow]


@pytest.mark.parametrize('name', ['stereo_pipeline', 'structured_light_pipeline'])
def test_shipped_graphs_compose_into_one_executor(name: str, context: Context,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(REPO)  # the speckle reference is named relative to the repository
    config = load_graph_config(REPO / 'config' / f'{name}.yaml')
    nodes = create_nodes(config, context=context)
    executor = MultiThreadedExecutor(num_threads=2, context=context)
    try:
        for node in nodes:
            executor.add_node(node)
        assert [n.get_fully_qualified_name() for n in nodes] == [
            s.fully_qualified_name for s in config.nodes]
        for node, spec in zip(nodes, config.nodes, strict=True):
            for param, value in spec.parameters.items():
                assert node.get_parameter(param).value == value, (spec.name, param)
        executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown()
        for node in nodes:
            node.destroy_node()


def test_a_params_file_overrides_the_config_and_a_typo_is_an_error(
        tmp_path: Path, context: Context) -> None:
    config = load_graph_config(REPO / 'config' / 'stereo_pipeline.yaml')
    params = tmp_path / 'params.yaml'
    params.write_text('/stereo/sgm_stereo:\n  ros__parameters: {P2: 300.0}\n'
                      '/**:\n  ros__parameters: {diagnostics_period: 2.0}\n')
    nodes = create_nodes(config, load_params_file(params), context=context)
    try:
        by_name = {n.get_fully_qualified_name(): n for n in nodes}
        assert by_name['/stereo/sgm_stereo'].get_parameter('P2').value == 300.0
        assert {n.get_parameter('diagnostics_period').value for n in nodes} == {2.0}
    finally:
        for node in nodes:
            node.destroy_node()
    params.write_text('point_cloud:\n  ros__parameters: {max_rang: 3.0}\n')
    with pytest.raises(ConfigError, match='has no parameter max_rang'):
        create_nodes(config, load_params_file(params), context=context)
