"""`depth-nodes export-mesh`: the final mesh of a processed bag (tsdf_fusion's ``mesh``
topic, or any MarkerArray of triangle lists) as a binary PLY file, and with ``--preview``
a picture of it (:func:`~depth_nodes.tools.evaluation.mesh_preview.render_mesh`)."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2

from depth_nodes.core.fusion.ply import write_ply
from depth_nodes.errors import ArgumentError
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bags.meshes import final_mesh
from depth_nodes.tools.evaluation.mesh_preview import render_mesh

#: ``--preview-up`` names of the world's up direction.
AXES = {'x': (1.0, 0.0, 0.0), '-x': (-1.0, 0.0, 0.0), 'y': (0.0, 1.0, 0.0),
        '-y': (0.0, -1.0, 0.0), 'z': (0.0, 0.0, 1.0), '-z': (0.0, 0.0, -1.0)}
#: Custom-data keys of the bags the simulator writes: its world is y down.
SIMULATOR_KEY = 'depth_nodes.sim.'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `export-mesh`."""
    parser.add_argument('bag', help='a bag processed with tsdf_fusion in its graph (e.g. '
                        'depth-nodes process BAG OUT --config config/fusion_pipeline.yaml)')
    parser.add_argument('out', help='the PLY file to write (binary: vertices, faces, colour '
                        'when the markers have it)')
    parser.add_argument('--topic', help='the MarkerArray topic (default: the bag\'s only one)')
    parser.add_argument('--preview', metavar='PNG', help='also draw the mesh into this image '
                        '(960 x 720, shaded, seen from above at three quarters)')
    parser.add_argument('--preview-up', choices=sorted(AXES), help='the world axis pointing '
                        'up in the preview (default: -y for a bag the simulator wrote, whose '
                        'world is y down; z, as REP 103 has it, for any other)')
    parser.add_argument('--force', action='store_true', help='replace existing files')


def run(args: argparse.Namespace) -> int:
    """Replay the mesh topic to its end; write the mesh (and its picture); say what was
    written."""
    out = Path(args.out)
    preview = Path(args.preview) if args.preview else None
    for path in (out, preview):
        if path is None:
            continue
        if path.is_dir():
            raise ArgumentError(f'{path} is a folder')
        if path.exists() and not args.force:
            raise ArgumentError(f'{path} exists (--force replaces it)')
        if not path.parent.is_dir():
            raise ArgumentError(f'{path.parent} is not a folder')
    if preview is not None and not cv2.haveImageWriter(str(preview)):
        raise ArgumentError(f'--preview {preview}: OpenCV writes no such image (name it '
                            '.png)')
    mesh = final_mesh(args.bag, args.topic)
    try:
        write_ply(out, mesh.vertices, mesh.faces, mesh.colors)
    except OSError as exc:
        raise ArgumentError(f'cannot write {out}: {exc.strerror or exc}') from None
    print(f'{out}: {len(mesh.vertices)} vertices, {len(mesh.faces)} triangles'
          f'{", coloured" if mesh.colors is not None else ""} ({mesh.topic}: '
          f'{mesh.markers} blocks after {mesh.messages} messages)')
    if preview is not None:
        up = args.preview_up or _world_up(args.bag)
        image = render_mesh(mesh.vertices, mesh.faces, colors=mesh.colors, up=AXES[up])
        try:
            written = cv2.imwrite(str(preview), image[:, :, ::-1])
        except cv2.error:
            written = False
        if not written:
            raise ArgumentError(f'cannot write {preview}')
        print(f'{preview}: preview {image.shape[1]}x{image.shape[0]}, up {up}')
    return 0


def _world_up(bag: str) -> str:
    """-y for a bag the simulator wrote, else z."""
    with BagReader(bag) as reader:
        simulated = any(key.startswith(SIMULATOR_KEY) for key in reader.custom_data)
    return '-y' if simulated else 'z'
