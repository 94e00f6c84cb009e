"""`depth-nodes import-pair`: a real image pair (and its ground truth) as a bag."""

from __future__ import annotations

import argparse
from pathlib import Path

from depth_nodes.tools.bags.pairs import PairSource, import_pair


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `import-pair`."""
    parser.description = (
        'Write a stereo pair, and optionally its ground-truth disparity, into a bag with the '
        'topics of the bundled ones, so `depth-nodes process` runs the graph on it and '
        '`depth-nodes eval` scores the result. A rectified pair gets an identity calibration; '
        'a raw one takes its two camera_info YAML files (--calibration), and its ground truth '
        'must be in the rectified left frame.')
    parser.epilog = ('Example (Middlebury 2003, quarter size): depth-nodes import-pair im2.png '
                     'im6.png teddy_bag --gt disp2.pgm --gt-scale 4 --gt-right disp6.pgm')
    parser.add_argument('left', help='left image (PNG, PPM, PGM, JPEG; 8-bit colour or grey, '
                        '16-bit grey)')
    parser.add_argument('right', help='right image, same size and type')
    parser.add_argument('out_bag', help='bag folder to create')
    parser.add_argument('--gt', help='ground-truth disparity of the left view')
    parser.add_argument('--gt-format', default='auto',
                        choices=('auto', 'scaled', 'kitti', 'pfm'),
                        help='auto (default): pfm by extension, kitti for a 16-bit PNG '
                        'without --gt-scale, scaled otherwise')
    parser.add_argument('--gt-scale', type=float,
                        help='stored value per px of disparity (Middlebury 2003 quarter '
                        'size: 4, 2001: 8; KITTI: 256)')
    parser.add_argument('--gt-right', help='ground truth of the right view, same format: '
                        'derives the non-occlusion mask')
    parser.add_argument('--nonocc', help='non-occlusion mask image (nonzero = visible in both '
                        'views), e.g. Middlebury nonocc.png or KITTI disp_noc')
    parser.add_argument('--calibration', nargs=2, metavar=('LEFT.yaml', 'RIGHT.yaml'),
                        help='camera_info YAML files of a raw (unrectified) pair')
    parser.add_argument('--focal', type=float, default=0.0,
                        help='rectified pair: focal length in px (default: the image width)')
    parser.add_argument('--baseline', type=float, default=0.1,
                        help='rectified pair: baseline in m (default 0.1)')
    parser.add_argument('--namespace', default='/stereo',
                        help='topic namespace (default /stereo)')
    parser.add_argument('--mono', action='store_true', help='store colour images as mono8')
    parser.add_argument('--frames', type=int, default=1,
                        help='write the pair this many times, 0.1 s apart (default 1)')
    parser.add_argument('--force', action='store_true', help='replace an existing OUT_BAG')


def _path(value: str | None) -> Path | None:
    return Path(value) if value else None


def run(args: argparse.Namespace) -> int:
    """Write the bag; print what it holds."""
    source = PairSource(
        left=Path(args.left), right=Path(args.right), ground_truth=_path(args.gt),
        gt_format=args.gt_format, gt_scale=args.gt_scale,
        ground_truth_right=_path(args.gt_right), nonoccluded_mask=_path(args.nonocc),
        calibration=(Path(args.calibration[0]), Path(args.calibration[1]))
        if args.calibration else None,
        focal=args.focal, baseline=args.baseline, namespace=args.namespace, mono=args.mono,
        frames=args.frames)
    summary = import_pair(source, args.out_bag, overwrite=args.force)
    print(summary.format(Path(args.out_bag)))
    return 0
