"""The fused volume's settings, named as the tsdf_fusion node's parameters (nvblox's and
voxblox's names where the meaning is the same).

``truncation_distance`` is in voxels, as nvblox's ``truncation_distance_vox`` (voxblox
gives metres: 4 voxels of 5 cm are its 0.2 m). The weight of one observation
(``weighting_mode``) is 1 (``constant``), ``1 / Z^2`` with Z in metres (``inverse_square``),
``(voxel_size / sigma)^2`` (``sigma``: a measurement as uncertain as a voxel is wide weighs
1) or the confidence (``confidence``, 0 - 1); ``max_weight`` caps a voxel's sum.
"""

from __future__ import annotations

from dataclasses import dataclass

from depth_nodes.core.settings import check_settings, setting
from depth_nodes.errors import ArgumentError

__all__ = ['BLOCK_SIZES', 'WEIGHTING_MODES', 'TsdfParams']

#: How one observation is weighted (see the module notes).
WEIGHTING_MODES = ('constant', 'inverse_square', 'sigma', 'confidence')
#: Voxels along a block's side.
BLOCK_SIZES = (8, 16)


@dataclass(frozen=True)
class TsdfParams:
    """Settings of :class:`~depth_nodes.core.fusion.volume.TsdfVolume`."""

    voxel_size: float = setting(0.05, 'Side of a voxel, metres (changing it clears the map)',
                                low=0.002, high=1.0)
    block_size: int = setting(8, 'Voxels along a block\'s side (changing it clears the map)',
                              choices=BLOCK_SIZES)
    truncation_distance: float = setting(4.0, 'Truncation of the signed distance, in voxels '
                                         '(nvblox\'s truncation_distance_vox)', low=1.0,
                                         high=32.0)
    min_integration_distance: float = setting(0.1, 'Depths nearer than this, metres, are '
                                              'not integrated (voxblox\'s min_ray_length_m)',
                                              low=0.0, high=100.0)
    max_integration_distance: float = setting(5.0, 'Depths beyond this, metres, are not '
                                              'integrated', low=0.05, high=1000.0)
    max_weight: float = setting(100.0, 'Largest weight a voxel sums (a cap lets a surface '
                                'change again)', low=1e-3, high=1e9)
    weighting_mode: str = setting('constant', 'Weight of one observation: constant, '
                                  'inverse_square (1/Z^2), sigma ((voxel_size/sigma)^2, '
                                  'from a sigma image) or confidence (from a confidence '
                                  'image)', choices=WEIGHTING_MODES)
    weight_dropoff: bool = setting(False, 'Lower the weight linearly behind the surface, to '
                                   '0 at the truncation distance (voxblox\'s '
                                   'use_weight_dropoff)', choices=(True, False))
    free_space_carving: bool = setting(True, 'A voxel seen through (more than twice the '
                                       'truncation distance in front of the measured '
                                       'surface) loses half its weight before the update: a '
                                       'surface that moved away leaves within a few frames',
                                       choices=(True, False))
    allow_clear: bool = setting(False, 'A depth beyond max_integration_distance makes no '
                                'surface but clears the free space before it, up to that '
                                'distance (voxblox\'s allow_clear): an object that leaves '
                                'before a far background is carved, at a cost to the '
                                'surfaces near that distance', choices=(True, False))
    decay_factor: float = setting(1.0, 'Every voxel\'s weight is multiplied by this at each '
                                  'frame; a voxel below min_weight is forgotten (1: no '
                                  'decay)', low=0.0, high=1.0)
    clearing_radius: float = setting(0.0, 'Blocks farther than this from the camera, '
                                     'metres, are dropped (0: none)', low=0.0, high=1e6)
    memory_mb: float = setting(1024.0, 'Largest memory of the voxels, MB; past it the blocks '
                               'farthest from the camera are dropped', low=1.0, high=1e6)
    min_weight: float = setting(1e-4, 'A voxel with less weight is unobserved: no mesh, no '
                                'surface point, no distance', low=0.0, high=1e9)

    def validate(self) -> TsdfParams:
        """Check every field; returns self.

        Raises:
            ArgumentError: The first rule broken.
        """
        check_settings(self, 'tsdf')
        if self.min_integration_distance >= self.max_integration_distance:
            raise ArgumentError(f'tsdf min_integration_distance={self.min_integration_distance!r}'
                                f': must be below max_integration_distance='
                                f'{self.max_integration_distance!r}')
        return self

    @property
    def truncation_m(self) -> float:
        """The truncation distance in metres."""
        return self.truncation_distance * self.voxel_size
