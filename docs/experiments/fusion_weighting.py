"""The weighting table of docs/fusion.md: the stereo graph's depth of a processed
stereo_orbit bag fused by the core volume with each weighting mode, and by Open3D's
VoxelBlockGrid, all at the same voxel size, truncation and depth range, each mesh scored
against the simulator's exact surface as `depth-nodes eval` scores a fused bag.

    python docs/experiments/fusion_weighting.py OUT_BAG [--voxel 0.05] [--max-depth 8]

OUT_BAG: `depth-nodes generate BAG --preset stereo_orbit`, then `depth-nodes process BAG
OUT_BAG` (the stereo graph). The modes:
* constant, inverse_square (1 / Z^2);
* sigma: 1 / sigma^2 with the depth's sigma from stereo's model, sigma_Z = Z^2 sigma_d /
  (f B), sigma_d 0.1 px (what point_cloud's depth_std gives; no per-pixel evidence);
* confidence: cross_check's confidence image (per pixel).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from depth_nodes.core.fusion import TsdfParams, TsdfVolume
from depth_nodes.core.fusion.mesh import block_meshes, weld
from depth_nodes.core.geometry import intrinsics
from depth_nodes.core.stamps import stamp_ns
from depth_nodes.ros.image import image_to_array
from depth_nodes.sim.depth_sequence import pose_at, scene_at, stamp_at
from depth_nodes.tools.bags import fusion_stereo
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.evaluation.fusion import (
    MeshScore,
    _frames,
    _samples,
    fuse_with_open3d,
    score_mesh,
    sequence_of,
)

DISPARITY_SIGMA = 0.1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bag')
    parser.add_argument('--voxel', type=float, default=0.05)
    parser.add_argument('--max-depth', type=float, default=8.0)
    args = parser.parse_args()
    with BagReader(args.bag) as reader:
        custom = dict(reader.custom_data)
    config, prefix = sequence_of(custom, args.bag)
    baseline = fusion_stereo.config_from_metadata(custom, args.bag).sequence.baseline_m
    frames, _ = _frames(args.bag, config, prefix, '/stereo/depth')
    index = {stamp_at(config, i): i for i in range(config.n_frames)}
    confidence = {}
    with BagReader(args.bag) as reader:
        for message in reader.messages(['/stereo/confidence']):
            image = message.deserialize()
            confidence[index[stamp_ns(image.header)]] = image_to_array(image).astype(
                np.float32)
    samples = _samples(frames, config, args.max_depth)
    scene = scene_at(config, config.n_frames - 1)
    camera = intrinsics(frames.camera)

    def sigma(i: int) -> np.ndarray:
        z = frames.depth[i]
        return (z * z * DISPARITY_SIGMA / (camera.fx * baseline)).astype(np.float32)

    modes = [('constant', None), ('inverse_square', None), ('sigma', sigma),
             ('confidence', confidence.__getitem__)]
    print(f'{args.bag}: {len(frames.depth)} frames, voxel {args.voxel * 100:g} cm, '
          f'truncation 4 voxels, depths to {args.max_depth:g} m')
    print(f'{"weighting":28s} {"median mm":>10s} {"p90 mm":>8s} {"complete":>9s} '
          f'{"vertices":>9s}')
    for mode, noise in modes:
        volume = TsdfVolume(TsdfParams(voxel_size=args.voxel, weighting_mode=mode,
                                       max_integration_distance=args.max_depth))
        for i in sorted(frames.depth):
            volume.integrate(frames.depth[i], camera, pose_at(config, i),
                             noise=None if noise is None else noise(i))
        vertices, faces = weld(block_meshes(volume, volume.slots()).vertices)
        _print(score_mesh(mode, vertices, len(faces), scene, samples, args.voxel))
    vertices, faces, _ = fuse_with_open3d(
        [(frames.depth[i], pose_at(config, i)) for i in sorted(frames.depth)], camera,
        voxel=args.voxel, truncation_voxels=4.0, max_depth=args.max_depth)
    _print(score_mesh('Open3D VoxelBlockGrid', vertices, len(faces), scene, samples,
                      args.voxel))
    return 0


def _print(s: MeshScore) -> None:
    print(f'{s.label:28s} {s.median * 1000:10.1f} {s.p90 * 1000:8.1f} {s.completeness:9.2%} '
          f'{s.vertices:9d}')


if __name__ == '__main__':
    sys.exit(main())
