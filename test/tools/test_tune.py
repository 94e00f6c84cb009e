"""`depth-nodes tune` (depth_nodes.tools.tune): the score without ground truth ranks
settings as the ground truth does where they differ clearly; the search never ends worse
than where it started; the parameter file it writes is one `process --params` takes;
Ctrl-C keeps the best settings so far; mistakes are one-line errors."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from helpers import REPO, run_cli

from depth_nodes.tools.train.adapt import stereo_pairs
from depth_nodes.tools.tune import _shipped_settings, ground_truth, score_pairs, search

BAG = REPO / 'bags' / 'stereo_qvga_color'


def test_the_score_ranks_a_clearly_worse_setting_as_the_truth_does() -> None:
    pairs = list(stereo_pairs(BAG, 2))
    truth = ground_truth(BAG)
    assert len(truth) >= 2
    shipped = _shipped_settings()
    good = score_pairs(pairs, shipped, truth)
    # penalties so high that the disparity cannot follow the scene's slants and edges
    flat = score_pairs(pairs, {**shipped, 'P1': 400, 'P2': 4000}, truth)
    assert good.bad2 is not None
    assert flat.bad2 is not None
    assert flat.bad2 > good.bad2  # the truth: worse
    assert flat.score > good.score  # and so says the score, without it
    assert 0.5 < good.density <= 1.0
    assert 0.0 < good.photometric < 20.0


def test_the_search_never_ends_worse_than_its_start() -> None:
    pairs = list(stereo_pairs(BAG, 1))
    result = search(pairs, _shipped_settings(), trials=3, seed=1)
    assert len(result.trials) == 3
    assert result.best.score <= result.start.score
    assert all(trial.changes for trial in result.trials)  # each one changes something


@pytest.mark.slow
def test_the_parameter_file_is_one_process_takes(tmp_path: Path) -> None:
    out = tmp_path / 'tuned.yaml'
    done = run_cli(['tune', str(BAG), '--out', str(out), '--frames', '2', '--trials', '4'])
    assert done.returncode == 0, done.stderr
    assert 'bad-2 (truth)' in done.stdout  # the bag has ground truth: reported
    assert f'{out}: written (2 pair(s), 4 trial(s)' in done.stdout
    assert 'trial 4/4' in done.stderr  # progress
    doc = yaml.safe_load(out.read_text())
    assert doc is not None
    assert set(doc) <= {'sgm_stereo'}
    done = run_cli(['process', str(BAG), str(tmp_path / 'processed'), '--params', str(out)])
    assert done.returncode == 0, done.stderr
    assert 'warning' not in done.stderr  # every entry reached a node


@pytest.mark.slow
def test_ctrl_c_keeps_the_best_settings_so_far(tmp_path: Path) -> None:
    out = tmp_path / 'tuned.yaml'
    proc = subprocess.Popen(
        [sys.executable, '-m', 'depth_nodes.tools.cli', 'tune', str(BAG), '--out', str(out),
         '--frames', '1', '--trials', '100000'], cwd=REPO, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not out.exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
        assert out.exists(), proc.stderr.read() if proc.stderr else ''
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert 'changed:' in stdout  # the report of what was tried
    assert 'depth-nodes tune: interrupted after' in stderr
    assert 'holds the best settings so far' in stderr
    assert out.read_text().startswith(f'# depth-nodes tune {BAG}:')
    assert not list(tmp_path.glob('*.partial'))


def test_mistakes_are_one_line(tmp_path: Path) -> None:
    out = tmp_path / 'p.yaml'
    out.write_text('{}\n')
    done = run_cli(['tune', str(BAG), '--out', str(out)])
    assert done.returncode == 1
    assert done.stderr.strip() == f'depth-nodes tune: error: {out} exists (--force replaces it)'
    done = run_cli(['tune', str(REPO / 'bags' / 'depth_moving_camera'), '--out',
                    str(tmp_path / 'q.yaml')])
    assert done.returncode == 1
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith('depth-nodes tune: error: ')
    assert 'no stereo pair' in line
