"""The dynamic-scene and memory figures of docs/fusion.md, from the simulator's depth
sequences fused by the core volume with the node's defaults (2 cm voxels here):

    python docs/experiments/fusion_sequences.py [leaves] [still] [long]

* leaves: depth_object_leaves (a box in front of the still camera for the first half of
  the frames, then gone; its background past max_integration_distance, so allow_clear):
  per frame after it leaves, the mesh vertices within 2 voxels of the box's surface and
  farther than that from the scene left, beside a volume that never saw the box, and the
  frames until they are down to its floor.
* still: depth_static repeated for 300 frames (its noise and holes drawn anew each frame):
  the mesh's accuracy and completeness after 10, 30 and 300 frames, with the default
  truncation and with one above the far depths' noise.
* long: depth_long (300 frames through a 9 - 10 m room) with memory_mb 8: the volume's
  largest memory against the limit, blocks dropped, and the process's peak RSS.
"""

from __future__ import annotations

import dataclasses
import itertools
import resource
import sys

import numpy as np

from depth_nodes.core.fusion import TsdfParams, TsdfVolume
from depth_nodes.core.fusion.mesh import block_meshes, weld
from depth_nodes.sim.depth_sequence import scene_at, simulate_depth_sequence
from depth_nodes.tools.bags.depth_filter import PRESETS
from depth_nodes.tools.evaluation.fusion import nearest_distance

VOXEL = 0.02


def _mesh(volume: TsdfVolume) -> np.ndarray:
    vertices, _ = weld(block_meshes(volume, volume.slots()).vertices)
    return vertices.astype(np.float64)


def leaves() -> None:
    config = PRESETS['depth_object_leaves']
    gone = config.n_frames // 2
    box = scene_at(config, gone - 1).primitives[-1]  # the leaving box, while it is there
    after = scene_at(config, gone)
    # the background lies past max_integration_distance (5 m): it clears only with
    # allow_clear
    settings = TsdfParams(voxel_size=VOXEL, allow_clear=True)
    volume = TsdfVolume(settings)
    # the floor: a volume that sees only the frames after the box left (noise and mixed
    # pixels there make vertices off the scene too)
    never = TsdfVolume(settings)
    print(f'depth_object_leaves: {config.n_frames} frames {config.width}x{config.height}, '
          f'the box gone from frame {gone}; voxel {VOXEL * 100:g} cm, allow_clear; vertices '
          "within 2 voxels of the box's surface and farther than that from the scene left, "
          'beside a volume that never saw the box')

    def stray(v: TsdfVolume) -> int:
        vertices = _mesh(v)
        return int(((box.distance(vertices) <= 2 * VOXEL) &
                    (after.distance(vertices) > 2 * VOXEL)).sum())

    cleared = None
    for i, frame in enumerate(simulate_depth_sequence(config)):
        volume.integrate(frame.depth, frame.camera, frame.pose)
        if i < gone - 1:
            continue
        if i >= gone:
            never.integrate(frame.depth, frame.camera, frame.pose)
        ours, floor = stray(volume), stray(never) if i >= gone else 0
        print(f'  frame {i:2d} ({i - gone + 1:+d} after it left): {ours} vertices there '
              f'(never saw it: {floor})')
        if i >= gone and ours <= 1.02 * floor and cleared is None:
            cleared = i - gone + 1
    print(f'  the box left the mesh (within 2 % of the floor) {cleared} frame(s) after it '
          'left')


def still() -> None:
    config = dataclasses.replace(PRESETS['depth_static'], n_frames=300)
    scene = scene_at(config, 0)
    frames = simulate_depth_sequence(config)
    first = next(frames)
    c = first.camera
    ys, xs = np.mgrid[0:c.height, 0:c.width]
    rays = np.stack([(xs - c.cx) / c.fx, (ys - c.cy) / c.fy, np.ones(xs.shape)],
                    -1).reshape(-1, 3)
    z = first.truth.reshape(-1)
    seen = np.isfinite(z) & (z <= TsdfParams().max_integration_distance)
    truth = ((rays[seen] * z[seen, None]) @ first.pose.rotation.T + first.pose.position)[::16]
    # the default truncation (4 voxels, 8 cm) and one above the noise of the far depths
    # (0.12 m at 5 m: 0.1 px of disparity, f 256 px, B 0.08 m)
    volumes = {t: TsdfVolume(TsdfParams(voxel_size=VOXEL, truncation_distance=t))
               for t in (4.0, 8.0)}
    print(f'depth_static, 300 frames {c.width}x{c.height} (noise 0.1 px of disparity); '
          f'voxel {VOXEL * 100:g} cm')
    for i, frame in enumerate(itertools.chain([first], frames)):
        for truncation, volume in volumes.items():
            volume.integrate(frame.depth, frame.camera, frame.pose)
            if i + 1 in (10, 30, 300):
                vertices = _mesh(volume)
                error = scene.distance(vertices)
                near = nearest_distance(truth, vertices, 4 * VOXEL)
                print(f'  truncation {truncation:g} voxels, after {i + 1:3d} frames: '
                      f'{len(vertices)} vertices, median {np.median(error) * 1000:.1f} mm, '
                      f'completeness {(near <= 2 * VOXEL).mean():.2%}')


def long() -> None:
    config = PRESETS['depth_long']
    limit = 8.0
    volume = TsdfVolume(TsdfParams(voxel_size=VOXEL, memory_mb=limit,
                                   max_integration_distance=5.0))
    peak, evicted, refused = 0.0, 0, 0
    for frame in simulate_depth_sequence(config):
        result = volume.integrate(frame.depth, frame.camera, frame.pose)
        evicted += result.evicted
        refused += result.refused
        peak = max(peak, volume.memory_bytes / 2 ** 20)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f'depth_long: {config.n_frames} frames {config.width}x{config.height}, voxel '
          f'{VOXEL * 100:g} cm, memory_mb {limit:g}: the volume at most {peak:.3f} MB, '
          f'{len(volume.slots())} blocks at the end, {evicted} dropped for memory, {refused} '
          f'not allocated; peak RSS of the process {rss:.0f} MB')


if __name__ == '__main__':
    groups = {'leaves': leaves, 'still': still, 'long': long}
    for name in sys.argv[1:] or list(groups):
        groups[name]()
    sys.exit(0)
