"""`depth-nodes eval`: accuracy of a processed bag against its ground truth (stereo, or
multi-view depth; real multi-view images without depth truth: consistency across views)."""

from __future__ import annotations

import argparse
import contextlib
from pathlib import Path

from depth_nodes.core.sgm.params import MATCHING_COSTS
from depth_nodes.errors import ArgumentError, BagError, DepthNodesError
from depth_nodes.tools.evaluation.evaluate import evaluate_bag, has_ground_truth
from depth_nodes.tools.evaluation.multiview import (
    evaluate_multiview_bag,
    evaluate_views_bag,
    is_multiview_bag,
    is_views_bag,
)
from depth_nodes.tools.evaluation.previews import bag_previews


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `eval`."""
    parser.add_argument('bag')
    parser.add_argument('--threshold', type=float, default=2.0, help='N of bad-N (default 2)')
    parser.add_argument('--previews', metavar='DIR',
                        help='write PNG previews into DIR: every disparity, depth and '
                        'confidence colour-mapped beside the left image, with a colour bar '
                        '(also for a bag without ground truth, which is then only drawn)')
    parser.add_argument('--preview-frames', type=int, default=10, metavar='N',
                        help='previews of the first N frames (default 10)')
    parser.add_argument('--no-baseline', action='store_true', help='skip OpenCV StereoSGBM')
    parser.add_argument('--matching-costs', default='', metavar='LIST',
                        help='comma-separated matching costs (census, learned, '
                        'census+learned): a row each for the SGM matcher alone with that '
                        'cost, on the same rectified pair as OpenCV')
    parser.add_argument('--grid', action='store_true',
                        help='also print every setting of the 18-setting OpenCV grid')
    parser.add_argument('--skip', type=int, default=10, metavar='N',
                        help='multi-view: summarise from the N-th frame with depth on, once '
                        'the depth filter has had N frames (default 10: about five '
                        'keyframes of the simulated sequences)')
    parser.add_argument('--object-threshold', type=float, default=20.0, metavar='GREY',
                        help='imported views: pixels brighter than this are the object, '
                        'for its coverage (default 20)')


def run(args: argparse.Namespace) -> int:
    """Score the bag (or only draw it); a previews folder made here goes on failure."""
    if args.previews and not Path(args.previews).exists():  # made here: gone on failure
        try:
            return _evaluate(args)
        except DepthNodesError:
            with contextlib.suppress(OSError):
                Path(args.previews).rmdir()  # only when it is still empty
            raise
    return _evaluate(args)


def _matching_costs(text: str) -> tuple[str, ...]:
    costs = tuple(c.strip() for c in text.split(',') if c.strip())
    for cost in costs:
        if cost not in MATCHING_COSTS:
            raise ArgumentError(f'--matching-costs: {cost!r} is not one of '
                                f'{", ".join(MATCHING_COSTS)}')
    return costs


def _evaluate(args: argparse.Namespace) -> int:
    if args.skip < 0:
        raise BagError(f'--skip must be >= 0, got {args.skip}')
    costs = _matching_costs(args.matching_costs)
    if is_multiview_bag(args.bag):
        print(evaluate_multiview_bag(args.bag, skip=args.skip).format())
        return 0
    if is_views_bag(args.bag):
        print(evaluate_views_bag(args.bag, object_threshold=args.object_threshold).format())
        return 0
    if not has_ground_truth(args.bag):
        if not args.previews:
            raise BagError(f'{args.bag} has no ground truth (…/left/disparity_gt) to score '
                           'against; --previews DIR draws its disparity, depth and '
                           'confidence instead')
        written = bag_previews(args.bag, args.previews, max_frames=args.preview_frames)
        print(f'{args.bag}: no ground truth, nothing scored; {len(written)} previews '
              f'written to {args.previews}')
        return 0
    report = evaluate_bag(args.bag, threshold=args.threshold, baselines=not args.no_baseline,
                          previews=args.previews, preview_frames=args.preview_frames,
                          matching_costs=costs)
    if not report.rows:
        raise BagError(f'nothing to score in {args.bag}: no disparity besides the ground '
                       'truth, and --no-baseline')
    print(report.format(grid=args.grid))
    if args.previews:
        print(f'previews written to {args.previews}')
    return 0
