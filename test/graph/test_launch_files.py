"""Launch files, checked without `launch` (it is not on PyPI): they compile, start only the
package's console scripts, and describe the same nodes as the pipeline config they mirror
(the machinery is launch_checks.py; the colcon install space is checked in
packaging/test_colcon_workspace.py).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from helpers import REPO
from launch_checks import (
    LAUNCH_FILES,
    check_launch_file,
    mirrored_config,
    node_scripts,
    run_launch_file,
    source_prefix,
)

from depth_nodes.nodes import NODE_PLUGINS, UPSTREAM_EXECUTABLES


@pytest.mark.parametrize('path', LAUNCH_FILES, ids=lambda p: p.name)
def test_launch_file_compiles_and_defines_generate_launch_description(path: Path) -> None:
    tree = ast.parse(path.read_text(), str(path))
    compile(tree, str(path), 'exec')
    functions = {node.name for node in tree.body if isinstance(node, ast.FunctionDef)}
    assert 'generate_launch_description' in functions


@pytest.mark.parametrize('path', LAUNCH_FILES, ids=lambda p: p.name)
def test_launch_file_from_source_tree(path: Path, tmp_path: Path,
                                      monkeypatch: pytest.MonkeyPatch) -> None:
    check_launch_file(path, source_prefix(tmp_path), monkeypatch)


def test_stereo_pipeline_launch_mirrors_its_config() -> None:
    launch = REPO / 'launch' / 'stereo_pipeline.launch.py'
    assert launch in LAUNCH_FILES
    assert mirrored_config(launch, REPO) == REPO / 'config' / 'stereo_pipeline.yaml'


def test_every_node_plugin_has_a_console_script_of_the_same_name() -> None:
    """`ros2 run depth_nodes <plugin>` and the launch files rely on it: setup.py's scripts
    are the registry's names and image_pipeline's executable names, all made by
    depth_nodes.nodes.scripts."""
    scripts = node_scripts()
    assert set(scripts) == set(NODE_PLUGINS) | set(UPSTREAM_EXECUTABLES)
    assert len(scripts) == len(NODE_PLUGINS) + len(UPSTREAM_EXECUTABLES)
    for name, target in scripts.items():
        assert target == f'depth_nodes.nodes.scripts:{name}', name


def test_a_mismatch_with_the_config_is_caught(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """The check is not vacuous: a launch file that drifts from its config fails it."""
    prefix = source_prefix(tmp_path)
    launch_dir = tmp_path / 'drift'
    launch_dir.mkdir()
    drifted = launch_dir / 'stereo_pipeline.launch.py'
    source = (REPO / 'launch' / 'stereo_pipeline.launch.py').read_text()
    text = source.replace("launch_description('stereo_pipeline.yaml')",
                          "launch_description('structured_light_pipeline.yaml')")
    assert text != source, 'update this test to the launch file'
    drifted.write_text(text)
    with pytest.raises(AssertionError, match=r'vs stereo_pipeline\.yaml'):
        check_launch_file(drifted, prefix, monkeypatch)


def test_structured_light_pipeline_launch_mirrors_its_config() -> None:
    launch = REPO / 'launch' / 'structured_light_pipeline.launch.py'
    assert launch in LAUNCH_FILES
    assert mirrored_config(launch, REPO) == REPO / 'config' / 'structured_light_pipeline.yaml'


def test_launch_arguments_take_a_driver_and_a_stereo_image_proc_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`ros2 launch depth_nodes stereo_pipeline.launch.py namespace:=/camera
    image_transport:=compressed params_file:=sip.yaml`: the nodes move to the driver's
    names, the rectifiers read compressed images, and the file's `disparity_node` entry
    reaches the matcher (launch_ros alone would match it by node name only)."""
    params = tmp_path / 'sip.yaml'
    params.write_text('disparity_node:\n  ros__parameters: {stereo_algorithm: 1, '
                      'correlation_window_size: 7, disparity_range: 64}\n'
                      '/**:\n  ros__parameters: {disp12_max_diff: 0}\n')
    calls = run_launch_file(REPO / 'launch' / 'stereo_pipeline.launch.py',
                            source_prefix(tmp_path), monkeypatch,
                            {'namespace': '/camera', 'image_transport': 'compressed',
                             'params_file': str(params)})
    by_name = {c['name']: c for c in calls}
    assert by_name['rectify_left']['namespace'] == '/camera/left'
    assert by_name['rectify_left']['parameters'][0]['image_transport'] == 'compressed'
    assert 'image_transport' not in by_name['sgm_stereo']['parameters'][0]
    sgm = by_name['sgm_stereo']['parameters'][0]
    assert (sgm['stereo_algorithm'], sgm['correlation_window_size'], sgm['disp12_max_diff'],
            sgm['disparity_range']) == (1, 7, 0, 64)
    assert by_name['cross_check']['parameters'][0]['disp12_max_diff'] == 0
    assert by_name['sgm_stereo']['namespace'] == '/camera'


def test_a_parameter_file_entry_for_no_node_stops_the_launch(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from depth_nodes.errors import ConfigError

    params = tmp_path / 'typo.yaml'
    params.write_text('sgm_stero:\n  ros__parameters: {P2: 300.0}\n')
    with pytest.raises(ConfigError, match="entry 'sgm_stero' matches no node of the graph "
                                          r"\(did you mean sgm_stereo\?\)"):
        run_launch_file(REPO / 'launch' / 'stereo_pipeline.launch.py',
                        source_prefix(tmp_path), monkeypatch, {'params_file': str(params)})
