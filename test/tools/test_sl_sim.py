"""Projector-camera simulator: ground truth is geometrically exact, shadows are dark, and the
decoder meets its figures on a small render."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from depth_nodes.core.structured_light import (
    PatternSet,
    ProjectorGeometry,
    camera_rays,
    generate_patterns,
)
from depth_nodes.core.structured_light.reconstruct import reconstruct
from depth_nodes.errors import ConfigError
from depth_nodes.sim.projector import (
    SHADOW_LIT,
    SHADOW_OCCLUDED,
    ProjectorCameraSim,
    ProjectorSimConfig,
)
from depth_nodes.sim.rig import distort_rays
from depth_nodes.tools.evaluation.structured_light import interior_mask

SMALL = ProjectorSimConfig(width=160, height=120, focal_px=140.0, projector_width=160,
                           projector_height=120, projector_focal_px=125.0,
                           camera_distortion=(-0.1, 0.02, 0.0, 0.0, 0.0), seed=3)
PHASE = PatternSet('phase', 160, 120, steps=6, period=8.0)


@pytest.fixture(scope='module')
def sim() -> ProjectorCameraSim:
    return ProjectorCameraSim(SMALL)


@pytest.fixture(scope='module')
def capture(sim: ProjectorCameraSim):  # type: ignore[no-untyped-def]
    return sim.capture(generate_patterns(PHASE))


def test_ground_truth_projects_to_the_projector_coordinates(capture) -> None:  # type: ignore[no-untyped-def]
    geometry = ProjectorGeometry.from_models(capture.camera, capture.projector)
    rays = camera_rays(capture.camera)
    ok = np.isfinite(capture.depth)
    assert ok.all()  # the wall and floor close the scene
    points = rays[ok] * capture.depth[ok, None].astype(np.float64)
    proj = distort_rays(capture.projector, points @ geometry.rotation.T + geometry.translation)
    lit = capture.shadow[ok] == SHADOW_LIT
    np.testing.assert_allclose(proj[lit, 0], capture.u[ok][lit], atol=2e-3)  # float32 GT
    np.testing.assert_allclose(proj[lit, 1], capture.v[ok][lit], atol=2e-3)


def test_shadowed_pixels_get_no_projector_light() -> None:
    sim = ProjectorCameraSim(dataclasses.replace(SMALL, noise_sigma=0.0))
    white, black = sim.render(np.stack([np.ones((120, 160)), np.zeros((120, 160))]))
    shadow = sim.capture(np.zeros((1, 120, 160))).shadow
    deep = cv2.erode((shadow == SHADOW_OCCLUDED).astype(np.uint8), np.ones((3, 3))).astype(bool)
    assert deep.sum() > 50  # the box and sphere cast shadows
    assert np.abs(white[deep].astype(int) - black[deep]).max() <= 1
    lit = cv2.erode((shadow == SHADOW_LIT).astype(np.uint8), np.ones((3, 3))).astype(bool)
    assert (white[lit].astype(int) - black[lit]).min() > 5


def test_phase_decoding_meets_the_targets_on_a_small_render(capture) -> None:  # type: ignore[no-untyped-def]
    geometry = ProjectorGeometry.from_models(capture.camera, capture.projector)
    result = reconstruct(capture.images, PHASE, geometry)
    lit = capture.shadow == SHADOW_LIT
    inner = interior_mask(capture.depth, capture.shadow)
    assert result.decoded.valid[lit].mean() >= 0.99
    err = (result.decoded.u - capture.u)[inner & result.decoded.valid]
    assert np.sqrt(np.mean(err**2)) < 0.1  # projector px
    dz = (result.depth - capture.depth)[inner & np.isfinite(result.depth)]
    # dZ = Z^2 / (f_p b) du: at Z 1.5 m, f_p 125 px, b 0.1 m, 0.1 px is 18 mm
    assert np.sqrt(np.mean(dz**2)) < 0.025


@pytest.mark.parametrize(('change', 'message'), [
    ({'width': 8}, 'ProjectorSimConfig.width is invalid: 8'),
    ({'baseline_m': 0.0}, 'ProjectorSimConfig.baseline_m is invalid: 0.0'),
    ({'camera_distortion': (0.1,)}, r'ProjectorSimConfig.camera_distortion is invalid'),
    ({'projector_yaw_deg': 45.0}, 'ProjectorSimConfig.projector_yaw_deg is invalid: 45.0'),
])
def test_invalid_config(change: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        ProjectorCameraSim(dataclasses.replace(SMALL, **change))


def test_patterns_of_the_wrong_size(sim: ProjectorCameraSim) -> None:
    with pytest.raises(ConfigError, match=r'patterns must be \(F, 120, 160\), got \(1, 12, 16\)'):
        sim.render(np.zeros((1, 12, 16)))
