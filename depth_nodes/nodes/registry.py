"""The node registry: one entry per node, and everything that follows from it.

An entry names the node (its plugin name in graph descriptions and its console script,
``ros2 run depth_nodes <name>``), where its class is, a one-line summary (the first line
of its script's ``--help``), image_pipeline's executable it stands in for, whether it reads
a camera driver's images, and the kind of input it takes. From the entries follow
:data:`depth_nodes.nodes.NODE_PLUGINS`, :data:`depth_nodes.nodes.UPSTREAM_EXECUTABLES`,
setup.py's console scripts (:func:`console_scripts`), the nodes the ``image_transport``
launch argument and `process`'s compressed-image detection apply to (``camera_reader``),
and the hostile-input test's node list (test/nodes/test_fuzz_nodes.py, by ``inputs``).

Adding a node: its core module, its node module, one entry here, its tests, its docs.

Standard library only: setup.py reads this file with ``runpy.run_path``, before the package
or rclpy can be imported.
"""

from dataclasses import dataclass
from typing import NamedTuple

#: The module whose attributes are the console scripts (see depth_nodes/nodes/scripts.py).
SCRIPTS_MODULE = 'depth_nodes.nodes.scripts'

#: What a node subscribes to, by kind (``NodeEntry.inputs``); the fuzz test builds valid
#: frames of each kind.
INPUT_KINDS = {
    'camera': 'one camera: image (raw) + camera_info',
    'stereo_rect': 'a rectified stereo pair: left/ and right/ image_rect + camera_info',
    'disparity_pair': 'both views\' disparity + the matcher\'s cost_ratio',
    'stereo_disparity': 'disparity + left/image_rect_color + both camera_infos '
                        '(+ confidence)',
    'pattern_sequence': 'a camera\'s pattern images + camera_info + pattern tags + the '
                        'projector\'s camera_info',
    'none': 'nothing: the node publishes once, at start-up',
    'depth': 'a depth image (image_rect) + its camera_info',
    'depth_colour': 'a registered depth image + the colour image + its camera_info',
    'depth_two_cameras': 'a depth image + its camera_info + the colour camera\'s',
    'depth_raw': 'a depth image (image_raw) alone',
    'depth_stereo': 'a left depth image + the right camera_info (the baseline)',
    'tof_correlation': 'a time-of-flight camera\'s raw correlation frame + camera_info',
    'posed_camera': 'one camera\'s rectified image + camera_info, and its poses (odometry)',
    'posed_depth': 'a depth image (image_rect) + its camera_info (+ a confidence or sigma '
                   'image), and the camera\'s poses (odometry) where a pose source is set',
    'posed_depth_map': 'a depth image (image_rect) + its camera_info (+ a confidence or '
                       'sigma image) and the camera\'s poses (odometry), fused into a map '
                       '(a mesh out)',
}


class Upstream(NamedTuple):
    """image_pipeline's executable a node stands in for."""

    #: The executable's name, also a console script here (``ros2 run depth_nodes <it>``).
    executable: str
    #: The image_pipeline package it comes from.
    package: str
    #: The node name upstream gives it: the script starts the node under it, so a
    #: parameter file keyed by that name applies.
    node_name: str


@dataclass(frozen=True)
class NodeEntry:
    """One node of the package."""

    #: Plugin name (graph descriptions: ``plugin: <name>``) and console script.
    name: str
    #: ``module:Class`` of the node class.
    target: str
    #: One line: what the node does (the first line of its script's ``--help``).
    summary: str
    #: The kind of input it takes: a key of :data:`INPUT_KINDS`.
    inputs: str
    #: It reads images straight from a camera driver, so a camera's ``image_transport``
    #: (the launch argument, `process`'s compressed-image detection) applies to it.
    camera_reader: bool = False
    #: image_pipeline's executable it stands in for, if any.
    upstream: Upstream | None = None

    @property
    def module(self) -> str:
        """The node's module."""
        return self.target.partition(':')[0]


#: Every node, in the order ``depth-nodes --help`` lists them.
NODES = (
    NodeEntry('rectify', 'depth_nodes.nodes.rectify:RectifyNode',
              'Rectifier: a camera\'s raw images -> rectified mono and colour images '
              '(image_proc\'s RectifyNode)', 'camera', camera_reader=True,
              upstream=Upstream('rectify_node', 'image_proc', 'RectifyNode')),
    NodeEntry('sgm_stereo', 'depth_nodes.nodes.sgm_stereo:SgmStereoNode',
              'Census SGM stereo matcher: a rectified pair -> both views\' disparity and the '
              'cost ratio (stereo_image_proc\'s DisparityNode)', 'stereo_rect',
              upstream=Upstream('disparity_node', 'stereo_image_proc', 'disparity_node')),
    NodeEntry('cross_check', 'depth_nodes.nodes.cross_check:CrossCheckNode',
              'Cross-check: left-right consistency, speckle removal, hole filling and '
              'confidence of a disparity', 'disparity_pair'),
    NodeEntry('point_cloud', 'depth_nodes.nodes.point_cloud:PointCloudNode',
              'Point cloud: disparity -> organised PointCloud2 and depth image '
              '(stereo_image_proc\'s PointCloudNode)', 'stereo_disparity',
              upstream=Upstream('point_cloud_node', 'stereo_image_proc', 'point_cloud_node')),
    NodeEntry('structured_light', 'depth_nodes.nodes.structured_light:StructuredLightNode',
              'Structured light: a camera\'s pattern sequence (or one speckle image) -> depth '
              'and points', 'pattern_sequence', camera_reader=True),
    NodeEntry('static_transform', 'depth_nodes.nodes.static_transform:StaticTransformNode',
              'Static transform: a camera\'s optical frame on the robot, latched on '
              '/tf_static', 'none'),
    NodeEntry('point_cloud_xyz', 'depth_nodes.nodes.point_cloud_xyz:PointCloudXyzNode',
              'Depth image -> organised PointCloud2 (depth_image_proc\'s PointCloudXyzNode)',
              'depth', upstream=Upstream('point_cloud_xyz_node', 'depth_image_proc',
                                         'PointCloudXyzNode')),
    NodeEntry('point_cloud_xyzrgb', 'depth_nodes.nodes.point_cloud_xyzrgb:PointCloudXyzrgbNode',
              'Registered depth + colour image -> coloured organised PointCloud2 '
              '(depth_image_proc\'s PointCloudXyzrgbNode)', 'depth_colour',
              upstream=Upstream('point_cloud_xyzrgb_node', 'depth_image_proc',
                                'PointCloudXyzrgbNode')),
    NodeEntry('register_depth', 'depth_nodes.nodes.register_depth:RegisterNode',
              'Depth image moved into another camera, usually the colour one '
              '(depth_image_proc\'s RegisterNode)', 'depth_two_cameras',
              upstream=Upstream('register_node', 'depth_image_proc', 'RegisterNode')),
    NodeEntry('convert_metric', 'depth_nodes.nodes.convert_metric:ConvertMetricNode',
              'Depth image in millimetres (16UC1) -> metres (32FC1) (depth_image_proc\'s '
              'ConvertMetricNode)', 'depth_raw',
              upstream=Upstream('convert_metric_node', 'depth_image_proc',
                                'ConvertMetricNode')),
    # depth_image_proc's executable is disparity_node, which stereo_image_proc's matcher
    # has here (the two packages use the same name): this one is depth_disparity_node
    NodeEntry('depth_disparity', 'depth_nodes.nodes.depth_disparity:DepthDisparityNode',
              'Depth image -> stereo_msgs/DisparityImage (depth_image_proc\'s DisparityNode)',
              'depth_stereo', upstream=Upstream('depth_disparity_node', 'depth_image_proc',
                                                'DisparityNode')),
    NodeEntry('tof', 'depth_nodes.nodes.tof:ToFNode',
              'Time of flight: raw correlation frames -> depth, amplitude, confidence and '
              'points', 'tof_correlation', camera_reader=True),
    NodeEntry('depth_filter', 'depth_nodes.nodes.depth_filter:DepthFilterNode',
              'Depth filter: decimation, flying pixels, spatial and motion-compensated '
              'temporal smoothing, hole filling of any depth camera\'s depth image',
              'posed_depth'),
    NodeEntry('multiview_stereo', 'depth_nodes.nodes.multiview_stereo:MultiViewStereoNode',
              'Multi-view stereo: a moving camera\'s posed images (or a rig\'s) -> depth, '
              'sigma, confidence and points', 'posed_camera', camera_reader=True),
    NodeEntry('tsdf_fusion', 'depth_nodes.nodes.tsdf_fusion:TsdfFusionNode',
              'TSDF fusion: posed depth images (weighted by their sigma or confidence) -> '
              'a mesh, surface points and a distance-field slice', 'posed_depth_map'),
)


def entry_of(plugin: str) -> NodeEntry | None:
    """The entry of a graph description's ``plugin``: a registry name, or the ``module:Class``
    of a registry node; None for any other class."""
    for entry in NODES:
        if plugin in (entry.name, entry.target):
            return entry
    return None


def script_names() -> list[str]:
    """Every console script of a node: the registry's names, then image_pipeline's
    executable names."""
    return [entry.name for entry in NODES] + [
        entry.upstream.executable for entry in NODES if entry.upstream is not None]


def console_scripts() -> list[str]:
    """setup.py's ``console_scripts`` entries of the nodes: ``name = module:name``."""
    return [f'{name} = {SCRIPTS_MODULE}:{name}' for name in script_names()]
