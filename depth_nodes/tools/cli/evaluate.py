"""`depth-nodes eval`: accuracy of a processed bag against its ground truth, by the scorer
the bag's kind needs (told from what it holds: depth_nodes.tools.evaluation.kinds).

Stereo (beside OpenCV's StereoSGBM), structured light (beside OpenCV's GrayCodePattern),
time of flight, the depth filter (beside librealsense's filters, stage by stage), multi-view
depth, and real multi-view images without depth truth (consistency across views). A bag of
no kind is drawn with ``--previews`` and refused without. `eval-sl`, `eval-tof` and
`eval-depth-filter` are this command with the kind given (:func:`run_kind`).

Each option applies to some kinds (:data:`OPTIONS`); one given for a bag of another kind
is an error that names the bag's kind.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from depth_nodes.core.sgm.params import MATCHING_COSTS
from depth_nodes.errors import ArgumentError, BagError, DepthNodesError
from depth_nodes.tools import signals
from depth_nodes.tools.evaluation.depth_filter_stages import compare, read_sequence
from depth_nodes.tools.evaluation.evaluate import evaluate_bag
from depth_nodes.tools.evaluation.fusion import evaluate_fusion_bag
from depth_nodes.tools.evaluation.kinds import (
    DEPTH_FILTER,
    FUSION,
    KINDS,
    MULTIVIEW,
    STEREO,
    STRUCTURED_LIGHT,
    TOF,
    VIEWS,
    Kind,
    bag_kind,
    looked_for,
)
from depth_nodes.tools.evaluation.multiview import evaluate_multiview_bag, evaluate_views_bag
from depth_nodes.tools.evaluation.previews import bag_previews, previews_folder
from depth_nodes.tools.evaluation.structured_light import evaluate_structured_light_bag
from depth_nodes.tools.evaluation.tof import evaluate_tof_bag


@dataclass(frozen=True)
class Option:
    """An option of `eval` and the kinds of bag it applies to.

    Attributes:
        flags: Its flags (the first long one names it).
        defaults: Its default for each kind it applies to.
        help: Its help: one text, or one per kind (the alias of a kind shows its own).
        kwargs: argparse's other arguments (``type``, ``metavar``, ``action``).
    """

    flags: tuple[str, ...]
    defaults: dict[Kind, Any]
    help: str | dict[Kind, str]
    kwargs: dict[str, Any] = field(default_factory=dict)

    @property
    def dest(self) -> str:
        """Its attribute in the parsed arguments."""
        return self.flags[0].lstrip('-').replace('-', '_')

    def help_for(self, kind: Kind | None) -> str:
        """Its help in ``kind``'s alias, or in `eval` (None: saying which kinds it is for)."""
        if isinstance(self.help, dict):
            if kind is not None:
                return self.help[kind]
            return '; '.join(f'{k.name}: {text}' for k, text in self.help.items())
        if kind is not None or len(self.defaults) == len(KINDS):
            return self.help
        return f'{", ".join(k.name for k in self.defaults)}: {self.help}'


#: Frames drawn by --previews unless --preview-frames says.
PREVIEW_FRAMES = 10


def _every_kind(value: Any) -> dict[Kind, Any]:
    return dict.fromkeys(KINDS, value)


#: Every option of `eval`, in the order --help lists them.
OPTIONS = (
    Option(('--previews',), _every_kind(None),
           'write PNG previews into DIR: every disparity, depth and confidence colour-mapped '
           'beside the left image, with a colour bar (also for a bag without ground truth, '
           'which is then only drawn)', {'metavar': 'DIR'}),
    Option(('--preview-frames',), _every_kind(PREVIEW_FRAMES), 'previews of the first N '
           f'frames (default {PREVIEW_FRAMES})', {'type': int, 'metavar': 'N'}),
    Option(('--threshold',), {STEREO: 2.0}, 'N of bad-N (default 2)',
           {'type': float, 'metavar': 'N'}),
    Option(('--no-baseline',), {STEREO: False}, 'skip OpenCV StereoSGBM',
           {'action': 'store_true'}),
    Option(('--matching-costs',), {STEREO: ''},
           'comma-separated matching costs (census, learned, census+learned): a row each for '
           'the SGM matcher alone with that cost, on the same rectified pair as OpenCV',
           {'metavar': 'LIST'}),
    Option(('--grid',), {STEREO: False}, 'also print every setting of the 18-setting OpenCV '
           'grid', {'action': 'store_true'}),
    Option(('--no-opencv',), {STRUCTURED_LIGHT: False}, 'skip OpenCV (its per-pixel API is '
           'slow)', {'action': 'store_true'}),
    Option(('--depth-topic',), {TOF: '/tof/depth/image_rect'},
           'the depth to score (default /tof/depth/image_rect)', {'metavar': 'TOPIC'}),
    Option(('--librealsense',), {DEPTH_FILTER: False},
           "run librealsense's own filters on the same frames, stage by stage (needs the "
           'realsense extra: pip install .[realsense])', {'action': 'store_true'}),
    Option(('--skip',), {MULTIVIEW: 10, DEPTH_FILTER: 3}, {
        MULTIVIEW: 'summarise from the N-th frame with depth on, once the depth filter has '
                   'had N frames (default 10: about five keyframes of the simulated '
                   'sequences)',
        DEPTH_FILTER: 'score from frame N, once the temporal stage has a past (default 3)'},
           {'type': int, 'metavar': 'N'}),
    Option(('--persistence',), {DEPTH_FILTER: 3}, "trails: frames an uncovered pixel may keep "
           "the object's depth (the temporal persistence; default 3)",
           {'type': int, 'metavar': 'N'}),
    Option(('--object-threshold',), {VIEWS: 20.0}, 'pixels brighter than this are the object, '
           'for its coverage (default 20)', {'type': float, 'metavar': 'GREY'}),
    Option(('--voxel-size',), {FUSION: 0.02}, "the voxel size tsdf_fusion ran with, metres "
           "(default 0.02, config/fusion_pipeline.yaml's): the unit of the errors, and "
           "Open3D's", {'type': float, 'metavar': 'M'}),
    Option(('--truncation',), {FUSION: 4.0}, 'its truncation_distance, voxels (default 4), '
           "for Open3D's", {'type': float, 'metavar': 'VOXELS'}),
    Option(('--max-depth',), {FUSION: 5.0}, 'its max_integration_distance, metres (default 5), '
           "for Open3D's and the surface completeness counts", {'type': float, 'metavar': 'M'}),
    Option(('--open3d',), {FUSION: False}, "also fuse the same depth at the true poses with "
           "Open3D's VoxelBlockGrid and score its mesh the same way (the open3d extra: pip "
           "install .[open3d])", {'action': 'store_true'}),
    Option(('--fused-depth',), {FUSION: None}, 'the depth topic tsdf_fusion fused (default: '
           '/camera/filtered/image_rect, /stereo/depth or /camera/depth/image_rect_raw, the '
           'first the bag has)', {'metavar': 'TOPIC'}),
)


def add_options(parser: argparse.ArgumentParser, kind: Kind | None) -> None:
    """The bag and the options of `eval` (``kind`` None: every option, its default settled
    once the bag's kind is known) or of the alias of ``kind`` (its options and defaults)."""
    parser.add_argument('bag', help='a bag with ground truth: generated (depth-nodes '
                        'generate), imported (import-pair, import-views) or one processed '
                        'from it')
    for option in OPTIONS:
        if kind is None or kind in option.defaults:
            default = None if kind is None else option.defaults[kind]
            parser.add_argument(*option.flags, default=default, help=option.help_for(kind),
                                **option.kwargs)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `eval`."""
    parser.description = (
        'Score a bag against its ground truth with the scorer its kind needs, told by its '
        'metadata (a generated or imported bag, and one processed from it) or its stereo '
        f'ground truth: {", ".join(kind.name for kind in KINDS)}. An option applies to the '
        'kinds its help names (none named: to every kind).')
    add_options(parser, None)


def run(args: argparse.Namespace) -> int:
    """Score the bag by its kind (or only draw a bag of no kind)."""
    return _keeping_previews_tidy(args, lambda: _run(args))


def run_kind(kind: Kind, args: argparse.Namespace) -> int:
    """Score the bag as ``kind`` (an alias: `eval-sl`, `eval-tof`, `eval-depth-filter`)."""
    return _keeping_previews_tidy(args, lambda: _score(kind, args))


def _keeping_previews_tidy(args: argparse.Namespace, score: Callable[[], int]) -> int:
    """``score()``; a previews folder it made goes again when it fails (if still empty)."""
    folder = getattr(args, 'previews', None)
    if folder and not Path(folder).exists():
        try:
            return score()
        except DepthNodesError:
            with contextlib.suppress(OSError):
                Path(folder).rmdir()
            raise
    return score()


def _run(args: argparse.Namespace) -> int:
    kind = bag_kind(args.bag)
    if kind is None:
        return _draw_only(args)
    for option in OPTIONS:
        value = getattr(args, option.dest)
        if kind in option.defaults:
            if value is None:
                setattr(args, option.dest, option.defaults[kind])
        elif value is not None:
            *others, last = [k.name for k in option.defaults]
            names = f'{", ".join(others)} and {last}' if others else last
            raise ArgumentError(f'{option.flags[0]} does not apply to {args.bag}, {kind.what} '
                                f'(it applies to {names} bags)')
    return _score(kind, args)


def _draw_only(args: argparse.Namespace) -> int:
    """A bag of no kind: its maps drawn when ``--previews`` asks, else an error."""
    if not args.previews:
        raise BagError(f'{args.bag} has no ground truth to score against: cannot tell its '
                       f'kind (looked for {looked_for()}); --previews DIR draws its '
                       'disparity, depth and confidence instead')
    for option in OPTIONS:
        if len(option.defaults) < len(KINDS) and getattr(args, option.dest) is not None:
            raise ArgumentError(f'{option.flags[0]} does not apply to {args.bag}: it has no '
                                'ground truth to score, and is only drawn')
    frames = PREVIEW_FRAMES if args.preview_frames is None else args.preview_frames
    written = bag_previews(args.bag, args.previews, max_frames=frames)
    print(f'{args.bag}: no ground truth, nothing scored; {len(written)} previews written to '
          f'{args.previews}')
    return 0


def _score(kind: Kind, args: argparse.Namespace) -> int:
    """Print ``kind``'s report of the bag, then its previews when asked for; the exit
    status."""
    if kind is STEREO:
        return _stereo(args)  # its previews show the errors too
    if args.previews:
        previews_folder(Path(args.previews))  # a folder that cannot be: before the scoring
    status = SCORERS[kind](args)
    if args.previews and status == 0:
        written = bag_previews(args.bag, args.previews, max_frames=args.preview_frames)
        print(f'{len(written)} previews written to {args.previews}')
    return status


def _matching_costs(text: str) -> tuple[str, ...]:
    costs = tuple(c.strip() for c in text.split(',') if c.strip())
    for cost in costs:
        if cost not in MATCHING_COSTS:
            raise ArgumentError(f'--matching-costs: {cost!r} is not one of '
                                f'{", ".join(MATCHING_COSTS)}')
    return costs


def _stereo(args: argparse.Namespace) -> int:
    report = evaluate_bag(args.bag, threshold=args.threshold, baselines=not args.no_baseline,
                          previews=args.previews, preview_frames=args.preview_frames,
                          matching_costs=_matching_costs(args.matching_costs))
    if not report.rows:
        raise BagError(f'nothing to score in {args.bag}: no disparity besides the ground '
                       'truth, and --no-baseline')
    print(report.format(grid=args.grid))
    if args.previews:
        print(f'previews written to {args.previews}')
    return 0


def _multiview(args: argparse.Namespace) -> int:
    if args.skip < 0:
        raise BagError(f'--skip must be >= 0, got {args.skip}')
    print(evaluate_multiview_bag(args.bag, skip=args.skip).format())
    return 0


def _views(args: argparse.Namespace) -> int:
    print(evaluate_views_bag(args.bag, object_threshold=args.object_threshold).format())
    return 0


def _structured_light(args: argparse.Namespace) -> int:
    print(evaluate_structured_light_bag(args.bag, opencv=not args.no_opencv).format())
    return 0


def _tof(args: argparse.Namespace) -> int:
    print(evaluate_tof_bag(args.bag, depth_topic=args.depth_topic).format())
    return 0


def _depth_filter(args: argparse.Namespace) -> int:
    """The tables, stage by stage (a signal stops between stages)."""
    if args.skip < 0 or args.persistence < 0:
        raise BagError('--skip and --persistence must be >= 0')
    seq = read_sequence(args.bag)
    if args.skip >= len(seq.depth):
        raise BagError(f'--skip {args.skip}: the bag has {len(seq.depth)} frames')
    with signals.graceful():
        def progress(name: str) -> None:
            if signals.stop_requested():
                raise KeyboardInterrupt
            print(f'  {name} ...', file=sys.stderr)

        try:
            print(compare(seq, librealsense=args.librealsense, skip=args.skip,
                          persistence=args.persistence, on_stage=progress))
        except KeyboardInterrupt:
            print(f'depth-nodes {args.command}: interrupted', file=sys.stderr)
            return 130
    return 0


def _fusion(args: argparse.Namespace) -> int:
    if not args.voxel_size > 0 or not args.truncation > 0:
        raise ArgumentError('--voxel-size and --truncation must be positive')
    report = evaluate_fusion_bag(args.bag, voxel=args.voxel_size, truncation=args.truncation,
                                 max_depth=args.max_depth, open3d=args.open3d,
                                 depth_topic=args.fused_depth,
                                 on_stage=lambda name: print(f'  {name} ...', file=sys.stderr))
    print(report.format())
    return 0


#: The scorer of each kind but stereo, which draws its own previews.
SCORERS: dict[Kind, Callable[[argparse.Namespace], int]] = {
    MULTIVIEW: _multiview, VIEWS: _views, STRUCTURED_LIGHT: _structured_light, TOF: _tof,
    DEPTH_FILTER: _depth_filter, FUSION: _fusion}
