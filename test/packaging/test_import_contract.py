"""The import contract of the layers, read from the source (no import runs, so it is fast):
dependencies go one way, nodes -> ros -> core, tools above all; core and sim know no ROS;
the one geometry is everyone's.

* ``core`` imports no ``rclpy`` or message package and nothing of ``ros``, ``nodes``,
  ``graph``, ``sim`` or ``tools``;
* ``sim`` imports only ``core`` of the package, and no ROS;
* ``ros`` imports only ``core`` of the package;
* ``nodes`` imports ``ros`` and ``core``, never ``tools`` or ``graph``;
* ``graph`` imports no ``tools``;
* poses, transforms and splats come from ``core.geometry``: outside ``core/mvs`` nothing
  imports ``core.mvs`` but the multi-view node and the tools that run or score it, and no
  node subscribes to poses itself (``Odometry``, ``PoseStamped``, ``TFMessage``) but
  through ``ros/poses.py``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from helpers import REPO

PACKAGE = REPO / 'depth_nodes'
ROS_PACKAGES = ('rclpy', 'sensor_msgs', 'stereo_msgs', 'std_msgs', 'geometry_msgs',
                'nav_msgs', 'tf2_msgs', 'diagnostic_msgs', 'rcl_interfaces', 'visualization_msgs',
                'std_srvs', 'builtin_interfaces')
LAYERS = ('core', 'sim', 'ros', 'nodes', 'graph', 'tools')
#: what each layer may import of the package (besides itself, errors and the top level)
ALLOWED = {
    'core': set(),
    'sim': {'core'},
    'ros': {'core'},
    'nodes': {'core', 'ros'},
    'graph': {'core', 'ros', 'nodes'},
    'tools': {'core', 'ros', 'nodes', 'graph', 'sim'},
}


def _imports(path: Path) -> list[str]:
    """Every module ``path`` imports, absolute, at any depth (also inside functions)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append(node.module)
    return found


def _layer(path: Path) -> str:
    return path.relative_to(PACKAGE).parts[0]


MODULES = sorted(p for p in PACKAGE.rglob('*.py') if _layer(p) in LAYERS)


def test_every_layer_has_modules() -> None:
    assert {_layer(p) for p in MODULES} == set(LAYERS)
    assert len(MODULES) > 150


@pytest.mark.parametrize('layer', LAYERS)
def test_a_layer_imports_only_the_layers_below(layer: str) -> None:
    wrong = []
    for path in (p for p in MODULES if _layer(p) == layer):
        for name in _imports(path):
            parts = name.split('.')
            if parts[0] == 'depth_nodes' and len(parts) > 1 and parts[1] in LAYERS:
                if parts[1] != layer and parts[1] not in ALLOWED[layer]:
                    wrong.append(f'{path.relative_to(REPO)} imports {name}')
            elif layer in ('core', 'sim') and parts[0] in ROS_PACKAGES:
                wrong.append(f'{path.relative_to(REPO)} imports {name}')
    assert not wrong, '\n'.join(wrong)


def test_multi_view_stereo_is_imported_only_where_it_runs() -> None:
    """The depth filter, the simulator, the ROS glue and every other node take their poses
    and warps from core.geometry."""
    users = {path.relative_to(PACKAGE).as_posix() for path in MODULES
             if any(n.startswith('depth_nodes.core.mvs') for n in _imports(path))
             and not path.relative_to(PACKAGE).as_posix().startswith('core/mvs/')}
    allowed = {'nodes/multiview_stereo.py'}
    tools = {u for u in users if u.startswith('tools/')}
    assert users - tools == allowed, sorted(users - tools)
    # the tools that do: writing, importing, scoring and timing multi-view bags
    assert all(any(word in u for word in ('multiview', 'views', 'bench', 'cli/'))
               for u in tools), sorted(tools)


def test_only_the_pose_input_subscribes_to_poses() -> None:
    pose_types = {'Odometry', 'PoseStamped', 'TFMessage'}
    wrong = []
    subscribers = (p for p in MODULES if _layer(p) in ('nodes', 'ros')
                   and p.relative_to(PACKAGE).as_posix() != 'ros/poses.py')
    for path in subscribers:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, 'attr', '') in (
                    'add_input', 'create_subscription') and node.args and \
                    getattr(node.args[0], 'id', '') in pose_types:
                wrong.append(f'{path.relative_to(REPO)}:{node.lineno}')
    assert not wrong, wrong


def test_stamps_are_read_in_one_place() -> None:
    """``sec * 1e9 + nanosec`` is written out only in core/stamps.py, and NS_PER_S defined
    only there."""
    wrong = []
    for path in PACKAGE.rglob('*.py'):
        text = path.read_text()
        rel = path.relative_to(REPO).as_posix()
        if rel == 'depth_nodes/core/stamps.py':
            continue
        if 'NS_PER_S =' in text or '1_000_000_000' in text:
            wrong.append(rel)
    assert not wrong, sorted(wrong)
