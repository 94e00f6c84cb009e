"""Settings defined once: each algorithm's frozen ``*Params`` dataclass declares its fields
with :func:`setting` (default, one-line description, range, choices, odd), and every user
of a field reads its rule from there: the dataclass's own ``validate``, the node that
declares it as a ROS parameter (``depth_nodes.ros.params.specs_from``), the CLI. A rule
broken gives the same reason wherever it is checked (:func:`problem`).

Typical use::

    @dataclass(frozen=True)
    class MyParams:
        window: int = setting(5, 'Box side in px', low=1, high=31, odd=True)

        def validate(self) -> MyParams:
            return check_settings(self, 'my parameter')
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, TypeVar

from depth_nodes.errors import ArgumentError

T = TypeVar('T')


@dataclass(frozen=True)
class Rule:
    """What a setting accepts.

    Attributes:
        description: One line, shown by ``ros2 param describe`` and in the docs.
        low: Inclusive lower bound (numbers).
        high: Inclusive upper bound (numbers).
        choices: The only values allowed, if set.
        odd: The value must be odd (window sizes).
        number: An int or a float is accepted for a float setting (a ROS parameter with
            dynamic typing, as stereo_image_proc's files give some px values as integers).
    """

    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[Any, ...] | None = None
    odd: bool = False
    number: bool = False


def setting(default: Any, description: str | Rule, *, low: float | None = None,
            high: float | None = None, choices: tuple[Any, ...] | None = None,
            odd: bool = False, number: bool = False) -> Any:
    """A dataclass field with its :class:`Rule` (see the module notes); ``description``
    may be a whole :class:`Rule` that two dataclasses share."""
    rule = description if isinstance(description, Rule) else \
        Rule(description, low, high, choices, odd, number)
    return dataclasses.field(default=default, metadata={'rule': rule})


def problem(rule: Rule, value: Any) -> str | None:
    """Why ``value`` breaks ``rule``, or None when it does not."""
    if rule.choices is not None:
        same_kind = isinstance(value, bool) == isinstance(rule.choices[0], bool)
        if same_kind and value in rule.choices:  # True is not the choice 1
            return None
        return f'must be one of {", ".join(map(str, rule.choices))}'
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if isinstance(value, float) and not math.isfinite(value):
            return 'must be finite'
        low, high = rule.low, rule.high
        if low is not None and high is not None and not low <= value <= high:
            return f'must be in [{low:g}, {high:g}]'
        if low is not None and value < low:
            return f'must be >= {low:g}'
        if high is not None and value > high:
            return f'must be <= {high:g}'
        if rule.odd and value % 2 != 1:
            return 'must be odd'
    elif rule.number:
        return 'must be a number (integer or double)'
    return None


def rules(cls: type) -> Iterator[tuple[str, Any, Rule]]:
    """(name, default, rule) of every field of ``cls`` declared with :func:`setting`."""
    for f in dataclasses.fields(cls):
        rule = f.metadata.get('rule')
        if rule is not None:
            yield f.name, f.default, rule


def rule_of(cls: type, name: str) -> Rule:
    """The rule of field ``name`` of ``cls``."""
    for field_name, _, rule in rules(cls):
        if field_name == name:
            return rule
    raise KeyError(f'{cls.__name__} has no setting {name}')


def check_settings(params: T, label: str) -> T:
    """Check every field of ``params`` against its rule; returns ``params``.

    Raises:
        ArgumentError: ``'{label} {name}={value!r}: {reason}'`` for the first field that
            breaks its rule.
    """
    for name, _, rule in rules(type(params)):
        value = getattr(params, name)
        reason = problem(rule, value)
        if reason:
            raise ArgumentError(f'{label} {name}={value!r}: {reason}')
    return params
