"""`depth-nodes param` against a real sgm_stereo node in a subprocess: list, get, set (with
the node's reasons for refusing), dump into a params file that another node starts from."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from helpers import REPO, START_TIMEOUT, graph_env, interrupt, run_cli
from rcl_interfaces.msg import ParameterDescriptor, ParameterType

from depth_nodes.tools.live.param import coerce_to_declared, nest, parse_value, to_python

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NODE = '/stereo/sgm_stereo'
def _start_sgm_node(env: dict[str, str], *ros_args: str) -> subprocess.Popen[str]:
    """sgm_stereo in namespace /stereo, once `param list` reaches it."""
    proc = subprocess.Popen(
        [sys.executable, '-m', 'depth_nodes.nodes.scripts', 'sgm_stereo', '--ros-args',
         '-r', '__ns:=/stereo', *ros_args],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=REPO)
    deadline = time.monotonic() + START_TIMEOUT
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f'sgm_stereo exited with {proc.returncode}: '
                                 f'{proc.stdout.read() if proc.stdout else ""}')
        if run_cli(['param', 'list', NODE, '--timeout', '5'], env=env).returncode == 0:
            return proc
    interrupt(proc)
    raise AssertionError(f'sgm_stereo did not come up within {START_TIMEOUT:g} s')


@pytest.fixture(scope='module')
def graph() -> Iterator[dict[str, str]]:
    """One sgm_stereo node shared by the tests of this module; yields the environment
    that reaches it. Tests that set values each use parameters of their own."""
    env = graph_env()
    proc = _start_sgm_node(env)
    try:
        yield env
    finally:
        output = interrupt(proc)
    assert proc.returncode == 0, output  # a clean exit on Ctrl-C


def _param(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return run_cli(['param', *args], env=env, timeout=120)


def _get(env: dict[str, str], name: str, node: str = NODE) -> str:
    result = _param(env, 'get', node, name)
    assert result.returncode == 0, result.stderr
    return result.stdout.strip()


def test_parse_value_like_ros2_param() -> None:
    assert (parse_value('5').type, parse_value('5').integer_value) == (
        ParameterType.PARAMETER_INTEGER, 5)
    assert parse_value('-4').integer_value == -4
    assert (parse_value('5.0').type, parse_value('5.0').double_value) == (
        ParameterType.PARAMETER_DOUBLE, 5.0)
    assert (parse_value('true').type, parse_value('true').bool_value) == (
        ParameterType.PARAMETER_BOOL, True)
    assert to_python(parse_value('[1, 2]')) == [1, 2]
    assert parse_value('[1, 2]').type == ParameterType.PARAMETER_INTEGER_ARRAY
    assert parse_value('[1.5, 2.0]').type == ParameterType.PARAMETER_DOUBLE_ARRAY
    assert to_python(parse_value('[a, b]')) == ['a', 'b']
    for text in ('linear', '[1, a]', '{a: 1}', 'a: b: c', ''):
        value = parse_value(text)
        assert (value.type, value.string_value) == (ParameterType.PARAMETER_STRING,
                                                    text), text


def test_coerce_only_int_to_double() -> None:
    double = ParameterDescriptor(type=ParameterType.PARAMETER_DOUBLE)
    value = coerce_to_declared(parse_value('300'), double)
    assert (value.type, value.double_value) == (ParameterType.PARAMETER_DOUBLE, 300.0)
    doubles = ParameterDescriptor(type=ParameterType.PARAMETER_DOUBLE_ARRAY)
    assert to_python(coerce_to_declared(parse_value('[1, 2]'), doubles)) == [1.0, 2.0]
    integer = ParameterDescriptor(type=ParameterType.PARAMETER_INTEGER)
    assert coerce_to_declared(parse_value('2.5'), integer).type == (
        ParameterType.PARAMETER_DOUBLE)
    dynamic = ParameterDescriptor(type=ParameterType.PARAMETER_DOUBLE, dynamic_typing=True)
    assert coerce_to_declared(parse_value('3'), dynamic).type == ParameterType.PARAMETER_INTEGER


def test_nest_splits_dotted_names() -> None:
    assert nest({'a.b.c': 1, 'a.b.d': 2, 'e': 3}) == {'a': {'b': {'c': 1, 'd': 2}}, 'e': 3}
    # 'a' is a value and a prefix: 'a.b' keeps its dotted name beside it
    assert nest({'a': 1, 'a.b': 2, 'a.c.d': 3}) == {'a': 1, 'a.b': 2, 'a.c.d': 3}


def test_list_names_every_parameter_sorted(graph: dict[str, str]) -> None:
    result = _param(graph, 'list', NODE)
    assert result.returncode == 0, result.stderr
    names = result.stdout.split()
    assert names == sorted(names)
    assert {'P1', 'P2', 'disparity_range', 'uniqueness_ratio', 'stereo_algorithm', 'queue_size',
            'use_sim_time'} <= set(names)
    assert 'qos_overrides./stereo/disparity.publisher.reliability' in names


def test_get_prints_defaults_by_type(graph: dict[str, str]) -> None:
    assert _get(graph, 'P2') == 'Double value is: 220.0'
    assert _get(graph, 'disparity_range') == 'Integer value is: 128'
    assert _get(graph, 'intensity_cost') == 'String value is: bt'
    assert _get(graph, 'median_filter') == 'Boolean value is: False'


def test_node_name_without_leading_slash(graph: dict[str, str]) -> None:
    assert _get(graph, 'P1', node=NODE.lstrip('/')) == 'Double value is: 18.0'


def test_set_then_get(graph: dict[str, str]) -> None:
    result = _param(graph, 'set', NODE, 'intensity_truncation', '40')
    assert (result.returncode, result.stdout, result.stderr) == (
        0, 'Set parameter successful\n', '')
    assert _get(graph, 'intensity_truncation') == 'Integer value is: 40'
    assert _param(graph, 'set', NODE, 'min_disparity', '-4').returncode == 0
    assert _get(graph, 'min_disparity') == 'Integer value is: -4'
    assert _param(graph, 'set', NODE, 'subpixel', 'equiangular').returncode == 0
    assert _get(graph, 'subpixel') == 'String value is: equiangular'


def test_set_int_into_double_parameter(graph: dict[str, str]) -> None:
    result = _param(graph, 'set', NODE, 'uniqueness_ratio', '15')
    assert result.returncode == 0, result.stderr
    assert _get(graph, 'uniqueness_ratio') == 'Double value is: 15.0'


@pytest.mark.parametrize(('name', 'value', 'reason', 'kept'), [
    ('disparity_range', '0', 'Parameter disparity_range out of range. Min: 1, Max: 4096, '
     'value: 0', 'Integer value is: 128'),
    ('P2', '10', 'SGM parameter P2=10: must be >= P1 (18)', 'Double value is: 220.0'),
    ('census_width', '4', "census_width=4 rejected: must be odd", 'Integer value is: 5'),
    ('census_weight', 'abc', "Wrong parameter type, expected 'Type.INTEGER' got "
     "'Type.STRING'", 'Integer value is: 1'),
    ('queue_size', '7', 'Trying to set a read-only parameter: queue_size.',
     'Integer value is: 5'),
])
def test_refused_value_fails_with_node_reason(graph: dict[str, str], name: str, value: str,
                                              reason: str, kept: str) -> None:
    result = _param(graph, 'set', NODE, name, value)
    assert result.returncode == 1
    assert result.stdout == ''
    assert result.stderr == f'depth-nodes param: error: Setting parameter failed: {reason}\n'
    assert _get(graph, name) == kept


def test_unknown_parameter(graph: dict[str, str]) -> None:
    got = _param(graph, 'get', NODE, 'no_such_param')
    assert got.returncode == 1
    assert got.stderr == ("depth-nodes param: error: node /stereo/sgm_stereo has no "
                          "parameter 'no_such_param'\n")
    put = _param(graph, 'set', NODE, 'no_such_param', '1')
    assert put.returncode == 1
    assert put.stderr == ('depth-nodes param: error: Setting parameter failed: node '
                          "/stereo/sgm_stereo has no parameter 'no_such_param'\n")


def test_unknown_node_names_the_visible_ones(graph: dict[str, str]) -> None:
    prefix = 'depth-nodes param: error: node /stereo/no_such_node not found ('
    why = ('not in the graph', 'its parameter services did not appear within 2 s')
    visible = '; visible nodes: /stereo/sgm_stereo\n'
    # A new process may not have discovered the node's name within 2 s: then the list is
    # left out (and the reason is the timeout). Ask again until it is there.
    for _ in range(10):
        result = _param(graph, 'list', '/stereo/no_such_node', '--timeout', '2')
        assert (result.returncode, result.stdout) == (1, '')
        assert result.stderr in {f'{prefix}{w}){end}' for w in why for end in ('\n', visible)}
        if result.stderr.endswith(visible):
            break
    assert result.stderr.endswith(visible)


@pytest.mark.parametrize(('args', 'message'), [
    (['list', '/bad name'], "invalid node name '/bad name' (expected e.g. /stereo/sgm_stereo)"),
    (['list', '/stereo/'], "invalid node name '/stereo/' (expected e.g. /stereo/sgm_stereo)"),
    (['get', NODE, 'P1', '--timeout', '-1'], '--timeout must be positive, got -1'),
])
def test_bad_arguments(args: list[str], message: str) -> None:
    result = run_cli(['param', *args])
    assert (result.returncode, result.stderr) == (1, f'depth-nodes param: error: {message}\n')


def test_dump_round_trips_through_params_file(graph: dict[str, str], tmp_path: Path) -> None:
    assert _param(graph, 'set', NODE, 'p2_adaptive_scale', '12.5').returncode == 0
    assert _param(graph, 'set', NODE, 'full_dp', 'false').returncode == 0
    dumped = _param(graph, 'dump', NODE)
    assert dumped.returncode == 0, dumped.stderr
    first = yaml.safe_load(dumped.stdout)
    assert list(first) == [NODE]
    params = first[NODE]['ros__parameters']
    assert (params['p2_adaptive_scale'], params['full_dp'], params['P2']) == (12.5, False, 220.0)
    assert params['qos_overrides']['/stereo/disparity']['publisher']['reliability'] == (
        'reliable')
    params_file = tmp_path / 'params.yaml'
    params_file.write_text(dumped.stdout)

    # the same node name, in a graph of its own, started from the file
    env = graph_env()
    proc = _start_sgm_node(env, '--params-file', str(params_file))
    try:
        assert _get(env, 'p2_adaptive_scale') == 'Double value is: 12.5'
        assert _get(env, 'full_dp') == 'Boolean value is: False'
        again = _param(env, 'dump', NODE)
        assert again.returncode == 0, again.stderr
        assert yaml.safe_load(again.stdout) == first
    finally:
        output = interrupt(proc)
    assert proc.returncode == 0, output  # a clean exit on Ctrl-C
    # and the offline harness takes the same file (nested qos_overrides included)
    processed = run_cli(['process', str(REPO / 'bags' / 'stereo_qvga_color'),
                         str(tmp_path / 'out'), '--params', str(params_file)])
    assert processed.returncode == 0, processed.stderr


def test_describe_shows_the_rule_the_core_defines(graph: dict[str, str]) -> None:
    """census_width's description, range and oddness come from SgmParams' setting."""
    from depth_nodes.core.settings import rule_of
    from depth_nodes.core.sgm import SgmParams

    result = _param(graph, 'describe', NODE, 'census_width')
    assert result.returncode == 0, result.stderr
    rule = rule_of(SgmParams, 'census_width')
    assert result.stdout.splitlines() == [
        'Parameter name: census_width', '  Type: integer',
        f'  Description: census SGM: {rule.description}', '  Constraints:',
        '    Min value: 3', '    Max value: 9', '  Other constraints: odd']
    missing = _param(graph, 'describe', NODE, 'census_wdith')
    assert missing.returncode == 1
    assert f"node {NODE} has no parameter 'census_wdith'" in missing.stderr
