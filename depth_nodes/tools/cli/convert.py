"""`depth-nodes convert`: rewrite a bag as a camera driver records it."""

from __future__ import annotations

import argparse
import sys

from depth_nodes.errors import ConfigError
from depth_nodes.tools import signals
from depth_nodes.tools.bags.convert import ConvertOptions, convert_bag


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `convert`."""
    parser.description = (
        'Copy a bag, turning its raw camera images (sensor_msgs/Image topics ending in '
        '/image_raw) into what a driver records: a Bayer mosaic (--bayer), image_transport\'s '
        'compressed topics (--compress), under another namespace (--namespace). Every other '
        'message is copied, ground truth included, so process and eval show what the '
        'compression costs.')
    parser.epilog = ('Example: depth-nodes convert bags/stereo_vga out/vga_jpeg --compress '
                     'jpeg --quality 80 --namespace /camera')
    parser.add_argument('in_bag')
    parser.add_argument('out_bag')
    parser.add_argument('--compress', choices=('jpeg', 'png'),
                        help='store the images as <topic>/compressed (CompressedImage)')
    parser.add_argument('--quality', type=int, default=90,
                        help='JPEG quality 1..100 (default 90)')
    parser.add_argument('--bayer', choices=('rggb', 'bggr', 'gbrg', 'grbg'),
                        help='sample colour images on this Bayer tile (bayer_<order>8)')
    parser.add_argument('--namespace', help='replace the first namespace of every topic')
    parser.add_argument('--rename', action='append', default=[], metavar='OLD=NEW',
                        help='rename a topic level below the namespace, e.g. left=infra1 or '
                        'image_raw=image_rect_raw (a driver\'s layout; repeat for more)')
    parser.add_argument('--force', action='store_true', help='replace an existing OUT_BAG')


def run(args: argparse.Namespace) -> int:
    """Convert the bag; print the message count of every topic written."""
    renames = []
    for pair in args.rename:
        old, sep, new = pair.partition('=')
        if not sep or not old or not new:
            raise ConfigError(f'--rename {pair}: expected OLD=NEW, e.g. left=infra1')
        renames.append((old, new))
    options = ConvertOptions(namespace=args.namespace, codec=args.compress,
                             quality=args.quality, bayer=args.bayer, rename=tuple(renames))
    with signals.graceful():
        counts = convert_bag(args.in_bag, args.out_bag, options, overwrite=args.force)
    print(f'{args.in_bag} -> {args.out_bag}')
    for topic, count in sorted(counts.items()):
        print(f'  {topic:<48} {count:>6}')
    if signals.stop_requested():
        print(f'depth-nodes convert: interrupted; {args.out_bag} holds the messages written '
              'before the signal', file=sys.stderr)
    return 0
