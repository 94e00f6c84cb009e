"""What the launch files start: one node process per node of a graph description.

``launch/*.launch.py`` (through :mod:`depth_nodes.graph.launch_file`) call
:func:`launch_nodes` with their launch arguments, so the nodes `ros2 launch` starts are
the ones `depth-nodes pipeline` composes and `depth-nodes process` runs, under the same
camera names and with the same parameter-file rules:

* ``params_file``: a ROS 2 parameter file, such as one written for stereo_image_proc; an
  entry applies to a node by its name, full name or alias (``disparity_node``) or through
  ``/**``, and is merged into the node's inline parameters here (launch_ros would match
  entries by the node's own name only);
* ``camera``: a camera preset (``config/cameras/NAME.yaml``,
  :mod:`~depth_nodes.graph.presets`) in place of the launch file's graph;
* ``namespace``, ``left``, ``right``, ``image``: a camera driver's names
  (:func:`~depth_nodes.graph.description.rename_cameras`);
* ``image_transport``: how the nodes that read the driver's images take them (the
  rectifiers, the structured-light decoder and the time-of-flight node: the registry's
  camera readers, see :func:`~depth_nodes.graph.description.camera_readers`).

Pure Python on the package's own modules: the launch files' tests run it without `launch`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from depth_nodes.errors import ConfigError
from depth_nodes.graph.description import (
    camera_readers,
    load_graph_config,
    load_params_file,
    parameters_for,
    rename_cameras,
    unmatched_entries,
    unmatched_warning,
    with_transport,
)
from depth_nodes.graph.presets import load_camera
from depth_nodes.ros.transport import TRANSPORTS

#: The launch arguments of the package's launch files: name -> description.
LAUNCH_ARGUMENTS = {
    'params_file': 'ROS 2 parameter file applied to the nodes (a stereo_image_proc one '
                   'works unchanged: entries by node name, alias such as disparity_node, or '
                   '/**)',
    'camera': 'a camera preset of config/cameras (realsense_d435, realsense_d455, zed2i, '
              'oakd, orbbec_femto, generic_stereo) in place of this file\'s graph',
    'namespace': 'camera namespace replacing the graph\'s (e.g. /camera)',
    'left': 'left camera name below it (default left)',
    'right': 'right camera name below it (default right)',
    'image': 'raw image topic name (default image_raw)',
    'image_transport': 'raw, compressed or compressedDepth: how the camera images arrive',
}


def launch_nodes(config_path: str | Path, *, params_file: str | None = None,
                 camera: str | None = None, namespace: str | None = None, left: str | None = None,
                 right: str | None = None, image: str | None = None,
                 image_transport: str | None = None) -> list[dict[str, Any]]:
    """Keyword arguments of ``launch_ros.actions.Node`` for every node of the graph.

    Empty strings count as not given (launch arguments default to ``''``).

    Raises:
        ConfigError: A bad graph, parameter file, name or transport, or a parameter-file
            entry that matches no node (``ros2 launch`` would start the nodes without it).
    """
    if camera:
        preset = load_camera(camera, Path(config_path).parent)
        graph = preset.config
        image_transport = image_transport or preset.image_transport
    else:
        graph = load_graph_config(config_path)
    config = rename_cameras(graph, namespace=namespace or None, left=left or None,
                            right=right or None, image=image or None)
    params = load_params_file(params_file) if params_file else {}
    unmatched = unmatched_entries(config, params)
    if unmatched:
        raise ConfigError(f'{params_file}: '
                          f'{unmatched_warning(config, unmatched[0], ignored=False)}')
    if image_transport and image_transport not in TRANSPORTS:
        raise ConfigError(f'image_transport {image_transport!r} is not one of '
                          f'{", ".join(TRANSPORTS)}')
    if image_transport:
        params = with_transport(params, camera_readers(config), image_transport)
    nodes = []
    for spec in config.nodes:
        values = parameters_for(spec, params)
        nodes.append({'executable': spec.plugin, 'name': spec.name,
                      'namespace': spec.namespace, 'parameters': [values],
                      'remappings': list(spec.remappings.items())})
    return nodes

