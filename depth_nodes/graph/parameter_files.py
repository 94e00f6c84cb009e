"""ROS 2 parameter files applied to a graph's nodes.

Parameter files use the ``--params-file`` layout (``node: {ros__parameters: {...}}``, with
``/**`` matching every node), so the same file works with ``ros2 run``. An entry applies to
a node by its name, its full name or an alias (``disparity_node``, stereo_image_proc's
name for the matcher), or to every node through ``/**``; an entry that matches no node is
reported, since rclpy would ignore it.
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Any

from depth_nodes.errors import ConfigError
from depth_nodes.graph.schema import GraphConfig, NodeSpec, load_yaml


def _flatten(params: dict[str, Any], prefix: str = '') -> dict[str, Any]:
    """Nested parameter names as ROS reads them: ``{qos_overrides: {/t: {publisher:
    {depth: 5}}}}`` is ``qos_overrides./t.publisher.depth`` (what ``ros2 param dump`` and
    ``depth-nodes param dump`` write)."""
    flat: dict[str, Any] = {}
    for key, value in params.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            flat.update(_flatten(value, f'{name}.'))
        else:
            flat[name] = value
    return flat


def load_params_file(path: str | Path) -> dict[str, dict[str, Any]]:
    """Read a ROS 2 parameter file into ``{node key: {name: value}}``.

    Node keys are as written (``rectify_left``, ``/stereo/rectify_left`` or ``/**``);
    nested namespaces (``stereo: {rectify_left: {ros__parameters: ...}}``) and nested
    parameter names (``qos_overrides: {...}``) are flattened.

    Raises:
        ConfigError: The file is missing, not YAML, or has no ``ros__parameters``.
    """
    path = Path(path)
    doc = load_yaml(path, 'parameter file')
    if not isinstance(doc, dict):
        raise ConfigError(f'parameter file {path} must be a mapping of node names')
    out: dict[str, dict[str, Any]] = {}

    def walk(prefix: str, node: dict[str, Any]) -> None:
        for key, value in node.items():
            if key == 'ros__parameters':
                if not isinstance(value, dict):
                    raise ConfigError(f'parameter file {path}: ros__parameters of {prefix} '
                                      'must be a mapping')
                out[prefix or '/**'] = _flatten(value)
            elif isinstance(value, dict):
                walk(f'{prefix}/{key}' if prefix else str(key), value)
            else:
                raise ConfigError(f'parameter file {path}: unexpected entry {key!r} under '
                                  f'{prefix or "the top level"} (missing ros__parameters?)')

    walk('', doc)
    if not out:
        raise ConfigError(f'parameter file {path} sets no ros__parameters')
    return out


def node_keys(spec: NodeSpec) -> list[str]:
    """The keys of a parameter file that address ``spec`` in particular, weakest first:
    its aliases, its name, its full name (with and without the leading slash)."""
    fq = spec.fully_qualified_name
    keys: list[str] = []
    for name in (*spec.aliases, spec.name):
        if name.startswith('/'):  # a full name: the node's before rename_cameras moved it
            keys += [name.lstrip('/'), name]
            continue
        full = f'{spec.namespace.rstrip("/")}/{name}'
        keys += [name, full.lstrip('/'), full]
    return [k for i, k in enumerate(keys) if k not in keys[:i]] + (
        [fq] if fq not in keys else [])


def parameters_for(spec: NodeSpec, params: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The parameters of ``spec``: its own, then ``/**``, then by alias, name, full name."""
    merged = dict(spec.parameters)
    for key in ('/**', *node_keys(spec)):
        merged.update(params.get(key, {}))
    return merged


def addressed_parameters(spec: NodeSpec, params: dict[str, dict[str, Any]]) -> set[str]:
    """Names set for this node in particular (not through ``/**``): these must exist."""
    names = set(spec.parameters)
    for key in node_keys(spec):
        names.update(params.get(key, {}))
    return names


def unmatched_entries(config: GraphConfig, params: dict[str, dict[str, Any]]) -> list[str]:
    """The keys of a parameter file that address no node of ``config`` (``/**`` always
    matches): rclpy would ignore them, so the commands report them."""
    known = {key for spec in config.nodes for key in node_keys(spec)}
    return sorted(key for key in params if key != '/**' and key not in known)


def unmatched_warning(config: GraphConfig, key: str, *, ignored: bool = True) -> str:
    """What to say of a parameter-file entry that matches no node: the closest name a node
    answers to, and the names of the graph's nodes."""
    known = sorted({k for spec in config.nodes for k in node_keys(spec)})
    close = difflib.get_close_matches(key, known, n=1)
    hint = f' (did you mean {close[0]}?)' if close else ''
    return (f'parameter file entry {key!r} matches no node of the graph{hint}'
            f'{"; it is ignored" if ignored else ""} (nodes: '
            f'{", ".join(n.fully_qualified_name for n in config.nodes)})')
