"""depth_image_proc's operations (depth_nodes.core.depth_image) against exact ground truth:
a depth camera and a colour camera of different sizes, focal lengths and poses rendered
from the stereo simulator's scene (depth_nodes.sim.depth_camera).

Tolerances: points from a 32FC1 depth equal the rendered points to a relative 1e-6 of Z
(float32); registration is exact on a fronto-parallel plane, and elsewhere within the
range the true depth spans over the 5x5 target pixels around a pixel (a registered pixel
takes the Z of the depth pixel whose footprint covers it: on a slanted surface that is
up to half a depth pixel off) for at least 99.9 % of the registered pixels.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from helpers import Lazy, kernel_size
from reference.geometry import splat_reference

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.depth_image import (
    colour_at_depth_pixels,
    depth_to_disparity,
    depth_to_points,
    from_metres,
    register_depth,
    to_metres,
)
from depth_nodes.core.geometry import (
    Intrinsics,
    Motion,
    Pose,
    intrinsics,
    quaternion_from_rpy,
    rotation_matrix,
)
from depth_nodes.errors import ArgumentError, CalibrationError
from depth_nodes.sim.depth_camera import render_view
from depth_nodes.sim.layout import build_scene, rotation
from depth_nodes.sim.projector import reference_plane_scene

DEPTH_CAM = Intrinsics(140.0, 141.0, 79.5, 59.0, 160, 120)
RGB_CAM = Intrinsics(290.0, 290.0, 161.0, 118.5, 320, 240)
DEPTH_POSE = Pose()
RGB_POSE = Pose(rotation(1.0, -0.5, 0.3), np.array([0.025, 0.002, -0.003]))
SCENE = Lazy(lambda: build_scene(3, 0, 140.0, 160, 120))
DEPTH_VIEW = Lazy(lambda: render_view(SCENE, DEPTH_CAM, DEPTH_POSE))
RGB_VIEW = Lazy(lambda: render_view(SCENE, RGB_CAM, RGB_POSE, colour=True))


def _relative() -> tuple[np.ndarray, np.ndarray]:
    return DEPTH_POSE.relative_to(RGB_POSE)


def register_reference(depth: np.ndarray, source: Intrinsics, target: Intrinsics,
                       motion: Motion) -> np.ndarray:
    """register_depth by the plain splat (corners footprint): Z as float32, NaN where
    nothing landed or Z is beyond float32."""
    landed = splat_reference(depth, source, target, motion, footprint='corners')
    with np.errstate(over='ignore'):
        out = landed.depth.astype(np.float32)
    out[~np.isfinite(out)] = np.nan
    return out


# ------------------------------------------------------------------ units


def test_millimetres_to_metres_and_back() -> None:
    mm = np.array([[0, 1, 1500], [65535, 2, 0]], np.uint16)
    m = to_metres(mm, '16UC1')
    assert m.dtype == np.float32
    assert np.isnan(m[0, 0])
    assert np.isnan(m[1, 2])
    np.testing.assert_allclose(m[0, 1:], [0.001, 1.5], rtol=1e-7)
    np.testing.assert_array_equal(from_metres(m, '16UC1'), mm)


def test_metres_unknown_values_become_nan() -> None:
    m = np.array([[0.0, -1.0, np.inf, np.nan, 2.5]], np.float32)
    out = to_metres(m, '32FC1')
    assert np.isnan(out[0, :4]).all()
    assert out[0, 4] == np.float32(2.5)
    np.testing.assert_array_equal(np.isnan(from_metres(out, '32FC1')), np.isnan(out))


@pytest.mark.parametrize(('pixels', 'encoding', 'message'), [
    (np.zeros((2, 2), np.uint16), 'mono16', 'depth encoding must be one of 16UC1, 32FC1'),
    (np.zeros((2, 2), np.float32), '16UC1', '16UC1 depth must be uint16'),
    (np.zeros((2, 2), np.uint16), '32FC1', '32FC1 depth must be float32'),
    (np.zeros((2, 2, 3), np.uint16), '16UC1', 'a depth image is (H, W)'),
])
def test_bad_depth_arrays_are_refused(pixels: np.ndarray, encoding: str, message: str) -> None:
    with pytest.raises(ArgumentError, match=message.replace('(', r'\(').replace(')', r'\)')):
        to_metres(pixels, encoding)


# ------------------------------------------------------------ intrinsics


def _model(width: int, height: int, fx: float, cx: float, cy: float) -> CameraModel:
    K = np.array([[fx, 0, cx], [0, fx, cy], [0, 0, 1.0]])
    return CameraModel(width, height, K, P=np.hstack([K, np.zeros((3, 1))]))


def test_intrinsics_of_the_camera_info_size_are_its_own() -> None:
    cam = intrinsics(_model(640, 480, 500.0, 320.5, 240.5))
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (
        500.0, 500.0, 320.5, 240.5, 640, 480)


@pytest.mark.parametrize('shape', [(240, 320), (120, 160), (960, 1280), (240, 640)])
def test_scaled_intrinsics_map_pixel_centres_onto_pixel_centres(shape: tuple[int, int]) -> None:
    """A point imaged at full size lands where the resized image shows it."""
    full = intrinsics(_model(640, 480, 500.0, 320.5, 240.5))
    scaled = intrinsics(_model(640, 480, 500.0, 320.5, 240.5), shape)
    point = np.array([0.3, -0.2, 2.0])
    u, v = full.fx * point[0] / point[2] + full.cx, full.fy * point[1] / point[2] + full.cy
    sx, sy = shape[1] / 640, shape[0] / 480
    us = scaled.fx * point[0] / point[2] + scaled.cx
    vs = scaled.fy * point[1] / point[2] + scaled.cy
    # pixel centre u of the full image is at (u + 0.5) * sx - 0.5 in the resized one
    assert us == pytest.approx((u + 0.5) * sx - 0.5, abs=1e-9)
    assert vs == pytest.approx((v + 0.5) * sy - 0.5, abs=1e-9)
    assert (scaled.width, scaled.height) == (shape[1], shape[0])


def test_intrinsics_with_binning_are_those_of_the_binned_image() -> None:
    model = _model(640, 480, 500.0, 320.5, 240.5)
    model.binning_x = model.binning_y = 2
    cam = intrinsics(model)
    assert (cam.width, cam.height, cam.fx) == (320, 240, 250.0)


def test_a_camera_without_focal_length_is_refused() -> None:
    model = _model(64, 48, 50.0, 32.0, 24.0)
    model.P = np.zeros((3, 4))
    model.P[0, 0], model.P[1, 1] = -5.0, 5.0
    with pytest.raises(CalibrationError, match='focal lengths must be positive'):
        intrinsics(model)


# ---------------------------------------------------------------- points


def test_points_of_the_rendered_depth_are_the_rendered_points() -> None:
    view = DEPTH_VIEW
    points = depth_to_points(view.depth, DEPTH_CAM)
    assert points.shape == (120, 160, 3)
    assert points.dtype == np.float32
    z = view.points[..., 2]
    err = np.linalg.norm(points - view.points, axis=-1) / z
    assert np.isfinite(points).all()
    assert err.max() < 1e-6


def test_points_are_nan_where_the_depth_is_unknown() -> None:
    depth = DEPTH_VIEW.depth.copy()
    depth[10:20, 30:50] = np.nan
    points = depth_to_points(depth, DEPTH_CAM)
    assert np.isnan(points[10:20, 30:50]).all()
    assert np.isfinite(points[:10]).all()


def test_points_need_the_intrinsics_of_the_depth_size() -> None:
    with pytest.raises(ArgumentError, match='intrinsics are for 160x120'):
        depth_to_points(np.ones((60, 80), np.float32), DEPTH_CAM)


# ------------------------------------------------------------- disparity


def test_disparity_of_the_depth_is_the_stereo_disparity() -> None:
    """f B / Z is what a right camera B to the right sees: checked by projecting."""
    view = DEPTH_VIEW
    baseline = 0.07
    disparity = depth_to_disparity(view.depth, focal=DEPTH_CAM.fx, baseline=baseline)
    p = view.points
    u_left = DEPTH_CAM.fx * p[..., 0] / p[..., 2] + DEPTH_CAM.cx
    u_right = DEPTH_CAM.fx * (p[..., 0] - baseline) / p[..., 2] + DEPTH_CAM.cx
    np.testing.assert_allclose(disparity, u_left - u_right, rtol=1e-6)


def test_disparity_is_nan_without_depth_and_needs_a_baseline() -> None:
    out = depth_to_disparity(np.array([[np.nan, 0.0, 2.0]]), focal=100.0, baseline=0.1)
    assert np.isnan(out[0, :2]).all()
    assert out[0, 2] == pytest.approx(5.0)
    with pytest.raises(ArgumentError, match='focal \\* baseline must be positive'):
        depth_to_disparity(np.ones((2, 2)), focal=100.0, baseline=-0.1)


# --------------------------------------------------------------- colour


def test_colour_resampled_to_the_depth_size_takes_the_pixel_under_each_centre() -> None:
    colour = np.arange(8 * 6 * 3, dtype=np.uint8).reshape(6, 8, 3)
    out = colour_at_depth_pixels(colour, (3, 4))
    np.testing.assert_array_equal(out, colour[1::2, 1::2])  # centres 0.5 -> 1, 2.5 -> 5...
    assert colour_at_depth_pixels(colour, (6, 8)) is colour
    up = colour_at_depth_pixels(colour, (12, 16))
    np.testing.assert_array_equal(up, np.repeat(np.repeat(colour, 2, axis=0), 2, axis=1))


# ----------------------------------------------------------- registration


@pytest.mark.kernels
def test_registration_matches_the_plain_reference() -> None:
    """The numba kernel against the plain one, upsampling, downsampling and a random depth
    with holes and points behind the target camera."""
    rng = np.random.default_rng(5)
    depth = DEPTH_VIEW.depth.copy()
    depth[rng.random(depth.shape) < 0.1] = np.nan
    R, t = _relative()
    downsampled = Intrinsics(60.0, 60.0, 39.5, 29.5, 80, 60)
    for target in kernel_size((downsampled, Intrinsics(150.0, 150.0, 80.5, 59.0, 160, 120),
                               Intrinsics(330.0, 320.0, 100.0, 90.0, 200, 170)),
                              (downsampled,)):
        np.testing.assert_array_equal(register_depth(depth, DEPTH_CAM, target, (R, t)),
                                      register_reference(depth, DEPTH_CAM, target, (R, t)))
    noise = rng.uniform(0.05, 3.0, (30, 40)).astype(np.float32)
    small = Intrinsics(30.0, 30.0, 19.5, 14.5, 40, 30)
    turned = rotation_matrix(quaternion_from_rpy(0.3, -0.4, 0.2))
    shift = np.array([0.2, -0.1, 0.5])
    np.testing.assert_array_equal(register_depth(noise, small, small, (turned, shift)),
                                  register_reference(noise, small, small, (turned, shift)))


def test_registration_into_the_colour_camera_gives_its_depth() -> None:
    R, t = _relative()
    registered = register_depth(DEPTH_VIEW.depth, DEPTH_CAM, RGB_CAM, (R, t))
    truth = RGB_VIEW.depth
    both = np.isfinite(registered) & np.isfinite(truth)
    assert both.mean() > 0.97  # the rest: the border the depth camera does not see
    filled = np.where(np.isfinite(truth), truth, 0).astype(np.float32)
    kernel = np.ones((5, 5), np.uint8)
    spread = cv2.dilate(filled, kernel) - cv2.erode(filled, kernel)
    err = np.abs(registered - truth)
    within = err[both] <= spread[both] + 1e-5 * truth[both]
    assert within.mean() >= 0.999
    assert np.median(err[both] / truth[both]) < 1e-3


def test_registration_of_a_fronto_parallel_plane_is_exact() -> None:
    """A plane facing the target camera: every covered pixel has the same Z, exactly."""
    z = 2.0
    wall = reference_plane_scene(z)
    target_pose = Pose(position=np.array([0.05, 0.01, 0.0]))
    source = render_view(wall, DEPTH_CAM)
    R, t = Pose().relative_to(target_pose)
    registered = register_depth(source.depth, DEPTH_CAM, RGB_CAM, (R, t))
    truth = render_view(wall, RGB_CAM, target_pose).depth
    covered = np.isfinite(registered)
    assert covered.mean() > 0.9
    np.testing.assert_allclose(registered[covered], truth[covered], rtol=1e-6)


def test_the_nearest_surface_wins() -> None:
    """Two depth pixels that land on one target pixel: the nearer is kept, also when it is
    written first."""
    cam = Intrinsics(10.0, 10.0, 1.0, 0.0, 3, 1)
    depth = np.array([[0.5, 1.0, np.nan]], np.float32)
    # x = -0.05 at 0.5 m and x = 0 at 1 m; seen 0.1 m further left both are at u = 2
    shift = np.array([0.1, 0.0, 0.0])
    out = register_depth(depth, cam, cam, (np.eye(3), shift))
    assert out[0, 2] == np.float32(0.5)
    np.testing.assert_array_equal(out, register_reference(depth, cam, cam,
                                                          (np.eye(3), shift)))


#: Finite depths far from any camera's working range, metres: float32's smallest
#: subnormal and normal, tiny, and huge up to float32's largest.
EXTREME_DEPTHS = (1e-45, 1.2e-38, 1e-30, 1e-9, 1e9, 1e30, 3.4e38)


@pytest.mark.kernels
@pytest.mark.parametrize('z', EXTREME_DEPTHS)
@pytest.mark.parametrize('pose', ['beside', 'turned'])
def test_an_extreme_depth_writes_its_footprint_only(z: float, pose: str) -> None:
    """One depth pixel at an extreme but finite depth writes the target pixels its footprint
    covers and no other, as the plain reference does. A pixel of 1e-30 m seen from 2 cm
    beside it projects ~1e30 px away: the float loop bound became the most negative integer
    when converted and the pixel filled its whole row."""
    cam = Intrinsics(30.0, 30.0, 15.5, 11.5, 32, 24)
    R, t = ((np.eye(3), np.array([0.02, 0.0, 0.0])) if pose == 'beside' else
            (rotation_matrix(quaternion_from_rpy(0.3, -0.4, 0.2)), np.array([0.02, 0.01, 0.0])))
    for v, u in ((11, 15), (0, 0), (23, 31), (5, 25)):
        depth = np.full((24, 32), np.nan, np.float32)
        depth[v, u] = z
        out = register_depth(depth, cam, cam, (R, t))
        np.testing.assert_array_equal(out, register_reference(depth, cam, cam, (R, t)))
        assert np.isfinite(out).sum() <= 4, (v, u)  # a pixel's footprint, never a row
    one = np.full((24, 32), np.nan, np.float32)
    one[11, 15] = 1e-30
    beside = (np.eye(3), np.array([0.02, 0.0, 0.0]))
    assert np.isnan(register_depth(one, cam, cam, beside)).all()


@pytest.mark.parametrize(('R', 't', 'message'), [
    (np.eye(2), np.zeros(3), 'rotation must be a finite \\(3, 3\\)'),
    (np.eye(3), np.zeros(2), 'translation must be 3 finite'),
    (2 * np.eye(3), np.zeros(3), 'not a rotation matrix'),
    (np.diag([1.0, 1.0, -1.0]), np.zeros(3), 'not a rotation matrix: a reflection'),
    (np.eye(3), np.array([0, np.nan, 0]), 'translation must be 3 finite'),
])
def test_bad_extrinsics_are_refused(R: np.ndarray, t: np.ndarray, message: str) -> None:
    with pytest.raises(ArgumentError, match=message):
        register_depth(DEPTH_VIEW.depth, DEPTH_CAM, RGB_CAM, (R, t))
