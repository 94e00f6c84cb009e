"""The nodes of a graph description created: a plugin name resolved to its class, each node
instantiated with its parameters and remappings, and which nodes read a camera driver's
images.
"""

from __future__ import annotations

import importlib
from typing import Any

from rclpy.parameter import Parameter

from depth_nodes.errors import ConfigError
from depth_nodes.graph.parameter_files import addressed_parameters, parameters_for
from depth_nodes.graph.schema import GraphConfig, NodeSpec
from depth_nodes.nodes import NODE_PLUGINS
from depth_nodes.nodes.registry import entry_of
from depth_nodes.ros.node import DepthNode


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
    registry entry says ``camera_reader``: the rectifier, the structured-light decoder, the
    time-of-flight node): the ones an ``image_transport`` choice for the camera applies to.
    A plugin given as ``module:Class`` counts when it is a registry node's class."""
    readers = []
    for spec in config.nodes:
        entry = entry_of(spec.plugin)
        if entry is not None and entry.camera_reader:
            readers.append(spec.fully_qualified_name)
    return readers


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
