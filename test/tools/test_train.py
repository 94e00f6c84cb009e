"""Training of the learned matching cost and confidence (the ``train`` extra): the
training pairs' ground truth, the augmentation, JAX's network against the numpy one the
nodes run, short reproducible training runs, and the commands' errors."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import REPO, interrupt_once_written, run_cli
from reference.learned import features_reference

from depth_nodes.core.learned.confidence import ConfidenceModel
from depth_nodes.core.learned.network import SHIPPED, FeatureNet, normalise
from depth_nodes.tools.train.confidence import ConfidenceConfig, train_confidence
from depth_nodes.tools.train.cost import TrainConfig, forward, init_params, load_jax, train
from depth_nodes.tools.train.data import DataConfig, augment, split, triplets
from depth_nodes.tools.train.photos import load_photos, photo_scene


@pytest.fixture(scope='module')
def photos() -> list[np.ndarray]:
    return load_photos()


def test_photograph_pairs_have_exact_disparity(photos: list[np.ndarray]) -> None:
    scene = photo_scene(photos, 0, 3)
    h, w = scene.disparity.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    # the right view sampled at x - d is the left view where the right camera sees it
    warped = cv2.remap(scene.right.astype(np.float32), xs - scene.disparity, ys,
                       cv2.INTER_LINEAR)
    diff = np.abs(warped - scene.left.astype(np.float32)).mean(axis=2)
    assert 0.5 < scene.visible.mean() < 1.0
    assert np.median(diff[scene.visible]) < 2.0
    assert np.median(diff[~scene.visible]) > 5.0  # occluded: another layer is seen
    assert photo_scene(photos, 0, 3).disparity.tobytes() == scene.disparity.tobytes()


def test_augmentation_is_seeded_and_changes_the_pair(photos: list[np.ndarray]) -> None:
    scene = photo_scene(photos, 1, 0)
    a = augment(scene, np.random.default_rng(5))
    b = augment(scene, np.random.default_rng(5))
    c = augment(scene, np.random.default_rng(6))
    assert a[0].dtype == np.uint8
    assert a[0].shape == scene.disparity.shape
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a[0], c[0])


def test_triplets_put_the_positive_on_the_true_match(photos: list[np.ndarray]) -> None:
    scene = photo_scene(photos, 2, 1)
    config = DataConfig(samples_per_scene=400)
    left, pos, neg = triplets(scene, config, np.random.default_rng(0))
    assert left.shape == pos.shape == neg.shape
    assert left.shape[1:] == (9, 9)
    # the true match's patch is closer to the left one than a patch a few px off
    d_pos = np.abs(left - pos).mean(axis=(1, 2))
    d_neg = np.abs(left - neg).mean(axis=(1, 2))
    assert (d_pos < d_neg).mean() > 0.65  # chance: 0.5 (noise, flat regions, 1 px negatives)
    _, _, candidates = triplets(scene, DataConfig(samples_per_scene=50, candidates=3),
                                np.random.default_rng(0))
    assert candidates.shape[1:] == (6, 9, 9)


def test_validation_scenes_are_held_out_of_each_kind() -> None:
    train_scenes, held = split(10, 20, 0.1)
    assert held == [('sim', 9), ('photo', 18), ('photo', 19)]
    assert not set(train_scenes) & set(held)
    assert len(train_scenes) == 27


def test_jax_network_is_the_numpy_network_the_nodes_run() -> None:
    jax = load_jax()
    params = init_params(TrainConfig(channels=5, layers=3), seed=2)
    net = FeatureNet(tuple(k for k, _ in params), tuple(b + 0.01 for _, b in params), 9)
    image = cv2.GaussianBlur(np.random.default_rng(3).integers(0, 256, (20, 24))
                             .astype(np.uint8), (3, 3), 0)
    whole = features_reference(net, image)
    patch = normalise(image, 9)[7:14, 9:16]  # the 7x7 receptive field of pixel (10, 12)
    jax_params = [(jax.numpy.asarray(k), jax.numpy.asarray(b))
                  for k, b in zip(net.kernels, net.biases, strict=True)]
    got = np.asarray(forward(jax, jax_params, patch[None]))[0]
    np.testing.assert_allclose(got, whole[10, 12], atol=1e-5)


@pytest.mark.slow
def test_a_short_cost_training_learns_and_repeats(tmp_path: Path) -> None:
    data = DataConfig(scenes=0, photo_scenes=6, samples_per_scene=400, seed=1)
    config = TrainConfig(channels=4, layers=2, steps=60, batch=64)
    first = train(data, config, log=lambda _: None, log_every=30)
    again = train(data, config, log=lambda _: None, log_every=30)
    assert first.validation_ranked[-1] > 0.6  # chance is 0.5
    assert first.validation_loss[-1] < first.validation_loss[0] or \
        first.train_loss[-1] < first.train_loss[0]
    for a, b in zip(first.net.kernels, again.net.kernels, strict=True):
        np.testing.assert_array_equal(a, b)
    first.net.save(tmp_path / 'w.npz')
    assert FeatureNet.load(tmp_path / 'w.npz').recipe['data']['photo_scenes'] == 6


@pytest.mark.slow
def test_a_short_confidence_training_predicts_right_pixels() -> None:
    config = ConfidenceConfig(scenes=0, photo_scenes=4, pixels_per_scene=3000, steps=300,
                              hidden=8, seed=1)
    model = train_confidence(config, log=lambda _: None)
    assert isinstance(model, ConfidenceModel)
    assert model.recipe['validation_loss'] < 0.6


@pytest.mark.slow
def test_training_commands_refuse_bad_arguments(tmp_path: Path) -> None:
    (tmp_path / 'there.npz').write_bytes(b'')
    cases = [
        (['train-cost', str(tmp_path / 'there.npz')], 'exists (--force replaces it)'),
        (['train-cost', str(tmp_path / 'w.pt')], 'must end in .npz'),
        (['train-cost', str(tmp_path / 'no' / 'w.npz')], 'is not a folder'),
        (['train-cost', str(tmp_path / 'w.npz'), '--steps', '0'], '--steps must be at least 1'),
        (['train-confidence', str(tmp_path / 'c.npz'), '--scenes', '1', '--photo-scenes',
          '0'], 'must add up to at least 2'),
    ]
    for args, message in cases:
        result = run_cli(args)
        assert result.returncode == 1, (args, result.stderr)
        assert message in result.stderr, result.stderr
        assert 'Traceback' not in result.stderr


@pytest.mark.slow
def test_adapting_to_a_recording_keeps_its_labels_and_says_what_it_learned_from(
        tmp_path: Path) -> None:
    """``train-cost --adapt`` on a stereo bag (raw images rectified here): proxy labels at
    most pixels of a clean simulated pair, weights that load and record the bag, and
    they stay near the shipped ones (the pull back to them)."""
    out = tmp_path / 'mine.npz'
    bag = REPO / 'bags' / 'stereo_qvga_color'
    result = run_cli(['train-cost', '--adapt', str(bag), '--out', str(out), '--steps', '40',
                      '--frames', '2', '--disparities', '48'])
    assert result.returncode == 0, result.stderr
    assert 'proxy labels' in result.stdout
    labelled = [float(line.split(': ')[1].split('%')[0]) for line in result.stdout.splitlines()
                if 'of the pixels labelled' in line]
    assert len(labelled) == 2
    assert min(labelled) > 30  # a clean pair: most pixels are consistent and distinctive
    net = FeatureNet.load(out)
    assert net.recipe['command'] == 'depth-nodes train-cost --adapt'
    assert all(s.startswith('stereo_qvga_color@') for s in net.recipe['adapted_on'])
    assert net.recipe['base']['command'] == 'depth-nodes train-cost'
    shipped = FeatureNet.load(SHIPPED)
    for a, b in zip(net.kernels, shipped.kernels, strict=True):
        assert a.shape == b.shape
        assert np.abs(a - b).max() < 0.5


@pytest.mark.slow
def test_adapting_refuses_what_it_cannot_use(tmp_path: Path) -> None:
    out = str(tmp_path / 'w.npz')
    cases = [
        (['train-cost', '--adapt', str(REPO / 'bags' / 'tof_vga'), '--out', out],
         'no stereo pair'),
        (['train-cost', '--adapt', str(tmp_path / 'nothing'), '--out', out], 'nothing'),
        (['train-cost', out, '--adapt', str(REPO / 'bags' / 'stereo_vga'), '--out', out],
         'give the weights file to write once'),
        (['train-cost', '--adapt', str(REPO / 'bags' / 'stereo_vga'), '--out', out,
          '--weights', str(tmp_path / 'base.npz')], 'cannot read feature weights'),
        (['train-cost', '--adapt', str(REPO / 'bags' / 'stereo_vga'), '--out', out,
          '--frames', '0'], '--frames must be at least 1'),
    ]
    for args, message in cases:
        result = run_cli(args)
        assert result.returncode == 1, (args, result.stderr)
        assert message in result.stderr, (args, result.stderr)
        assert 'Traceback' not in result.stderr


@pytest.mark.slow
def test_a_ctrl_c_keeps_the_best_adapted_weights(tmp_path: Path) -> None:
    out = tmp_path / 'mine.npz'
    done = interrupt_once_written(
        ['train-cost', '--adapt', str(REPO / 'bags' / 'stereo_qvga_color'), '--out', str(out),
         '--steps', '5000', '--frames', '1', '--disparities', '48'], out)
    stdout, stderr = done.stdout, done.stderr
    assert done.returncode == 0, stderr
    assert 'depth-nodes train-cost: interrupted;' in stderr
    assert 'holds the best weights so far' in stderr, stdout
    assert FeatureNet.load(out).recipe['command'] == 'depth-nodes train-cost --adapt'
    assert not list(tmp_path.glob('*.partial.npz'))
