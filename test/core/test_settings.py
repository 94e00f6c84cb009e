"""A setting's rule, defined once in a core dataclass, gives one reason wherever it is
checked (depth_nodes.core.settings)."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from depth_nodes.core.cross_check import CrossCheckParams, lr_threshold
from depth_nodes.core.settings import Rule, check_settings, problem, rule_of, rules, setting
from depth_nodes.errors import ArgumentError


@pytest.mark.parametrize(('rule', 'value', 'reason'), [
    (Rule('', low=1, high=31, odd=True), 4, 'must be odd'),
    (Rule('', low=1, high=31, odd=True), 33, 'must be in [1, 31]'),
    (Rule('', low=1, high=31, odd=True), 5, None),
    (Rule('', low=0), -0.5, 'must be >= 0'),
    (Rule('', high=2), 3, 'must be <= 2'),
    (Rule('', low=0, high=1), float('nan'), 'must be finite'),
    (Rule('', choices=(0, 3, 5)), 4, 'must be one of 0, 3, 5'),
    (Rule('', choices=(0, 3, 5)), False, 'must be one of 0, 3, 5'),  # False is not 0 here
    (Rule('', choices=('bt', 'ad')), 'ad', None),
    (Rule('', low=0, high=64, number=True), 'x', 'must be a number (integer or double)'),
    (Rule('', low=0, high=64, number=True), 3, None),
])
def test_problem(rule: Rule, value: object, reason: str | None) -> None:
    assert problem(rule, value) == reason


@dataclass(frozen=True)
class _Box:
    side: int = setting(5, 'Side in px', low=1, high=31, odd=True)
    mode: str = setting('a', 'Mode', choices=('a', 'b'))
    plain: int = 3


def test_check_settings_names_the_field_and_reads_only_settings() -> None:
    assert check_settings(_Box(), 'box') == _Box()
    with pytest.raises(ArgumentError, match=r"^box side=6: must be odd$"):
        check_settings(_Box(side=6), 'box')
    with pytest.raises(ArgumentError, match=r"^box mode='c': must be one of a, b$"):
        check_settings(_Box(mode='c'), 'box')
    assert [name for name, _, _ in rules(_Box)] == ['side', 'mode']
    assert rule_of(_Box, 'side').description == 'Side in px'
    with pytest.raises(KeyError):
        rule_of(_Box, 'plain')


def test_cross_check_params_give_the_function_its_arguments() -> None:
    """disp12_max_diff as the node takes it: 0 is 1 px (OpenCV), -1 no check."""
    assert CrossCheckParams(disp12_max_diff=0).arguments()['disp12_max_diff'] == 1.0
    assert CrossCheckParams(disp12_max_diff=-1).arguments()['disp12_max_diff'] >= 1e6
    args = CrossCheckParams(fill_holes=True, keep_extrapolated=False).arguments()
    assert (args['fill'], args['keep_outside']) == (True, False)
    assert [lr_threshold(v) for v in (-1, 0, 2.5)] == [-1.0, 1.0, 2.5]
    with pytest.raises(ArgumentError, match='cross-check parameter median_size=4: must be '
                                            'one of 0, 3, 5'):
        CrossCheckParams(median_size=4).validate()
