"""`depth-nodes import-views`: real images with known cameras as a bag for the multi-view
node (Middlebury's name_par.txt, or a COLMAP text model)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from depth_nodes.errors import ConfigError
from depth_nodes.tools import signals
from depth_nodes.tools.bags.views import read_colmap, read_middlebury, write_views_bag


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `import-views`."""
    parser.description = (
        'Write images with known cameras into a bag with the multi-view node\'s topics '
        '(image_rect, camera_info, pose and odom under --namespace), so `depth-nodes process '
        '--config config/multiview_pipeline.yaml --namespace /views` runs the node on them '
        'and `depth-nodes eval` scores its depth across the views (and against --bbox).')
    parser.epilog = ('Examples: depth-nodes import-views templeSR_par.txt temple_bag --bbox '
                     '-0.074 0.022 -0.013 0.029 0.182 0.063; depth-nodes import-views '
                     'sparse/0 my_bag --colmap-images images')
    parser.add_argument('cameras', help='a Middlebury name_par.txt, or a COLMAP text model\'s '
                        'folder (cameras.txt, images.txt)')
    parser.add_argument('out_bag', help='bag folder to create')
    parser.add_argument('--colmap-images', metavar='DIR',
                        help='COLMAP: the folder of the images (default: images/ beside the '
                        'model folder\'s parent)')
    parser.add_argument('--bbox', type=float, nargs=6,
                        metavar=('XMIN', 'YMIN', 'ZMIN', 'XMAX', 'YMAX', 'ZMAX'),
                        help='the object\'s bounding box in world coordinates, for eval')
    parser.add_argument('--namespace', default='/views', help='topic namespace (default '
                        '/views)')
    parser.add_argument('--rate', type=float, default=10.0,
                        help='views per second of the bag\'s stamps (default 10)')
    parser.add_argument('--force', action='store_true', help='replace an existing OUT_BAG')


def run(args: argparse.Namespace) -> int:
    """Read the cameras, write the bag, say what was skipped."""
    source = Path(args.cameras)
    if source.is_dir():
        images = Path(args.colmap_images) if args.colmap_images else \
            source.parent.parent / 'images'
        views, missing = read_colmap(source, images)
        kind = 'COLMAP model'
    elif source.suffix == '.txt':
        views, missing = read_middlebury(source)
        kind = 'Middlebury cameras'
    else:
        raise ConfigError(f'{source}: expected a Middlebury name_par.txt or a COLMAP text '
                          'model folder')
    for name in missing:
        print(f'depth-nodes import-views: skipped {name}: listed in {source} but not there',
              file=sys.stderr)
    with signals.graceful():
        count = write_views_bag(views, args.out_bag, namespace=args.namespace, rate=args.rate,
                                bbox=tuple(args.bbox) if args.bbox else None,
                                overwrite=args.force)
    print(f'{args.out_bag}: {len(views)} views from the {kind} {source} ({count} messages)'
          + (f', {len(missing)} listed views not found' if missing else ''))
    return 0
