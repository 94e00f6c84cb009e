"""`depth-nodes generate`: synthetic bags with ground truth (stereo, structured light, ToF,
multi-view, depth cameras, a moving stereo pair for fusion), and the hostile-input
campaign."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

from depth_nodes.errors import ConfigError
from depth_nodes.sim import StereoSimConfig
from depth_nodes.sim.depth_sequence import DepthSequenceConfig
from depth_nodes.sim.sequence import SequenceConfig
from depth_nodes.sim.tof import ToFSimConfig
from depth_nodes.tools import signals
from depth_nodes.tools.bags import depth_filter as depth
from depth_nodes.tools.bags import fusion_stereo as fusion
from depth_nodes.tools.bags import multiview as mvs
from depth_nodes.tools.bags import structured_light as sl
from depth_nodes.tools.bags import tof
from depth_nodes.tools.bags.bad_inputs import write_bad_input_bag
from depth_nodes.tools.bags.generate import PRESETS, write_stereo_bag
from depth_nodes.tools.cli.options import BUNDLED_BAGS

C = TypeVar('C')


@dataclass(frozen=True)
class PresetKind(Generic[C]):
    """Presets of one kind: how --seed and --frames apply to one, how its bag is written
    (returns the messages written) and what the printed line says of it."""

    presets: Mapping[str, C]
    with_seed: Callable[[C, int], C]
    with_frames: Callable[[C, int], C]
    write: Callable[[Path, C, bool], int]
    describe: Callable[[C], str]
    #: The kind's own options (``--size``, ``--pose-noise``: the multi-view presets'),
    #: applied to a config; None: the kind has none.
    with_options: Callable[[C, argparse.Namespace], C] | None = None
    #: The presets committed in bags/ (``--preset all``, `make bags`); None: every one.
    bundled: tuple[str, ...] | None = None

    def generate(self, name: str, path: Path, args: argparse.Namespace) -> str:
        """Write preset ``name`` at ``path`` with the options applied; the printed line.

        Raises:
            ConfigError: An option the preset's kind does not take.
        """
        config = self.presets[name]
        if args.seed is not None:
            config = self.with_seed(config, args.seed)
        if args.frames is not None:
            config = self.with_frames(config, args.frames)
        if self.with_options is not None:
            config = self.with_options(config, args)
        elif args.size is not None or args.pose_noise is not None:
            raise ConfigError(f'--size and --pose-noise apply to the multi-view presets '
                              f'(mvs_*), not to {name}')
        count = self.write(path, config, args.force)
        size = sum(f.stat().st_size for f in path.iterdir()) / 1e6
        return f'{path}: {name}, {self.describe(config)}, {count} messages, {size:.1f} MB'


def _frames(count: int) -> str:
    return f'{count} frames' if not signals.stop_requested() else 'frames up to the signal'


def _frame_done(count: int, index: int) -> None:
    """Progress of `generate` on stderr."""
    print(f'  frame {index + 1}/{count}', file=sys.stderr)


def _write_stereo(path: Path, config: StereoSimConfig, overwrite: bool) -> int:
    return write_stereo_bag(path, config, overwrite=overwrite,
                            on_frame=functools.partial(_frame_done, config.n_frames))


STEREO = PresetKind[StereoSimConfig](
    PRESETS,
    with_seed=lambda c, seed: dataclasses.replace(c, seed=seed),
    with_frames=lambda c, frames: dataclasses.replace(c, n_frames=frames),
    write=_write_stereo,
    describe=lambda c: f'{c.width}x{c.height}, {_frames(c.n_frames)}')
STRUCTURED_LIGHT = PresetKind[sl.StructuredLightBagConfig](
    sl.PRESETS,
    with_seed=lambda c, seed: dataclasses.replace(c, sim=dataclasses.replace(c.sim, seed=seed)),
    with_frames=lambda c, frames: dataclasses.replace(c, sequences=frames),
    write=lambda path, c, overwrite: sl.write_structured_light_bag(path, c, overwrite=overwrite),
    describe=lambda c: (f'{c.sim.width}x{c.sim.height}, {c.sequences} sequence(s) of '
                        f'{c.pattern_set.count} frames + {c.speckle_frames} speckle'))
TOF = PresetKind[ToFSimConfig](
    tof.PRESETS,
    with_seed=lambda c, seed: dataclasses.replace(c, seed=seed),
    with_frames=lambda c, frames: dataclasses.replace(c, n_frames=frames),
    write=lambda path, c, overwrite: tof.write_tof_bag(path, c, overwrite=overwrite),
    describe=lambda c: (f'{c.width}x{c.height}, {_frames(c.n_frames)} of '
                        f'{len(c.frequencies_mhz)} x {c.phase_steps} correlation planes'))
def _sequence_options(config: SequenceConfig, args: argparse.Namespace) -> SequenceConfig:
    """``--size`` (the same motion in metres: the focal length, 0.8 x the width, scales
    the parallax in pixels) and ``--pose-noise`` of a multi-view preset."""
    if args.size is not None:
        width, height = image_size(args.size)
        config = dataclasses.replace(config, width=width, height=height)
    if args.pose_noise is not None:
        degrees, metres = args.pose_noise
        config = dataclasses.replace(config, pose_noise_deg=degrees, pose_noise_m=metres)
    return config


def image_size(text: str) -> tuple[int, int]:
    """``WxH`` as (W, H).

    Raises:
        ConfigError: Not two integers of at least 16 joined by x.
    """
    parts = text.lower().split('x')
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts) or \
            min(int(p) for p in parts) < 16:
        raise ConfigError(f'--size must be WxH with both at least 16 (e.g. 640x480), got '
                          f'{text!r}')
    return int(parts[0]), int(parts[1])


MULTIVIEW = PresetKind[SequenceConfig](
    mvs.PRESETS,
    with_seed=lambda c, seed: dataclasses.replace(c, seed=seed),
    with_frames=lambda c, frames: dataclasses.replace(c, n_frames=frames),
    write=lambda path, c, overwrite: mvs.write_sequence_bag(path, c, overwrite=overwrite),
    describe=lambda c: (f'{c.width}x{c.height}, {c.motion}, {_frames(c.n_frames)}' +
                        (f' of {c.rig_cameras} cameras' if c.motion == 'rig' else '') +
                        (f', pose noise {c.pose_noise_deg:g} deg / {c.pose_noise_m:g} m'
                         if c.pose_noise_deg or c.pose_noise_m else '')),
    with_options=_sequence_options,
    bundled=mvs.BUNDLED)
DEPTH = PresetKind[DepthSequenceConfig](
    depth.PRESETS,
    with_seed=lambda c, seed: dataclasses.replace(c, seed=seed),
    with_frames=lambda c, frames: dataclasses.replace(c, n_frames=frames),
    write=lambda path, c, overwrite: depth.write_depth_bag(path, c, overwrite=overwrite),
    describe=lambda c: f'{c.width}x{c.height}, {c.kind}, {c.noise} noise, '
                       f'{_frames(c.n_frames)}',
    with_options=lambda c, args: _depth_options(c, args),
    bundled=depth.BUNDLED)


def _depth_options(config: DepthSequenceConfig, args: argparse.Namespace
                   ) -> DepthSequenceConfig:
    """``--size`` of a depth_* preset (``--pose-noise`` is the multi-view presets')."""
    if args.pose_noise is not None:
        raise ConfigError('--pose-noise applies to the multi-view presets (mvs_*), not to '
                          'the depth_* ones')
    if args.size is not None:
        width, height = image_size(args.size)
        config = dataclasses.replace(config, width=width, height=height)
    return config


def _fusion_options(config: fusion.FusionStereoConfig, args: argparse.Namespace
                    ) -> fusion.FusionStereoConfig:
    """``--size`` of a fusion stereo preset (``--pose-noise`` is the multi-view presets')."""
    if args.pose_noise is not None:
        raise ConfigError('--pose-noise applies to the multi-view presets (mvs_*), not to '
                          'stereo_orbit')
    if args.size is not None:
        width, height = image_size(args.size)
        config = fusion.with_sequence(config, width=width, height=height)
    return config


FUSION_STEREO = PresetKind[fusion.FusionStereoConfig](
    fusion.PRESETS,
    with_seed=lambda c, seed: fusion.with_sequence(c, seed=seed),
    with_frames=lambda c, frames: fusion.with_sequence(c, n_frames=frames),
    write=lambda path, c, overwrite: fusion.write_fusion_stereo_bag(path, c,
                                                                    overwrite=overwrite),
    describe=lambda c: (f'{c.sequence.width}x{c.sequence.height}, {c.sequence.kind} stereo '
                        f'pair, baseline {c.sequence.baseline_m:g} m, '
                        f'{_frames(c.sequence.n_frames)}'),
    with_options=_fusion_options,
    bundled=())


#: Every preset by name.
KINDS: dict[str, PresetKind[Any]] = {
    name: kind for kind in (STEREO, STRUCTURED_LIGHT, TOF, MULTIVIEW, DEPTH, FUSION_STEREO)
    for name in kind.presets}
#: The committed bags, in the order `--preset all` writes them.
BUNDLED = [name for name, kind in KINDS.items()
           if kind.bundled is None or name in kind.bundled]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `generate`."""
    parser.add_argument('out', help='bag folder to create (a parent folder with --preset all)')
    parser.add_argument('--preset', default='stereo_vga',
                        help='stereo_vga, stereo_qvga_color, stereo_qvga_fisheye, '
                        'structured_light_vga, tof_vga, mvs_sideways, mvs_forward, mvs_orbit, '
                        'mvs_rig (a moving camera, or a rig of three, with poses and exact '
                        'depth), depth_static, depth_moving_camera, depth_moving_object, '
                        'depth_tof_static (a depth camera\'s depth images with exact depth, '
                        'for depth_filter), depth_orbit, depth_object_leaves, depth_long '
                        '(the same, for volumetric fusion), stereo_orbit (a moving stereo '
                        'pair with odometry and exact depth, for fusion), all (the bundled '
                        'eight: not mvs_forward, mvs_orbit, stereo_orbit and six of the '
                        'depth_*), or bad_inputs (the hostile campaign, from --source)')
    parser.add_argument('--source', help='bad_inputs: stereo bag whose raw frames to use '
                        '(default: the bundled stereo_vga)')
    parser.add_argument('--seed', type=int, help='override the preset seed')
    parser.add_argument('--frames', type=int, help='override the number of frames')
    parser.add_argument('--size', metavar='WxH',
                        help='mvs_*, depth_*, stereo_orbit: the image size (default 320x240; '
                        'depth_orbit and stereo_orbit 640x480)')
    parser.add_argument('--pose-noise', type=float, nargs=2, metavar=('DEG', 'M'),
                        help='mvs_*: standard deviation of the poses the bag reports: '
                        'rotation in degrees, position in metres per axis (the images stay '
                        'exact)')
    parser.add_argument('--force', action='store_true', help='replace existing bags')


def run(args: argparse.Namespace) -> int:
    """Write the bags of --preset (a signal stops after the frame being written).

    Raises:
        ConfigError: Unknown preset, or an option the simulator refuses.
    """
    with signals.graceful():
        if args.preset == 'bad_inputs':
            return _bad_inputs(args)
        if args.preset != 'all' and args.preset not in KINDS:
            raise ConfigError(f'unknown preset {args.preset!r} (presets: {", ".join(KINDS)}, '
                              'bad_inputs, all)')
        names = BUNDLED if args.preset == 'all' else [args.preset]
        out = Path(args.out)
        for name in names:
            path = out / name if args.preset == 'all' else out
            print(KINDS[name].generate(name, path, args))
            if signals.stop_requested():
                break
        if signals.stop_requested():
            print('depth-nodes generate: interrupted; the last bag holds the frames written '
                  'before the signal (its metadata says how many)', file=sys.stderr)
    return 0


def _bad_inputs(args: argparse.Namespace) -> int:
    source = args.source or BUNDLED_BAGS / 'stereo_vga'
    campaign = write_bad_input_bag(args.out, source, overwrite=args.force)
    print(f'{args.out}: bad_inputs from {source}: {len(campaign.good)} good frames, '
          f'{len(campaign.cases)} hostile cases')
    return 0
