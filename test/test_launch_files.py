"""Launch files, checked without `launch` (it is not on PyPI): they compile, start only the
package's console scripts, and describe the same nodes as the pipeline config they mirror.

`generate_launch_description()` runs against stand-ins for `launch` and `launch_ros.actions`
that record each Node(...) call, with the real ament_index_python looking the package up
under AMENT_PREFIX_PATH: a prefix that mirrors the source tree here, the colcon install
space in test_colcon_workspace.py.
"""

from __future__ import annotations

import ast
import importlib.util
import os
import sys
import types
from pathlib import Path
from typing import Any

import pytest
from rclpy.parameter import Parameter

from conftest import REPO
from depth_nodes.graph.description import load_graph_config
from depth_nodes.nodes import NODE_PLUGINS

PACKAGE = 'depth_nodes'
LAUNCH_FILES = sorted((REPO / 'launch').glob('*.launch.py'))

#: Keyword arguments of launch_ros.actions.Node (Jazzy) and of the ExecuteProcess action it
#: extends; anything else is a typo that `ros2 launch` would reject.
NODE_KWARGS = frozenset({
    'executable', 'package', 'name', 'namespace', 'exec_name', 'parameters', 'remappings',
    'ros_arguments', 'arguments', 'output', 'emulate_tty', 'respawn', 'respawn_delay',
    'additional_env', 'env', 'cwd', 'prefix', 'sigterm_timeout', 'sigkill_timeout',
    'log_cmd', 'on_exit', 'condition',
})


def node_scripts() -> dict[str, str]:
    """``NODE_SCRIPTS`` of setup.py as ``{executable: 'module:function'}``."""
    tree = ast.parse((REPO / 'setup.py').read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == 'NODE_SCRIPTS' for t in node.targets):
            entries = ast.literal_eval(node.value)
            return {name.strip(): target.strip()
                    for name, _, target in (entry.partition('=') for entry in entries)}
    raise AssertionError('setup.py defines no NODE_SCRIPTS list')


def mirrored_config(launch_file: Path, share: Path) -> Path | None:
    """``config/X.yaml`` under ``share`` for ``launch/X.launch.py``, when it exists."""
    config = share / 'config' / (launch_file.name.removesuffix('.launch.py') + '.yaml')
    return config if config.is_file() else None


def source_prefix(tmp_path: Path) -> Path:
    """A prefix laid out like an install space whose share folder is the source tree's."""
    prefix = tmp_path / 'prefix'
    index = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages'
    index.mkdir(parents=True)
    (index / PACKAGE).touch()
    share = prefix / 'share' / PACKAGE
    share.mkdir()
    for name in ('config', 'launch', 'package.xml'):
        (share / name).symlink_to(REPO / name)
    return prefix


def run_launch_file(path: Path, prefix: Path, monkeypatch: pytest.MonkeyPatch,
                    arguments: dict[str, str] | None = None) -> list[dict[str, Any]]:
    """Call ``generate_launch_description()`` of ``path`` with ``prefix`` as the only
    AMENT_PREFIX_PATH entry, then its OpaqueFunctions with the launch ``arguments`` (the
    declared defaults otherwise); returns the keyword arguments of every Node created."""
    calls: list[dict[str, Any]] = []

    class LaunchDescription:
        def __init__(self, initial_entities: Any = None) -> None:
            self.entities = list(initial_entities or [])

    class Node:
        def __init__(self, **kwargs: Any) -> None:
            unknown = set(kwargs) - NODE_KWARGS
            assert not unknown, f'{path.name}: Node() has no arguments {sorted(unknown)}'
            assert 'executable' in kwargs, f'{path.name}: Node() needs executable='
            self.kwargs = kwargs
            calls.append(kwargs)

    class DeclareLaunchArgument:
        def __init__(self, name: str, *, default_value: str = '', description: str = '',
                     **kwargs: Any) -> None:
            assert not kwargs, f'{path.name}: DeclareLaunchArgument() got {sorted(kwargs)}'
            self.name, self.default_value, self.description = name, default_value, description

    class OpaqueFunction:
        def __init__(self, *, function: Any, **kwargs: Any) -> None:
            self.function = function

    class LaunchConfiguration:
        def __init__(self, name: str) -> None:
            self.name = name

        def perform(self, context: Any) -> str:
            return str(context.launch_configurations[self.name])

    launch = types.ModuleType('launch')
    launch.LaunchDescription = LaunchDescription  # type: ignore[attr-defined]
    launch_actions = types.ModuleType('launch.actions')
    launch_actions.DeclareLaunchArgument = DeclareLaunchArgument  # type: ignore[attr-defined]
    launch_actions.OpaqueFunction = OpaqueFunction  # type: ignore[attr-defined]
    substitutions = types.ModuleType('launch.substitutions')
    substitutions.LaunchConfiguration = LaunchConfiguration  # type: ignore[attr-defined]
    launch_ros = types.ModuleType('launch_ros')
    actions = types.ModuleType('launch_ros.actions')
    actions.Node = Node  # type: ignore[attr-defined]
    launch_ros.actions = actions  # type: ignore[attr-defined]
    for name, module in (('launch', launch), ('launch.actions', launch_actions),
                         ('launch.substitutions', substitutions), ('launch_ros', launch_ros),
                         ('launch_ros.actions', actions)):
        monkeypatch.setitem(sys.modules, name, module)
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(prefix))
    monkeypatch.setattr(sys, 'dont_write_bytecode', True)  # no __pycache__ in launch/

    spec = importlib.util.spec_from_file_location(f'_launch_{path.stem.replace(".", "_")}',
                                                  path)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    assert isinstance(description, LaunchDescription)
    declared = {e.name: e.default_value for e in description.entities
                if isinstance(e, DeclareLaunchArgument)}
    unknown = set(arguments or {}) - set(declared)
    assert not unknown, f'{path.name} declares no launch arguments {sorted(unknown)}'
    context = types.SimpleNamespace(launch_configurations={**declared, **(arguments or {})})
    nodes = [e for e in description.entities if isinstance(e, Node)]
    for entity in description.entities:
        if isinstance(entity, OpaqueFunction):
            nodes += entity.function(context)
    assert [n.kwargs for n in nodes] == calls
    return calls


def check_launch_file(path: Path, prefix: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every Node runs an installed console script of this package with parameter files
    that exist; a launch file with a pipeline config describes exactly its nodes."""
    share = prefix / 'share' / PACKAGE
    calls = run_launch_file(path, prefix, monkeypatch)
    assert calls, f'{path.name} starts no node'
    scripts = node_scripts()
    for call in calls:
        assert call.get('package') == PACKAGE, call
        assert call['executable'] in scripts, (
            f'{path.name}: executable {call["executable"]!r} is not a console script of '
            f'setup.py (NODE_SCRIPTS: {sorted(scripts)})')
        for entry in call.get('parameters') or []:
            if isinstance(entry, dict):
                for name, value in entry.items():
                    Parameter(name, value=value)  # raises for a value with no ROS type
            else:
                assert Path(os.fspath(entry)).is_file(), f'{path.name}: no file {entry}'
    config = mirrored_config(path, share)
    if config is None:
        return
    graph = load_graph_config(config)
    assert [c.get('name') for c in calls] == [n.name for n in graph.nodes]
    for call, spec in zip(calls, graph.nodes, strict=True):
        where = f'{path.name} vs {config.name}, node {spec.name}'
        assert call['executable'] == spec.plugin, where
        assert call.get('namespace', '/') == spec.namespace, where
        merged: dict[str, Any] = {}
        for entry in call.get('parameters') or []:
            assert isinstance(entry, dict), f'{where}: parameters must be inline'
            merged.update(entry)
        assert merged == spec.parameters, where
        assert dict(call.get('remappings') or []) == spec.remappings, where


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
    """`ros2 run depth_nodes <plugin>` and the launch files rely on it."""
    scripts = node_scripts()
    assert set(scripts) == set(NODE_PLUGINS)
    for name, target in scripts.items():
        assert target.partition(':')[0] == NODE_PLUGINS[name].partition(':')[0], name


def test_a_mismatch_with_the_config_is_caught(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """The check is not vacuous: a launch file that drifts from its config fails it."""
    prefix = source_prefix(tmp_path)
    launch_dir = tmp_path / 'drift'
    launch_dir.mkdir()
    drifted = launch_dir / 'stereo_pipeline.launch.py'
    source = (REPO / 'launch' / 'stereo_pipeline.launch.py').read_text()
    text = source.replace("output='screen', **node)",
                          "output='screen', **{**node, 'namespace': '/elsewhere'})")
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
