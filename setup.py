"""ament_python build description for depth_nodes.

Inside a colcon workspace on a ROS 2 install this builds like any ament_python package and
uses the system rclpy. Outside one, `pip install -e '.[ros,dev]'` pulls ROS 2 Jazzy from
its PyPI wheels (the `ros` extra); `make venv` does that with pinned versions.
"""

import runpy
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = 'depth_nodes'

# One console script per node (`ros2 run depth_nodes <node>`), plus image_pipeline's
# executable names, all from the node registry: read as a file, since neither the package
# nor rclpy can be imported while the package is being built.
REGISTRY = runpy.run_path(str(Path(__file__).resolve().parent / PACKAGE / 'nodes' /
                              'registry.py'))
NODE_SCRIPTS = REGISTRY['console_scripts']()

ROS_WHEELS = [
    'ros-jazzy-rclpy[fastrtps]',
    'ros-jazzy-sensor-msgs',
    'ros-jazzy-stereo-msgs',
    'ros-jazzy-std-msgs',
    'ros-jazzy-diagnostic-msgs',
    # poses for the multi-view node: odometry, PoseStamped
    'ros-jazzy-nav-msgs',
    'ros-jazzy-geometry-msgs',
    # tsdf_fusion: its mesh (MarkerArray) and its save_mesh / clear services
    'ros-jazzy-visualization-msgs',
    'ros-jazzy-std-srvs',
]

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    # the Fast DDS profile the nodes use for large messages (depth_nodes/ros/dds.py); the
    # learned matching cost's and confidence's weights
    package_data={PACKAGE: ['ros/*.xml', 'core/learned/weights/*.npz']},
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config', sorted(glob('config/*.yaml'))),
        (f'share/{PACKAGE}/config/cameras', sorted(glob('config/cameras/*.yaml'))),
        (f'share/{PACKAGE}/launch', sorted(glob('launch/*.py'))),
    ],
    python_requires='>=3.10',
    install_requires=[
        'setuptools',
        'numpy',
        # the contrib build (a superset of opencv-python-headless) for cv2.structured_light
        'opencv-contrib-python-headless',
        'numba',
        'rosbags',
        'pyyaml',
    ],
    extras_require={
        'ros': ROS_WHEELS,
        # pytest-xdist: `make test` runs the suite on two workers (test/helpers.py gives each
        # worker its own ROS_DOMAIN_IDs)
        'dev': ['pytest', 'pytest-xdist', 'ruff', 'mypy', 'colcon-common-extensions',
                'catkin_pkg'],
        # `depth-nodes process --ray`: bag archives on a Ray cluster (local or existing)
        'cluster': ['ray'],
        # to compare depth_filter with librealsense's filters (tools/evaluation); no node
        # needs it. libusb-package: pyrealsense2's native library needs libusb-1.0, which a
        # machine without a RealSense has no reason to carry
        'realsense': ['pyrealsense2', 'libusb-package'],
        # `depth-nodes train-cost` / `train-confidence` only (no node imports them): JAX on
        # the CPU for the gradients; scikit-image for its photographs (textures of the
        # training pairs) and its real Middlebury motorcycle pair (held-out validation)
        'train': ['jax', 'scikit-image'],
        # to compare tsdf_fusion with Open3D's VoxelBlockGrid (tools/evaluation); no node
        # imports it. libusb-package: its native library needs libusb-1.0 at import, as
        # pyrealsense2's does
        'open3d': ['open3d-cpu', 'libusb-package'],
    },
    zip_safe=False,  # Fast DDS reads the profile from a real file
    maintainer='depth_nodes maintainers',
    maintainer_email='depth-nodes@example.com',
    description='Stereo, confidence, point-cloud and structured-light depth nodes for ROS 2.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': ['depth-nodes = depth_nodes.tools.cli:main', *NODE_SCRIPTS],
    },
)
