"""The options `process` and `pipeline` share: the graph, its parameter file, and the
camera names that move the graph onto a driver's topics."""

from __future__ import annotations

import argparse

from depth_nodes.errors import ConfigError
from depth_nodes.graph.description import GraphConfig, load_graph_config, rename_cameras
from depth_nodes.graph.presets import load_camera
from depth_nodes.tools.bags.process import default_config_path
from depth_nodes.tools.cli.options import Once


def add_graph_arguments(parser: argparse.ArgumentParser) -> None:
    """--config, --camera and --params."""
    parser.add_argument('--config', help='graph YAML (default: config/stereo_pipeline.yaml)')
    parser.add_argument('--camera', metavar='NAME',
                        help='a camera preset (config/cameras/NAME.yaml): the graph on that '
                        "camera driver's topics with its settings, e.g. realsense_d435, "
                        'zed2i, oakd, orbbec_femto, generic_stereo')
    parser.add_argument('--params', action=Once,
                        help='ROS 2 parameter file overriding node parameters')


def add_camera_arguments(parser: argparse.ArgumentParser, *, auto: bool) -> None:
    """--namespace, --left, --right, --image, --image-transport: a camera driver's names.

    Args:
        parser: The command's parser.
        auto: The command finds the compressed transport by itself (in a bag).
    """
    group = parser.add_argument_group(
        'camera names', 'Move the graph to the topics a camera driver publishes, e.g. '
        '/camera/left/image_raw/compressed: --namespace /camera'
        + (' (the compressed transport is found by itself)' if auto else
           ' --image-transport compressed'))
    group.add_argument('--namespace', help='the camera namespace, replacing the graph\'s '
                       '(/stereo for the stereo graph)')
    group.add_argument('--left', help='name of the left camera below it (default left), e.g. '
                       'infra1')
    group.add_argument('--right', help='name of the right camera (default right), e.g. infra2')
    group.add_argument('--image', help='name of the raw image topic (default image_raw), e.g. '
                       'image_rect_raw')
    group.add_argument('--image-transport', choices=('raw', 'compressed', 'compressedDepth'),
                       help='how the camera images arrive' + (
                           ' (default: raw, or compressed when the bag holds only '
                           '<topic>/compressed)' if auto else ' (default raw)'))


def load_graph(args: argparse.Namespace) -> GraphConfig:
    """The graph of --config or --camera (default: the stereo graph) under the camera names
    given; a preset's image transport becomes ``args.image_transport`` unless one was
    given.

    Raises:
        ConfigError: --camera with --config, an unknown preset, or a bad graph.
    """
    if args.camera is not None:
        if args.config is not None:
            raise ConfigError('--camera and --config: give one (a preset names its graph)')
        preset = load_camera(args.camera, default_config_path().parent)
        config = preset.config
        if args.image_transport is None:
            args.image_transport = preset.image_transport
    else:
        config = load_graph_config(args.config or default_config_path())
    return rename_cameras(config, namespace=args.namespace, left=args.left, right=args.right,
                          image=args.image)
