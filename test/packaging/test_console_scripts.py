"""The nodes' console scripts follow from the registry: setup.py reads it without the
package or rclpy, declares one script per registry name and per image_pipeline executable
name, and every script, as pip's wrapper runs it, starts its node (``--help`` here: the
registry's summary, then the node's notes). The colcon install space's scripts are run in
packaging/test_colcon_workspace.py."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import REPO, TEST_DIR
from launch_checks import node_scripts
from pip._vendor.distlib.scripts import ScriptMaker  # what pip writes console scripts with

from depth_nodes.nodes import NODE_PLUGINS, UPSTREAM_EXECUTABLES, scripts
from depth_nodes.nodes.registry import INPUT_KINDS, NODES, script_names
from depth_nodes.ros.node import DepthNode

pytestmark = pytest.mark.slow

#: setup.py run with the package and rclpy made unimportable and setuptools.setup recorded.
_SETUP_WITHOUT_PACKAGE = """
import runpy, sys
import setuptools
sys.modules['rclpy'] = None
sys.modules['depth_nodes'] = None
given = {}
setuptools.setup = lambda **kwargs: given.update(kwargs)
runpy.run_path(sys.argv[1], run_name='__main__')
print(len(given['entry_points']['console_scripts']))
"""


def _env() -> dict[str, str]:
    """This process's environment with the source tree and the test nodes importable."""
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(REPO), str(TEST_DIR),
                                                      env.get('PYTHONPATH')]))
    return env


def test_setup_reads_the_registry_without_importing_the_package() -> None:
    result = subprocess.run([sys.executable, '-c', _SETUP_WITHOUT_PACKAGE,
                             str(REPO / 'setup.py')], capture_output=True, text=True,
                            cwd=REPO.parent, check=False)
    assert result.returncode == 0, result.stderr
    assert int(result.stdout) == len(script_names()) + 1  # and depth-nodes


def test_the_console_scripts_are_the_registry() -> None:
    declared = node_scripts()
    assert list(declared) == script_names()
    assert set(declared) == set(NODE_PLUGINS) | set(UPSTREAM_EXECUTABLES)
    assert len(set(declared)) == len(NODES) + sum(e.upstream is not None for e in NODES)


def test_registry_entries() -> None:
    names = [entry.name for entry in NODES]
    assert len(set(names)) == len(names)
    for entry in NODES:
        assert entry.inputs in INPUT_KINDS, entry.name
        assert entry.summary, entry.name
        assert '\n' not in entry.summary, entry.name
        module, _, cls = entry.target.partition(':')
        node_class = getattr(__import__(module, fromlist=[cls]), cls)
        assert issubclass(node_class, DepthNode), entry.name
        assert (sys.modules[module].__doc__ or '').strip(), f'{module} has no notes'


def test_every_script_is_an_attribute_of_the_scripts_module() -> None:
    for name in script_names():
        main = getattr(scripts, name)
        assert callable(main), name
        assert main.__name__ == name
        assert name in dir(scripts)
    # a script must never be shadowed by the module's own names
    assert not set(script_names()) & set(vars(scripts))
    with pytest.raises(AttributeError, match="has no attribute 'rectify_nod'"):
        scripts.rectify_nod  # noqa: B018


@pytest.fixture(scope='module')
def pip_scripts(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Every console script of setup.py, written as pip writes them (pip's settings)."""
    folder = tmp_path_factory.mktemp('bin')
    maker = ScriptMaker(None, str(folder))
    maker.clobber = True
    maker.variants = {''}
    maker.set_mode = True
    maker.executable = sys.executable
    made = maker.make_multiple([f'{name} = {target}' for name, target in
                                node_scripts().items()])
    assert sorted(Path(p).name for p in made) == sorted(script_names())
    return folder


@pytest.mark.parametrize('script', ['rectify', 'static_transform', 'tof', 'register_node',
                                    'point_cloud_xyzrgb_node'])
def test_a_pip_script_prints_its_summary_and_notes(pip_scripts: Path, script: str) -> None:
    shown = subprocess.run([str(pip_scripts / script), '--help'], capture_output=True,
                           text=True, env=_env(), timeout=120, check=False)
    assert shown.returncode == 0, shown.stderr
    entry = next(e for e in NODES if script in (e.name, getattr(e.upstream, 'executable', '')))
    first = shown.stdout.splitlines()[0]
    assert first.startswith(script), first
    assert first.endswith(f': {entry.summary}'), first
    if script != entry.name:
        assert f'node name {entry.upstream.node_name}' in first  # type: ignore[union-attr]
    notes = (sys.modules[entry.module].__doc__ or '').strip().splitlines()[0]
    assert notes in shown.stdout
    assert f'usage: {script} [--ros-args' in shown.stdout


@pytest.mark.parametrize('script', ['tof', 'register_node'])
def test_a_pip_script_refuses_bad_ros_args_in_one_line(pip_scripts: Path,
                                                       script: str) -> None:
    bad = subprocess.run([str(pip_scripts / script), '--ros-args', '--help'],
                         capture_output=True, text=True, env=_env(), timeout=120, check=False)
    assert bad.returncode == 1
    assert bad.stderr.strip().endswith("bad --ros-args: ['--help']")
    assert 'Traceback' not in bad.stderr


def test_scripts_module_runs_a_script_by_name() -> None:
    """``python -m depth_nodes.nodes.scripts NAME``: a script without an installation."""
    shown = subprocess.run([sys.executable, '-m', 'depth_nodes.nodes.scripts',
                            'depth_disparity_node', '--help'], capture_output=True, text=True,
                           env=_env(), timeout=120, check=False)
    assert shown.returncode == 0, shown.stderr
    assert shown.stdout.startswith('depth_disparity_node (depth_image_proc\'s executable, '
                                   'node name DisparityNode): ')
    assert 'usage: depth_disparity_node [--ros-args' in shown.stdout
    unknown = subprocess.run([sys.executable, '-m', 'depth_nodes.nodes.scripts', 'rectfy'],
                             capture_output=True, text=True, env=_env(), timeout=120,
                             check=False)
    assert unknown.returncode == 2
    assert unknown.stderr.startswith('usage: python -m depth_nodes.nodes.scripts SCRIPT')
    assert 'scripts: rectify, sgm_stereo' in unknown.stderr
