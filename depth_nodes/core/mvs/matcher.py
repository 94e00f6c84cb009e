"""Plane-sweep multi-view stereo for one reference view: the sweep's costs
(:mod:`depth_nodes.core.mvs.cost`) aggregated by the stereo matcher's SGM with the planes
as labels, its sub-label refinement, and per pixel an inverse depth, its standard
deviation and a confidence.

Typical use::

    matcher = MultiViewMatcher(MvsParams(min_depth=0.5, max_depth=10, planes=64))
    result = matcher.match(reference, camera, [SourceView(image, camera_j, (R_j, t_j)), ...])
    result.depth, result.sigma, result.confidence

Standard deviation, in inverse depth: ``label_sigma`` planes (SGM's sub-plane precision,
which the measurements on the simulator show to dominate) and, in quadrature,
``match_sigma_px`` pixels in the source view where a plane step moves the projection most
(the widest effective baseline at that pixel: ``match_sigma_px / (d q / d rho)``, which
takes over where the baselines are short), with the pixels a pose error moves the
projections by (``pose_sigma_deg``: f x angle; ``pose_sigma_m``: f x distance / Z) added
to ``match_sigma_px`` in quadrature (the reference camera's focal length standing for
the sources'; a rig's calibrated views get the same terms). A pixel has no depth where the
whole plane range moves every projection by less than ``min_parallax_px`` (no baseline for
it: near a forward-moving camera's epipole, or too far away), where its standard deviation
spans the whole sweep, and (``whole_range_view``) where no source sees its ray over the
whole plane range. Confidence: ``1 - cost_ratio`` (the best
over the second-best aggregated cost of a label away from the winner).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics
from depth_nodes.core.mvs.cost import (
    COSTS,
    DEPRECATED_COSTS,
    MAX_SOURCES,
    TOP_COST,
    SweepCostInputs,
    sweep_cost_inputs,
)
from depth_nodes.core.mvs.planes import FRONTO_PARALLEL, SweepPlanes
from depth_nodes.core.settings import check_settings, setting
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.errors import ArgumentError

__all__ = ['MultiViewMatcher', 'MvsParams', 'MvsResult', 'SourceView']

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
LABEL = 'multi-view parameter'


@dataclass(frozen=True)
class MvsParams:
    """Settings of one plane sweep (names follow the stereo matcher's where they mean the
    same; every field's rule is its :func:`setting`)."""

    min_depth: float = setting(0.5, 'Nearest plane of the sweep, metres (Z)', low=1e-3,
                               high=1e4)
    max_depth: float = setting(20.0, 'Farthest plane of the sweep, metres (Z)', low=1e-3,
                               high=1e6)
    planes: int = setting(64, 'Planes of the sweep, evenly spaced in inverse depth', low=2,
                          high=1024)
    best_views: int = setting(2, 'Source views averaged per plane, the best ones (Kang et '
                              'al. 2001: occlusion-robust); capped by the views that see '
                              'the point', low=1, high=MAX_SOURCES)
    matching_cost: str = setting('census', "census: the stereo matcher's cost (census "
                                 'Hamming and truncated intensity difference, by their '
                                 "weights); zncc: a 3 x 3 window's ZNCC (slower); "
                                 'census_intensity: the old name of census (deprecated)',
                                 choices=(*COSTS, *DEPRECATED_COSTS))
    census_width: int = setting(5, 'census window width (odd)', low=3, high=9, odd=True)
    census_height: int = setting(5, 'census window height (odd; width x height - 1 <= 63)',
                                 low=3, high=9, odd=True)
    census_weight: int = setting(1, 'weight of the census Hamming cost (0: intensity only)',
                                 low=0, high=8)
    intensity_weight: int = setting(1, 'weight of the intensity cost (0: census only)',
                                    low=0, high=8)
    intensity_truncation: int = setting(10, 'cap of the intensity cost, grey levels (low: '
                                        'real views differ in shading, which census '
                                        'ignores)', low=1, high=255)
    unseen_cost: int = setting(40, 'cost of a plane no source view sees', low=0,
                               high=TOP_COST)
    P1: int = setting(18, 'Penalty of a one-plane change between neighbours', low=0,
                      high=4000)
    P2: int = setting(220, 'Penalty of a larger change (>= P1)', low=0, high=4000)
    p2_adaptive_scale: float = setting(8.0, 'grey-level scale of the image-adaptive P2 (0: '
                                       'constant)', low=0.0, high=255.0)
    paths: int = setting(8, 'aggregation paths: 4, 5 (one pass, bounded memory), 8 or 16',
                         choices=(4, 5, 8, 16))
    uniqueness_ratio: float = setting(5.0, 'Percent by which the best cost must beat the '
                                      'best plane away from it (0: off; 15 clears most '
                                      'depths of a dark, textureless background)',
                                      low=0.0, high=99.0)
    speckle_size: int = setting(50, 'Largest region of similar planes removed as a speckle '
                                '(0: off)', low=0, high=100000)
    speckle_range: float = setting(2.0, 'Largest plane step within one speckle region',
                                   low=0.0, high=1024.0)
    label_sigma: float = setting(0.3, 'Standard deviation of the refined plane, in planes '
                                 '(SGM\'s sub-plane precision: about 0.3 with 8 paths, '
                                 '0.55 with 5, measured on the simulator)', low=1e-3,
                                 high=100.0)
    match_sigma_px: float = setting(0.1, 'Matching precision, px, in the source view that '
                                    'resolves a pixel best (added to label_sigma in '
                                    'quadrature: it dominates where the baseline is short)',
                                    low=0.0, high=10.0)
    pose_sigma_deg: float = setting(0.0, 'Standard deviation of the rotation between a view '
                                    'and its sources, degrees (the pose source\'s '
                                    'relative error): it moves projections by f x angle '
                                    'px, added to match_sigma_px in quadrature', low=0.0,
                                    high=10.0)
    pose_sigma_m: float = setting(0.0, 'Standard deviation of the translation between a '
                                  'view and its sources, metres: f x it / Z px, added in '
                                  'quadrature', low=0.0, high=10.0)
    min_parallax_px: float = setting(2.0, 'A pixel whose projections move less than this '
                                     'over the whole plane range, in every view, has no '
                                     'depth (px)', low=0.0, high=1000.0)
    whole_range_view: bool = setting(True, 'A pixel has a depth only where some source view '
                                     'sees its ray over the whole plane range (the '
                                     "stereo matcher's border rule: near an image edge the "
                                     'near planes leave the sources, and the far ones win '
                                     'unopposed)')
    memory_mb: float = setting(160.0, 'memory for the cost volumes, MB (bands above it)',
                               low=0.0, high=1e6)

    def __post_init__(self) -> None:
        # a deprecated name of a cost (DEPRECATED_COSTS) stands for the cost it maps to
        if isinstance(self.matching_cost, str) and self.matching_cost in DEPRECATED_COSTS:
            object.__setattr__(self, 'matching_cost', DEPRECATED_COSTS[self.matching_cost])

    def validate(self, width: int | None = None) -> MvsParams:
        """Check every field (and, with ``width``, that the planes fit it); returns self.

        Raises:
            ArgumentError: Naming the first invalid field and why.
        """
        check_settings(self, LABEL)
        if not self.min_depth < self.max_depth:
            raise ArgumentError(f'{LABEL} min_depth={self.min_depth!r}: must be below '
                                f'max_depth ({self.max_depth})')
        if self.P2 < self.P1:
            raise ArgumentError(f'{LABEL} P2={self.P2}: must be >= P1 ({self.P1})')
        self.sgm_params().validate()
        if width is not None and self.planes >= width:
            raise ArgumentError(f'{LABEL} planes={self.planes}: must be below the image '
                                f'width {width}')
        return self

    def planes_of(self, normal: tuple[float, float, float] = FRONTO_PARALLEL, *,
                  offset: float = 0.0) -> SweepPlanes:
        """The sweep's labels (``offset``: see :attr:`SweepPlanes.offset`)."""
        return SweepPlanes(self.min_depth, self.max_depth, self.planes, normal, offset)

    def sgm_params(self) -> SgmParams:
        """The stereo matcher's settings for the sweep's volume: planes as disparities, no
        border statistic, no left-right check (the labels are not a stereo pair's)."""
        return SgmParams(
            min_disparity=0, disparity_range=self.planes, census_width=self.census_width,
            census_height=self.census_height, P1=self.P1, P2=self.P2,
            p2_adaptive_scale=self.p2_adaptive_scale, paths=self.paths,
            uniqueness_ratio=self.uniqueness_ratio, subpixel='parabola',
            match_brightness=False, border_cost=0.0, border_extrapolation=1.0,
            disp12_max_diff=-1.0, speckle_size=self.speckle_size,
            speckle_range=self.speckle_range, memory_mb=self.memory_mb)


@dataclass(frozen=True)
class SourceView:
    """A source view of a sweep.

    Attributes:
        image: (H, W) grey image, the reference's size.
        camera: Its pinhole camera.
        relative: ``(R, t)`` taking reference-frame points into its frame.
        census: Its census image, when already computed (reused), else None.
    """

    image: NDArray[Any]
    camera: Intrinsics
    relative: tuple[F64, F64]
    census: NDArray[Any] | None = None


@dataclass
class MvsResult:
    """One reference view's estimate (arrays are the result's own).

    Attributes:
        depth: (H, W) float32 Z, metres; NaN where none.
        rho: (H, W) float32 inverse depth, 1/m; NaN where none.
        rho_var: (H, W) float32 variance of ``rho``.
        sigma: (H, W) float32 standard deviation of Z (first order), metres.
        confidence: (H, W) float32 in [0, 1]; 0 where no depth.
        label: (H, W) float32 fractional plane index; NaN where none.
        inputs: The sweep's prepared inputs (census images reused by later sweeps).
    """

    depth: F32
    rho: F32
    rho_var: F32
    sigma: F32
    confidence: F32
    label: F32
    inputs: SweepCostInputs


@njit(cache=True, nogil=True)
def _parallax_kernel(rho: F32, k_inv: F64, normal: F64, a_matrix: F64, b_vector: F64,
                     width: int, height: int, rho_lo: float, rho_hi: float, rate: F32,
                     span: F32, covered: NDArray[np.uint8]) -> None:
    """Per pixel, the largest rate (px per unit inverse depth) at which a source
    projection moves at ``rho``, over the views that see the point, the largest
    distance any projection moves over [rho_lo, rho_hi], and how many views see the
    pixel's ray over the whole of [rho_lo, rho_hi] (both ends in front of the camera and
    inside its image: the projections between lie on the segment joining them)."""
    h, w = rho.shape
    views = a_matrix.shape[0]
    for y in range(h):
        for x in range(w):
            rx = k_inv[0, 0] * x + k_inv[0, 1] * y + k_inv[0, 2]
            ry = k_inv[1, 0] * x + k_inv[1, 1] * y + k_inv[1, 2]
            rz = k_inv[2, 0] * x + k_inv[2, 1] * y + k_inv[2, 2]
            s = normal[0] * rx + normal[1] * ry + normal[2] * rz
            best = 0.0
            widest = 0.0
            seeing = 0
            r = rho[y, x]
            for j in range(views):
                a0 = a_matrix[j, 0, 0] * x + a_matrix[j, 0, 1] * y + a_matrix[j, 0, 2]
                a1 = a_matrix[j, 1, 0] * x + a_matrix[j, 1, 1] * y + a_matrix[j, 1, 2]
                a2 = a_matrix[j, 2, 0] * x + a_matrix[j, 2, 1] * y + a_matrix[j, 2, 2]
                b0 = b_vector[j, 0] * s
                b1 = b_vector[j, 1] * s
                b2 = b_vector[j, 2] * s
                w_lo = a2 + rho_lo * b2
                w_hi = a2 + rho_hi * b2
                if w_lo > 1e-9 and w_hi > 1e-9:
                    u_lo, v_lo = (a0 + rho_lo * b0) / w_lo, (a1 + rho_lo * b1) / w_lo
                    u_hi, v_hi = (a0 + rho_hi * b0) / w_hi, (a1 + rho_hi * b1) / w_hi
                    du = u_hi - u_lo
                    dv = v_hi - v_lo
                    widest = max(widest, math.sqrt(du * du + dv * dv))
                    if 0.0 <= u_lo <= width - 1 and 0.0 <= v_lo <= height - 1 and \
                            0.0 <= u_hi <= width - 1 and 0.0 <= v_hi <= height - 1:
                        seeing += 1
                if not (r > 0 and math.isfinite(r)):
                    continue
                wz = a2 + r * b2
                if not wz > 1e-9:
                    continue
                u = (a0 + r * b0) / wz
                v = (a1 + r * b1) / wz
                if not (0.0 <= u <= width - 1 and 0.0 <= v <= height - 1):
                    continue
                du = (b0 * a2 - a0 * b2) / (wz * wz)
                dv = (b1 * a2 - a1 * b2) / (wz * wz)
                best = max(best, math.sqrt(du * du + dv * dv))
            rate[y, x] = best
            span[y, x] = widest
            covered[y, x] = seeing


def parallax(rho: F32, inputs: SweepCostInputs) -> tuple[F32, F32, NDArray[np.uint8]]:
    """``(rate, span, covered)`` of :func:`_parallax_kernel` for a sweep's inputs."""
    h, w = rho.shape
    rate = np.empty((h, w), np.float32)
    span = np.empty((h, w), np.float32)
    covered = np.empty((h, w), np.uint8)
    rhos = inputs.rho
    _parallax_kernel(np.ascontiguousarray(rho, np.float32), inputs.k_inv, inputs.normal,
                     inputs.a_matrix, inputs.b_vector, w, h, float(rhos[0]), float(rhos[-1]),
                     rate, span, covered)
    return rate, span, covered


class MultiViewMatcher:
    """Plane sweep + SGM with buffers reused across reference views.

    Args:
        params: Settings; :meth:`set_params` changes them between views.
    """

    def __init__(self, params: MvsParams | None = None) -> None:
        self.params = (params or MvsParams()).validate()
        self._sgm = SgmMatcher(self.params.sgm_params())

    def set_params(self, params: MvsParams) -> None:
        """Use ``params`` from the next view on (validated now)."""
        self.params = params.validate()
        self._sgm.set_params(self.params.sgm_params())

    @property
    def workspace_bytes(self) -> int:
        """Bytes of the SGM buffers kept between views (bounded by ``memory_mb``)."""
        return self._sgm.workspace_bytes

    def match(self, reference: NDArray[Any], camera: Intrinsics,
              sources: list[SourceView], *, offset: float = 0.0) -> MvsResult:
        """The depth of ``reference`` from ``sources``, on ``numba.get_num_threads()``
        threads.

        Raises:
            ArgumentError: Sizes or counts that do not fit the settings.
        """
        p = self.params
        ref = np.asarray(reference)
        if ref.ndim != 2:
            raise ArgumentError(f'the reference must be a grey (H, W) image, got {ref.shape}')
        p.validate(ref.shape[1])
        planes = p.planes_of(offset=offset)
        inputs = sweep_cost_inputs(
            ref, camera, [s.image for s in sources], [s.camera for s in sources],
            [s.relative for s in sources], planes,
            census_window=(p.census_height, p.census_width), census_weight=p.census_weight,
            intensity_weight=p.intensity_weight, truncation=p.intensity_truncation,
            best_k=min(p.best_views, len(sources)), unseen_cost=p.unseen_cost,
            source_census=[s.census for s in sources], cost=p.matching_cost)
        result = self._sgm.match_costs(inputs, ref)
        label = result.disparity.copy()
        rho = planes.rho_of(label).astype(np.float32)
        rate, span, covered = parallax(rho, inputs)
        step = planes.rho_step
        with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
            focal = 0.5 * (camera.fx + camera.fy)
            pixel_var = p.match_sigma_px ** 2 + (focal * math.radians(p.pose_sigma_deg)) ** 2 \
                + (focal * p.pose_sigma_m * rho) ** 2
            sigma_rho = np.sqrt(np.float32(p.label_sigma * step) ** 2 +
                                pixel_var / (rate * rate)).astype(np.float32)
            # no depth: too little parallax over the sweep, no view that sees the whole
            # sweep (its near planes leave every source image: what the reference sees
            # there, they may not), or a standard deviation as wide as the sweep itself
            bad = ~(span >= p.min_parallax_px) | ~(rho > 0) | \
                ~(sigma_rho < float(inputs.rho[-1] - inputs.rho[0]))
            if p.whole_range_view:
                bad |= covered == 0
            rho[bad] = np.nan
            label[bad] = np.nan
            rho_var = np.where(bad, np.nan, sigma_rho * sigma_rho).astype(np.float32)
            depth = (1.0 / rho).astype(np.float32)
            sigma = np.where(bad, np.nan, sigma_rho / (rho * rho)).astype(np.float32)
            confidence = np.where(bad, 0.0, np.clip(1.0 - result.cost_ratio, 0, 1)).astype(
                np.float32)
        return MvsResult(depth, rho, rho_var, sigma, confidence, label, inputs)
