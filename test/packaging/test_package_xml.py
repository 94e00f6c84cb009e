"""package.xml as ROS tooling reads it: catkin_pkg finds no error or warning, it agrees with
setup.py, and every dependency is a key that rosdep resolves for Jazzy."""

from __future__ import annotations

import ast
import sys

from catkin_pkg.package import Package, parse_package
from helpers import REPO

#: ROS packages released for Jazzy, so rosdep resolves them by name. Checked in
#: ros/rosdistro jazzy/distribution.yaml (repositories rclpy; rcl_interfaces, which
#: releases rcl_interfaces and rosgraph_msgs; common_interfaces, which releases
#: sensor_msgs, stereo_msgs, std_msgs, std_srvs, diagnostic_msgs, geometry_msgs, nav_msgs and
#: visualization_msgs; geometry2, which releases tf2_msgs; ament_index; launch; launch_ros).
JAZZY_ROS_PACKAGES = frozenset({
    'rclpy', 'rcl_interfaces', 'rosgraph_msgs', 'sensor_msgs', 'stereo_msgs', 'std_msgs',
    'std_srvs', 'diagnostic_msgs', 'geometry_msgs', 'nav_msgs', 'visualization_msgs',
    'tf2_msgs', 'ament_index_python', 'launch',
    'launch_ros',
})

#: Keys of ros/rosdistro rosdep/python.yaml that resolve on Ubuntu Noble (Jazzy's platform).
#: - python3-numpy, python3-opencv, python3-yaml, python3-pytest: `ubuntu: [python3-...]`
#:   for every release.
#: - python3-numba: added for bionic/focal only (ros/rosdistro#32274); ros/rosdistro#36477
#:   (merged 2023-03) maps it for every Ubuntu release.
#: - python3-rosbags-pip: ros/rosdistro#37795 (merged 2023-06), installed by pip from PyPI
#:   (rosbags has no Debian/Ubuntu package; `-pip` is rosdep's convention for that).
ROSDEP_KEYS = frozenset({
    'python3-numpy', 'python3-opencv', 'python3-yaml', 'python3-pytest', 'python3-numba',
    'python3-rosbags-pip',
})

#: Top-level module -> the key that provides it. `backports.zstd` (Python < 3.14) comes
#: with rosbags; `compression.zstd` is its standard-library name from Python 3.14.
MODULE_KEYS = {
    'numpy': 'python3-numpy',
    'cv2': 'python3-opencv',
    'numba': 'python3-numba',
    'yaml': 'python3-yaml',
    'rosbags': 'python3-rosbags-pip',
    'backports': 'python3-rosbags-pip',
    'compression': 'python3-rosbags-pip',
    'lz4': 'python3-rosbags-pip',  # a dependency of rosbags (its MCAP reader's LZ4 chunks)
    **{name: name for name in JAZZY_ROS_PACKAGES},
}
#: Imports of an optional feature, behind an ImportError that says what to install: not a
#: dependency of the package on a robot (setup.py's extras name them).
OPTIONAL = {
    'ray': 'cluster',  # depth-nodes process --ray
    # eval --librealsense, bench depth_filter: librealsense's filters beside
    'pyrealsense2': 'realsense',
    'libusb_package': 'realsense',
    'jax': 'train',  # depth-nodes train-cost / train-confidence
    'open3d': 'open3d',  # eval --open3d, bench fusion: Open3D's VoxelBlockGrid beside
}
#: The distribution of an optional module, where its name is not the module's.
DISTRIBUTIONS = {'open3d': 'open3d_cpu'}


def _package() -> tuple[Package, list[str]]:
    warnings: list[str] = []
    package = parse_package(str(REPO / 'package.xml'), warnings=warnings)
    package.validate(warnings=warnings)  # raises InvalidPackage on an error
    return package, warnings


def _setup_keywords() -> dict[str, object]:
    """The literal keyword arguments of the setup() call in setup.py."""
    tree = ast.parse((REPO / 'setup.py').read_text())
    constants = {t.id: node.value for node in tree.body if isinstance(node, ast.Assign)
                 for t in node.targets if isinstance(t, ast.Name)}
    call = next(node for node in ast.walk(tree) if isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name) and node.func.id == 'setup')
    out = {}
    for kw in call.keywords:
        value = constants.get(kw.value.id, kw.value) if isinstance(kw.value, ast.Name) else kw.value
        try:
            out[str(kw.arg)] = ast.literal_eval(value)
        except ValueError:
            continue
    return out


def _imported_modules() -> dict[str, list[str]]:
    """Top-level third-party modules imported by the package and its launch files."""
    found: dict[str, list[str]] = {}
    files = sorted((REPO / 'depth_nodes').rglob('*.py')) + sorted((REPO / 'launch').glob('*.py'))
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.partition('.')[0]
                if top != 'depth_nodes' and top not in sys.stdlib_module_names:
                    found.setdefault(top, []).append(str(path.relative_to(REPO)))
    return found


def test_catkin_pkg_parses_without_errors_or_warnings() -> None:
    package, warnings = _package()
    assert warnings == []
    assert package.package_format == 3
    assert package.get_build_type() == 'ament_python'


def test_metadata_matches_setup_py() -> None:
    package, _ = _package()
    setup = _setup_keywords()
    assert package.name == setup['name']
    assert package.version == setup['version']
    assert [str(lic) for lic in package.licenses] == [setup['license']]
    assert [m.email for m in package.maintainers] == [setup['maintainer_email']]
    assert (REPO / 'resource' / package.name).is_file()  # the ament index marker


def test_every_dependency_is_a_key_rosdep_resolves_for_jazzy() -> None:
    package, _ = _package()
    deps = {d.name for d in package.build_depends + package.buildtool_depends
            + package.exec_depends + package.test_depends + package.build_export_depends}
    unknown = deps - JAZZY_ROS_PACKAGES - ROSDEP_KEYS
    assert not unknown, f'not checked against rosdistro: {sorted(unknown)}'


def test_every_imported_module_is_declared() -> None:
    """A new third-party import needs its key in package.xml (and in MODULE_KEYS here)."""
    package, _ = _package()
    declared = {d.name for d in package.exec_depends}
    imported = {m: files for m, files in _imported_modules().items() if m not in OPTIONAL}
    unmapped = {m: files[0] for m, files in imported.items() if m not in MODULE_KEYS}
    assert not unmapped, f'imports with no known rosdep key: {unmapped}'
    missing = {m: MODULE_KEYS[m] for m in imported if MODULE_KEYS[m] not in declared}
    assert not missing, f'imported but not an exec_depend in package.xml: {missing}'
    for module in ('rclpy', 'numpy', 'cv2', 'yaml', 'rosbags', 'launch_ros'):
        assert module in imported  # the scan sees the package's real imports


def test_optional_imports_are_setup_extras() -> None:
    tree = ast.parse((REPO / 'setup.py').read_text())
    extras = next(kw.value for node in ast.walk(tree) if isinstance(node, ast.Call)
                  for kw in node.keywords if kw.arg == 'extras_require')
    assert isinstance(extras, ast.Dict)
    literal = {ast.literal_eval(k): v for k, v in zip(extras.keys, extras.values, strict=True)
               if k is not None}
    for module, extra in OPTIONAL.items():  # a distribution named with - imports with _
        names = [name.replace('-', '_') for name in ast.literal_eval(literal[extra])]
        assert DISTRIBUTIONS.get(module, module) in names, module
