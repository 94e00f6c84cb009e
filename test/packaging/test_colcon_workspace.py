"""The package in a colcon workspace: built by colcon (once per session, in a temporary
workspace whose only source is this repository), installed with the layout `ros2 run` and
`ros2 launch` expect, and run from the install space (`source install/setup.bash`).

colcon comes from PyPI (the `dev` extra) and builds ament_python packages without a ROS
install; the install space's Python runs the venv's interpreter, so its rclpy is the PyPI
one, while `depth_nodes` itself is imported from the install space.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import rclpy
from helpers import REPO, interrupt
from launch_checks import PACKAGE, check_launch_file, node_scripts
from rcl_interfaces.srv import GetParameters, ListParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from depth_nodes.graph.description import load_params_file
from depth_nodes.nodes.rectify import PARAMETERS as RECTIFY_PARAMETERS
from depth_nodes.nodes.registry import NODES
from depth_nodes.ros.image import image_to_array, to_gray
from depth_nodes.tools.bags.io import BagReader

pytestmark = pytest.mark.slow

COLCON = Path(sys.executable).with_name('colcon')
#: What colcon and setuptools would write into the source tree if run from it.
BUILD_OUTPUTS = ('build', 'install', 'log', f'{PACKAGE}.egg-info')
#: Set by a ROS install or another workspace; the test workspace has no underlay.
UNDERLAY_VARS = ('AMENT_PREFIX_PATH', 'COLCON_PREFIX_PATH', 'CMAKE_PREFIX_PATH')

BAG = REPO / 'bags' / 'stereo_qvga_color'
CAMERA = '/stereo/left'
NODE = 'rectify'
MARGIN = 16  # px at the border where a remap samples near the raw image's edge
WAIT = 120.0  # s; a guard against hanging, not a time limit: every wait ends on its event


@dataclass
class Workspace:
    """A built colcon workspace (isolated install layout, as plain `colcon build`)."""

    root: Path
    build_log: str
    repo_outputs: tuple[dict[str, int], dict[str, int]] = field(default=({}, {}))

    @property
    def prefix(self) -> Path:
        """The package's install prefix, ``install/depth_nodes``."""
        return self.root / 'install' / PACKAGE

    @property
    def share(self) -> Path:
        return self.prefix / 'share' / PACKAGE

    @property
    def lib(self) -> Path:
        return self.prefix / 'lib' / PACKAGE

    def environment(self, base: dict[str, str]) -> dict[str, str]:
        """``base`` after ``source install/setup.bash``, as a user's shell has it."""
        result = subprocess.run(
            ['bash', '-c', 'source "$1/setup.bash" && env -0', 'source',
             str(self.root / 'install')],
            env=base, capture_output=True, text=True, check=False)
        assert result.returncode == 0, result.stderr
        env = dict(line.split('=', 1) for line in result.stdout.split('\0') if '=' in line)
        assert env['PYTHONPATH'].split(os.pathsep)[0].startswith(str(self.prefix))
        return env


def _clean_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in UNDERLAY_VARS}


def _repo_outputs() -> dict[str, int]:
    """Modification times of every build output in the source tree (they are gitignored,
    so `git status` would not show them)."""
    found = {}
    for name in BUILD_OUTPUTS:
        for path in [REPO / name, *(REPO / name).rglob('*')]:
            if path.exists():
                found[str(path.relative_to(REPO))] = path.stat().st_mtime_ns
    return found


@pytest.fixture(scope='module')
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Workspace:
    """`colcon build` of the repository in a fresh workspace, run from that workspace so
    build/, install/ and log/ land there; colcon's setup.py call puts the egg-info into
    build/ (`egg_info --egg-base`)."""
    root = tmp_path_factory.mktemp('colcon_ws')
    env = _clean_env()
    env['COLCON_HOME'] = str(root / '.colcon')  # no user defaults or mixins
    before = _repo_outputs()
    result = subprocess.run(
        [str(COLCON), '--log-base', 'log', 'build', '--base-paths', str(REPO),
         '--build-base', 'build', '--install-base', 'install', '--packages-select', PACKAGE,
         '--event-handlers', 'console_cohesion+', 'desktop_notification-', 'status-',
         'terminal_title-'],
        cwd=root, env=env, capture_output=True, text=True, timeout=600, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    return Workspace(root, result.stdout, (before, _repo_outputs()))


def test_build_writes_nothing_into_the_source_tree(workspace: Workspace) -> None:
    before, after = workspace.repo_outputs
    assert after == before
    assert f'Finished <<< {PACKAGE}' in workspace.build_log
    assert (workspace.root / 'build' / PACKAGE / f'{PACKAGE}.egg-info').is_dir()


def test_one_executable_per_node_and_the_depth_nodes_command(workspace: Workspace) -> None:
    expected = set(node_scripts()) | {'depth-nodes'}
    assert {p.name for p in workspace.lib.iterdir()} == expected
    for name in expected:
        path = workspace.lib / name
        assert os.access(path, os.X_OK), name
        shebang = path.read_text().splitlines()[0]
        assert shebang.startswith('#!'), name
        assert Path(shebang[2:]).resolve() == Path(sys.executable).resolve(), name


@pytest.mark.parametrize('script', ['rectify', 'sgm_stereo', 'disparity_node'])
def test_an_installed_node_script_starts_its_node(workspace: Workspace, script: str,
                                                  tmp_path: Path) -> None:
    """setuptools' wrapper (it looks the entry point up in the install space's metadata)
    reaches the registry's script: ``--help`` prints its summary and its node's notes."""
    env = workspace.environment(_clean_env())
    shown = subprocess.run([str(workspace.lib / script), '--help'], env=env, cwd=tmp_path,
                           capture_output=True, text=True, timeout=120, check=False)
    assert shown.returncode == 0, shown.stderr
    entry = next(e for e in NODES if script in (e.name, getattr(e.upstream, 'executable', '')))
    assert shown.stdout.splitlines()[0].endswith(f': {entry.summary}')
    assert f'usage: {script} [--ros-args' in shown.stdout


def test_share_folder_and_ament_index(workspace: Workspace) -> None:
    index = workspace.prefix / 'share' / 'ament_index' / 'resource_index' / 'packages'
    assert (index / PACKAGE).is_file()
    assert (workspace.share / 'package.xml').read_bytes() == (REPO / 'package.xml').read_bytes()
    for folder, pattern in (('config', '*.yaml'), ('launch', '*')):
        # the camera presets in config/cameras too
        source = {p.relative_to(REPO / folder): p.read_bytes()
                  for p in (REPO / folder).rglob(pattern) if p.is_file()
                  and '__pycache__' not in p.parts}
        installed = {p.relative_to(workspace.share / folder): p.read_bytes()
                     for p in (workspace.share / folder).rglob('*') if p.is_file()}
        assert source, folder
        assert installed == source, folder
    assert (workspace.share / 'config' / f'{NODE}.yaml').is_file()
    assert (workspace.share / 'config' / 'cameras' / 'realsense_d435.yaml').is_file()


def test_every_module_is_installed(workspace: Workspace) -> None:
    site = next(workspace.prefix.glob('lib/python3*/site-packages'))
    source = {p.relative_to(REPO) for p in (REPO / PACKAGE).rglob('*.py')
              if '__pycache__' not in p.parts}
    installed = {p.relative_to(site) for p in (site / PACKAGE).rglob('*.py')}
    assert installed == source


def test_install_space_shadows_the_source_tree(workspace: Workspace) -> None:
    """After sourcing, `depth_nodes` and its share folder come from the install space."""
    env = workspace.environment(_clean_env())
    code = ('import depth_nodes\n'
            'from ament_index_python.packages import get_package_share_directory\n'
            'print(depth_nodes.__file__)\n'
            f'print(get_package_share_directory({PACKAGE!r}))\n')
    result = subprocess.run([sys.executable, '-c', code], env=env, cwd=workspace.root,
                            capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    module, share = result.stdout.splitlines()
    assert Path(module).is_relative_to(workspace.prefix)
    assert Path(share) == workspace.share


def test_depth_nodes_command_from_install_space(workspace: Workspace, tmp_path: Path) -> None:
    """The installed command processes a bundled bag with the installed pipeline config
    (found through the ament index) and the installed rectify parameter file."""
    env = workspace.environment(_clean_env())
    result = subprocess.run(
        [str(workspace.lib / 'depth-nodes'), 'process', str(BAG), str(tmp_path / 'out'),
         '--params', str(workspace.share / 'config' / f'{NODE}.yaml')],
        env=env, cwd=tmp_path, capture_output=True, text=True, timeout=600, check=False)
    assert result.returncode == 0, result.stderr
    assert 'nodes: /stereo/left/rectify_left, /stereo/right/rectify_right' in result.stdout
    assert 'dropped: 0' in result.stdout


def test_launch_files_against_install_space(workspace: Workspace,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    launch_files = sorted((workspace.share / 'launch').glob('*.launch.py'))
    assert launch_files
    for path in launch_files:
        check_launch_file(path, workspace.prefix, monkeypatch)


# --- a node started from the install space ----------------------------------------------


@pytest.fixture
def probe(ros_env: dict[str, str]) -> Iterator[tuple[Node, SingleThreadedExecutor]]:
    """An rclpy node of the test's own (isolated) graph, in its own context."""
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('install_space_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield node, executor
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)


def _call(node: Node, executor: SingleThreadedExecutor, srv_type: type,
          name: str, request: object) -> object:
    client = node.create_client(srv_type, name)
    assert client.wait_for_service(timeout_sec=WAIT), f'{name} never came up'
    future = client.call_async(request)
    executor.spin_until_future_complete(future, timeout_sec=WAIT)
    assert future.done(), f'{name} did not answer'
    node.destroy_client(client)
    return future.result()


def _spin_until(executor: SingleThreadedExecutor, done: object) -> None:
    deadline = time.monotonic() + WAIT
    while not done() and time.monotonic() < deadline:  # type: ignore[operator]
        executor.spin_once(timeout_sec=0.05)


@pytest.mark.ros
def test_node_from_install_space_answers_parameter_services_and_rectifies_a_frame(
        workspace: Workspace, ros_env: dict[str, str], probe: tuple, tmp_path: Path) -> None:
    node, executor = probe
    env = workspace.environment(ros_env)
    params_file = workspace.share / 'config' / f'{NODE}.yaml'
    from_file = load_params_file(params_file)['/**']
    defaults = {spec.name: spec.default for spec in RECTIFY_PARAMETERS}
    # The file must differ from the defaults somewhere, or a match would prove nothing:
    # interpolation is the string 'linear' there, the integer 1 by default.
    assert any(type(v) is not type(defaults[k]) or v != defaults[k] for k, v in from_file.items())

    with BagReader(BAG) as reader:
        renders = [m.deserialize() for m in reader.messages([f'{CAMERA}/image_rect_gt'])]
    truth = {(m.header.stamp.sec, m.header.stamp.nanosec): m for m in renders}

    received: list[Image] = []
    node.create_subscription(Image, f'{CAMERA}/image_rect', received.append,
                             QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    proc = subprocess.Popen(
        [str(workspace.lib / NODE), '--ros-args', '--params-file', str(params_file),
         '-r', f'__ns:={CAMERA}', '-r', 'image:=image_raw'],
        env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        listed = _call(node, executor, ListParameters, f'{CAMERA}/{NODE}/list_parameters',
                       ListParameters.Request())
        assert set(defaults) <= set(listed.result.names)  # type: ignore[attr-defined]
        got = _call(node, executor, GetParameters, f'{CAMERA}/{NODE}/get_parameters',
                    GetParameters.Request(names=sorted(from_file)))
        values = dict(zip(sorted(from_file), map(parameter_value_to_python,
                                                 got.values), strict=True))  # type: ignore[attr-defined]
        assert values == from_file
        assert {k: type(v) for k, v in values.items()} == {k: type(v)
                                                           for k, v in from_file.items()}

        # our subscription must be matched before the node publishes its first frame
        _spin_until(executor, lambda: node.count_publishers(f'{CAMERA}/image_rect') > 0)
        assert node.count_publishers(f'{CAMERA}/image_rect') >= 1
        play = subprocess.run(
            [str(workspace.lib / 'depth-nodes'), 'play', str(BAG), '--topics',
             f'{CAMERA}/image_raw', f'{CAMERA}/camera_info', '--wait-for-subscribers',
             str(WAIT), '--delay', '1'],
            env=env, cwd=tmp_path, capture_output=True, text=True, timeout=600, check=False)
        assert play.returncode == 0, play.stderr
        _spin_until(executor, lambda: len(received) == len(truth))
    finally:
        output = interrupt(proc, timeout=WAIT)
    assert proc.returncode == 0, output  # clean shutdown on Ctrl-C
    assert 'Traceback' not in output, output

    # Best-effort image input may lose a frame on a busy machine; every one that came out
    # must be right: the rectified view of the bag's noise-free render.
    assert received, f'no image_rect from the installed node; its output:\n{output}'
    for msg in received:
        gt_msg = truth[(msg.header.stamp.sec, msg.header.stamp.nanosec)]
        assert msg.encoding == 'mono8'
        assert (msg.width, msg.height) == (320, 240)
        rect = image_to_array(msg).astype(np.float32)
        expected = to_gray(image_to_array(gt_msg), gt_msg.encoding).astype(np.float32)
        mad = np.abs(rect - expected)[MARGIN:-MARGIN, MARGIN:-MARGIN].mean()
        assert mad < 2.5, mad  # raw noise sigma 2: about 1.4 is the floor (README)
