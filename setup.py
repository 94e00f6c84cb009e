"""ament_python build description for depth_nodes.

Inside a colcon workspace on a ROS 2 install this builds like any ament_python package and
uses the system rclpy. Outside one, `pip install -e '.[ros,dev]'` pulls ROS 2 Jazzy from
its PyPI wheels (the `ros` extra); `make venv` does that with pinned versions.
"""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'depth_nodes'

# One console script per node, so `ros2 run depth_nodes <node>` works; named like the node's
# plugin in depth_nodes/nodes/__init__.py::NODE_PLUGINS.
NODE_SCRIPTS = [
    'rectify = depth_nodes.nodes.rectify:main',
    'sgm_stereo = depth_nodes.nodes.sgm_stereo:main',
    'cross_check = depth_nodes.nodes.cross_check:main',
    'point_cloud = depth_nodes.nodes.point_cloud:main',
    'structured_light = depth_nodes.nodes.structured_light:main',
    'static_transform = depth_nodes.nodes.static_transform:main',
    'point_cloud_xyz = depth_nodes.nodes.point_cloud_xyz:main',
    'point_cloud_xyzrgb = depth_nodes.nodes.point_cloud_xyzrgb:main',
    'register_depth = depth_nodes.nodes.register_depth:main',
    'convert_metric = depth_nodes.nodes.convert_metric:main',
    'depth_disparity = depth_nodes.nodes.depth_disparity:main',
    'tof = depth_nodes.nodes.tof:main',
    # image_pipeline's executable names (depth_nodes/nodes/__init__.py: UPSTREAM_EXECUTABLES)
    'rectify_node = depth_nodes.nodes.upstream:rectify_node',
    'disparity_node = depth_nodes.nodes.upstream:disparity_node',
    'point_cloud_node = depth_nodes.nodes.upstream:point_cloud_node',
    'convert_metric_node = depth_nodes.nodes.upstream:convert_metric_node',
    'point_cloud_xyz_node = depth_nodes.nodes.upstream:point_cloud_xyz_node',
    'point_cloud_xyzrgb_node = depth_nodes.nodes.upstream:point_cloud_xyzrgb_node',
    'register_node = depth_nodes.nodes.upstream:register_node',
    'depth_disparity_node = depth_nodes.nodes.upstream:depth_disparity_node',
]

ROS_WHEELS = [
    'ros-jazzy-rclpy[fastrtps]',
    'ros-jazzy-sensor-msgs',
    'ros-jazzy-stereo-msgs',
    'ros-jazzy-std-msgs',
    'ros-jazzy-diagnostic-msgs',
]

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    # the Fast DDS profile the nodes use for large messages (depth_nodes/ros/dds.py)
    package_data={PACKAGE: ['ros/*.xml']},
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config', sorted(glob('config/*.yaml'))),
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
        'dev': ['pytest', 'ruff', 'mypy', 'colcon-common-extensions', 'catkin_pkg'],
        # `depth-nodes process --ray`: bag archives on a Ray cluster (local or existing)
        'cluster': ['ray'],
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
