"""Decoding: ideal captures decode exactly; shadows and weak signal are masked; errors."""

from __future__ import annotations

import numpy as np
import pytest

from depth_nodes.core.structured_light import (
    PatternSet,
    decode_sequence,
    generate_patterns,
    wrapped_phase,
)
from depth_nodes.errors import ConfigError

W, H = 64, 32


def _capture(ps: PatternSet, *, seed: int = 0, noise: float = 0.0) -> np.ndarray:
    """Camera = projector pixel grid; random albedo and ambient; no blur."""
    rng = np.random.default_rng(seed)
    albedo = rng.uniform(0.4, 1.0, (ps.height, ps.width))
    ambient = rng.uniform(5, 30, (ps.height, ps.width))
    img = ambient + 200 * albedo * generate_patterns(ps)
    return img + rng.normal(0, noise, img.shape) if noise else img


def test_phase_decodes_exact_columns_with_any_albedo_and_ambient() -> None:
    ps = PatternSet('phase', W, H, steps=4, period=8.0)
    result = decode_sequence(_capture(ps), ps)
    assert result.valid.all()
    assert result.v is None
    np.testing.assert_allclose(result.u, np.tile(np.arange(W), (H, 1)), atol=1e-3)
    assert (result.confidence > 0.9).all()


def test_phase_noise_gives_subpixel_error() -> None:
    ps = PatternSet('phase', W, H, steps=6, period=8.0)
    result = decode_sequence(_capture(ps, noise=2.0), ps)
    err = result.u - np.arange(W)
    assert result.valid.mean() > 0.99
    assert np.sqrt(np.nanmean(err**2)) < 0.05  # projector px, 6 steps, noise 2 levels


def test_gray_both_axes() -> None:
    ps = PatternSet('gray', W, H, axes='both')
    result = decode_sequence(_capture(ps), ps)
    assert result.v is not None
    np.testing.assert_array_equal(result.u, np.tile(np.arange(W), (H, 1)))
    np.testing.assert_array_equal(result.v, np.tile(np.arange(H)[:, None], (1, W)))


def test_opencv_layout_decodes_both_axes() -> None:
    ps = PatternSet('opencv', 40, 20)
    result = decode_sequence(_capture(ps), ps)
    assert result.valid.all()
    np.testing.assert_array_equal(result.u[0], np.arange(40))
    np.testing.assert_array_equal(result.v[:, 0], np.arange(20))


def test_shadow_and_low_modulation_are_invalid() -> None:
    ps = PatternSet('phase', W, H, steps=4, period=8.0)
    img = _capture(ps)
    img[:, 5:10, 5:10] = 40.0  # shadow: no pattern at all
    img[:, 20:25, 20:30] = 40 + 0.02 * (img[:, 20:25, 20:30] - 40)  # barely modulated
    result = decode_sequence(img, ps, shadow_threshold=12, min_modulation=4)
    assert not result.valid[5:10, 5:10].any()
    assert not result.lit[5:10, 5:10].any()
    assert not result.valid[20:25, 20:30].any()
    assert np.isnan(result.u[5:10, 5:10]).all()
    assert (result.confidence[5:10, 5:10] == 0).all()
    assert result.valid.sum() == W * H - 25 - 50


def test_codes_beyond_the_projector_are_invalid() -> None:
    ps = PatternSet('gray', 40, 8)  # 6 bits: codes 40..63 exist but are not columns
    img = _capture(PatternSet('gray', 64, 8))
    result = decode_sequence(img, ps)
    assert result.valid[:, :40].all()
    assert not result.valid[:, 40:].any()


def test_wrapped_phase_least_squares() -> None:
    phi = np.linspace(0.1, 6.2, 7, dtype=np.float32)[None, :]
    steps = np.stack([10 + 3 * np.cos(phi - 2 * np.pi * k / 5) for k in range(5)])
    got, amp = wrapped_phase(steps.astype(np.float32))
    np.testing.assert_allclose(got, phi, atol=1e-5)
    np.testing.assert_allclose(amp, 3.0, atol=1e-5)


@pytest.mark.parametrize(('images', 'kwargs', 'message'), [
    (np.zeros((4, 8)), {}, r'images must be a \(frames, H, W\) stack, got shape \(4, 8\)'),
    (np.zeros((3, 4, 8)), {}, 'phase pattern set has 18 frames, got 3 images'),
    (np.zeros((18, 4, 8)), {'shadow_threshold': -1},
     'shadow_threshold and min_modulation must be >= 0'),
])
def test_decode_errors(images: np.ndarray, kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        decode_sequence(images, PatternSet('phase', 64, 8, steps=4, period=8.0), **kwargs)


def test_speckle_set_is_not_decoded() -> None:
    with pytest.raises(ConfigError, match='speckle frames are matched, not decoded'):
        decode_sequence(np.zeros((1, 4, 8)), PatternSet('speckle', 8, 4))
