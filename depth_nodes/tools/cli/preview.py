"""`depth-nodes preview BAG OUT.mp4`: a processed bag as a video for sharing, one frame per
stamp, each the sheet `eval --previews` draws (the left image and every disparity, error,
depth and confidence map side by side; :mod:`depth_nodes.tools.evaluation.previews`),
written with OpenCV's VideoWriter."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from depth_nodes.errors import ArgumentError, BagError
from depth_nodes.tools import signals
from depth_nodes.tools.evaluation.previews import bag_sheets

#: FourCC of each container OpenCV's wheels write.
CODECS = {'.mp4': 'mp4v', '.avi': 'MJPG'}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', help='a bag with disparity, depth or confidence topics (e.g. '
                        'depth-nodes process BAG OUT)')
    parser.add_argument('out', help='the video to write: .mp4 (MPEG-4) or .avi (Motion JPEG)')
    parser.add_argument('--fps', type=float, default=10.0,
                        help='frames a second of the video (default 10)')
    parser.add_argument('--frames', type=int, metavar='N',
                        help='the first N frames only (default: all)')
    parser.add_argument('--force', action='store_true', help='replace an existing OUT')


def run(args: argparse.Namespace) -> int:
    """Draw every frame's sheet into the video; say what was written."""
    out = Path(args.out)
    codec = CODECS.get(out.suffix.lower())
    if codec is None:
        raise ArgumentError(f'{out}: name it .mp4 or .avi')
    if out.exists() and not args.force:
        raise ArgumentError(f'{out} exists (--force replaces it)')
    if not out.parent.is_dir():
        raise ArgumentError(f'{out.parent} is not a folder')
    if not args.fps > 0:
        raise ArgumentError(f'--fps must be positive, got {args.fps}')
    if args.frames is not None and args.frames < 1:
        raise ArgumentError(f'--frames must be at least 1, got {args.frames}')
    writer = None
    size = (0, 0)
    count = 0
    with signals.graceful():
        try:
            for _, sheet in bag_sheets(args.bag, max_frames=args.frames):
                if writer is None:
                    size = (sheet.shape[1] + sheet.shape[1] % 2,
                            sheet.shape[0] + sheet.shape[0] % 2)  # even, for MPEG-4
                    fourcc = cv2.VideoWriter.fourcc(*codec)
                    writer = cv2.VideoWriter(str(out), fourcc, args.fps, size)
                    if not writer.isOpened():
                        raise ArgumentError(f'cannot write {out}: OpenCV has no {codec} '
                                            'encoder here')
                writer.write(_fitted(sheet, size))
                count += 1
                if signals.stop_requested():
                    break
        finally:
            if writer is not None:
                writer.release()
    if not count:
        raise BagError(f'{args.bag}: no frame had a map to draw; {out} was not written')
    print(f'{out}: {count} frames, {size[0]}x{size[1]}, {args.fps:g} fps')
    if signals.stop_requested():
        print(f'depth-nodes preview: interrupted; {out} holds the {count} frames drawn before '
              'the signal', file=sys.stderr)
    return 0


def _fitted(sheet: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The sheet on a white canvas of the video's size (a frame with fewer maps is
    smaller; one with more is cut)."""
    width, height = size
    canvas = np.full((height, width, 3), 255, np.uint8)
    h, w = min(height, sheet.shape[0]), min(width, sheet.shape[1])
    canvas[:h, :w] = sheet[:h, :w]
    return canvas
