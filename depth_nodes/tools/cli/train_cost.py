"""`depth-nodes train-cost`: train the learned matching cost's feature network on the
simulator's scenes (needs the ``train`` extra: JAX)."""

from __future__ import annotations

import argparse
from pathlib import Path

from depth_nodes.core.learned.network import SHIPPED
from depth_nodes.errors import ArgumentError
from depth_nodes.tools.train.cost import TrainConfig, train
from depth_nodes.tools.train.data import DataConfig

_DATA, _TRAIN = DataConfig(), TrainConfig()


def add_common_arguments(parser: argparse.ArgumentParser, *, seed: int, scenes: int,
                         photo_scenes: int) -> None:
    """The options both training commands take: OUT, the seed, the scenes, the cache
    (with that command's defaults)."""
    parser.add_argument('out', help='weights file to write (.npz)')
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
                     'depth-nodes train-cost OUT.npz')
    add_common_arguments(parser, seed=_DATA.seed, scenes=_DATA.scenes,
                         photo_scenes=_DATA.photo_scenes)
    parser.add_argument('--samples', type=int, default=_DATA.samples_per_scene,
                        help=f'patch triplets per scene (default {_DATA.samples_per_scene})')
    parser.add_argument('--steps', type=int, default=_TRAIN.steps,
                        help=f'optimiser steps (default {_TRAIN.steps})')
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
    """Train; write the weights; print the curves as they come."""
    out = weights_path(args.out, args.force)
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
