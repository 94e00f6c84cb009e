"""`depth-nodes export-mesh`: the final mesh of a processed bag (tsdf_fusion's ``mesh``
topic, or any MarkerArray of triangle lists) as a binary PLY file."""

from __future__ import annotations

import argparse
from pathlib import Path

from depth_nodes.core.fusion.ply import write_ply
from depth_nodes.errors import ArgumentError
from depth_nodes.tools.bags.meshes import final_mesh


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `export-mesh`."""
    parser.add_argument('bag', help='a bag processed with tsdf_fusion in its graph (e.g. '
                        'depth-nodes process BAG OUT --config config/fusion_pipeline.yaml)')
    parser.add_argument('out', help='the PLY file to write (binary: vertices, faces, colour '
                        'when the markers have it)')
    parser.add_argument('--topic', help='the MarkerArray topic (default: the bag\'s only one)')
    parser.add_argument('--force', action='store_true', help='replace an existing file')


def run(args: argparse.Namespace) -> int:
    """Replay the mesh topic to its end; write the mesh; say what was written."""
    out = Path(args.out)
    if out.exists() and not args.force:
        raise ArgumentError(f'{out} exists (--force replaces it)')
    if not out.parent.is_dir():
        raise ArgumentError(f'{out.parent} is not a folder')
    mesh = final_mesh(args.bag, args.topic)
    try:
        write_ply(out, mesh.vertices, mesh.faces, mesh.colors)
    except OSError as exc:
        raise ArgumentError(f'cannot write {out}: {exc.strerror or exc}') from None
    print(f'{out}: {len(mesh.vertices)} vertices, {len(mesh.faces)} triangles'
          f'{", coloured" if mesh.colors is not None else ""} ({mesh.topic}: '
          f'{mesh.markers} blocks after {mesh.messages} messages)')
    return 0
