"""The `depth-nodes` parser follows from its table of commands: ``--help`` lists them and the
package's nodes without importing any command's implementation, every command's and every
bench stage's ``--help`` works, and each bench stage has its own options and defaults."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from helpers import REPO, run_cli

from depth_nodes.errors import ConfigError
from depth_nodes.nodes import NODE_PLUGINS
from depth_nodes.tools.cli import COMMANDS, build_parser
from depth_nodes.tools.cli import bench as bench_cli
from depth_nodes.tools.cli.options import BUNDLED_BAGS

HEAVY = ('rclpy', 'numba', 'cv2', 'ray')


def _python(script: str) -> Any:
    """Run ``script`` in a fresh interpreter; what its last line printed, as JSON."""
    done = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                          cwd=REPO, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_top_level_help_imports_no_implementation() -> None:
    code, loaded = _python(f'''
import json, sys
from depth_nodes.tools.cli import main
try:
    main(['--help'])
except SystemExit as exc:
    code = exc.code
print(json.dumps([code, [m for m in {HEAVY!r} if m in sys.modules]]))
''')
    assert code == 0
    assert loaded == []


def test_top_level_help_lists_the_commands_and_the_nodes() -> None:
    result = run_cli(['--help'])
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith('usage: depth-nodes')
    for command in COMMANDS:
        assert f'    {command.name} ' in result.stdout
    epilog = result.stdout.split('nodes (run one with: ros2 run depth_nodes NAME, or NAME '
                                 '--help):\n')[1]
    assert ' '.join(epilog.split()) == ', '.join(NODE_PLUGINS)


def test_every_command_and_bench_stage_prints_its_help() -> None:
    """``CMD --help`` through main, which imports that command's module only."""
    helps = _python('''
import contextlib, io, json
from depth_nodes.tools.cli import COMMANDS, main
from depth_nodes.tools.cli.bench import STAGES
out = {}
for words in [[c.name] for c in COMMANDS] + [['bench', s] for s in STAGES]:
    text = io.StringIO()
    code = 'returned'
    with contextlib.redirect_stdout(text):
        try:
            main([*words, '--help'])
        except SystemExit as exc:
            code = exc.code
    out[' '.join(words)] = [code, text.getvalue()]
print(json.dumps(out))
''')
    expected = [c.name for c in COMMANDS] + [f'bench {s}' for s in bench_cli.STAGES]
    assert list(helps) == expected
    for words, (code, text) in helps.items():
        assert code == 0, words
        assert text.startswith(f'usage: depth-nodes {words} [-h]'), (words, text[:200])


#: Arguments each command needs at least.
MINIMAL = {'generate': ['out'], 'process': ['in', 'out'], 'convert': ['in', 'out'],
           'import-pair': ['l.png', 'r.png', 'out'], 'import-views': ['par.txt', 'out'],
           'pipeline': [], 'play': ['bag'],
           'record': ['out', '--topics', '/a'], 'preview': ['bag', 'v.mp4'],
           'export-mesh': ['bag', 'm.ply'],
           'reindex': ['bag'], 'param': ['list'],
           'node': ['list'], 'topic': ['list'], 'diag': [], 'eval': ['bag'],
           'eval-sl': ['bag'], 'eval-tof': ['bag'], 'eval-depth-filter': ['bag'],
           'bench': ['sgm'], 'tune': ['bag', '--out', 'p.yaml'], 'train-cost': ['w.npz'],
           'train-confidence': ['c.npz']}


def test_the_full_parser_runs_each_command_with_its_module() -> None:
    assert list(MINIMAL) == [command.name for command in COMMANDS]
    parser = build_parser()
    for command in COMMANDS:
        args = parser.parse_args([command.name, *MINIMAL[command.name]])
        assert args.command == command.name
        assert args.run.__module__ == f'depth_nodes.tools.cli.{command.module}'


def test_a_parser_for_one_command_has_only_its_arguments() -> None:
    parser = build_parser(['eval'])
    assert parser.parse_args(['eval', 'bag', '--grid']).grid
    args, extras = parser.parse_known_args(['process', 'in', 'out'])
    assert extras == ['in', 'out']  # listed, without its arguments
    assert not hasattr(args, 'run')


def _bench(*words: str) -> Any:
    return build_parser(['bench']).parse_args(['bench', *words])


@pytest.mark.parametrize(('words', 'defaults'), [
    (['rectify'], {'frames': 200, 'threads': 2, 'width': 640, 'height': 480,
                   'interpolation': 'linear'}),
    (['sgm'], {'frames': 10, 'threads': 2, 'disparities': 128, 'size': '640x480', 'busy': 0,
               'paths': 8}),
    (['cross_check'], {'frames': 20, 'threads': 2}),
    (['point_cloud'], {'frames': 20, 'threads': 2}),
    (['structured_light'], {'frames': 20, 'threads': 2,
                            'bag': str(BUNDLED_BAGS / 'structured_light_vga')}),
    (['tof'], {'frames': 20, 'threads': 2, 'bag': str(BUNDLED_BAGS / 'tof_vga')}),
    (['soak'], {'duration': 1800.0, 'tune_every': 10.0, 'memory_log': None, 'rate': 10.0,
                'composed': False}),
    (['live'], {'rate': 10.0, 'composed': False, 'frames': 50, 'sgm_threads': None,
                'paths': None, 'no_opencv': False, 'bag': str(BUNDLED_BAGS / 'stereo_vga'),
                'watch': 'all'}),
])
def test_each_bench_stage_has_its_own_options_and_defaults(words: list[str],
                                                           defaults: dict[str, Any]) -> None:
    args = _bench(*words)
    options = {k: v for k, v in vars(args).items()
               if k not in ('command', 'run', 'stage', 'live')}
    assert options == defaults
    bench_cli.check_arguments(args)  # the defaults pass
    for bag in ('bag',) if 'bag' in defaults else ():
        assert Path(getattr(args, bag)).is_dir()


def test_an_option_of_another_stage_is_not_accepted() -> None:
    for words in (['soak', '--frames', '5'], ['live', '--size', '320x240'],
                  ['cross_check', '--bag', 'x']):
        _, extras = build_parser(['bench']).parse_known_args(['bench', *words])
        assert extras == words[1:]
    result = run_cli(['bench', 'soak', '--frames', '5'])
    assert result.returncode == 1
    assert result.stderr.strip() == ('depth-nodes bench: error: unrecognized arguments: '
                                     '--frames 5 (see depth-nodes bench --help)')


@pytest.mark.parametrize(('words', 'message'), [
    (['sgm', '--frames', '0'], '--frames must be at least 1, got 0'),
    (['tof', '--threads', '0'], '--threads must be at least 1, got 0'),
    (['live', '--threads', '-1'], '--threads must be >= 0 (0: every core), got -1'),
    (['rectify', '--height', '8'], '--width and --height must be at least 16, got 640x8'),
    (['sgm', '--size', '10x10'], "--size must be WxH with both at least 16 (e.g. 1280x720), "
                                 "got '10x10'"),
    (['sgm', '--size', '640by480'], "--size must be WxH with both at least 16 (e.g. "
                                    "1280x720), got '640by480'"),
    (['sgm', '--size', '320x240', '--disparities', '320'],
     '--disparities must be in 1..319 (the pair is 320 px wide), got 320'),
    (['sgm', '--busy', '-1'], '--busy must be >= 0, got -1'),
    (['soak', '--rate', '0'], '--rate must be positive, got 0.0'),
    (['live', '--rate', '-5'], '--rate must be positive, got -5.0'),
])
def test_bench_refuses_values_no_benchmark_runs_with(words: list[str], message: str) -> None:
    with pytest.raises(ConfigError) as caught:
        bench_cli.check_arguments(_bench(*words))
    assert str(caught.value) == message


def test_live_threads_may_be_zero_where_a_stage_in_this_process_refuses_it() -> None:
    bench_cli.check_arguments(_bench('live', '--threads', '0'))  # every core
    with pytest.raises(ConfigError, match='--threads must be at least 1'):
        bench_cli.check_arguments(_bench('sgm', '--threads', '0'))


def test_bench_without_a_stage_names_them() -> None:
    with pytest.raises(ConfigError) as caught:
        bench_cli.run(_bench())
    assert str(caught.value) == ('bench needs a stage (rectify, sgm, cross_check, point_cloud, '
                                 'multiview, structured_light, tof, depth_filter, fusion, soak, '
                                 'live)')


def test_bench_live_passes_its_options_on(monkeypatch: pytest.MonkeyPatch,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    calls: list[dict[str, Any]] = []

    class Report:
        def format(self) -> str:
            return 'the report'

    def fake_bench_live(**kwargs: Any) -> Report:
        calls.append(kwargs)
        return Report()

    monkeypatch.setattr(bench_cli, 'bench_live', fake_bench_live)
    assert bench_cli.run(_bench('live', '--watch', 'points2', '--rate', '15', '--frames',
                                '100', '--no-opencv', '--paths', '5', '--threads', '0')) == 0
    assert calls == [{'rate': 15.0, 'count': 100, 'threads': 0, 'opencv': False,
                      'bag': str(BUNDLED_BAGS / 'stereo_vga'), 'paths': 5, 'composed': False,
                      'watch': 'points2'}]
    assert capsys.readouterr().out == 'the report\n'
    bench_cli.run(_bench('live'))
    assert calls[1]['watch'] == 'all'
    assert calls[1]['threads'] is None
    assert calls[1]['paths'] is None
