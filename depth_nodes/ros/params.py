"""Node parameters: declared with descriptors, validated, and applied atomically.

A node lists :class:`ParamSpec` entries. :class:`NodeParameters` declares them (with
description, range and read-only flag, so ``ros2 param describe`` shows them), rejects a
change that is out of range, of the wrong type (rclpy checks these against the
descriptor), or that a spec's own check or the node's check of the whole set refuses
(with the reason returned to the caller), and otherwise swaps in a new immutable snapshot
of all values. A node reads :attr:`NodeParameters.values` once at the start of a frame, so
every frame sees one consistent set and a change applies from the next frame on.
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter

from depth_nodes.core.settings import Rule, problem, rules
from depth_nodes.errors import ArgumentError, ConfigError
from depth_nodes.ros.transport import TRANSPORTS

#: Returns None when a value is acceptable, else the reason it is not.
Check = Callable[[Any], str | None]
ValuesCheck = Callable[[Mapping[str, Any]], str | None]


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name, default, description and constraints.

    Attributes:
        name: Parameter name.
        default: Default value; its type is the parameter's type unless ``dynamic_typing``.
            A callable is given the values declared before this one and returns the
            default (a default that depends on another parameter's start-up value).
        description: One line shown by ``ros2 param describe``.
        min_value: Inclusive lower bound (numbers only).
        max_value: Inclusive upper bound (numbers only).
        read_only: Only settable at start-up (``--ros-args -p`` or a params file).
        dynamic_typing: Accept values of more than one type (``check`` must vet them).
        check: Extra validation: returns None when fine, else the reason.
        constraints: What ``check`` enforces, in words (``ros2 param describe`` shows it).
    """

    name: str
    default: Any
    description: str
    min_value: float | None = None
    max_value: float | None = None
    read_only: bool = False
    dynamic_typing: bool = False
    check: Check | None = None
    constraints: str = ''

    def descriptor(self) -> ParameterDescriptor:
        """The ROS descriptor: description, range, read-only and typing flags."""
        desc = ParameterDescriptor(description=self.description, read_only=self.read_only,
                                   dynamic_typing=self.dynamic_typing,
                                   additional_constraints=self.constraints)
        if self.min_value is not None and self.max_value is not None:
            if isinstance(self.default, int) and not isinstance(self.default, bool):
                desc.integer_range = [IntegerRange(from_value=int(self.min_value),
                                                   to_value=int(self.max_value), step=0)]
            elif isinstance(self.default, float):
                desc.floating_point_range = [FloatingPointRange(
                    from_value=float(self.min_value), to_value=float(self.max_value), step=0.0)]
        return desc


class NodeParameters:
    """Declares ``specs`` on ``node`` and keeps an atomically replaced snapshot of them.

    Args:
        node: The node.
        specs: Its parameters.
        check_values: Validation of the whole set (e.g. two values that must agree).

    Raises:
        ConfigError: A start-up value (override) is invalid.
    """

    def __init__(self, node: Node, specs: list[ParamSpec],
                 check_values: ValuesCheck | None = None) -> None:
        self._specs = {s.name: s for s in specs}
        self._check_values = check_values
        self._lock = threading.Lock()
        values: dict[str, Any] = {}
        for spec in specs:
            if callable(spec.default):
                spec = dataclasses.replace(spec, default=spec.default(dict(values)))
                self._specs[spec.name] = spec
            try:
                param = node.declare_parameter(spec.name, spec.default, spec.descriptor())
            except ParameterException as exc:
                raise ConfigError(f'{node.get_fully_qualified_name()}: parameter {spec.name}: '
                                  f'{exc}') from None
            values[spec.name] = param.value
        reason = self._validate(values, values)
        if reason:
            raise ConfigError(f'{node.get_fully_qualified_name()}: {reason}')
        self._values: Mapping[str, Any] = MappingProxyType(values)
        node.add_on_set_parameters_callback(self._on_set)

    @property
    def values(self) -> Mapping[str, Any]:
        """The current values (an immutable snapshot; take it once per frame)."""
        return self._values

    def _validate(self, candidate: Mapping[str, Any], changed: Mapping[str, Any]) -> str | None:
        for name, value in changed.items():
            spec = self._specs.get(name)
            if spec is not None and spec.check is not None:
                reason = spec.check(value)
                if reason:
                    return f'{name}={value!r} rejected: {reason}'
        if self._check_values is not None:
            return self._check_values(candidate)
        return None

    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        changed = {p.name: p.value for p in params if p.name in self._specs}
        if not changed:
            return SetParametersResult(successful=True)
        with self._lock:
            candidate = {**self._values, **changed}
            reason = self._validate(candidate, changed)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
            self._values = MappingProxyType(candidate)
        return SetParametersResult(successful=True)


def spec_of(name: str, default: Any, rule: Rule, *, prefix: str = '',
            read_only: bool = False) -> ParamSpec:
    """The parameter of a setting with ``rule`` (see :mod:`depth_nodes.core.settings`):
    its description, its range in the descriptor, its other rules (choices, odd, number)
    checked on set with the same reason the core gives."""
    ranged = rule.low is not None and rule.high is not None and not rule.number
    said = [f'one of {", ".join(map(str, rule.choices))}' if rule.choices else '',
            'odd' if rule.odd else '',
            f'integer or double in [{rule.low:g}, {rule.high:g}]' if rule.number and
            rule.low is not None and rule.high is not None else '']
    return ParamSpec(name, default, prefix + rule.description,
                     rule.low if ranged else None, rule.high if ranged else None,
                     read_only=read_only, dynamic_typing=rule.number,
                     check=lambda value: problem(rule, value),
                     constraints='; '.join(s for s in said if s))


def specs_from(params: type, names: tuple[str, ...] | list[str], *,
               prefix: str = '') -> list[ParamSpec]:
    """The parameters ``names`` of a core ``*Params`` dataclass, declared from its
    settings (default, description and rule)."""
    table = {name: (default, rule) for name, default, rule in rules(params)}
    return [spec_of(name, *table[name], prefix=prefix) for name in names]


def validated(build: Callable[[Mapping[str, Any]], Any]) -> ValuesCheck:
    """The check of the whole set of a node whose settings make a core ``*Params``:
    ``build`` makes it from a parameter snapshot, and its ``validate()`` error is the
    reason a change is refused."""
    def check(values: Mapping[str, Any]) -> str | None:
        try:
            build(values).validate()
        except ArgumentError as exc:
            return str(exc)
        return None
    return check


def one_of(choices: tuple[Any, ...] | list[Any]) -> Check:
    """A check that a value is one of ``choices`` (the reason lists them)."""
    rule = Rule('', choices=tuple(choices))
    return lambda value: problem(rule, value)


#: The ``image_transport`` parameter of a node with camera-image inputs, as image_pipeline's
#: nodes have it (image_transport's TransportHints).
IMAGE_TRANSPORT = ParamSpec(
    'image_transport', 'raw', 'How the camera images arrive: raw (sensor_msgs/Image on the '
    'topic), compressed (sensor_msgs/CompressedImage, JPEG or PNG, on <topic>/compressed) or '
    'compressedDepth (<topic>/compressedDepth)', read_only=True, check=one_of(TRANSPORTS))


def synchroniser_specs(inputs: str, *, qos: bool = True) -> list[ParamSpec]:
    """The synchronisation parameters of a node with several inputs, named and ranged as
    image_pipeline's nodes have them (``inputs`` names them for the description)."""
    specs = [
        ParamSpec('queue_size', 5, f'Synchroniser queue of {inputs}', 1, 1000,
                  read_only=True),
        ParamSpec('approximate_sync', False, 'Match inputs by the ApproximateTime policy '
                  'instead of exact stamps', read_only=True),
        ParamSpec('approximate_sync_tolerance_seconds', 0.0, 'Largest stamp spread of a set '
                  'with approximate_sync (0: no limit)', 0.0, 10.0, read_only=True),
    ]
    if qos:
        specs.append(ParamSpec('use_system_default_qos', False, 'Subscribe with the system '
                               'default QoS (reliable) instead of sensor data QoS',
                               read_only=True))
    return specs


#: The ``threads`` parameter of a node whose frame takes a few ms (the matcher has its own).
THREADS = ParamSpec('threads', 1, "Threads of this node's OpenCV and numba work; 0 (or more "
                    'than the cores): every core. A frame takes 5 - 20 ms here; under load a '
                    'second thread mostly spins waiting for the first (see the README, bench '
                    '--live)', 0, 1024)
