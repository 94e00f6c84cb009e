"""One thin module per node: subscribe, convert, call core, publish.

:data:`NODE_PLUGINS` registers them: graph descriptions (``plugin: rectify``), the composed
pipeline and the launch files find a node's class here, by the name that is also its
console script (``ros2 run depth_nodes <name>``). Strings, so that reading the registry
imports no node.
"""

NODE_PLUGINS: dict[str, str] = {
    'rectify': 'depth_nodes.nodes.rectify:RectifyNode',
    'sgm_stereo': 'depth_nodes.nodes.sgm_stereo:SgmStereoNode',
    'cross_check': 'depth_nodes.nodes.cross_check:CrossCheckNode',
    'point_cloud': 'depth_nodes.nodes.point_cloud:PointCloudNode',
    'structured_light': 'depth_nodes.nodes.structured_light:StructuredLightNode',
    'static_transform': 'depth_nodes.nodes.static_transform:StaticTransformNode',
    'point_cloud_xyz': 'depth_nodes.nodes.point_cloud_xyz:PointCloudXyzNode',
    'point_cloud_xyzrgb': 'depth_nodes.nodes.point_cloud_xyzrgb:PointCloudXyzrgbNode',
    'register_depth': 'depth_nodes.nodes.register_depth:RegisterNode',
    'convert_metric': 'depth_nodes.nodes.convert_metric:ConvertMetricNode',
    'depth_disparity': 'depth_nodes.nodes.depth_disparity:DepthDisparityNode',
    'tof': 'depth_nodes.nodes.tof:ToFNode',
}

#: Executables under image_pipeline's names, so that a launch file written for image_proc,
#: stereo_image_proc or depth_image_proc runs these nodes when only its ``package`` is
#: changed: executable -> (upstream package, plugin here, the node's default name there).
#: depth_image_proc's ``disparity_node`` (depth -> disparity) shares its name with
#: stereo_image_proc's matcher; the matcher keeps it, the other is
#: ``depth_disparity_node``.
UPSTREAM_EXECUTABLES: dict[str, tuple[str, str, str]] = {
    'rectify_node': ('image_proc', 'rectify', 'RectifyNode'),
    'disparity_node': ('stereo_image_proc', 'sgm_stereo', 'disparity_node'),
    'point_cloud_node': ('stereo_image_proc', 'point_cloud', 'point_cloud_node'),
    'convert_metric_node': ('depth_image_proc', 'convert_metric', 'ConvertMetricNode'),
    'point_cloud_xyz_node': ('depth_image_proc', 'point_cloud_xyz', 'PointCloudXyzNode'),
    'point_cloud_xyzrgb_node': ('depth_image_proc', 'point_cloud_xyzrgb',
                                'PointCloudXyzrgbNode'),
    'register_node': ('depth_image_proc', 'register_depth', 'RegisterNode'),
    'depth_disparity_node': ('depth_image_proc', 'depth_disparity', 'DisparityNode'),
}
