"""Tests of the stereo simulator: ground-truth geometry, raw images vs CameraInfo, config.

All scenes are small (160x120 or 240x180) with fixed seeds. Tolerances are stated where
they are used; the image comparisons run with ``noise_sigma=0`` so that they measure the
geometry, not the noise.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from depth_nodes.core.camera import EQUIDISTANT, PLUMB_BOB, RATIONAL_POLYNOMIAL
from depth_nodes.errors import ConfigError
from depth_nodes.sim import (
    OCCLUSION_OCCLUDED,
    OCCLUSION_OUTSIDE,
    OCCLUSION_VISIBLE,
    StereoFrame,
    StereoSimConfig,
    left_label_map,
    scene_for_frame,
    simulate_stereo,
    undistort_pixels,
)

MODELS = (PLUMB_BOB, RATIONAL_POLYNOMIAL, EQUIDISTANT)
SMALL = StereoSimConfig(width=160, height=120, n_frames=1, seed=3)
CLEAN = dataclasses.replace(SMALL, noise_sigma=0.0)


def first_frame(config: StereoSimConfig) -> StereoFrame:
    return next(iter(simulate_stereo(config)))


@pytest.fixture(scope='module')
def clean_frame() -> StereoFrame:
    """240x180, no noise, no vignetting, nonzero cx offset."""
    cfg = StereoSimConfig(
        width=240,
        height=180,
        n_frames=1,
        seed=1,
        noise_sigma=0.0,
        vignetting=0.0,
        right_cx_offset=5.5,
    )
    return first_frame(cfg)


def away_from_depth_edges(disparity: np.ndarray, margin: int = 2) -> np.ndarray:
    """Pixels whose (2 * margin + 1)^2 neighbourhood has a disparity spread below 1 px."""
    k = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    spread = cv2.dilate(disparity, k) - cv2.erode(disparity, k)
    return spread < 1.0


def warp_right_to_left(frame: StereoFrame, disparity: np.ndarray) -> np.ndarray:
    """Right rect GT sampled at (x - d, y), with the right gain and offset undone."""
    h, w = disparity.shape
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    right = frame.right_rect_gt.astype(np.float32)
    warped = cv2.remap(
        right,
        xs - disparity,
        ys,
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=np.nan,
    )
    cfg = StereoSimConfig()
    return (warped - cfg.right_offset) / cfg.right_gain


# ------------------------------------------------------------------ 1. disparity


def test_disparity_maps_left_onto_right(clean_frame: StereoFrame) -> None:
    """Median |left - warped right| < 1.5 grey levels on visible, edge-free pixels.

    vignetting=0: vignetting is evaluated at each camera's own raw pixel, so with it on
    the two views of a point differ by design. Shifting the disparity by 1 px must make
    the error clearly larger (> 3x and > 1 grey level), which shows the check can fail
    (measured: about 0.33 vs 1.8 at seed 1).
    """
    f = clean_frame
    mask = (f.occlusion_gt == OCCLUSION_VISIBLE) & away_from_depth_edges(f.disparity_gt)
    left = f.left_rect_gt.astype(np.float32)
    err = np.abs(warp_right_to_left(f, f.disparity_gt) - left)
    err_shift = np.abs(warp_right_to_left(f, f.disparity_gt + 1.0) - left)
    valid = mask & np.isfinite(err) & np.isfinite(err_shift)
    assert valid.mean() > 0.6
    good = np.median(err[valid])
    bad = np.median(err_shift[valid])
    assert good < 1.5
    assert bad > max(1.0, 3.0 * good)


def test_disparity_is_dense_and_in_range(clean_frame: StereoFrame) -> None:
    f = clean_frame
    assert f.disparity_gt.dtype == np.float32
    assert f.depth_gt.dtype == np.float32
    assert np.isfinite(f.disparity_gt).all()
    assert np.isfinite(f.depth_gt).all()
    # Depth stays within the designed 0.8 .. 10 m, so fB/Z stays small.
    assert f.depth_gt.min() > 0.8
    assert f.depth_gt.max() < 10.0


# ------------------------------------------------------------------- 2. depth


def test_depth_matches_disparity_with_cx_offset(clean_frame: StereoFrame) -> None:
    f = clean_frame
    p_left, p_right = f.left_camera.P, f.right_camera.P
    focal = p_left[0, 0]
    baseline = -p_right[0, 3] / p_right[0, 0]
    assert baseline == pytest.approx(0.12)
    dcx = p_left[0, 2] - p_right[0, 2]
    assert dcx == pytest.approx(-5.5)
    depth = focal * baseline / (f.disparity_gt.astype(np.float64) - dcx)
    np.testing.assert_allclose(depth, f.depth_gt, rtol=2e-6)


# ------------------------------------------------- 3. raw images vs CameraInfo


def rectify(raw: np.ndarray, cam, r_override: np.ndarray | None = None) -> tuple:
    r = cam.R if r_override is None else r_override
    size = (cam.width, cam.height)
    if cam.distortion_model == EQUIDISTANT:
        mx, my = cv2.fisheye.initUndistortRectifyMap(
            cam.K, cam.D, r, cam.P[:, :3], size, cv2.CV_32FC1
        )
    else:
        mx, my = cv2.initUndistortRectifyMap(cam.K, cam.D, r, cam.P[:, :3], size, cv2.CV_32FC1)
    return cv2.remap(raw.astype(np.float32), mx, my, cv2.INTER_LINEAR), mx, my


@pytest.mark.parametrize('model', MODELS)
def test_rectified_raw_matches_rect_gt(model: str) -> None:
    """cv2 rectification of raw with the CameraInfo: mean |diff| < 3 grey levels inside.

    noise_sigma=0 and a 6 px border excluded. Using R^T instead of R (a ~2 degree error)
    must at least double the error. The rectification maps must stay inside the raw image
    (no black border).
    """
    cfg = dataclasses.replace(CLEAN, distortion_model=model, right_cx_offset=-4.0)
    f = first_frame(cfg)
    assert len(f.left_camera.D) == {PLUMB_BOB: 5, RATIONAL_POLYNOMIAL: 8, EQUIDISTANT: 4}[model]
    inner = np.s_[6:-6, 6:-6]
    for raw, gt, cam in (
        (f.left_raw, f.left_rect_gt, f.left_camera),
        (f.right_raw, f.right_rect_gt, f.right_camera),
    ):
        rect, mx, my = rectify(raw, cam)
        assert mx.min() >= 0
        assert mx.max() <= cam.width - 1
        assert my.min() >= 0
        assert my.max() <= cam.height - 1
        err = np.abs(rect - gt.astype(np.float32))[inner].mean()
        wrong, _, _ = rectify(raw, cam, cam.R.T)
        err_wrong = np.abs(wrong - gt.astype(np.float32))[inner].mean()
        assert err < 3.0
        assert err_wrong > 2.0 * err


# ------------------------------------------------------ 4. undistortion round trip


@pytest.mark.parametrize('model', MODELS)
def test_undistorted_rays_redistort_to_their_pixels(model: str) -> None:
    """cv2.projectPoints / cv2.fisheye.projectPoints return each sample to < 1e-3 px."""
    cfg = dataclasses.replace(SMALL, distortion_model=model)
    cam = first_frame(dataclasses.replace(cfg, width=64, height=48)).left_camera
    # Supersample positions across the whole image, corners included.
    v, u = np.mgrid[-0.25 : cam.height - 0.5 : 0.5, -0.25 : cam.width - 0.5 : 0.5]
    pixels = np.column_stack([u.ravel(), v.ravel()])
    rays = undistort_pixels(cam, pixels)
    zero = np.zeros(3)
    if model == EQUIDISTANT:
        back, _ = cv2.fisheye.projectPoints(rays.reshape(1, -1, 3), zero, zero, cam.K, cam.D)
    else:
        back, _ = cv2.projectPoints(rays, zero, zero, cam.K, cam.D)
    assert np.abs(back.reshape(-1, 2) - pixels).max() < 1e-3


# ------------------------------------------------- 5. determinism and scene content


def test_same_seed_identical_other_seed_differs() -> None:
    cfg = dataclasses.replace(SMALL, n_frames=2)
    a = list(simulate_stereo(cfg))
    b = list(simulate_stereo(cfg))
    c = list(simulate_stereo(dataclasses.replace(cfg, seed=4)))
    names = (
        'left_raw',
        'right_raw',
        'left_rect_gt',
        'right_rect_gt',
        'disparity_gt',
        'depth_gt',
        'occlusion_gt',
    )
    for fa, fb in zip(a, b, strict=True):
        for name in names:
            assert getattr(fa, name).tobytes() == getattr(fb, name).tobytes()
    assert not np.array_equal(a[0].disparity_gt, c[0].disparity_gt)
    assert not np.array_equal(a[0].left_raw, c[0].left_raw)
    assert not np.array_equal(a[0].left_camera.K, c[0].left_camera.K)
    # Objects move between frames; the stamps follow the frame rate.
    assert not np.array_equal(a[0].disparity_gt, a[1].disparity_gt)
    assert a[1].stamp_ns - a[0].stamp_ns == 100_000_000
    assert a[0].stamp_ns == cfg.start_stamp_ns


def test_occlusions_lie_left_of_nearer_surfaces(clean_frame: StereoFrame) -> None:
    """Occluded pixels have a nearer surface to their right within the max disparity."""
    f = clean_frame
    occluded = f.occlusion_gt == OCCLUSION_OCCLUDED
    assert occluded.mean() > 0.01
    assert (f.occlusion_gt == OCCLUSION_OUTSIDE).any()
    assert set(np.unique(f.occlusion_gt)) <= {0, 128, 255}
    reach = int(np.ceil(f.disparity_gt.max())) + 1
    depth = f.depth_gt
    _h, w = depth.shape
    ys, xs = np.nonzero(occluded)
    nearer_right = np.zeros(len(xs), bool)
    for k in range(1, reach + 1):
        xr = np.minimum(xs + k, w - 1)
        nearer_right |= depth[ys, xr] < depth[ys, xs] * 0.99
    assert nearer_right.mean() > 0.99
    # Outside pixels sit at the image borders, no further in than the disparity reaches
    # (at the right border too: the +5.5 px cx offset makes far disparities negative).
    _, x_out = np.nonzero(f.occlusion_gt == OCCLUSION_OUTSIDE)
    near_left = x_out < f.disparity_gt.max() + 1
    near_right = x_out > w - 2 + min(0.0, f.disparity_gt.min())
    assert (near_left | near_right).all()
    assert near_left.any()


def test_occluded_pixels_see_nearer_surface_in_right_view(clean_frame: StereoFrame) -> None:
    """Independent check: a right rectified depth render at the projected pixel."""
    f = clean_frame
    cfg = StereoSimConfig(width=240, height=180, seed=1, right_cx_offset=5.5)
    scene = scene_for_frame(cfg, 0)
    p = f.right_camera.P
    h, w = f.depth_gt.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.column_stack(
        [((u - p[0, 2]) / p[0, 0]).ravel(), ((v - p[1, 2]) / p[1, 1]).ravel(), np.ones(h * w)]
    )
    right_depth, _ = scene.cast(np.array([cfg.baseline_m, 0.0, 0.0]), rays)
    right_depth = right_depth.reshape(h, w)
    xr = np.rint(u - f.disparity_gt).astype(int)
    inside = f.occlusion_gt != OCCLUSION_OUTSIDE
    yi = v.astype(int)
    rd = np.where(inside, right_depth[yi, np.clip(xr, 0, w - 1)], np.nan)
    occluded = f.occlusion_gt == OCCLUSION_OCCLUDED
    # Rounding to the pixel grid blurs edges by half a pixel: demand most, not all.
    assert np.mean(rd[occluded] < f.depth_gt[occluded] * 0.995) > 0.9
    visible = (f.occlusion_gt == OCCLUSION_VISIBLE) & away_from_depth_edges(f.disparity_gt)
    assert np.mean(np.abs(rd[visible] - f.depth_gt[visible]) < 0.01 * f.depth_gt[visible]) > 0.99


def test_scene_has_thin_weak_and_repetitive_regions() -> None:
    cfg = StereoSimConfig(width=240, height=180, seed=1, noise_sigma=0.0)
    labels, names = left_label_map(cfg)
    img = first_frame(cfg).left_rect_gt.astype(np.float64)
    for required in (
        'background',
        'ground',
        'fronto',
        'slanted',
        'box',
        'sphere',
        'pole',
        'bar',
        'weak',
        'repetitive',
    ):
        assert required in names
        ids = [i for i, n in enumerate(names) if n == required]
        assert np.isin(labels, ids).sum() > 20, required
    # Poles: 1..7 px wide per row; the bar: 1..7 px high per column.
    for name, axis in (('pole', 1), ('bar', 0)):
        for k in (i for i, n in enumerate(names) if n == name):
            runs = (labels == k).sum(axis=axis)
            runs = runs[runs > 0]
            assert len(runs) > 20, name
            assert 1 <= np.median(runs) <= 7, name

    def region(name: str) -> np.ndarray:
        k = names.index(name)
        return cv2.erode((labels == k).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0

    weak, strong = region('weak'), region('fronto')
    assert img[weak].std() < 4.0 < img[strong].std()
    # Repetitive: the dominant horizontal period of the stripes is 8..16 px.
    ys, xs = np.nonzero(region('repetitive'))
    row = int(np.median(ys))
    cols = xs[ys == row]
    profile = img[row, cols.min() : cols.max() + 1]
    spectrum = np.abs(np.fft.rfft(profile - profile.mean()))
    period = len(profile) / (1 + np.argmax(spectrum[1:]))
    assert 7.0 <= period <= 17.0


def test_colour_and_mono_and_camera_info() -> None:
    cfg = dataclasses.replace(CLEAN, right_cx_offset=3.0)
    mono = first_frame(cfg)
    colour = first_frame(dataclasses.replace(cfg, colour=True))
    assert mono.left_raw.shape == (120, 160)
    assert mono.left_raw.dtype == np.uint8
    assert colour.left_raw.shape == (120, 160, 3)
    assert colour.right_rect_gt.dtype == np.uint8
    luma = colour.left_rect_gt.astype(np.float64) @ [0.299, 0.587, 0.114]
    assert np.abs(luma - mono.left_rect_gt).max() <= 1.0
    left, right = mono.left_camera, mono.right_camera
    f = 0.8 * 160
    np.testing.assert_allclose(left.P, [[f, 0, 79.5, 0], [0, f, 59.5, 0], [0, 0, 1, 0]])
    np.testing.assert_allclose(right.P, [[f, 0, 82.5, -f * 0.12], [0, f, 59.5, 0], [0, 0, 1, 0]])
    for cam in (left, right):
        np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-12)
        angle = np.degrees(np.arccos((np.trace(cam.R) - 1) / 2))
        assert 0.7 < angle < 1.3
        assert 0.9 < cam.K[0, 0] / f < 0.995
    assert not np.allclose(left.R, right.R)
    assert left.frame_id != right.frame_id


# --------------------------------------------------------------- 6. validation


@pytest.mark.parametrize(
    ('field', 'value', 'message'),
    [
        ('width', 8, 'width must be >= 16'),
        ('height', 15, 'height must be >= 16'),
        ('width', 64.0, 'width must be an integer'),
        ('n_frames', 0, 'n_frames must be >= 1'),
        ('seed', -1, 'seed must be >= 0'),
        ('focal_px', -100.0, 'focal_px must be positive'),
        ('baseline_m', 0.0, 'baseline_m must be positive'),
        ('baseline_m', float('nan'), 'baseline_m must be finite'),
        ('distortion_model', 'fisheye', 'distortion_model must be one of'),
        ('rotation_deg', 20.0, r'rotation_deg must be in \[0, 10\]'),
        ('supersample', 0, r'supersample must be in \[1, 8\]'),
        ('vignetting', 1.0, r'vignetting must be in \[0, 1\)'),
        ('noise_sigma', -1.0, 'noise_sigma must be >= 0'),
        ('frame_rate_hz', 0.0, 'frame_rate_hz must be positive'),
        ('right_gain', 0.0, 'right_gain must be positive'),
        ('right_cx_offset', 100.0, 'right_cx_offset must be within'),
    ],
)
def test_config_validation(field: str, value: object, message: str) -> None:
    cfg = dataclasses.replace(SMALL, **{field: value})
    with pytest.raises(ValueError, match=message):
        simulate_stereo(cfg)
    with pytest.raises(ConfigError, match=field):
        left_label_map(cfg)
