"""`depth-nodes train-cost`: train the learned matching cost's feature network on the
simulator's scenes, or (``--adapt BAG ...``) adapt it to a user's own recordings without
ground truth (needs the ``train`` extra: JAX)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from depth_nodes.core.learned.network import SHIPPED, FeatureNet
from depth_nodes.errors import ArgumentError
from depth_nodes.tools import signals
from depth_nodes.tools.train.adapt import AdaptConfig, adapt, write_atomically
from depth_nodes.tools.train.cost import TrainConfig, train
from depth_nodes.tools.train.data import DataConfig

_DATA, _TRAIN, _ADAPT = DataConfig(), TrainConfig(), AdaptConfig()


def add_common_arguments(parser: argparse.ArgumentParser, *, seed: int, scenes: int,
                         photo_scenes: int) -> None:
    """The options both training commands take: OUT, the seed, the scenes, the cache
    (with that command's defaults)."""
    parser.add_argument('out', nargs='?', help='weights file to write (.npz)')
    parser.add_argument('--seed', type=int, default=seed,
                        help=f'seed of the scenes, augmentation, sampling and initial '
                        f'weights (default {seed})')
    parser.add_argument('--scenes', type=int, default=scenes,
                        help=f'simulated scenes, a tenth held out for validation (default '
                        f'{scenes})')
    parser.add_argument('--photo-scenes', type=int, default=photo_scenes,
                        help=f'pairs of planes covered with photographs (scikit-image\'s '
                        f'data set), a tenth held out (default {photo_scenes})')
    parser.add_argument('--cache', metavar='DIR',
                        help='keep the rendered simulator scenes in DIR and reuse them '
                        '(a scene takes seconds to render; both training commands read '
                        'the same files)')
    parser.add_argument('--force', action='store_true', help='replace an existing OUT')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `train-cost`."""
    parser.description = (
        "Train the feature network of sgm_stereo's matching_cost learned on simulated "
        'scenes (rendered here, augmented like real cameras; no real image is used) and '
        'write its weights with the recipe that made them. The same options and seed give '
        'the same weights on the same machine. Needs JAX: pip install '
        "'depth_nodes[train]'.")
    parser.epilog = (f'The shipped weights ({SHIPPED.name}) were made by the defaults: '
                     'depth-nodes train-cost OUT.npz. Adapting to your camera: '
                     'depth-nodes train-cost --adapt BAG [BAG ...] --out WEIGHTS.npz, then '
                     "sgm_stereo's learned_weights: WEIGHTS.npz (docs/learned.md)")
    add_common_arguments(parser, seed=_DATA.seed, scenes=_DATA.scenes,
                         photo_scenes=_DATA.photo_scenes)
    parser.add_argument('--adapt', nargs='+', metavar='BAG',
                        help='adapt the network to the stereo pairs of these bags (your '
                        'camera\'s recordings; no ground truth needed) instead of training it '
                        'on the simulator: proxy labels where the matcher is left-right '
                        'consistent, distinctive and photometrically consistent')
    parser.add_argument('--out', dest='out_option', metavar='OUT',
                        help='weights file to write (.npz), the same as OUT')
    parser.add_argument('--weights', default='', metavar='FILE',
                        help='--adapt: the weights to start from (default: the shipped ones)')
    parser.add_argument('--frames', type=int, default=_ADAPT.frames,
                        help=f'--adapt: pairs read from each bag, spread over it (default '
                        f'{_ADAPT.frames})')
    parser.add_argument('--disparities', type=int, default=_ADAPT.disparity_range,
                        help=f'--adapt: disparities the proxy matcher searches (default '
                        f'{_ADAPT.disparity_range})')
    parser.add_argument('--samples', type=int, default=_DATA.samples_per_scene,
                        help=f'patch triplets per scene (default {_DATA.samples_per_scene})')
    parser.add_argument('--steps', type=int, default=None,
                        help=f'optimiser steps (default {_TRAIN.steps}; --adapt: '
                        f'{_ADAPT.steps})')
    parser.add_argument('--batch', type=int, default=_TRAIN.batch,
                        help=f'triplets per step (default {_TRAIN.batch})')
    parser.add_argument('--channels', type=int, default=_TRAIN.channels,
                        help=f'features per pixel (default {_TRAIN.channels})')
    parser.add_argument('--layers', type=int, default=_TRAIN.layers,
                        help=f'3x3 convolutions (default {_TRAIN.layers})')
    parser.add_argument('--log-every', type=int, default=1000, metavar='N',
                        help='print the losses every N steps (default 1000)')


def weights_path(text: str, force: bool) -> Path:
    """The output file of a training command, checked.

    Raises:
        ArgumentError: It exists (without ``force``), is not an ``.npz``, or its folder
            does not exist.
    """
    out = Path(text)
    if out.exists() and not force:
        raise ArgumentError(f'{out} exists (--force replaces it)')
    if out.suffix != '.npz':
        raise ArgumentError(f'{out}: the weights file must end in .npz')
    if not out.parent.is_dir():
        raise ArgumentError(f'{out.parent} is not a folder')
    return out


def check_counts(args: argparse.Namespace, names: tuple[str, ...]) -> None:
    """Counts of a training command: each at least 1; scenes (either kind) at least 2 in
    total, one of each kind with two or more being held out.

    Raises:
        ArgumentError: Naming the option.
    """
    for name in names:
        if getattr(args, name) < 1:
            raise ArgumentError(f'--{name.replace("_", "-")} must be at least 1')
    for name in ('scenes', 'photo_scenes'):
        if getattr(args, name) < 0:
            raise ArgumentError(f'--{name.replace("_", "-")} must be at least 0')
    if args.scenes + args.photo_scenes < 2:
        raise ArgumentError('--scenes and --photo-scenes must add up to at least 2 (a share '
                            'is held out for validation)')


def cache_folder(text: str | None) -> Path | None:
    """The ``--cache`` folder, made if missing.

    Raises:
        ArgumentError: It cannot be made.
    """
    if not text:
        return None
    folder = Path(text)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ArgumentError(f'--cache {folder}: {error.strerror}') from None
    return folder


def run(args: argparse.Namespace) -> int:
    """Train (or adapt); write the weights; print the curves as they come."""
    chosen = [a for a in (args.out, getattr(args, 'out_option', None)) if a]
    if len(chosen) != 1:
        raise ArgumentError('give the weights file to write once: OUT or --out OUT')
    args.out = chosen[0]
    out = weights_path(args.out, args.force)
    if getattr(args, 'adapt', None):
        args.steps = _ADAPT.steps if args.steps is None else args.steps
        return _adapt(args, out)
    args.steps = _TRAIN.steps if args.steps is None else args.steps
    check_counts(args, ('samples', 'steps', 'batch', 'channels', 'layers', 'log_every'))
    data = DataConfig(scenes=args.scenes, photo_scenes=args.photo_scenes, seed=args.seed,
                      samples_per_scene=args.samples, radius=args.layers)
    config = TrainConfig(channels=args.channels, layers=args.layers, steps=args.steps,
                         batch=args.batch)
    result = train(data, config, cache=cache_folder(args.cache),
                   log=lambda line: print(line, flush=True), log_every=args.log_every)
    result.net.save(out)
    print(f'wrote {out} ({out.stat().st_size / 1024:.0f} KB, {result.net.channels} features, '
          f'{len(result.net.kernels)} layers) in {result.seconds:.0f} s')
    return 0


def _adapt(args: argparse.Namespace, out: Path) -> int:
    """``--adapt``: fine-tune on the bags' proxy labels; the best network so far is on
    the disk at every moment, so a Ctrl-C keeps it."""
    check_counts_adapt(args)
    if args.weights:
        FeatureNet.load(args.weights)  # a file it cannot read: one line, before any work
    config = AdaptConfig(frames=args.frames, disparity_range=args.disparities,
                         steps=args.steps, seed=args.seed)
    saved: list[int] = []

    def checkpoint(net: FeatureNet) -> None:
        write_atomically(net, out)
        saved.append(1)

    with signals.graceful():
        result = adapt(args.adapt, config, weights=args.weights,
                       log=lambda line: print(line, flush=True), checkpoint=checkpoint,
                       stop=signals.stop_requested)
        if signals.stop_requested():
            if saved:
                print(f'depth-nodes train-cost: interrupted; {out} holds the best weights '
                      f'so far (step {result.best_step})', file=sys.stderr)
            else:
                print('depth-nodes train-cost: interrupted before any weights were kept; '
                      'nothing written', file=sys.stderr)
            return 0
    write_atomically(result.net, out)
    print(f'wrote {out} ({out.stat().st_size / 1024:.0f} KB), adapted on {result.pairs} '
          f'pair(s), {result.labels} proxy labels, best at step {result.best_step}, in '
          f'{result.seconds:.0f} s')
    return 0


def check_counts_adapt(args: argparse.Namespace) -> None:
    """The counts of ``--adapt``.

    Raises:
        ArgumentError: Naming the option.
    """
    for name in ('frames', 'steps', 'disparities'):
        if getattr(args, name) < 1:
            raise ArgumentError(f'--{name} must be at least 1')
