"""`depth-nodes bench multiview` as a user runs it: the report's lines, its times and the
ratio against the stereo matcher measured in the same run."""

from __future__ import annotations

import re

import pytest
from helpers import run_cli

pytestmark = pytest.mark.slow


def test_bench_multiview_prints_the_sweep_beside_the_stereo_matcher() -> None:
    done = run_cli(['bench', 'multiview', '--size', '160x120', '--planes', '32',
                    '--sources', '2', '--frames', '1', '--threads', '1'])
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert out.startswith('multiview: 160x120, 32 planes, 2 source views, 8 paths, 1 threads')
    sweep = float(re.search(r'plane sweep \(costs, SGM, refinement\)\s+([\d.]+) ms', out)[1])
    stereo = float(re.search(r'census SGM stereo, 32 disparities\s+([\d.]+) ms', out)[1])
    ratio = float(re.search(r'sweep / stereo =\s+([\d.]+)', out)[1])
    assert sweep > 0
    assert stereo > 0
    assert ratio == pytest.approx(sweep / stereo, rel=0.02, abs=0.01)
    # the stream's frame is swept against as many keyframes as the sweep has sources
    assert re.search(r'a frame of the stream \(sweep, check, filter\)\s+[\d.]+ ms\s+'
                     r'\(2 keyframes\)', out), out
    # the memory line: the plane counts below the width only (64 and 128 of 64, 128, 256)
    assert re.search(r'\(memory_mb 25\): 64 planes [\d.]+ MB, 128 planes [\d.]+ MB$',
                     out, re.MULTILINE), out
