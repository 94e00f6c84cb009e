"""The YAML schema of a graph description: which nodes to run, with what names,
namespaces, parameters and remappings::

    graph:
      name: stereo
      nodes:
        - name: rectify_left          # node name
          plugin: rectify             # a name in NODE_PLUGINS, or 'package.module:Class'
          namespace: /stereo/left
          parameters: {interpolation: linear}
          remappings: {image: image_raw}
          aliases: [rectify_node]     # other names a parameter file may use for it
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from depth_nodes.errors import ConfigError, yaml_problem

#: The keys a node entry may have.
NODE_KEYS = frozenset({'name', 'plugin', 'namespace', 'parameters', 'remappings', 'aliases'})


@dataclass
class NodeSpec:
    """One node of a graph description."""

    name: str
    plugin: str
    namespace: str = '/'
    parameters: dict[str, Any] = field(default_factory=dict)
    remappings: dict[str, str] = field(default_factory=dict)
    #: Other names a parameter file may address this node by (e.g. ``disparity_node``,
    #: stereo_image_proc's name for the node this one replaces).
    aliases: list[str] = field(default_factory=list)

    @property
    def fully_qualified_name(self) -> str:
        """``/namespace/name``."""
        return f'{self.namespace.rstrip("/")}/{self.name}'


@dataclass
class GraphConfig:
    """A named list of nodes."""

    name: str
    nodes: list[NodeSpec]
    source: str = ''


def load_yaml(path: Path, what: str) -> Any:
    """The YAML document at ``path``.

    Raises:
        ConfigError: The file (called ``what`` in the message) is missing or not YAML.
    """
    if not path.is_file():
        raise ConfigError(f'{what} not found: {path}')
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f'{what} {path} is not valid YAML: {yaml_problem(exc)}') from None


def load_graph_config(path: str | Path) -> GraphConfig:
    """Read a graph description.

    Raises:
        ConfigError: The file is missing, not YAML, or a node entry is malformed.
    """
    path = Path(path)
    doc = load_yaml(path, 'graph config')
    graph = doc.get('graph') if isinstance(doc, dict) else None
    if not isinstance(graph, dict):
        raise ConfigError(f'graph config {path} needs a top-level "graph:" mapping')
    entries = graph.get('nodes') or []
    if not isinstance(entries, list):
        raise ConfigError(f'graph config {path}: "nodes" must be a list')
    nodes = [_node_spec(entry, path, i) for i, entry in enumerate(entries)]
    names = [n.fully_qualified_name for n in nodes]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ConfigError(f'graph config {path}: node names used twice: {", ".join(dupes)}')
    return GraphConfig(str(graph.get('name', path.stem)), nodes, str(path))


def _node_spec(entry: Any, path: Path, index: int) -> NodeSpec:
    where = f'graph config {path}, node #{index + 1}'
    if not isinstance(entry, dict):
        raise ConfigError(f'{where}: expected a mapping, got {entry!r}')
    unknown = set(entry) - NODE_KEYS
    if unknown:
        raise ConfigError(f'{where}: unknown keys {sorted(unknown)}')
    for key in ('name', 'plugin'):
        if not isinstance(entry.get(key), str) or not entry[key]:
            raise ConfigError(f'{where}: "{key}" must be a non-empty string')
    namespace = entry.get('namespace', '/')
    if not isinstance(namespace, str) or not namespace.startswith('/'):
        raise ConfigError(f'{where}: "namespace" must be absolute, got {namespace!r}')
    params = entry.get('parameters') or {}
    remaps = entry.get('remappings') or {}
    aliases = entry.get('aliases') or []
    if not isinstance(params, dict) or not isinstance(remaps, dict):
        raise ConfigError(f'{where}: "parameters" and "remappings" must be mappings')
    if not isinstance(aliases, list) or not all(isinstance(a, str) and a for a in aliases):
        raise ConfigError(f'{where}: "aliases" must be a list of node names')
    return NodeSpec(
        entry['name'], entry['plugin'], namespace, dict(params),
        {str(k): str(v) for k, v in remaps.items()}, list(aliases),
    )
