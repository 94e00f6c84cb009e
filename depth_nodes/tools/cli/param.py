"""`depth-nodes param`: a running node's parameters, like ``ros2 param``."""

from __future__ import annotations

import argparse
from collections.abc import Callable

from depth_nodes.tools.live import param


def _list(args: argparse.Namespace) -> None:
    if args.node is not None:
        print('\n'.join(param.list_parameters(args.node, timeout=args.timeout)))
        return
    for node, names in param.list_all_parameters(timeout=args.timeout).items():
        print(f'{node}:')
        if names is None:
            print(f'  (no answer within {args.timeout:g} s)')
            continue
        print('\n'.join(f'  {name}' for name in names) or '  (no parameter services)')


def _get(args: argparse.Namespace) -> None:
    print(param.format_value(param.get_parameter(args.node, args.name, timeout=args.timeout)))


def _set(args: argparse.Namespace) -> None:
    param.set_parameter(args.node, args.name, args.value, timeout=args.timeout)
    print('Set parameter successful')


def _describe(args: argparse.Namespace) -> None:
    print(param.describe_parameter(args.node, args.name, timeout=args.timeout))


def _dump(args: argparse.Namespace) -> None:
    print(param.dump_parameters(args.node, timeout=args.timeout), end='')


#: The verbs: name, help, what they do.
VERBS: list[tuple[str, str, Callable[[argparse.Namespace], None]]] = [
    ('list', 'parameter names, sorted', _list),
    ('get', 'one value', _get),
    ('set', 'change one value', _set),
    ('describe', 'type, description and range of one parameter', _describe),
    ('dump', 'all values as a params file', _dump),
]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The verbs of `param` and their options."""
    verbs = parser.add_subparsers(dest='verb', required=True)
    for verb, what, act in VERBS:
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
        cmd.set_defaults(act=act)


def run(args: argparse.Namespace) -> int:
    """Do what the verb says."""
    args.act(args)
    return 0
