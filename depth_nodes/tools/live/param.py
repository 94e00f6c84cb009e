"""`depth-nodes param`: a running node's parameters, like ``ros2 param`` (not on PyPI).

Talks to the node's standard parameter services (``<node>/list_parameters``,
``get_parameters``, ``set_parameters``, ``describe_parameters``) from a short-lived,
hidden client node. Discovery settings (``ROS_DOMAIN_ID``, ``ROS_AUTOMATIC_DISCOVERY_RANGE``)
come from the environment, as for any ROS 2 tool.
"""

from __future__ import annotations

import difflib
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import Any

import yaml
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterDescriptor, ParameterType, ParameterValue
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
from rclpy.exceptions import InvalidNamespaceException, InvalidNodeNameException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.validate_namespace import validate_namespace
from rclpy.validate_node_name import validate_node_name

from depth_nodes.errors import ConfigError
from depth_nodes.tools.live.introspect import (
    DISCOVERY_S,
    STABLE_S,
    graph_node,
    settle,
    unnamed_endpoints,
    visible_nodes,
)

#: Seconds to wait for the node's services (and for each answer) unless told otherwise.
DEFAULT_TIMEOUT = 10.0

#: ``get`` output labels by parameter type, as ``ros2 param get`` prints them.
_LABELS = {
    ParameterType.PARAMETER_BOOL: 'Boolean value is:',
    ParameterType.PARAMETER_INTEGER: 'Integer value is:',
    ParameterType.PARAMETER_DOUBLE: 'Double value is:',
    ParameterType.PARAMETER_STRING: 'String value is:',
    ParameterType.PARAMETER_BYTE_ARRAY: 'Byte values are:',
    ParameterType.PARAMETER_BOOL_ARRAY: 'Boolean values are:',
    ParameterType.PARAMETER_INTEGER_ARRAY: 'Integer values are:',
    ParameterType.PARAMETER_DOUBLE_ARRAY: 'Double values are:',
    ParameterType.PARAMETER_STRING_ARRAY: 'String values are:',
}

_SERVICES = {
    'list': ListParameters, 'get': GetParameters, 'set': SetParameters,
    'describe': DescribeParameters,
}


def full_node_name(node: str) -> str:
    """``node`` as a fully qualified name: ``stereo/sgm_stereo`` -> ``/stereo/sgm_stereo``.

    Raises:
        ConfigError: Not a valid node name.
    """
    full = node if node.startswith('/') else f'/{node}'
    namespace, _, name = full.rpartition('/')
    try:
        validate_node_name(name)
        validate_namespace(namespace or '/')
    except (InvalidNodeNameException, InvalidNamespaceException):
        raise ConfigError(f'invalid node name {node!r} (expected e.g. /stereo/sgm_stereo)'
                          ) from None
    return full


def parse_value(text: str) -> ParameterValue:
    """``text`` as ``ros2 param set`` reads it: a YAML bool, integer, double or a list of
    one of those (or of strings); anything else is the string itself."""
    try:
        loaded = yaml.safe_load(text)
    except yaml.YAMLError:
        loaded = text
    value = ParameterValue()
    if isinstance(loaded, bool):
        value.type, value.bool_value = ParameterType.PARAMETER_BOOL, loaded
    elif isinstance(loaded, int):
        value.type, value.integer_value = ParameterType.PARAMETER_INTEGER, loaded
    elif isinstance(loaded, float):
        value.type, value.double_value = ParameterType.PARAMETER_DOUBLE, loaded
    elif isinstance(loaded, list) and all(isinstance(v, bool) for v in loaded):
        value.type, value.bool_array_value = ParameterType.PARAMETER_BOOL_ARRAY, loaded
    elif isinstance(loaded, list) and all(type(v) is int for v in loaded):
        value.type, value.integer_array_value = ParameterType.PARAMETER_INTEGER_ARRAY, loaded
    elif isinstance(loaded, list) and all(type(v) is float for v in loaded):
        value.type, value.double_array_value = ParameterType.PARAMETER_DOUBLE_ARRAY, loaded
    elif isinstance(loaded, list) and all(isinstance(v, str) for v in loaded):
        value.type, value.string_array_value = ParameterType.PARAMETER_STRING_ARRAY, loaded
    else:
        value.type = ParameterType.PARAMETER_STRING
        value.string_value = loaded if isinstance(loaded, str) else text
    return value


def coerce_to_declared(value: ParameterValue, descriptor: ParameterDescriptor) -> ParameterValue:
    """``value`` converted to the declared type where no information is lost: an integer
    (array) typed for a double (array) parameter becomes a double (array).

    ``ros2 param set`` sends ``300`` as an integer and the node refuses it for a double
    parameter; ``depth-nodes param set`` sends ``300.0`` instead. Other mismatches are sent
    as they are, so the node names them.
    """
    if descriptor.dynamic_typing:
        return value
    if (value.type == ParameterType.PARAMETER_INTEGER
            and descriptor.type == ParameterType.PARAMETER_DOUBLE):
        return ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                              double_value=float(value.integer_value))
    if (value.type == ParameterType.PARAMETER_INTEGER_ARRAY
            and descriptor.type == ParameterType.PARAMETER_DOUBLE_ARRAY):
        return ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY,
                              double_array_value=[float(v) for v in value.integer_array_value])
    return value


def to_python(value: ParameterValue) -> Any:
    """The plain Python value (lists for arrays, ints for bytes); None when not set."""
    if value.type == ParameterType.PARAMETER_BYTE_ARRAY:
        return [int.from_bytes(b, 'little') for b in value.byte_array_value]
    return parameter_value_to_python(value)


def format_value(value: ParameterValue) -> str:
    """One line as ``ros2 param get`` prints it: ``Double value is: 220.0``."""
    return f'{_LABELS[value.type]} {to_python(value)}'


def nest(values: Mapping[str, Any]) -> dict[str, Any]:
    """Parameters as the nested mapping of a parameter file: ``a.b.c`` -> ``{a: {b: {c:}}}``.

    Where a name is both a parameter and a prefix (``a`` and ``a.b``), the longer one keeps
    its dotted name at the deepest level that is still a mapping; the YAML parser of
    ``--params-file`` joins nested keys with dots, so both forms load the same.
    """
    tree: dict[str, Any] = {}
    for name in sorted(values):  # a prefix sorts before its children
        level, parts = tree, name.split('.')
        for i, part in enumerate(parts[:-1]):
            child = level.setdefault(part, {})
            if not isinstance(child, dict):
                level['.'.join(parts[i:])] = values[name]
                break
            level = child
        else:
            level[parts[-1]] = values[name]
    return tree


def dump_yaml(node: str, values: Mapping[str, Any]) -> str:
    """A parameter file for ``--params-file``: ``/ns/node: {ros__parameters: {...}}``."""
    return str(yaml.safe_dump({node: {'ros__parameters': nest(values)}},
                              default_flow_style=False, sort_keys=True))


def srv_name(verb: str) -> str:
    """The service name of ``verb``: ``list`` -> ``list_parameters``."""
    return f'{verb}_parameters'


class ParameterClient:
    """Calls one remote node's parameter services; use :func:`connect` to make one.

    Args:
        node: The local client node.
        executor: Spins ``node`` while waiting for answers.
        target: Fully qualified name of the remote node.
        timeout: Seconds to wait for each answer.
    """

    def __init__(self, node: Node, executor: SingleThreadedExecutor, target: str,
                 timeout: float) -> None:
        self.target = target
        self._node = node
        self._executor = executor
        self._timeout = timeout
        self._clients = {verb: node.create_client(srv, f'{target}/{srv_name(verb)}')
                         for verb, srv in _SERVICES.items()}

    def wait(self, verbs: tuple[str, ...]) -> None:
        """Wait up to the timeout for the services of ``verbs``; give up sooner when the
        graph's node list has settled (see ``introspect.settle``) without the node.

        Raises:
            ConfigError: They did not appear; names the nodes that are visible.
        """
        start = time.monotonic()
        deadline = start + self._timeout
        seen, stable_since = visible_nodes(self._node), start
        while not all(self._clients[v].service_is_ready() for v in verbs):
            now = time.monotonic()
            visible = visible_nodes(self._node)
            if visible != seen:
                seen, stable_since = visible, now
            # a missing node is reported before the timeout once the node list has held
            # still without it, but not before half the timeout: a busy process (a graph
            # at full load on few cores) can announce itself seconds late
            settled = (now - start >= max(DISCOVERY_S, self._timeout / 2)
                       and now - stable_since >= STABLE_S
                       and visible and self.target not in visible
                       and not unnamed_endpoints(self._node))
            if now >= deadline or settled:
                shown = f'; visible nodes: {", ".join(visible)}' if visible else ''
                close = difflib.get_close_matches(self.target, visible, n=1)
                if close:
                    shown = f'; did you mean {close[0]}?{shown}'
                why = ('not in the graph' if settled else
                       f'its parameter services did not appear within {self._timeout:g} s')
                raise ConfigError(f'node {self.target} not found ({why}){shown}')
            self._executor.spin_once(timeout_sec=0.05)

    def call(self, verb: str, request: Any) -> Any:
        """Send ``request`` to the ``verb`` service and return the response.

        Raises:
            ConfigError: No answer within the timeout.
        """
        future = self._clients[verb].call_async(request)
        self._executor.spin_until_future_complete(future, timeout_sec=self._timeout)
        if not future.done() or future.result() is None:
            future.cancel()
            raise ConfigError(f'node {self.target} did not answer {srv_name(verb)} within '
                              f'{self._timeout:g} s')
        return future.result()

    def names(self) -> list[str]:
        """Every parameter name of the node, sorted."""
        return sorted(self.call('list', ListParameters.Request()).result.names)

    def values(self, names: list[str]) -> list[ParameterValue]:
        """The values of ``names``; empty when one of them is not declared."""
        return list(self.call('get', GetParameters.Request(names=names)).values)


@contextmanager
def connect(node: str, verbs: tuple[str, ...], *,
            timeout: float = DEFAULT_TIMEOUT) -> Iterator[ParameterClient]:
    """A client of ``node``'s parameter services, once those of ``verbs`` are available.

    Raises:
        ConfigError: Invalid node name or timeout, or the node was not found.
    """
    target = full_node_name(node)
    if not timeout > 0:
        raise ConfigError(f'--timeout must be positive, got {timeout:g}')
    with graph_node('param') as (local, executor):
        client = ParameterClient(local, executor, target, timeout)
        client.wait(verbs)
        yield client


def list_parameters(node: str, *, timeout: float = DEFAULT_TIMEOUT) -> list[str]:
    """The parameter names of ``node``, sorted (``ros2 param list``)."""
    with connect(node, ('list',), timeout=timeout) as client:
        return client.names()


def get_parameter(node: str, name: str, *, timeout: float = DEFAULT_TIMEOUT) -> ParameterValue:
    """The value of ``name`` on ``node`` (``ros2 param get``).

    Raises:
        ConfigError: The node has no such parameter, or it is not set.
    """
    with connect(node, ('get', 'list'), timeout=timeout) as client:
        values = client.values([name])
        if values and values[0].type != ParameterType.PARAMETER_NOT_SET:
            return values[0]
        if name in client.names():
            raise ConfigError(f'parameter {name!r} of {client.target} is not set')
        raise ConfigError(f'node {client.target} has no parameter {name!r}')


def set_parameter(node: str, name: str, text: str, *,
                  timeout: float = DEFAULT_TIMEOUT) -> ParameterValue:
    """Set ``name`` on ``node`` to ``text`` read as :func:`parse_value` does (``ros2 param
    set``), converted by :func:`coerce_to_declared` to the type the node declared (its
    DescribeParameters answer). Returns the value sent.

    Raises:
        ConfigError: The node refused the value (the message carries the node's reason, or
            says that it has no such parameter).
    """
    with connect(node, ('describe', 'set'), timeout=timeout) as client:
        value = parse_value(text)
        described = client.call('describe', DescribeParameters.Request(names=[name]))
        if described.descriptors:
            value = coerce_to_declared(value, described.descriptors[0])
        request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)])
        results = client.call('set', request).results
        if not results or not results[0].successful:
            reason = ' '.join(results[0].reason.split()) if results else ''
            if not described.descriptors:  # rclpy's reason would name no parameter
                reason = f'node {client.target} has no parameter {name!r}'
            raise ConfigError('Setting parameter failed' + (f': {reason}' if reason else ''))
        return value


#: Type names as ``ros2 param describe`` prints them.
_TYPE_NAMES = {
    ParameterType.PARAMETER_BOOL: 'boolean', ParameterType.PARAMETER_INTEGER: 'integer',
    ParameterType.PARAMETER_DOUBLE: 'double', ParameterType.PARAMETER_STRING: 'string',
    ParameterType.PARAMETER_BYTE_ARRAY: 'byte array',
    ParameterType.PARAMETER_BOOL_ARRAY: 'boolean array',
    ParameterType.PARAMETER_INTEGER_ARRAY: 'integer array',
    ParameterType.PARAMETER_DOUBLE_ARRAY: 'double array',
    ParameterType.PARAMETER_STRING_ARRAY: 'string array',
}


def describe_parameter(node: str, name: str, *, timeout: float = DEFAULT_TIMEOUT) -> str:
    """What ``ros2 param describe`` prints: type, description, read-only and range.

    Raises:
        ConfigError: The node has no such parameter.
    """
    with connect(node, ('describe', 'list'), timeout=timeout) as client:
        if name not in client.names():
            raise ConfigError(f'node {client.target} has no parameter {name!r}')
        (d,) = client.call('describe', DescribeParameters.Request(names=[name])).descriptors
    lines = [f'Parameter name: {name}', f'  Type: {_TYPE_NAMES.get(d.type, "not set")}',
             f'  Description: {d.description}']
    if d.read_only or d.dynamic_typing:
        lines.append('  Read only: yes' if d.read_only else '  Dynamic typing: yes')
    for ranged in (*d.integer_range, *d.floating_point_range):
        lines += ['  Constraints:', f'    Min value: {ranged.from_value}',
                  f'    Max value: {ranged.to_value}']
    if d.additional_constraints:
        lines.append(f'  Other constraints: {d.additional_constraints}')
    return '\n'.join(lines)


def dump_parameters(node: str, *, timeout: float = DEFAULT_TIMEOUT) -> str:
    """Every parameter of ``node`` as a parameter file (``ros2 param dump``)."""
    with connect(node, ('list', 'get'), timeout=timeout) as client:
        names = client.names()
        values = client.values(names)
        if len(values) != len(names):  # a parameter was undeclared in between
            raise ConfigError(f'the parameters of {client.target} changed while reading them')
        python = {n: to_python(v) for n, v in zip(names, values, strict=True)
                  if v.type != ParameterType.PARAMETER_NOT_SET}
        return dump_yaml(client.target, python)


def _offers_parameters(node: Node, name: str) -> bool:
    """Whether the graph shows ``name``'s list_parameters service (a node may run without
    parameter services)."""
    namespace, _, base = name.rpartition('/')
    try:
        services = node.get_service_names_and_types_by_node(base, namespace or '/')
    except Exception:  # the node left meanwhile: ask it, the answer will say so
        return True
    return any(s == f'{name}/{srv_name("list")}' for s, _ in services)


def list_all_parameters(*, timeout: float = DEFAULT_TIMEOUT) -> dict[str, list[str] | None]:
    """Every visible node's parameter names (``ros2 param list`` without a node): none for
    a node without parameter services, None for one that did not answer within
    ``timeout`` s (gone, or not spinning)."""
    with graph_node('param_list') as (node, executor):
        settle(node, executor, DISCOVERY_S)
        # ask every node at once: one that never answers (a busy `play`) costs the
        # timeout once, not once per node
        clients = {name: node.create_client(ListParameters, f'{name}/{srv_name("list")}')
                   for name in visible_nodes(node) if _offers_parameters(node, name)}
        deadline = time.monotonic() + timeout
        futures: dict[str, Any] = {}
        while time.monotonic() < deadline:
            for name, client in clients.items():
                if name not in futures and client.service_is_ready():
                    futures[name] = client.call_async(ListParameters.Request())
            if len(futures) == len(clients) and all(f.done() for f in futures.values()):
                break
            executor.spin_once(timeout_sec=0.05)
        out: dict[str, list[str] | None] = {name: [] for name in visible_nodes(node)
                                            if name not in clients}
        for name in clients:
            future = futures.get(name)
            if future is not None and future.done() and future.result() is not None:
                out[name] = sorted(future.result().result.names)
            else:
                if future is not None:
                    future.cancel()
                out[name] = None
    return out
