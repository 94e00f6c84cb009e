"""Launch files run without `launch` (it is not on PyPI): `generate_launch_description()`
runs against stand-ins for `launch` and `launch_ros.actions` that record each Node(...)
call, with the real ament_index_python looking the package up under AMENT_PREFIX_PATH (a
prefix that mirrors the source tree, or a colcon install space). Used by
graph/test_launch_files.py and packaging/test_colcon_workspace.py.
"""

from __future__ import annotations

import importlib.util
import os
import runpy
import sys
import types
from pathlib import Path
from typing import Any
from unittest import mock

import pytest
from helpers import REPO
from rclpy.parameter import Parameter

from depth_nodes.graph.description import load_graph_config

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


def setup_arguments() -> dict[str, Any]:
    """The keyword arguments setup.py gives ``setuptools.setup`` (run against a stand-in
    for setuptools that records them)."""
    given: dict[str, Any] = {}
    setuptools = types.ModuleType('setuptools')
    setuptools.setup = lambda **kwargs: given.update(kwargs)  # type: ignore[attr-defined]
    setuptools.find_packages = lambda **kwargs: []  # type: ignore[attr-defined]
    with mock.patch.dict(sys.modules, {'setuptools': setuptools}):
        runpy.run_path(str(REPO / 'setup.py'), run_name='__main__')
    assert given, 'setup.py did not call setuptools.setup'
    return given


def node_scripts() -> dict[str, str]:
    """setup.py's console scripts but ``depth-nodes``, as ``{executable: 'module:function'}``."""
    entries = setup_arguments()['entry_points']['console_scripts']
    scripts = {name.strip(): target.strip()
               for name, _, target in (entry.partition('=') for entry in entries)}
    assert scripts.pop('depth-nodes') == 'depth_nodes.tools.cli:main'
    return scripts


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
    # imported afresh against these stand-ins (it imports `launch` at the top)
    monkeypatch.delitem(sys.modules, 'depth_nodes.graph.launch_file', raising=False)

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
    assert [c.get('name') for c in calls] == [n.name for n in graph.nodes], (
        f'{path.name} vs {config.name}: other nodes')
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


