"""The depth filter's settings, named as the depth_filter node's parameters.

The stages run in librealsense's recommended order: decimation, flying pixels, spatial,
temporal, hole filling. ``filter_domain`` says what the spatial and temporal stages average:
``disparity`` (1 / Z, librealsense's recommendation for stereo, where the noise grows with
Z squared) or ``depth`` (Z, for time of flight, whose noise grows about linearly). Their
``*_delta`` is in metres either way: in the disparity domain it is the step at 1 m, and it
grows with Z squared (a step of 0.02 m at 1 m is one of 0.32 m at 4 m).
"""

from __future__ import annotations

from dataclasses import dataclass

from depth_nodes.core.settings import check_settings, setting
from depth_nodes.errors import ArgumentError

#: Hole filling modes (librealsense's hole_filling_filter, by name).
HOLE_FILLING = ('off', 'fill_from_left', 'farthest_from_around', 'nearest_from_around')
#: Domains of the spatial and temporal stages.
DOMAINS = ('disparity', 'depth')
#: librealsense's spatial ``holes_fill`` codes: the widest hole, pixels, each fills
#: (0: off; 5: any width).
SPATIAL_HOLES = (0, 2, 4, 8, 16, 1 << 30)
#: librealsense's temporal persistence modes: (valid frames needed, of the last N),
#: the current frame included; 0: off, 8: always (a pixel keeps its last value forever).
PERSISTENCE = ((0, 0), (8, 8), (2, 3), (2, 4), (2, 8), (1, 2), (1, 5), (1, 8), (1, 1 << 30))


@dataclass(frozen=True)
class DepthFilterParams:
    """Settings of :class:`~depth_nodes.core.depth_filter.chain.DepthFilter`."""

    decimation: int = setting(1, 'Decimation factor: each n x n block becomes one pixel '
                              '(median of its valid pixels for 2 - 3, mean above; 1: off)',
                              low=1, high=8)
    flying_gap: float = setting(0.05, 'Flying pixels: the gap, metres, beyond their noise, '
                                'between the two neighbours of a depth that lies between '
                                'them, or beside a depth beyond both (0: keep them)',
                                low=0.0, high=10.0)
    flying_jump: float = setting(0.0, 'Flying pixels: also both sides of a depth jump larger '
                                 'than this fraction of the depth (0: off)', low=0.0,
                                 high=10.0)
    filter_domain: str = setting('disparity', 'What the spatial and temporal stages average: '
                                 'disparity (1/Z: stereo) or depth (Z: time of flight)',
                                 choices=DOMAINS)
    spatial: bool = setting(True, 'Edge-preserving spatial smoothing (domain transform)',
                            choices=(True, False))
    spatial_alpha: float = setting(0.5, 'Spatial smoothing weight of the current pixel '
                                   '(1: none)', low=0.25, high=1.0)
    spatial_delta: float = setting(0.02, 'Spatial: largest step, metres (at 1 m in the '
                                   'disparity domain), smoothed across; larger steps are '
                                   'edges', low=0.0, high=10.0)
    spatial_iterations: int = setting(2, 'Spatial: passes (each left, right, down, up)',
                                      low=1, high=5)
    spatial_holes_fill: int = setting(0, 'Spatial: fill holes from the left up to 2, 4, 8, '
                                      '16 px or any width (1 - 5, librealsense\'s codes; 0: '
                                      'off); filled pixels are in the mask', low=0, high=5)
    temporal: bool = setting(True, 'Temporal smoothing (with the camera\'s motion when '
                             'poses are given)', choices=(True, False))
    temporal_alpha: float = setting(0.4, 'Temporal smoothing weight of the current frame '
                                    '(1: none)', low=0.0, high=1.0)
    temporal_delta: float = setting(0.02, 'Temporal: largest change, metres (at 1 m in the '
                                    'disparity domain), smoothed; a larger one takes the '
                                    'new depth at once', low=0.0, high=10.0)
    temporal_persistence: int = setting(3, 'Temporal: keep a pixel\'s last depth while it is '
                                        'missing if it was valid in 8/8, 2/3, 2/4, 2/8, 1/2, '
                                        '1/5, 1/8 of the last frames or always (1 - 8, '
                                        'librealsense\'s modes; 0: off); kept pixels are in '
                                        'the mask', low=0, high=8)
    hole_filling: str = setting('off', 'Fill the remaining holes: off, fill_from_left, '
                                'farthest_from_around, nearest_from_around (filled pixels '
                                'are in the mask)', choices=HOLE_FILLING)

    def validate(self) -> DepthFilterParams:
        """Check every field; returns self.

        Raises:
            ArgumentError: The first rule broken.
        """
        check_settings(self, 'depth_filter parameter')
        if self.temporal and self.temporal_alpha == 0.0:
            raise ArgumentError('depth_filter parameter temporal_alpha=0.0: the depth would '
                                'never change (use 0 < alpha <= 1)')
        return self
