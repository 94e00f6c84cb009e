"""Triangulation recovers the depth of known points; calibration errors are explicit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from depth_nodes.core.structured_light import (
    ProjectorGeometry,
    camera_rays,
    epipolar_distance,
    pixel_rays,
    triangulate_columns,
    triangulate_pixels,
)
from depth_nodes.errors import CalibrationError
from depth_nodes.sim.projector import ProjectorSimConfig, projector_rig
from depth_nodes.sim.rig import distort_rays

CONFIG = ProjectorSimConfig(width=64, height=48, focal_px=60.0, projector_width=80,
                            projector_height=60, projector_focal_px=70.0, baseline_m=0.1,
                            projector_yaw_deg=-8.0,
                            camera_distortion=(-0.2, 0.05, 0.001, -0.001, 0.0))


def _points(n: int = 200) -> np.ndarray:
    rng = np.random.default_rng(3)
    z = rng.uniform(0.5, 3.0, n)
    return np.column_stack([rng.uniform(-0.3, 0.3, n) * z, rng.uniform(-0.3, 0.3, n) * z, z])


def _observe(geometry: ProjectorGeometry, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    cam_px = distort_rays(geometry.camera, pts)
    proj_px = distort_rays(geometry.projector, pts @ geometry.rotation.T + geometry.translation)
    rays = pixel_rays(geometry.camera, cam_px)[None]
    return rays, proj_px.astype(np.float32)[None]


def test_pose_decomposes_from_p() -> None:
    camera, projector = projector_rig(CONFIG)
    geometry = ProjectorGeometry.from_models(camera, projector)
    np.testing.assert_allclose(geometry.centre, [0.1, 0, 0], atol=1e-12)
    assert geometry.baseline == pytest.approx(0.1)


def test_ray_plane_recovers_depth() -> None:
    geometry = ProjectorGeometry.from_models(*projector_rig(CONFIG))
    pts = _points()
    rays, proj = _observe(geometry, pts)
    depth = triangulate_columns(rays, proj[..., 0], geometry)
    np.testing.assert_allclose(depth[0], pts[:, 2], rtol=1e-5)


def test_ray_ray_recovers_depth_with_projector_distortion() -> None:
    config = dataclasses.replace(CONFIG, projector_distortion=(0.1, -0.02, 0.0, 0.0, 0.0))
    geometry = ProjectorGeometry.from_models(*projector_rig(config))
    pts = _points()
    rays, proj = _observe(geometry, pts)
    depth = triangulate_pixels(rays, proj[..., 0], proj[..., 1], geometry)
    np.testing.assert_allclose(depth[0], pts[:, 2], rtol=1e-4)


def test_unknown_coordinates_give_nan() -> None:
    geometry = ProjectorGeometry.from_models(*projector_rig(CONFIG))
    rays = camera_rays(geometry.camera)
    u = np.full((48, 64), np.nan, dtype=np.float32)
    assert np.isnan(triangulate_columns(rays, u, geometry)).all()
    assert np.isnan(triangulate_pixels(rays, u, u, geometry)).all()


def test_columns_need_an_undistorted_projector() -> None:
    config = dataclasses.replace(CONFIG, projector_distortion=(0.1, 0.0, 0.0, 0.0, 0.0))
    geometry = ProjectorGeometry.from_models(*projector_rig(config))
    with pytest.raises(CalibrationError, match='columns-only triangulation needs an '
                       'undistorted projector'):
        triangulate_columns(camera_rays(geometry.camera), np.zeros((48, 64), np.float32),
                            geometry)


def test_projector_p_must_hold_a_pose() -> None:
    camera, projector = projector_rig(CONFIG)
    with pytest.raises(CalibrationError, match='projector P is all zero'):
        ProjectorGeometry.from_models(camera, dataclasses.replace(projector, P=np.zeros((3, 4))))
    skewed = projector.P.copy()
    skewed[:, 0] *= 1.5
    with pytest.raises(CalibrationError, match=r'projector P is not K_p \[R \| t\]'):
        ProjectorGeometry.from_models(camera, dataclasses.replace(projector, P=skewed))


def test_true_codes_lie_on_their_epipolar_line_and_moved_ones_do_not() -> None:
    """Exact projections of known points are on the line (to 1e-6 px, projector distortion
    undone); a code moved across the line by 3 px is 3 px x the sine of its angle off."""
    config = dataclasses.replace(CONFIG, projector_distortion=(0.1, -0.02, 0.0, 0.0, 0.0))
    geometry = ProjectorGeometry.from_models(*projector_rig(config))
    rays, proj = _observe(geometry, _points())
    on_line = epipolar_distance(rays, proj[..., 0], proj[..., 1], geometry)
    assert on_line.max() < 1e-3
    # no yaw, camera and projector side by side: the lines run along the rows, nearly
    flat = ProjectorGeometry.from_models(*projector_rig(dataclasses.replace(
        CONFIG, projector_yaw_deg=0.0)))
    rays, proj = _observe(flat, _points())
    moved = epipolar_distance(rays, proj[..., 0], proj[..., 1] + 3.0, flat)
    np.testing.assert_allclose(moved, 3.0, atol=0.05)
    along = epipolar_distance(rays, proj[..., 0] + 3.0, proj[..., 1], flat)
    assert along.max() < 0.05
    nan = np.full_like(proj[..., 0], np.nan)
    assert np.isnan(epipolar_distance(rays, nan, proj[..., 1], flat)).all()


def test_reconstruct_rejects_false_codes_off_their_epipolar_line() -> None:
    """A patch whose pattern frames arrive in reverse order decodes to false (column, row)
    pairs; ray-ray triangulation gives them a depth anyway, the epipolar check removes
    most; clean frames lose nothing to it (true codes lie within 1 px of their line)."""
    from depth_nodes.core.structured_light import PatternSet, generate_patterns
    from depth_nodes.core.structured_light.reconstruct import reconstruct
    from depth_nodes.sim.projector import ProjectorCameraSim

    config = ProjectorSimConfig(width=160, height=120, focal_px=140.0, projector_width=160,
                                projector_height=120, projector_focal_px=125.0, seed=3,
                                projector_distortion=(0.05, 0.0, 0.0, 0.0, 0.0))
    sim = ProjectorCameraSim(config)
    patterns = PatternSet('phase', 160, 120, 'both', 4, 16.0)
    capture = sim.capture(generate_patterns(patterns), noise_seed=1)
    geometry = ProjectorGeometry.from_models(sim.camera, sim.projector)
    rays = camera_rays(sim.camera)
    clean = reconstruct(capture.images, patterns, geometry, rays=rays, epipolar_tolerance=2.0)
    plain = reconstruct(capture.images, patterns, geometry, rays=rays)
    assert clean.epipolar_rejected == 0
    np.testing.assert_array_equal(clean.depth, plain.depth)
    images = capture.images.copy()
    images[:, 40:80, 40:100] = capture.images[::-1, 40:80, 40:100]
    patch = np.zeros((120, 160), bool)
    patch[40:80, 40:100] = True
    wrong = {}
    for tolerance in (0.0, 2.0):
        rec = reconstruct(images, patterns, geometry, rays=rays, epipolar_tolerance=tolerance)
        est = np.isfinite(rec.depth) & patch
        wrong[tolerance] = int((est & (np.abs(rec.depth - capture.depth) > 0.02)).sum())
    assert wrong[0.0] >= 5
    assert wrong[2.0] <= wrong[0.0] // 2
