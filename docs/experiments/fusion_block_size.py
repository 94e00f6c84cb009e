"""Blocks of 8^3 or 16^3 voxels: integration and the mesh update per 640x480 frame (the
frames and settings of `depth-nodes bench fusion`, two threads), and the voxels' memory,
at 5 and 2 cm; two rounds, to see the spread.

    python docs/experiments/fusion_block_size.py
"""

from __future__ import annotations

import time

import numpy as np

from depth_nodes.core.fusion import TsdfParams, TsdfVolume
from depth_nodes.core.fusion.layer import MeshLayer
from depth_nodes.tools.bench.fusion import MAX_DEPTH, TRUNCATION, _frames

camera, frames = _frames(640, 480, 10)
for round_ in range(2):
    for voxel in (0.05, 0.02):
        for block in (8, 16):
            volume = TsdfVolume(TsdfParams(voxel_size=voxel, block_size=block,
                                           truncation_distance=TRUNCATION,
                                           max_integration_distance=MAX_DEPTH,
                                           memory_mb=4096.0))
            layer = MeshLayer()
            integrate, mesh = [], []
            for depth, pose in frames:
                start = time.perf_counter()
                volume.integrate(depth, camera, pose)
                middle = time.perf_counter()
                layer.update(volume)
                integrate.append(middle - start)
                mesh.append(time.perf_counter() - middle)
            print(f'round {round_}, {voxel * 100:g} cm, blocks of {block}^3: integrate '
                  f'{1000 * np.median(integrate[1:]):.2f} ms, mesh '
                  f'{1000 * np.median(mesh[1:]):.2f} ms, memory '
                  f'{volume.memory_bytes / 2 ** 20:.1f} MB, {len(volume.slots())} blocks')
