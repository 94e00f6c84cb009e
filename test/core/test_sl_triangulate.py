"""Triangulation recovers the depth of known points; calibration errors are explicit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from depth_nodes.core.structured_light import (
    ProjectorGeometry,
    camera_rays,
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
