"""`depth-nodes bench STAGE`: speed figures, always beside OpenCV measured in the same run.

One sub-command per stage, each with its own options and defaults. rectify, sgm,
cross_check, point_cloud, structured_light and tof time the work in this process on
``--threads`` OpenCV and numba threads; soak and live run the stereo graph as processes
over DDS.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NoReturn

import cv2
import numba

from depth_nodes.errors import ArgumentError, ConfigError
from depth_nodes.tools.bench.depth_filter import bench_depth_filter
from depth_nodes.tools.bench.fusion import bench_fusion
from depth_nodes.tools.bench.live import WATCH, bench_live
from depth_nodes.tools.bench.multiview import bench_multiview
from depth_nodes.tools.bench.nodes import bench_cross_check, bench_point_cloud
from depth_nodes.tools.bench.rectify import bench_rectify
from depth_nodes.tools.bench.sgm import bench_sgm
from depth_nodes.tools.bench.soak import soak
from depth_nodes.tools.bench.structured_light import bench_structured_light
from depth_nodes.tools.bench.tof import bench_tof
from depth_nodes.tools.cli.options import BUNDLED_BAGS

#: The aggregation paths the matcher offers.
PATHS = (4, 5, 8, 16)


@dataclass(frozen=True)
class Stage:
    """A bench sub-command: its name, its help, its options, and the run that returns the
    printed report; ``in_process`` stages run on ``--threads`` OpenCV and numba threads."""

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    report: Callable[[argparse.Namespace], str]
    in_process: bool = True


def _in_process_options(parser: argparse.ArgumentParser, *, frames: int,
                        what: str = 'timed rounds (median)') -> None:
    parser.add_argument('--frames', type=int, default=frames,
                        help=f'{what}; default {frames}')
    parser.add_argument('--threads', type=int, default=2,
                        help='OpenCV and numba threads (default 2)')


def _bag_option(parser: argparse.ArgumentParser, bundled: str, what: str) -> None:
    parser.add_argument('--bag', default=str(BUNDLED_BAGS / bundled),
                        help=f'{what} (default: the bundled {bundled})')


def _rectify_arguments(parser: argparse.ArgumentParser) -> None:
    _in_process_options(parser, frames=200, what='timed frames (median)')
    parser.add_argument('--width', type=int, default=640, help='frame width (default 640)')
    parser.add_argument('--height', type=int, default=480, help='frame height (default 480)')
    parser.add_argument('--interpolation', default='linear',
                        help='nearest, linear, cubic, area or lanczos4 (default linear)')


def _rectify(args: argparse.Namespace) -> str:
    return bench_rectify(width=args.width, height=args.height, repeats=args.frames,
                         interpolation=args.interpolation).format()


def _sgm_arguments(parser: argparse.ArgumentParser) -> None:
    _in_process_options(parser, frames=10)
    parser.add_argument('--disparities', type=int, default=128,
                        help='disparity range (default 128)')
    parser.add_argument('--size', default='640x480', metavar='WxH',
                        help='frame size; the bundled pair is resized to it (default 640x480)')
    parser.add_argument('--busy', type=int, default=0, metavar='N',
                        help='also time everything with N busy-loop processes beside it (a '
                        'robot computer\'s other work), and our matcher on one thread '
                        '(default 0)')
    parser.add_argument('--paths', type=int, choices=PATHS, default=8,
                        help='aggregation paths (default 8)')


def _sgm(args: argparse.Namespace) -> str:
    return bench_sgm(repeats=args.frames, disparities=args.disparities, paths=args.paths,
                     size=frame_size(args.size), busy=args.busy).format()


def _multiview_arguments(parser: argparse.ArgumentParser) -> None:
    _in_process_options(parser, frames=10)
    parser.add_argument('--size', default='320x240', metavar='WxH',
                        help='frame size of the simulated views (default 320x240)')
    parser.add_argument('--planes', type=int, default=64, help='planes of the sweep, and '
                        'disparities of the stereo matcher beside it (default 64)')
    parser.add_argument('--sources', type=int, default=4, help='source views (default 4)')
    parser.add_argument('--paths', type=int, choices=PATHS, default=8,
                        help='aggregation paths, of both (default 8, as '
                        'config/multiview_pipeline.yaml)')
    parser.add_argument('--busy', type=int, default=0, metavar='N',
                        help='also time with N busy-loop processes beside it (default 0)')


def _multiview(args: argparse.Namespace) -> str:
    return bench_multiview(size=frame_size(args.size), planes=args.planes,
                           sources=args.sources, paths=args.paths, repeats=args.frames,
                           busy=args.busy).format()


def _node_arguments(parser: argparse.ArgumentParser) -> None:
    _in_process_options(parser, frames=20)


def _structured_light_arguments(parser: argparse.ArgumentParser) -> None:
    _bag_option(parser, 'structured_light_vga', 'the structured-light bag to decode')
    _in_process_options(parser, frames=20, what='timed runs of one sequence (median)')


def _structured_light(args: argparse.Namespace) -> str:
    return bench_structured_light(args.bag, repeats=args.frames).format()


def _tof_arguments(parser: argparse.ArgumentParser) -> None:
    _bag_option(parser, 'tof_vga', 'the ToF bag whose first frame to decode')
    _in_process_options(parser, frames=20, what='timed frames (median)')


def _tof(args: argparse.Namespace) -> str:
    return bench_tof(args.bag, repeats=args.frames, threads=args.threads).format()


def _depth_filter_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--frames', type=int, default=20,
                        help='timed frames (median); default 20')
    parser.add_argument('--size', default='640x480', metavar='WxH',
                        help='frame size of the simulated depth camera (default 640x480)')
    parser.add_argument('--busy', type=int, default=0, metavar='N',
                        help='also time with N busy-loop processes beside it (default 0)')


def _depth_filter(args: argparse.Namespace) -> str:
    return bench_depth_filter(size=frame_size(args.size), repeats=args.frames,
                              busy=args.busy).format()


def _fusion_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--frames', type=int, default=12,
                        help='frames of the circling depth camera (median of all but the '
                        'first); default 12')
    parser.add_argument('--size', default='640x480', metavar='WxH',
                        help='frame size (default 640x480)')
    parser.add_argument('--busy', type=int, default=0, metavar='N',
                        help='time with N busy-loop processes beside it (default 0)')
    parser.add_argument('--no-open3d', action='store_true',
                        help="skip Open3D's VoxelBlockGrid (without the open3d extra it is "
                        'skipped, and the report says so)')


def _fusion(args: argparse.Namespace) -> str:
    if args.frames < 2:
        raise ArgumentError('--frames must be at least 2 (the first is not timed)')
    return bench_fusion(size=frame_size(args.size), frames=args.frames, busy=args.busy,
                        open3d=not args.no_open3d).format()


def _graph_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--rate', type=float, default=10.0,
                        help='frames per second to publish (default 10)')
    parser.add_argument('--composed', action='store_true',
                        help='run each graph composed in one `depth-nodes pipeline` process '
                        'instead of one process per node')


def _soak_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--duration', type=float, default=1800.0,
                        help='seconds to run (default 1800)')
    parser.add_argument('--tune-every', type=float, default=10.0,
                        help='seconds between two changes of P2 (default 10)')
    parser.add_argument('--memory-log', metavar='CSV',
                        help='write every memory sample (seconds, process, MB) here')
    _graph_options(parser)


def _soak(args: argparse.Namespace) -> str:
    return soak(duration=args.duration, rate=args.rate, tune_every=args.tune_every,
                composed=args.composed, memory_log=args.memory_log).format()


def _live_arguments(parser: argparse.ArgumentParser) -> None:
    _graph_options(parser)
    parser.add_argument('--frames', type=int, default=50,
                        help='frames to publish after the warm-up (default 50)')
    parser.add_argument('--threads', type=int, dest='sgm_threads', metavar='THREADS',
                        help='threads of the SGM node (0 = every core; default: as '
                        'config/stereo_pipeline.yaml says)')
    parser.add_argument('--paths', type=int, choices=PATHS,
                        help='aggregation paths of the SGM node (default: as '
                        'config/stereo_pipeline.yaml says); OpenCV then in MODE_SGBM for 4 '
                        'and 5, MODE_HH for 8 and 16')
    parser.add_argument('--no-opencv', action='store_true', help='skip the OpenCV graph')
    _bag_option(parser, 'stereo_vga', 'the bag whose stereo frames to publish')
    parser.add_argument('--watch', choices=WATCH, default='all',
                        help='subscribe to every stage\'s output (all: per-stage latency) or '
                        'to the final output only (points2: end-to-end latency, as a robot '
                        'that reads the point cloud only); default all')


def _live(args: argparse.Namespace) -> str:
    return bench_live(rate=args.rate, count=args.frames, threads=args.sgm_threads,
                      opencv=not args.no_opencv, bag=args.bag, paths=args.paths,
                      composed=args.composed, watch=args.watch).format()


STAGES = {stage.name: stage for stage in (
    Stage('rectify', 'the rectify node beside cv2.remap and cv2.undistort',
          _rectify_arguments, _rectify),
    Stage('sgm', 'the census SGM matcher beside OpenCV MODE_HH and MODE_SGBM',
          _sgm_arguments, _sgm),
    Stage('cross_check', 'the cross-check node beside census SGM on the same pair',
          _node_arguments, lambda args: bench_cross_check(repeats=args.frames).format()),
    Stage('point_cloud', 'the point-cloud node beside census SGM on the same pair',
          _node_arguments, lambda args: bench_point_cloud(repeats=args.frames).format()),
    Stage('multiview', 'the multi-view plane sweep beside the stereo matcher on as many '
          'pixels x labels', _multiview_arguments, _multiview),
    Stage('structured_light', 'decoding one sequence of a structured-light bag, beside '
          'OpenCV GrayCodePattern', _structured_light_arguments, _structured_light),
    Stage('tof', "the tof node and its decoding on a ToF bag's first frame",
          _tof_arguments, _tof),
    Stage('depth_filter', "the depth filter's stages on one core, beside librealsense's "
          'filters on the same frames', _depth_filter_arguments, _depth_filter,
          in_process=False),
    Stage('fusion', 'the TSDF volume at 5 and 2 cm, one and two cores: integration, mesh, '
          "slice and memory, beside Open3D's VoxelBlockGrid on the same frames",
          _fusion_arguments, _fusion, in_process=False),
    Stage('soak', 'the stereo graph fed for --duration s at --rate, P2 changed every '
          '--tune-every s: losses, memory, parameter answers', _soak_arguments, _soak,
          in_process=False),
    Stage('live', 'the stereo pipeline as separate processes over DDS: sustained rate and '
          'per-stage (--watch points2: end-to-end) latency, beside the OpenCV graph',
          _live_arguments, _live,
          in_process=False),
)}


class _MovedToLive(argparse.Action):
    """``bench --live``, which became ``bench live``: an error that says so."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, help=argparse.SUPPRESS)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> NoReturn:
        parser.error('--live is a sub-command now; use: depth-nodes bench live')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The sub-commands of `bench` and their options."""
    parser.add_argument('--live', action=_MovedToLive)
    stages = parser.add_subparsers(dest='stage')
    for stage in STAGES.values():
        stage.add_arguments(stages.add_parser(stage.name, help=stage.help))


def frame_size(text: str) -> tuple[int, int]:
    """``WxH`` as (W, H).

    Raises:
        ConfigError: It is not two integers of at least 16 joined by x.
    """
    parts = text.lower().split('x')
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts) or \
            min(int(p) for p in parts) < 16:
        raise ConfigError(f'--size must be WxH with both at least 16 (e.g. 1280x720), got '
                          f'{text!r}')
    return int(parts[0]), int(parts[1])


def check_arguments(args: argparse.Namespace) -> None:
    """Refuse values no benchmark can run with, in one line each (of the options the
    sub-command has)."""
    given = vars(args)
    if 'frames' in given and args.frames < 1:
        raise ConfigError(f'--frames must be at least 1, got {args.frames}')
    if 'threads' in given and args.threads < 1:
        raise ConfigError(f'--threads must be at least 1, got {args.threads}')
    if given.get('sgm_threads') is not None and args.sgm_threads < 0:
        raise ConfigError(f'--threads must be >= 0 (0: every core), got {args.sgm_threads}')
    if 'width' in given and (args.width < 16 or args.height < 16):
        raise ConfigError(f'--width and --height must be at least 16, got {args.width}x'
                          f'{args.height}')
    if 'disparities' in given:
        width = frame_size(args.size)[0]
        if not 1 <= args.disparities < width:
            raise ConfigError(f'--disparities must be in 1..{width - 1} (the pair is {width} '
                              f'px wide), got {args.disparities}')
    if 'planes' in given:
        width = frame_size(args.size)[0]
        if not 2 <= args.planes < width:
            raise ConfigError(f'--planes must be in 2..{width - 1} (the views are {width} px '
                              f'wide), got {args.planes}')
    if 'sources' in given and not 1 <= args.sources <= 16:
        raise ConfigError(f'--sources must be in 1..16, got {args.sources}')
    if 'busy' in given and args.busy < 0:
        raise ConfigError(f'--busy must be >= 0, got {args.busy}')
    if 'rate' in given and not args.rate > 0:
        raise ConfigError(f'--rate must be positive, got {args.rate}')


def run(args: argparse.Namespace) -> int:
    """Run the stage's benchmark and print its report.

    Raises:
        ConfigError: No stage given, or a value no benchmark can run with.
    """
    if args.stage is None:
        raise ConfigError(f'bench needs a stage ({", ".join(STAGES)})')
    stage = STAGES[args.stage]
    check_arguments(args)
    if stage.in_process:
        os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'OFF')  # nodes run in-process
        cv2.setNumThreads(args.threads)
        numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    print(stage.report(args))
    return 0
