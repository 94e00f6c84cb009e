"""The `depth-nodes` command.

Subcommands: ``generate`` (synthetic bags), ``convert`` (a bag as a camera driver records
it), ``process`` (run nodes over a bag offline),
``pipeline`` (the nodes of a graph live, in one process), ``param`` (a running node's
parameters), ``play`` / ``record`` (bags into and out of a live graph), ``eval``
(accuracy against the ground truth in a bag), ``bench`` (speed beside OpenCV). A user error
prints one line and exits non-zero; never a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from depth_nodes.errors import BagError, ConfigError, DepthNodesError
from depth_nodes.tools import signals

if TYPE_CHECKING:
    from depth_nodes.graph.description import GraphConfig

EXIT_ERROR = 1
#: The bags committed with the package (a source checkout).
BUNDLED_BAGS = Path(__file__).resolve().parents[2] / 'bags'


def _cmd_generate(args: argparse.Namespace) -> int:
    with signals.graceful():
        return _generate(args)


def _frame_done(count: int, index: int) -> None:
    """Progress of `generate` on stderr."""
    print(f'  frame {index + 1}/{count}', file=sys.stderr)


def _generate(args: argparse.Namespace) -> int:
    from depth_nodes.tools.bags import structured_light as sl
    from depth_nodes.tools.bags import tof
    from depth_nodes.tools.bags.generate import PRESETS, preset, write_stereo_bag

    known = [*PRESETS, *sl.PRESETS, *tof.PRESETS]
    if args.preset == 'bad_inputs':
        from depth_nodes.tools.evaluation.campaign import write_bad_input_bag

        source = args.source or BUNDLED_BAGS / 'stereo_vga'
        campaign = write_bad_input_bag(args.out, source, overwrite=args.force)
        print(f'{args.out}: bad_inputs from {source}: {len(campaign.good)} good frames, '
              f'{len(campaign.cases)} hostile cases')
        return 0
    if args.preset != 'all' and args.preset not in known:
        raise ConfigError(f'unknown preset {args.preset!r} (presets: {", ".join(known)}, '
                          'bad_inputs, all)')
    names = known if args.preset == 'all' else [args.preset]
    out = Path(args.out)
    for name in names:
        path = out / name if args.preset == 'all' else out
        if name in tof.PRESETS:
            tof_config = tof.PRESETS[name]
            if args.seed is not None:
                tof_config = dataclasses.replace(tof_config, seed=args.seed)
            if args.frames is not None:
                tof_config = dataclasses.replace(tof_config, n_frames=args.frames)
            count = tof.write_tof_bag(path, tof_config, overwrite=args.force)
            size = sum(f.stat().st_size for f in path.iterdir()) / 1e6
            frames = (f'{tof_config.n_frames} frames' if not signals.stop_requested() else
                      'frames up to the signal')
            print(f'{path}: {name}, {tof_config.width}x{tof_config.height}, {frames} of '
                  f'{len(tof_config.frequencies_mhz)} x {tof_config.phase_steps} correlation '
                  f'planes, {count} messages, {size:.1f} MB')
            if signals.stop_requested():
                break
            continue
        if name in sl.PRESETS:
            sl_config = sl.PRESETS[name]
            if args.seed is not None:
                sl_config = dataclasses.replace(
                    sl_config, sim=dataclasses.replace(sl_config.sim, seed=args.seed))
            if args.frames is not None:
                sl_config = dataclasses.replace(sl_config, sequences=args.frames)
            count = sl.write_structured_light_bag(path, sl_config, overwrite=args.force)
            size = sum(f.stat().st_size for f in path.iterdir()) / 1e6
            print(f'{path}: {name}, {sl_config.sim.width}x{sl_config.sim.height}, '
                  f'{sl_config.sequences} sequence(s) of {sl_config.pattern_set.count} frames '
                  f'+ {sl_config.speckle_frames} speckle, {count} messages, {size:.1f} MB')
            if signals.stop_requested():
                break
            continue
        config = preset(name)
        if args.seed is not None:
            config = dataclasses.replace(config, seed=args.seed)
        if args.frames is not None:
            config = dataclasses.replace(config, n_frames=args.frames)
        count = write_stereo_bag(
            path, config, overwrite=args.force,
            on_frame=functools.partial(_frame_done, config.n_frames),
        )
        size = sum(f.stat().st_size for f in path.iterdir()) / 1e6
        frames = (f'{config.n_frames} frames' if not signals.stop_requested() else
                  'frames up to the signal')
        print(f'{path}: {name}, {config.width}x{config.height}, {frames}, '
              f'{count} messages, {size:.1f} MB')
        if signals.stop_requested():
            break
    if signals.stop_requested():
        print('depth-nodes generate: interrupted; the last bag holds the frames written '
              'before the signal (its metadata says how many)', file=sys.stderr)
    return 0


def _cmd_process(args: argparse.Namespace) -> int:
    # Offline processing needs no network: keep DDS discovery off unless told otherwise.
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'OFF')
    from depth_nodes.graph.description import load_graph_config
    from depth_nodes.tools.bags.process import default_config_path, process_bag, select_nodes

    if args.workers < 1:
        raise ConfigError(f'--workers must be at least 1, got {args.workers}')
    config = _renamed(load_graph_config(args.config or default_config_path()), args)
    config = select_nodes(config, args.nodes)
    _warn_unmatched(config, args.params)
    with signals.graceful():
        report = process_bag(args.in_bag, args.out_bag, config=config,
                             params_file=args.params, overwrite=args.force,
                             progress=sys.stderr, image_transport=args.image_transport,
                             workers=args.workers, ray=args.ray or bool(args.ray_address),
                             ray_address=args.ray_address)
    print(f'{args.in_bag} -> {args.out_bag} (graph {config.name})')
    print(report.format())
    print(report.summary())
    if report.interrupted:
        print(f'depth-nodes process: interrupted after {report.done} of {report.total} '
              f'messages; {args.out_bag} holds what was done', file=sys.stderr)
    elif not report.published:
        raise BagError(f'{report.nothing_published()}; {args.out_bag} was removed')
    return 0


def _warn_unmatched(config: GraphConfig, params_file: str | None) -> None:
    """Say at once which entries of the parameter file address no node of the graph."""
    from depth_nodes.graph.description import load_params_file, unmatched_entries, unmatched_warning

    if params_file:
        for key in unmatched_entries(config, load_params_file(params_file)):
            print(f'depth-nodes process: warning: {unmatched_warning(config, key)}',
                  file=sys.stderr)


def _renamed(config: GraphConfig, args: argparse.Namespace) -> GraphConfig:
    """The graph under the camera names given on the command line."""
    from depth_nodes.graph.description import rename_cameras

    return rename_cameras(config, namespace=args.namespace, left=args.left, right=args.right,
                          image=args.image)


def _camera_options(parser: argparse.ArgumentParser, *, auto: bool) -> None:
    """--namespace, --left, --right, --image, --image-transport: a camera driver's names."""
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


def _cmd_convert(args: argparse.Namespace) -> int:
    from depth_nodes.tools.bags.convert import ConvertOptions, convert_bag

    options = ConvertOptions(namespace=args.namespace, codec=args.compress,
                             quality=args.quality, bayer=args.bayer)
    with signals.graceful():
        counts = convert_bag(args.in_bag, args.out_bag, options, overwrite=args.force)
    print(f'{args.in_bag} -> {args.out_bag}')
    for topic, count in sorted(counts.items()):
        print(f'  {topic:<48} {count:>6}')
    if signals.stop_requested():
        print(f'depth-nodes convert: interrupted; {args.out_bag} holds the messages written '
              'before the signal', file=sys.stderr)
    return 0


def _cmd_import_pair(args: argparse.Namespace) -> int:
    from depth_nodes.tools.bags.pairs import PairSource, import_pair

    def path(value: str | None) -> Path | None:
        return Path(value) if value else None

    source = PairSource(
        left=Path(args.left), right=Path(args.right), ground_truth=path(args.gt),
        gt_format=args.gt_format, gt_scale=args.gt_scale,
        ground_truth_right=path(args.gt_right), nonoccluded_mask=path(args.nonocc),
        calibration=(Path(args.calibration[0]), Path(args.calibration[1]))
        if args.calibration else None,
        focal=args.focal, baseline=args.baseline, namespace=args.namespace, mono=args.mono,
        frames=args.frames)
    summary = import_pair(source, args.out_bag, overwrite=args.force)
    print(summary.format(Path(args.out_bag)))
    return 0


def _cmd_pipeline(args: argparse.Namespace) -> int:
    from depth_nodes.graph.description import load_graph_config
    from depth_nodes.tools.bags.process import default_config_path
    from depth_nodes.tools.live.pipeline import run_pipeline

    config = _renamed(load_graph_config(args.config or default_config_path()), args)
    return run_pipeline(config, params_file=args.params, threads=args.threads,
                        ros_args=args.ros_args, log=sys.stdout,
                        image_transport=args.image_transport)


def _cmd_play(args: argparse.Namespace) -> int:
    from depth_nodes.tools.bags.live import PlayOptions, play_bag

    remap = {}
    for rule in args.remap or []:
        source, sep, target = rule.partition(':=')
        if not sep or not source or not target:
            raise ConfigError(f'--remap {rule!r}: expected FROM:=TO')
        remap[source] = target
    options = PlayOptions(rate=args.rate, loop=args.loop, clock=args.clock, topics=args.topics,
                          wait_for_subscribers=args.wait_for_subscribers, delay=args.delay,
                          linger=args.linger, restamp=not args.keep_stamps, remap=remap)
    with signals.graceful():
        count = play_bag(args.bag, options, log=sys.stdout)
    print(f'played {count} messages')
    return 0


def _cmd_record(args: argparse.Namespace) -> int:
    from depth_nodes.tools.bags.io import remove_bag
    from depth_nodes.tools.bags.live import record_bag

    with signals.graceful():
        count = record_bag(args.out_bag, args.topics, duration=args.duration,
                           max_messages=args.max_messages, overwrite=args.force,
                           log=sys.stdout)
    if count == 0:
        remove_bag(args.out_bag)
        raise BagError(f'nothing was recorded (no message on {", ".join(args.topics)}); '
                       f'{args.out_bag} was removed')
    print(f'recorded {count} messages to {args.out_bag}')
    return 0


def _cmd_param(args: argparse.Namespace) -> int:
    from depth_nodes.tools.live import param

    if args.verb == 'list' and args.node is None:
        for node, names in param.list_all_parameters(timeout=args.timeout).items():
            print(f'{node}:')
            if names is None:
                print(f'  (no answer within {args.timeout:g} s)')
                continue
            print('\n'.join(f'  {name}' for name in names) or '  (no parameter services)')
    elif args.verb == 'list':
        print('\n'.join(param.list_parameters(args.node, timeout=args.timeout)))
    elif args.verb == 'get':
        value = param.get_parameter(args.node, args.name, timeout=args.timeout)
        print(param.format_value(value))
    elif args.verb == 'set':
        param.set_parameter(args.node, args.name, args.value, timeout=args.timeout)
        print('Set parameter successful')
    elif args.verb == 'describe':
        print(param.describe_parameter(args.node, args.name, timeout=args.timeout))
    elif args.verb == 'dump':
        print(param.dump_parameters(args.node, timeout=args.timeout), end='')
    return 0


def _cmd_node(args: argparse.Namespace) -> int:
    from depth_nodes.tools.live.introspect import list_nodes

    print('\n'.join(list_nodes(wait=args.wait)))
    return 0


def _cmd_topic(args: argparse.Namespace) -> int:
    from depth_nodes.tools.live import introspect

    with signals.graceful():
        if args.verb == 'list':
            for name, types in introspect.list_topics(wait=args.wait):
                print(f'{name} [{", ".join(types)}]' if args.show_types else name)
        elif args.verb == 'echo':
            introspect.echo(args.topic, count=1 if args.once else args.count,
                            timeout=args.timeout)
        else:
            introspect.measure(args.topic, args.verb, window=args.window,
                               timeout=args.timeout)
    return 0


def _cmd_diag(args: argparse.Namespace) -> int:
    from depth_nodes.tools.live.introspect import diagnostics_view

    clear = None
    if sys.stdout.isatty() and not args.once:
        def clear() -> None:
            sys.stdout.write('\x1b[H\x1b[2J')
    with signals.graceful():
        diagnostics_view(period=args.period, once=args.once, timeout=args.timeout,
                         clear=clear)
    return 0


def _cmd_eval(args: argparse.Namespace) -> int:
    if args.previews and not Path(args.previews).exists():  # made here: gone on failure
        try:
            return _eval(args)
        except DepthNodesError:
            with contextlib.suppress(OSError):
                Path(args.previews).rmdir()  # only when it is still empty
            raise
    return _eval(args)


def _eval(args: argparse.Namespace) -> int:
    from depth_nodes.tools.evaluation.evaluate import evaluate_bag, has_ground_truth
    from depth_nodes.tools.evaluation.previews import bag_previews

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
                          previews=args.previews, preview_frames=args.preview_frames)
    if not report.rows:
        raise BagError(f'nothing to score in {args.bag}: no disparity besides the ground '
                       'truth, and --no-baseline')
    print(report.format(grid=args.grid))
    if args.previews:
        print(f'previews written to {args.previews}')
    return 0


def _cmd_eval_sl(args: argparse.Namespace) -> int:
    from depth_nodes.tools.evaluation.structured_light import evaluate_structured_light_bag

    print(evaluate_structured_light_bag(args.bag, opencv=not args.no_opencv).format())
    return 0


def _cmd_eval_tof(args: argparse.Namespace) -> int:
    from depth_nodes.tools.evaluation.tof import evaluate_tof_bag

    print(evaluate_tof_bag(args.bag, depth_topic=args.depth_topic).format())
    return 0


def _check_bench_args(args: argparse.Namespace) -> None:
    """Refuse values no benchmark can run with, in one line each."""
    if args.frames is not None and args.frames < 1:
        raise ConfigError(f'--frames must be at least 1, got {args.frames}')
    if args.threads is not None and args.threads < 0:
        raise ConfigError(f'--threads must be >= 0 (0: every core), got {args.threads}')
    if args.width < 16 or args.height < 16:
        raise ConfigError(f'--width and --height must be at least 16, got {args.width}x'
                          f'{args.height}')
    width = _size(args.size)[0]
    if not 1 <= args.disparities < width:
        raise ConfigError(f'--disparities must be in 1..{width - 1} (the pair is {width} px '
                          f'wide), got {args.disparities}')
    if args.busy < 0:
        raise ConfigError(f'--busy must be >= 0, got {args.busy}')
    if not args.rate > 0:
        raise ConfigError(f'--rate must be positive, got {args.rate}')


def _size(text: str) -> tuple[int, int]:
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


def _cmd_bench(args: argparse.Namespace) -> int:
    if args.live:
        _check_bench_args(args)
        from depth_nodes.tools.bench.live import bench_live

        print(bench_live(rate=args.rate, count=args.frames or 50, threads=args.threads,
                         opencv=not args.no_opencv, bag=args.bag, paths=args.paths,
                         composed=args.composed).format())
        return 0
    if args.stage is None:
        raise ConfigError('bench needs a stage (rectify, sgm, cross_check, point_cloud, '
                          'structured_light, tof, soak) or --live')
    _check_bench_args(args)
    if args.stage == 'soak':
        from depth_nodes.tools.bench.soak import soak

        print(soak(duration=args.duration, rate=args.rate, tune_every=args.tune_every,
                   composed=args.composed, memory_log=args.memory_log).format())
        return 0
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'OFF')  # nodes run in-process
    import cv2

    from depth_nodes.tools.bench.rectify import bench_rectify
    from depth_nodes.tools.bench.sgm import bench_sgm

    threads = 2 if args.threads is None else args.threads
    cv2.setNumThreads(threads)
    import numba

    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    if args.stage == 'rectify':
        print(bench_rectify(width=args.width, height=args.height, repeats=args.frames or 200,
                            interpolation=args.interpolation).format())
    elif args.stage == 'sgm':
        print(bench_sgm(repeats=args.frames or 10, disparities=args.disparities,
                        paths=args.paths or 8, size=_size(args.size),
                        busy=args.busy).format())
    elif args.stage == 'cross_check':
        from depth_nodes.tools.bench.nodes import bench_cross_check

        print(bench_cross_check(repeats=args.frames or 20).format())
    elif args.stage == 'point_cloud':
        from depth_nodes.tools.bench.nodes import bench_point_cloud

        print(bench_point_cloud(repeats=args.frames or 20).format())
    elif args.stage == 'tof':
        from depth_nodes.tools.bench.tof import bench_tof

        bag = args.bag or str(BUNDLED_BAGS / 'tof_vga')
        print(bench_tof(bag, repeats=args.frames or 20, threads=threads).format())
    elif args.stage == 'structured_light':
        from depth_nodes.tools.bench.structured_light import bench_structured_light

        bag = args.bag or str(BUNDLED_BAGS / 'structured_light_vga')
        print(bench_structured_light(bag, repeats=args.frames or 20).format())
    return 0


class _Parser(argparse.ArgumentParser):
    """argparse with the command's error convention: one line on stderr, status 1 (its
    own prints the usage too and exits 2). ``--help`` still prints the usage."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_ERROR, f'{self.prog}: error: {message} (see {self.prog} --help)\n')


class _Once(argparse.Action):
    """An option that may be given once: a second one would silently replace the first."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        if getattr(namespace, self.dest, None) is not None:
            parser.error(f'{option_string} given twice: merge the files into one (a later '
                         'entry for the same node and parameter wins within a file)')
        setattr(namespace, self.dest, values)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the `depth-nodes` command."""
    parser = _Parser(prog='depth-nodes', description=__doc__.split('\n')[0])
    sub = parser.add_subparsers(dest='command', required=True)

    gen = sub.add_parser('generate', help='write synthetic stereo bags with ground truth')
    gen.add_argument('out', help='bag folder to create (a parent folder with --preset all)')
    gen.add_argument('--preset', default='stereo_vga',
                     help='stereo_vga, stereo_qvga_color, stereo_qvga_fisheye, '
                     'structured_light_vga, tof_vga, all (these five), or bad_inputs (the '
                     'hostile campaign, from --source)')
    gen.add_argument('--source', help='bad_inputs: stereo bag whose raw frames to use '
                     '(default: the bundled stereo_vga)')
    gen.add_argument('--seed', type=int, help='override the preset seed')
    gen.add_argument('--frames', type=int, help='override the number of frames')
    gen.add_argument('--force', action='store_true', help='replace existing bags')
    gen.set_defaults(func=_cmd_generate)

    proc = sub.add_parser('process', help='run the node graph over a bag, offline')
    proc.add_argument('in_bag')
    proc.add_argument('out_bag')
    proc.add_argument('--config', help='graph YAML (default: config/stereo_pipeline.yaml)')
    proc.add_argument('--params', action=_Once,
                      help='ROS 2 parameter file overriding node parameters')
    proc.add_argument('--nodes', nargs='+', help='run only these nodes of the graph')
    proc.add_argument('--force', action='store_true', help='replace an existing OUT_BAG')
    proc.add_argument('--workers', type=int, default=1, metavar='N',
                      help='copies of the graph processing segments of the bag at once, each '
                      'in its own (spawned) process; the output is the same as with one '
                      '(default 1)')
    proc.add_argument('--ray', action='store_true',
                      help='run the workers as Ray actors on a local Ray cluster started for '
                      'the run')
    proc.add_argument('--ray-address', metavar='ADDRESS',
                      help='run the workers on the existing Ray cluster at ADDRESS (e.g. '
                      'ray://head:10001 or auto); its machines need depth_nodes installed '
                      'and the bag at the same path')
    _camera_options(proc, auto=True)
    proc.set_defaults(func=_cmd_process)

    conv = sub.add_parser(
        'convert', help='rewrite a bag as a camera driver records it (compressed, Bayer, '
        'another namespace)',
        description='Copy a bag, turning its raw camera images (sensor_msgs/Image topics '
        'ending in /image_raw) into what a driver records: a Bayer mosaic (--bayer), '
        'image_transport\'s compressed topics (--compress), under another namespace '
        '(--namespace). Every other message is copied, ground truth included, so process and '
        'eval show what the compression costs.',
        epilog='Example: depth-nodes convert bags/stereo_vga out/vga_jpeg --compress jpeg '
        '--quality 80 --namespace /camera')
    conv.add_argument('in_bag')
    conv.add_argument('out_bag')
    conv.add_argument('--compress', choices=('jpeg', 'png'),
                      help='store the images as <topic>/compressed (CompressedImage)')
    conv.add_argument('--quality', type=int, default=90, help='JPEG quality 1..100 (default '
                      '90)')
    conv.add_argument('--bayer', choices=('rggb', 'bggr', 'gbrg', 'grbg'),
                      help='sample colour images on this Bayer tile (bayer_<order>8)')
    conv.add_argument('--namespace', help='replace the first namespace of every topic')
    conv.add_argument('--force', action='store_true', help='replace an existing OUT_BAG')
    conv.set_defaults(func=_cmd_convert)

    imp = sub.add_parser(
        'import-pair', help='a real image pair (and its ground truth) as a bag for process '
        'and eval',
        description='Write a stereo pair, and optionally its ground-truth disparity, into a '
        'bag with the topics of the bundled ones, so `depth-nodes process` runs the graph on '
        'it and `depth-nodes eval` scores the result. A rectified pair gets an identity '
        'calibration; a raw one takes its two camera_info YAML files (--calibration), and '
        'its ground truth must be in the rectified left frame.',
        epilog='Example (Middlebury 2003, quarter size): depth-nodes import-pair im2.png '
        'im6.png teddy_bag --gt disp2.pgm --gt-scale 4 --gt-right disp6.pgm')
    imp.add_argument('left', help='left image (PNG, PPM, PGM, JPEG; 8-bit colour or grey, '
                     '16-bit grey)')
    imp.add_argument('right', help='right image, same size and type')
    imp.add_argument('out_bag', help='bag folder to create')
    imp.add_argument('--gt', help='ground-truth disparity of the left view')
    imp.add_argument('--gt-format', default='auto', choices=('auto', 'scaled', 'kitti', 'pfm'),
                     help='auto (default): pfm by extension, kitti for a 16-bit PNG without '
                     '--gt-scale, scaled otherwise')
    imp.add_argument('--gt-scale', type=float,
                     help='stored value per px of disparity (Middlebury 2003 quarter size: 4, '
                     '2001: 8; KITTI: 256)')
    imp.add_argument('--gt-right', help='ground truth of the right view, same format: '
                     'derives the non-occlusion mask')
    imp.add_argument('--nonocc', help='non-occlusion mask image (nonzero = visible in both '
                     'views), e.g. Middlebury nonocc.png or KITTI disp_noc')
    imp.add_argument('--calibration', nargs=2, metavar=('LEFT.yaml', 'RIGHT.yaml'),
                     help='camera_info YAML files of a raw (unrectified) pair')
    imp.add_argument('--focal', type=float, default=0.0,
                     help='rectified pair: focal length in px (default: the image width)')
    imp.add_argument('--baseline', type=float, default=0.1,
                     help='rectified pair: baseline in m (default 0.1)')
    imp.add_argument('--namespace', default='/stereo', help='topic namespace (default /stereo)')
    imp.add_argument('--mono', action='store_true', help='store colour images as mono8')
    imp.add_argument('--frames', type=int, default=1,
                     help='write the pair this many times, 0.1 s apart (default 1)')
    imp.add_argument('--force', action='store_true', help='replace an existing OUT_BAG')
    imp.set_defaults(func=_cmd_import_pair)

    pipe = sub.add_parser('pipeline', help='run every node of a graph in one process, live',
                          epilog='Anything after --ros-args goes to rclpy (e.g. '
                          '--ros-args --log-level debug).')
    pipe.add_argument('--config', help='graph YAML (default: config/stereo_pipeline.yaml)')
    pipe.add_argument('--params', action=_Once,
                      help='ROS 2 parameter file overriding node parameters')
    pipe.add_argument('--threads', type=int,
                      help='threads of each node\'s executor (default 1: a node handles one '
                      'callback at a time, the nodes run beside each other)')
    _camera_options(pipe, auto=False)
    pipe.set_defaults(func=_cmd_pipeline)

    play = sub.add_parser('play', help='publish a bag into the live graph')
    play.add_argument('bag')
    play.add_argument('--rate', type=float, default=1.0, help='speed factor (default 1)')
    play.add_argument('--loop', action='store_true',
                      help='play again and again; each repeat\'s header stamps move on by '
                      'the bag\'s length plus one period, so nodes take it as a stream that '
                      'goes on')
    play.add_argument('--keep-stamps', action='store_true',
                      help='--loop: publish every repeat with the recorded stamps (nodes '
                      'start over on a jump back of 1 s or more, drop shorter ones)')
    play.add_argument('--remap', nargs='+', metavar='FROM:=TO',
                      help='publish topic FROM as TO (absolute names)')
    play.add_argument('--clock', action='store_true', help='publish /clock with bag time')
    play.add_argument('--topics', nargs='+', help='only these topics')
    play.add_argument('--wait-for-subscribers', type=float, default=0.0, metavar='SECONDS',
                      help='wait up to SECONDS for every topic played to have a '
                      'subscriber (with --topics, leave out what nothing reads, such as a '
                      "bundled bag's ground truth)")
    play.add_argument('--delay', type=float, default=0.0, metavar='SECONDS',
                      help='then wait SECONDS more before the first message')
    play.add_argument('--linger', type=float, default=1.0, metavar='SECONDS',
                      help='stay SECONDS after the last message, so best-effort '
                           'subscriptions receive it (default 1)')
    play.set_defaults(func=_cmd_play)

    rec = sub.add_parser('record', help='record live topics into a bag')
    rec.add_argument('out_bag')
    rec.add_argument('--topics', nargs='+', required=True)
    rec.add_argument('--duration', type=float, help='stop after SECONDS')
    rec.add_argument('--max-messages', type=int, help='stop after N messages')
    rec.add_argument('--force', action='store_true', help='replace an existing OUT_BAG')
    rec.set_defaults(func=_cmd_record)

    par = sub.add_parser('param', help="a running node's parameters (like ros2 param)")
    verbs = par.add_subparsers(dest='verb', required=True)
    for verb, what in [('list', 'parameter names, sorted'), ('get', 'one value'),
                       ('set', 'change one value'),
                       ('describe', 'type, description and range of one parameter'),
                       ('dump', 'all values as a params file')]:
        cmd = verbs.add_parser(verb, help=what)
        cmd.add_argument('node', nargs='?' if verb == 'list' else None,
                         help='node name, e.g. /stereo/sgm_stereo' + (
                             ' (list: every node when left out)' if verb == 'list' else ''))
        if verb in ('get', 'set', 'describe'):
            cmd.add_argument('name', help='parameter name')
        if verb == 'set':
            cmd.add_argument('value', help='YAML value: 5, 5.0, true, [1, 2], text')
        cmd.add_argument('--timeout', type=float, default=10.0, metavar='SECONDS',
                         help='wait up to this long for the node (default 10; a node missing '
                         'from a graph whose node list has settled is reported after half of it)')
    par.set_defaults(func=_cmd_param)

    nod = sub.add_parser('node', help='the nodes of the running graph (like ros2 node)')
    nod_verbs = nod.add_subparsers(dest='verb', required=True)
    nod_list = nod_verbs.add_parser('list', help='every node, sorted')
    nod_list.add_argument('--wait', type=float, default=2.0, metavar='SECONDS',
                          help='least discovery time before listing (default 2; it goes on '
                          'while nodes are still announcing themselves, up to 10)')
    nod.set_defaults(func=_cmd_node)

    top = sub.add_parser('topic', help='the topics of the running graph (like ros2 topic)')
    top_verbs = top.add_subparsers(dest='verb', required=True)
    top_list = top_verbs.add_parser('list', help='every topic, sorted')
    top_list.add_argument('-t', '--show-types', action='store_true',
                          help='print each topic\'s type')
    top_list.add_argument('--wait', type=float, default=2.0, metavar='SECONDS',
                          help='least discovery time before listing (default 2; it goes on '
                          'while nodes are still announcing themselves, up to 10)')
    for verb, what in [('echo', 'print its messages (images and clouds as one summary '
                                'line)'),
                       ('hz', 'its rate every second'), ('bw', 'its bandwidth every second')]:
        cmd = top_verbs.add_parser(verb, help=what)
        cmd.add_argument('topic')
        cmd.add_argument('--timeout', type=float, default=10.0, metavar='SECONDS',
                         help='wait this long for the topic to appear (default 10)')
        if verb == 'echo':
            cmd.add_argument('--count', type=int, help='stop after N messages')
            cmd.add_argument('--once', action='store_true', help='print one message and stop')
        else:
            cmd.add_argument('--window', type=int, default=100,
                             help='messages the figures are taken over (default 100)')
    top.set_defaults(func=_cmd_topic)

    dia = sub.add_parser('diag', help='every node\'s diagnostics, refreshed: rate, '
                         'processing time, drops by reason')
    dia.add_argument('--period', type=float, default=2.0, metavar='SECONDS',
                     help='refresh every SECONDS (default 2)')
    dia.add_argument('--once', action='store_true', help='print one table and stop')
    dia.add_argument('--timeout', type=float, default=10.0, metavar='SECONDS',
                     help='--once: wait this long for the first diagnostics (default 10)')
    dia.set_defaults(func=_cmd_diag)

    ev = sub.add_parser('eval', help='accuracy of a processed bag against its ground truth')
    ev.add_argument('bag')
    ev.add_argument('--threshold', type=float, default=2.0, help='N of bad-N (default 2)')
    ev.add_argument('--previews', metavar='DIR',
                    help='write PNG previews into DIR: every disparity, depth and confidence '
                    'colour-mapped beside the left image, with a colour bar (also for a bag '
                    'without ground truth, which is then only drawn)')
    ev.add_argument('--preview-frames', type=int, default=10, metavar='N',
                    help='previews of the first N frames (default 10)')
    ev.add_argument('--no-baseline', action='store_true', help='skip OpenCV StereoSGBM')
    ev.add_argument('--grid', action='store_true',
                    help='also print every setting of the 18-setting OpenCV grid')
    ev.set_defaults(func=_cmd_eval)

    evsl = sub.add_parser('eval-sl',
                          help='structured-light figures beside OpenCV GrayCodePattern')
    evsl.add_argument('bag', help='a bag written by generate --preset structured_light_vga')
    evsl.add_argument('--no-opencv', action='store_true',
                      help='skip OpenCV (its per-pixel API is slow)')
    evsl.set_defaults(func=_cmd_eval_sl)

    evtof = sub.add_parser('eval-tof',
                           help='time-of-flight depth against the simulator\'s ground truth')
    evtof.add_argument('bag', help='a bag processed from generate --preset tof_vga with '
                       'config/tof_pipeline.yaml')
    evtof.add_argument('--depth-topic', default='/tof/depth/image_rect',
                       help='the depth to score (default /tof/depth/image_rect)')
    evtof.set_defaults(func=_cmd_eval_tof)

    bench = sub.add_parser('bench', help='speed figures beside OpenCV, measured in one run')
    bench.add_argument('stage', nargs='?', choices=['rectify', 'sgm', 'cross_check',
                                                    'point_cloud', 'structured_light', 'tof',
                                                    'soak'],
                       help='what to time (or --live); soak: the stereo graph fed for '
                       '--duration s at --rate, P2 changed every --tune-every s: losses, '
                       'memory, parameter answers')
    bench.add_argument('--duration', type=float, default=1800.0,
                       help='soak: seconds to run (default 1800)')
    bench.add_argument('--tune-every', type=float, default=10.0,
                       help='soak: seconds between two changes of P2 (default 10)')
    bench.add_argument('--memory-log', metavar='CSV',
                       help='soak: write every memory sample (seconds, process, MB) here')
    bench.add_argument('--live', action='store_true',
                       help='the stereo pipeline as separate processes over DDS: sustained '
                       'rate and per-stage latency, beside the OpenCV graph')
    bench.add_argument('--rate', type=float, default=10.0,
                       help='--live: frames per second to publish (default 10)')
    bench.add_argument('--no-opencv', action='store_true',
                       help='--live: skip the OpenCV graph')
    bench.add_argument('--composed', action='store_true',
                       help='--live, soak: run each graph composed in one `depth-nodes '
                       'pipeline` process instead of one process per node')
    bench.add_argument('--bag', help='structured_light, tof, --live: the bag to use '
                       '(default: bundled)')
    bench.add_argument('--width', type=int, default=640, help='rectify: frame width')
    bench.add_argument('--height', type=int, default=480, help='rectify: frame height')
    bench.add_argument('--frames', type=int, help='timed repetitions (median); default 200 '
                       'for rectify, 10 for sgm, 50 frames for --live')
    bench.add_argument('--threads', type=int,
                       help='OpenCV and numba threads (default 2); --live: of the SGM node '
                       '(0 = every core; default: as config/stereo_pipeline.yaml says)')
    bench.add_argument('--disparities', type=int, default=128, help='sgm: disparity range')
    bench.add_argument('--size', default='640x480', metavar='WxH',
                       help='sgm: frame size; the bundled pair is resized to it (default '
                       '640x480)')
    bench.add_argument('--busy', type=int, default=0, metavar='N',
                       help='sgm: also time everything with N busy-loop processes beside '
                       'it (a robot computer\'s other work), and our matcher on one thread')
    bench.add_argument('--paths', type=int, choices=(4, 5, 8, 16),
                       help='sgm: aggregation paths (default 8); --live: of the SGM node '
                       '(default: as config/stereo_pipeline.yaml says), OpenCV then in '
                       'MODE_SGBM for 4 and 5, MODE_HH for 8 and 16')
    bench.add_argument('--interpolation', default='linear',
                       help='rectify: nearest, linear, cubic, area or lanczos4')
    bench.set_defaults(func=_cmd_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `depth-nodes`; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args: list[str] = []
    if '--ros-args' in argv:  # rclpy's arguments, for `pipeline`
        ros_args = argv[argv.index('--ros-args'):]
        argv = argv[:argv.index('--ros-args')]
    args, extras = build_parser().parse_known_args(argv)
    if extras:  # said by the subcommand, as every other mistake is
        print(f'depth-nodes {args.command}: error: unrecognized arguments: '
              f'{" ".join(extras)} (see depth-nodes {args.command} --help)', file=sys.stderr)
        return EXIT_ERROR
    args.ros_args = ros_args
    from depth_nodes.ros.dds import use_large_message_profile
    from depth_nodes.ros.memory import keep_freed_memory

    signals.install()  # SIGINT and SIGTERM, also when started in the background

    use_large_message_profile()  # before any rclpy.init: live commands move large messages
    keep_freed_memory()  # and without a page fault per 4 KiB of each (ros/memory.py)
    if ros_args and args.command != 'pipeline':
        print(f'depth-nodes {args.command}: error: --ros-args is only accepted by pipeline',
              file=sys.stderr)
        return EXIT_ERROR
    try:
        return int(args.func(args))
    except DepthNodesError as exc:
        message = ' '.join(str(exc).split())  # one line, whatever a library put in it
        print(f'depth-nodes {args.command}: error: {message}', file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:  # stopped by the user (SIGINT or SIGTERM): not a failure
        print(f'depth-nodes {args.command}: interrupted', file=sys.stderr)
        return 0


if __name__ == '__main__':
    sys.exit(main())
