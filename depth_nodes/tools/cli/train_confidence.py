"""`depth-nodes train-confidence`: train cross_check's learned confidence on simulated
scenes (needs the ``train`` extra: JAX, scikit-image)."""

from __future__ import annotations

import argparse

from depth_nodes.core.learned.confidence import SHIPPED
from depth_nodes.tools.cli.train_cost import (
    add_common_arguments,
    cache_folder,
    check_counts,
    weights_path,
)
from depth_nodes.tools.train.confidence import ConfidenceConfig, train_confidence

_DEFAULT = ConfidenceConfig()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `train-confidence`."""
    parser.description = (
        "Train cross_check's confidence_model learned: simulated scenes and photograph "
        "planes (no real image pair) go through the shipped graph's matcher and check; "
        'every pixel with a raw disparity gives its signals and whether that disparity is '
        'within --threshold px of the truth. Writes the weights with their recipe. Needs '
        "JAX and scikit-image: pip install 'depth_nodes[train]'.")
    parser.epilog = (f'The shipped weights ({SHIPPED.name}) were made by the defaults: '
                     'depth-nodes train-confidence OUT.npz')
    add_common_arguments(parser, seed=_DEFAULT.seed, scenes=_DEFAULT.scenes,
                         photo_scenes=_DEFAULT.photo_scenes)
    parser.add_argument('--pixels', type=int, default=_DEFAULT.pixels_per_scene,
                        help=f'pixels sampled per scene (default {_DEFAULT.pixels_per_scene})')
    parser.add_argument('--threshold', type=float, default=_DEFAULT.threshold,
                        help=f'a raw disparity within this many px of the truth counts as '
                        f'right (default {_DEFAULT.threshold:g}, eval\'s bad-2)')
    parser.add_argument('--hidden', type=int, default=_DEFAULT.hidden,
                        help=f'units of each of the two hidden layers (default '
                        f'{_DEFAULT.hidden})')
    parser.add_argument('--steps', type=int, default=_DEFAULT.steps,
                        help=f'optimiser steps (default {_DEFAULT.steps})')


def run(args: argparse.Namespace) -> int:
    """Train; write the weights; print the losses as they come."""
    out = weights_path(args.out, args.force)
    check_counts(args, ('pixels', 'hidden', 'steps'))
    config = ConfidenceConfig(scenes=args.scenes, photo_scenes=args.photo_scenes,
                              seed=args.seed, pixels_per_scene=args.pixels,
                              threshold=args.threshold, hidden=args.hidden, steps=args.steps)
    model = train_confidence(config, cache=cache_folder(args.cache),
                             log=lambda line: print(line, flush=True))
    model.save(out)
    print(f'wrote {out} ({out.stat().st_size / 1024:.0f} KB) in '
          f'{model.recipe["seconds"]:.0f} s')
    return 0
