"""Graph descriptions: which nodes to run, with what names, namespaces and parameters.

One YAML format serves the offline bag harness (``depth-nodes process``) and, later, the
composed live pipeline::

    graph:
      name: stereo
      nodes:
        - name: rectify_left          # node name
          plugin: rectify             # a name in NODE_PLUGINS, or 'package.module:Class'
          namespace: /stereo/left
          parameters: {interpolation: linear}
          remappings: {image: image_raw}

Parameter files use the ROS 2 ``--params-file`` layout (``node: {ros__parameters: {...}}``,
with ``/**`` matching every node), so the same file works with ``ros2 run``.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from rclpy.parameter import Parameter

from depth_nodes.errors import ConfigError, yaml_problem
from depth_nodes.nodes import NODE_PLUGINS
from depth_nodes.ros.node import DepthNode


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


def _load_yaml(path: Path, what: str) -> Any:
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
    doc = _load_yaml(path, 'graph config')
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
    unknown = set(entry) - {'name', 'plugin', 'namespace', 'parameters', 'remappings',
                            'aliases'}
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


#: Topic names of one camera that the graphs use below its namespace (renamed with it).
CAMERA_TOPICS = ('image_raw', 'camera_info', 'image_rect', 'image_rect_color', 'image_mono',
                 'image_color')


def root_namespace(config: GraphConfig) -> str:
    """The namespace every node of ``config`` lives in (``/stereo`` for the stereo graph:
    its nodes are in /stereo, /stereo/left and /stereo/right)."""
    parts = [n.namespace.strip('/').split('/') for n in config.nodes]
    common: list[str] = []
    for level in zip(*parts, strict=False):
        if len(set(level)) != 1:
            break
        common.append(level[0])
    return '/' + '/'.join(p for p in common if p)


def rename_cameras(config: GraphConfig, *, namespace: str | None = None,
                   left: str | None = None, right: str | None = None,
                   image: str | None = None) -> GraphConfig:
    """The graph moved to a camera driver's names.

    Args:
        config: The graph (e.g. config/stereo_pipeline.yaml, under /stereo).
        namespace: Replaces the graph's root namespace (``/camera`` for a driver that
            publishes ``/camera/left/image_raw``).
        left: Replaces the left camera's name below it (``left``), e.g. ``infra1``.
        right: Replaces the right camera's name (``right``), e.g. ``infra2``.
        image: Replaces the raw image's name (``image_raw``), e.g. ``image_rect_raw``.

    Nodes move with their namespace; a node at the root keeps its relative topic names
    (``left/image_rect``) and gets remappings to the new side names; a remapping that
    pointed at a renamed topic points at its new name. A moved node keeps its old full
    name as an alias, so a parameter file written for the graph's own names (e.g.
    ``/stereo/sgm_stereo``) still reaches it.

    Raises:
        ConfigError: A name that is empty, relative where it must be absolute, or has
            characters ROS does not allow.
    """
    root = root_namespace(config)
    new_root = root if namespace is None else checked_namespace(namespace)
    sides = {k: checked_name(v, f'--{k}') for k, v in (('left', left), ('right', right))
             if v is not None and v != k}
    new_image = None if image is None or image == 'image_raw' else checked_name(image,
                                                                                  '--image')

    def move(name: str) -> str:
        """A topic or namespace name, relative or absolute, under the new names."""
        absolute = name.startswith('/')
        if absolute:
            if name != root and not name.startswith(root.rstrip('/') + '/'):
                return name
            rest = name[len(root):].strip('/')
        else:
            rest = name
        parts = rest.split('/') if rest else []
        if parts and parts[0] in sides:
            parts[0] = sides[parts[0]]
        if new_image is not None and parts and parts[-1] == 'image_raw':
            parts[-1] = new_image
        rest = '/'.join(parts)
        if not absolute:
            return rest
        return '/' + '/'.join(p for p in (new_root.strip('/'), rest) if p)

    nodes = []
    for spec in config.nodes:
        remaps = {src: move(dst) for src, dst in spec.remappings.items()}
        in_root = spec.namespace.rstrip('/') == root.rstrip('/')
        # the relative camera names this node may use, where they moved (a node at the
        # root reaches them through left/ and right/, one in a side's namespace directly)
        prefixes = ('left/', 'right/') if in_root else ('',)
        for name in (f'{prefix}{topic}' for prefix in prefixes for topic in CAMERA_TOPICS):
            if move(name) != name:
                remaps.setdefault(name, move(name))
        namespace = move(spec.namespace) or '/'
        aliases = list(spec.aliases)
        if namespace != spec.namespace:  # a parameter file written for the graph's names
            aliases.append(spec.fully_qualified_name)
        nodes.append(NodeSpec(spec.name, spec.plugin, namespace, dict(spec.parameters),
                              remaps, aliases))
    return GraphConfig(config.name, nodes, config.source)


def checked_name(value: str, what: str) -> str:
    """``value`` if it is a relative ROS name, else ConfigError naming ``what``."""
    if not value or not all(part and (part[0].isalpha() or part[0] == '_') and
                            all(c.isalnum() or c == '_' for c in part)
                            for part in value.split('/')):
        raise ConfigError(f'{what} {value!r} is not a ROS name (parts of letters, digits '
                          'and _, each starting with a letter or _, joined by single /)')
    return value


def checked_namespace(value: str, what: str = '--namespace') -> str:
    """``value`` as an absolute namespace (``/camera``), else ConfigError."""
    if not value.startswith('/'):
        raise ConfigError(f'{what} {value!r} must be absolute (start with /)')
    if value.strip('/'):
        checked_name(value.strip('/'), what)
    return '/' + value.strip('/')


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
    doc = _load_yaml(path, 'parameter file')
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
    import difflib

    known = sorted({k for spec in config.nodes for k in node_keys(spec)})
    close = difflib.get_close_matches(key, known, n=1)
    hint = f' (did you mean {close[0]}?)' if close else ''
    return (f'parameter file entry {key!r} matches no node of the graph{hint}'
            f'{"; it is ignored" if ignored else ""} (nodes: '
            f'{", ".join(n.fully_qualified_name for n in config.nodes)})')


def resolve_plugin(plugin: str) -> type:
    """Return the node class for a plugin name or a ``module:Class`` path.

    Raises:
        ConfigError: Unknown name, or the module or class cannot be imported.
    """
    target = NODE_PLUGINS.get(plugin, plugin)
    if ':' not in target:
        known = ', '.join(sorted(NODE_PLUGINS)) or 'none yet'
        raise ConfigError(f'unknown node plugin {plugin!r} (known: {known}; '
                          'or give package.module:Class)')
    module_name, _, class_name = target.partition(':')
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f'cannot import node plugin {plugin!r}: {exc}') from None
    cls = getattr(module, class_name, None)
    if not isinstance(cls, type):
        raise ConfigError(f'node plugin {plugin!r}: {module_name} has no class {class_name}')
    return cls


def instantiate(spec: NodeSpec, params: dict[str, Any], *, required: set[str] | None = None,
                **node_kwargs: Any) -> Any:
    """Create the node described by ``spec`` with ``params`` (and extra Node kwargs).

    Args:
        spec: The node.
        params: Parameter values to start it with.
        required: Names that the node must declare (those addressed to it in particular);
            rclpy would silently ignore an undeclared one, so a typo raises instead.
            Default: every name in ``params``.
        **node_kwargs: Passed to the node (e.g. ``context``).

    Raises:
        ConfigError: The plugin cannot be resolved, a parameter value has no ROS type, or
            a required parameter is not declared by the node.
    """
    cls = resolve_plugin(spec.plugin)
    if not (isinstance(cls, type) and issubclass(cls, DepthNode)):
        raise ConfigError(f'node plugin {spec.plugin!r} is not a DepthNode class')
    overrides = []
    for name, value in params.items():
        try:
            overrides.append(Parameter(name, value=value))
        except (TypeError, ValueError) as exc:
            raise ConfigError(f'node {spec.fully_qualified_name}: parameter {name}={value!r} '
                              f'has no ROS parameter type: {exc}') from None
    cli_args = ['--ros-args']
    for src, dst in spec.remappings.items():
        cli_args += ['-r', f'{src}:={dst}']
    node = cls(
        node_name=spec.name,
        namespace=spec.namespace,
        parameter_overrides=overrides,
        cli_args=cli_args,
        **node_kwargs,
    )
    required = set(params) if required is None else required
    unknown = sorted(name for name in required if not node.has_parameter(name))
    if unknown:  # rclpy would ignore them: a typo must not pass silently
        known = ', '.join(sorted(n for n in node.get_parameters_by_prefix('')
                                 if not n.startswith('qos_overrides')))
        node.destroy_node()
        raise ConfigError(f'node {spec.fully_qualified_name} ({spec.plugin}) has no parameter '
                          f'{", ".join(unknown)} (parameters: {known})')
    return node


def camera_readers(config: GraphConfig) -> list[str]:
    """Full names of the nodes of ``config`` that read a camera driver's images (their
    class says ``reads_camera_images``: the rectifier, the structured-light decoder): the
    ones an ``image_transport`` choice for the camera applies to."""
    return [spec.fully_qualified_name for spec in config.nodes
            if getattr(resolve_plugin(spec.plugin), 'reads_camera_images', False)]


def with_transport(params: dict[str, dict[str, Any]], node_names: list[str],
                   transport: str) -> dict[str, dict[str, Any]]:
    """``params`` with ``image_transport: transport`` added for each of ``node_names``."""
    out = {key: dict(values) for key, values in params.items()}
    for name in node_names:
        out[name] = {**out.get(name, {}), 'image_transport': transport}
    return out


def create_nodes(config: GraphConfig, params: dict[str, dict[str, Any]] | None = None,
                 **node_kwargs: Any) -> list[Any]:
    """Instantiate every node of ``config``: its parameters from the config, then from
    ``params`` (a loaded parameter file, see :func:`load_params_file`).

    Raises:
        ConfigError: As :func:`instantiate`; the nodes created so far are destroyed first.
    """
    params = params or {}
    nodes: list[Any] = []
    try:
        for spec in config.nodes:
            nodes.append(instantiate(spec, parameters_for(spec, params),
                                     required=addressed_parameters(spec, params),
                                     **node_kwargs))
    except BaseException:
        for node in nodes:
            node.destroy_node()
        raise
    return nodes
