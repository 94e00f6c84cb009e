"""Volumetric fusion of depth images into a truncated signed distance function (TSDF):
blocks of voxels (:mod:`.volume`), their mesh (:mod:`.mesh`, :mod:`.layer`), the
distance field of the free space (:mod:`.esdf`) and mesh files (:mod:`.ply`). No ROS."""

from depth_nodes.core.fusion.mesh import BlockMeshes, block_meshes, surface_points, weld
from depth_nodes.core.fusion.params import BLOCK_SIZES, WEIGHTING_MODES, TsdfParams
from depth_nodes.core.fusion.volume import Integrated, TsdfVolume

__all__ = ['BLOCK_SIZES', 'WEIGHTING_MODES', 'BlockMeshes', 'Integrated', 'TsdfParams',
           'TsdfVolume', 'block_meshes', 'surface_points', 'weld']
