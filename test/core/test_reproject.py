"""depth_nodes.core.reproject against exact projection and the simulator's ground truth.

Tolerances: with ground-truth disparity, points agree with the ground-truth 3-D points to a
relative 1e-5 of Z (float32 precision; the arithmetic is float64, one final cast). With SGM
disparity, the per-pixel depth error agrees with the first-order prediction
Z^2 / (f B) * |d - d_gt| to 10% + 1 mm on pixels whose disparity error is under 5% of
d + delta_cx (where the first-order term is within 5.3% of the exact one).
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from helpers import Lazy
from reference.reproject import reproject_reference

from depth_nodes.core.camera import CameraModel, StereoModel
from depth_nodes.core.reproject import depth_std, depth_to_millimetres, reproject_disparity
from depth_nodes.core.sgm import sgm_match
from depth_nodes.sim import StereoSimConfig, simulate_stereo

CONFIG = StereoSimConfig(width=200, height=150, n_frames=1, seed=11, right_cx_offset=3.5,
                         baseline_m=0.3, distortion_scale=0.0, rotation_deg=0.0,
                         noise_sigma=1.0)
FRAME = Lazy(lambda: next(simulate_stereo(CONFIG)))
STEREO = Lazy(lambda: StereoModel(FRAME.left_camera, FRAME.right_camera))
RTOL = 1e-5


def gt_points(depth: np.ndarray, camera: CameraModel) -> np.ndarray:
    """Ground-truth 3-D points of the left rectified frame from the ground-truth depth."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    z = depth.astype(np.float64)
    return np.dstack([(u - camera.cx) * z / camera.fx, (v - camera.cy) * z / camera.fy, z])


def _pair(tx_left: float = 0.0, ty_left: float = 0.0, delta_cx: float = 4.0,
          size: tuple[int, int] = (40, 30)) -> StereoModel:
    w, h = size
    f, b = 50.0, 0.2
    K = np.array([[f, 0, 19.5], [0, f, 14.5], [0, 0, 1]])
    pl = np.array([[f, 0, 19.5, tx_left], [0, f, 14.5, ty_left], [0, 0, 1, 0]])
    pr = np.array([[f, 0, 19.5 + delta_cx, tx_left - f * b], [0, f, 14.5, ty_left],
                   [0, 0, 1, 0]])
    return StereoModel(CameraModel(w, h, K, P=pl), CameraModel(w, h, K, P=pr))


class TestGeometry:
    @pytest.mark.parametrize(('tx', 'ty', 'dcx'), [(0.0, 0.0, 0.0), (0.0, 0.0, 4.0),
                                                   (-3.0, 2.0, -2.5)])
    def test_points_reproject_to_both_pixels(self, tx: float, ty: float, dcx: float) -> None:
        stereo = _pair(tx, ty, dcx)
        rng = np.random.default_rng(3)
        disparity = rng.uniform(3.0, 30.0, (30, 40)).astype(np.float32)
        result = reproject_disparity(disparity, stereo)
        assert result.valid.all()
        xyz1 = np.concatenate([result.points.astype(np.float64), np.ones((30, 40, 1))], -1)
        for P, shift in ((stereo.left.projection, 0.0), (stereo.right.projection, disparity)):
            proj = xyz1 @ P.T
            u = proj[..., 0] / proj[..., 2]
            v = proj[..., 1] / proj[..., 2]
            np.testing.assert_allclose(u, np.arange(40)[None, :] - shift + 0 * u, atol=1e-4)
            np.testing.assert_allclose(v, np.arange(30)[:, None] + 0 * v, atol=1e-4)

    def test_agrees_with_stereo_model_and_q(self) -> None:
        stereo = _pair(delta_cx=4.0)
        disparity = np.random.default_rng(4).uniform(1.0, 20.0, (30, 40)).astype(np.float32)
        result = reproject_disparity(disparity, stereo)
        np.testing.assert_allclose(result.depth, stereo.disparity_to_depth(disparity),
                                   rtol=1e-6)
        u, v = np.meshgrid(np.arange(40.0), np.arange(30.0))
        hom = np.stack([u, v, disparity, np.ones_like(u)], -1) @ stereo.Q.T
        np.testing.assert_allclose(result.points, hom[..., :3] / hom[..., 3:], rtol=1e-5,
                                   atol=1e-6)

    def test_invalid_pixels_are_nan_everywhere(self) -> None:
        stereo = _pair(delta_cx=4.0)
        disparity = np.full((30, 40), 6.0, np.float32)
        disparity[0, 0] = np.nan
        disparity[0, 1] = np.inf
        disparity[0, 2] = -4.0  # d + delta_cx == 0: at infinity
        disparity[0, 3] = -5.0  # behind
        result = reproject_disparity(disparity, stereo)
        assert not result.valid[0, :4].any()
        assert result.valid[0, 4:].all()
        assert np.isnan(result.points[0, :4]).all()
        assert np.isnan(result.depth[0, :4]).all()
        assert np.isfinite(result.points[1:]).all()


class TestGroundTruth:
    def test_gt_disparity_gives_gt_points(self) -> None:
        assert STEREO.delta_cx == pytest.approx(3.5)
        result = reproject_disparity(FRAME.disparity_gt, STEREO)
        assert result.valid.all()
        z = FRAME.depth_gt.astype(np.float64)
        rel = np.abs(result.depth - z) / z
        assert rel.max() < RTOL
        err = np.linalg.norm(result.points - gt_points(FRAME.depth_gt, FRAME.left_camera),
                             axis=-1) / z
        assert err.max() < RTOL

    def test_sgm_error_matches_first_order_prediction(self) -> None:
        result = sgm_match(FRAME.left_rect_gt, FRAME.right_rect_gt, disparity_range=64,
                           min_disparity=-4)
        d = result.disparity
        fb = STEREO.focal * STEREO.baseline
        err_d = d.astype(np.float64) - FRAME.disparity_gt
        den = FRAME.disparity_gt.astype(np.float64) + STEREO.delta_cx
        good = (np.isfinite(err_d) & (FRAME.occlusion_gt == 0)
                & (np.abs(err_d) < 0.05 * den) & (np.abs(err_d) > 0))
        assert good.mean() > 0.5
        cloud = reproject_disparity(d, STEREO)
        z_gt = FRAME.depth_gt.astype(np.float64)
        measured = np.linalg.norm(cloud.points - gt_points(FRAME.depth_gt, FRAME.left_camera),
                                  axis=-1)
        h, w = d.shape
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        ray = np.sqrt(1 + ((u - STEREO.left.cx) / STEREO.left.fx) ** 2
                      + ((v - STEREO.left.cy) / STEREO.left.fy) ** 2)
        predicted = z_gt ** 2 / fb * np.abs(err_d) * ray
        m, p = measured[good], predicted[good]
        assert np.all(np.abs(m - p) <= 0.10 * p + 1e-3)
        dz = np.abs(cloud.depth.astype(np.float64) - z_gt)[good]
        assert np.all(np.abs(dz - (z_gt ** 2 / fb * np.abs(err_d))[good])
                      <= 0.10 * dz + 1e-3)


class TestMasks:
    def test_range_limits_apply_to_z(self) -> None:
        z = FRAME.depth_gt
        lo, hi = np.quantile(z, [0.2, 0.8])
        result = reproject_disparity(FRAME.disparity_gt, STEREO, min_range=float(lo),
                                     max_range=float(hi))
        inside = (result.depth >= lo) & (result.depth <= hi)
        np.testing.assert_array_equal(result.valid, np.isfinite(result.depth))
        expected = (z >= lo * (1 + 1e-6)) & (z <= hi * (1 - 1e-6))
        assert result.valid[expected].all()
        assert inside[result.valid].all()
        assert 0.5 < result.valid.mean() < 0.7

    def test_min_confidence(self) -> None:
        conf = np.random.default_rng(5).random(FRAME.disparity_gt.shape).astype(np.float32)
        conf[0, 0] = np.nan
        result = reproject_disparity(FRAME.disparity_gt, STEREO, confidence=conf,
                                     min_confidence=0.3)
        with np.errstate(invalid='ignore'):
            np.testing.assert_array_equal(result.valid, conf >= 0.3)
        assert np.isnan(result.points[~result.valid]).all()

    @pytest.mark.parametrize(('kwargs', 'message'), [
        ({'disparity': np.zeros((3, 4, 1), np.float32)}, 'must be a (H, W) array'),
        ({'disparity': np.zeros((3, 4), np.float32)}, 'disparity is 4x3 but the cameras'),
        ({'disparity': np.zeros((150, 200), np.int16)}, 'must be a float array'),
        ({'min_range': -1.0}, 'min_range=-1.0: must be in [0, 1e+06]'),
        ({'min_range': 5.0, 'max_range': 2.0}, 'max_range (2.0) must be >= min_range'),
        ({'confidence': np.zeros((10, 10), np.float32)}, 'confidence must have the disparity'),
    ])
    def test_validation(self, kwargs: dict[str, object], message: str) -> None:
        args = {'disparity': FRAME.disparity_gt, **kwargs}
        disparity = args.pop('disparity')
        with pytest.raises(ValueError, match=re.escape(message)):
            reproject_disparity(disparity, STEREO, **args)  # type: ignore[arg-type]


@pytest.mark.kernels
@pytest.mark.parametrize('dtype', [np.float32, np.float64])
@pytest.mark.parametrize(('min_range', 'max_range', 'min_confidence'),
                         [(0.0, 0.0, None), (0.5, 3.0, 0.1), (0.0, 2.0, 0.3)])
def test_kernel_equals_reference(dtype: type, min_range: float, max_range: float,
                                 min_confidence: float | None) -> None:
    """The numba pass against the numpy reference, bit for bit: NaN, infinities, disparities
    at and behind infinity, range limits, confidences at the threshold and NaN, and an
    absurd calibration whose points overflow float32."""
    rng = np.random.default_rng(4)
    disparity = rng.uniform(-6.0, 40.0, (30, 40)).astype(dtype)
    disparity[0, :4] = [np.nan, np.inf, -np.inf, -4.0]  # -4 + delta_cx 4 = 0: infinity
    conf = rng.random((30, 40)).astype(np.float32)
    if min_confidence is not None:
        conf[1, :3] = [np.float32(min_confidence), np.nextafter(np.float32(min_confidence),
                                                                np.float32(0)), np.nan]
    for absurd, stereo in ((False, _pair(-3.0, 2.0, 4.0)), (True, _pair(0.0, 1e41, 4.0))):
        args = (disparity, stereo, min_range, max_range,
                None if min_confidence is None else conf, min_confidence or 0.0)
        got = reproject_disparity(disparity, stereo, min_range=min_range,
                                  max_range=max_range,
                                  confidence=None if min_confidence is None else conf,
                                  min_confidence=min_confidence or 0.0)
        want = reproject_reference(*args)
        np.testing.assert_array_equal(got.valid, want.valid)
        np.testing.assert_array_equal(got.points, want.points)  # NaN where invalid
        np.testing.assert_array_equal(got.depth, want.depth)
        # the absurd Ty puts every Y beyond float32: no point valid
        assert got.valid.sum() == 0 if absurd else 0 < got.valid.sum() < got.valid.size


def test_depth_std_and_millimetres() -> None:
    z = np.array([1.0, 2.0, np.nan], np.float32)
    np.testing.assert_allclose(depth_std(z, 100.0, 0.1, 0.25), [0.025, 0.1, np.nan],
                               rtol=1e-6)
    with pytest.raises(ValueError, match='disparity_std must be >= 0'):
        depth_std(z, 100.0, 0.1, -1.0)
    with pytest.raises(ValueError, match='focal \\* baseline must be positive'):
        depth_std(z, 100.0, 0.0, 0.25)
    mm = depth_to_millimetres(np.array([0.0004, 0.0006, 1.2344, 1.2346, 65.535, 65.536,
                                        np.nan, -1.0]))
    np.testing.assert_array_equal(mm, [0, 1, 1234, 1235, 65535, 0, 0, 0])
    assert mm.dtype == np.uint16
