"""`depth-nodes tune` (depth_nodes.tools.tune): the score without ground truth ranks
settings as the ground truth does where they differ clearly; the search never ends worse
than where it started; the parameter file it writes is one `process --params` takes;
Ctrl-C keeps the best settings so far; mistakes are one-line errors."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml
from helpers import REPO, interrupt_once_written, run_cli

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


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_each_trial_is_new_and_its_score_is_reproducible(seed: int) -> None:
    pairs = list(stereo_pairs(BAG, 1))
    base = _shipped_settings()
    result = search(pairs, base, trials=6, seed=seed)
    assert len(result.trials) == 6
    keys = [frozenset(t.changes.items()) for t in result.trials]
    assert all(keys)  # each one changes something
    assert len(set(keys)) == 6  # and no setting is tried twice
    assert all(base.get(k) != v for t in result.trials for k, v in t.changes.items())
    best = result.best
    assert score_pairs(pairs, {**base, **best.changes}).score == pytest.approx(best.score)


@pytest.mark.slow
def test_the_parameter_file_is_one_process_takes(tmp_path: Path) -> None:
    out = tmp_path / 'tuned.yaml'
    done = run_cli(['tune', str(BAG), '--out', str(out), '--frames', '2', '--trials', '4'])
    assert done.returncode == 0, done.stderr
    assert 'bad-2 (truth)' in done.stdout  # the bag has ground truth: reported
    assert f'{out}: written (2 pair(s), 4 trial(s)' in done.stdout
    assert 'trial 4/4' in done.stderr  # progress
    doc = yaml.safe_load(out.read_text())
    changed = re.search(r'^changed: (.*)$', done.stdout, re.MULTILINE)
    assert changed is not None
    if changed.group(1) == 'nothing':
        assert doc == {}
    else:  # the report's changes are the file's
        written = doc['sgm_stereo']['ros__parameters']
        reported = dict(part.split(' ', 1) for part in changed.group(1).split(', '))
        assert set(reported) == set(written)
        for name, value in written.items():
            assert str(value) == reported[name] or float(value) == float(reported[name])
    done = run_cli(['process', str(BAG), str(tmp_path / 'processed'), '--params', str(out)])
    assert done.returncode == 0, done.stderr
    assert 'warning' not in done.stderr  # every entry reached a node


@pytest.mark.slow
def test_ctrl_c_keeps_the_best_settings_so_far(tmp_path: Path) -> None:
    out = tmp_path / 'tuned.yaml'
    done = interrupt_once_written(['tune', str(BAG), '--out', str(out), '--frames', '1',
                                   '--trials', '100000'], out, settle=1.0)
    stdout, stderr = done.stdout, done.stderr
    assert done.returncode == 0, stderr
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


@pytest.mark.slow
def test_a_camera_preset_s_topics_and_settings_are_the_start(tmp_path: Path) -> None:
    driver = tmp_path / 'rs'
    done = run_cli(['convert', str(BAG), str(driver), '--namespace', '/camera/camera',
                    '--rename', 'left=infra1', '--rename', 'right=infra2', '--rename',
                    'image_raw=image_rect_raw'])
    assert done.returncode == 0, done.stderr
    out = tmp_path / 'rs.yaml'
    done = run_cli(['tune', str(driver), '--out', str(out), '--camera', 'realsense_d435',
                    '--frames', '2', '--trials', '1'])
    assert done.returncode == 0, done.stderr
    assert f'{out}: written (2 pair(s), 1 trial(s)' in done.stdout
    assert 'disparity_range' not in out.read_text()  # the preset's 80 stays
    done = run_cli(['tune', str(driver), '--out', str(tmp_path / 'x.yaml'), '--camera',
                    'orbbec_femto'])
    assert done.returncode == 1
    assert done.stderr == ('depth-nodes tune: error: camera preset orbbec_femto has no stereo '
                           'pair to tune\n')
