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
}
