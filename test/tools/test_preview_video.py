"""`depth-nodes preview BAG OUT.mp4`: every frame's sheet in a video OpenCV reads back, of
the first sheet's size; mistakes are one-line errors."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import pytest
from helpers import REPO, run_cli

from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.evaluation.previews import bag_sheets

BAG = REPO / 'bags' / 'stereo_qvga_color'

pytestmark = pytest.mark.slow


def _frames(path: Path) -> list[Any]:
    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            return frames
        frames.append(frame)


@pytest.mark.parametrize('suffix', ['.mp4', '.avi'])
def test_every_frame_s_sheet_is_in_the_video(tmp_path: Path, suffix: str) -> None:
    out = tmp_path / f'bag{suffix}'
    done = run_cli(['preview', str(BAG), str(out), '--fps', '5'])
    assert done.returncode == 0, done.stderr
    with BagReader(BAG) as reader:
        stamps = {m.timestamp for m in reader.messages(['/stereo/left/disparity_gt'])}
    sheets = list(bag_sheets(BAG))
    assert len(sheets) == len(stamps) >= 2
    first = sheets[0][1]
    frames = _frames(out)
    assert len(frames) == len(stamps)
    assert frames[0].shape[:2] == (first.shape[0] + first.shape[0] % 2,
                                   first.shape[1] + first.shape[1] % 2)
    # the picture is the sheet's, up to the codec's loss
    h, w = first.shape[:2]
    assert abs(frames[0][:h, :w].astype(int) - first.astype(int)).mean() < 12
    assert f'{out}: {len(stamps)} frames' in done.stdout


def test_mistakes_are_one_line(tmp_path: Path) -> None:
    done = run_cli(['preview', str(BAG), str(tmp_path / 'v.mkv')])
    assert done.returncode == 1
    assert done.stderr == (f'depth-nodes preview: error: {tmp_path / "v.mkv"}: name it .mp4 '
                           'or .avi\n')
    (tmp_path / 'v.mp4').write_bytes(b'')
    done = run_cli(['preview', str(BAG), str(tmp_path / 'v.mp4')])
    assert done.stderr == (f'depth-nodes preview: error: {tmp_path / "v.mp4"} exists '
                           '(--force replaces it)\n')
    done = run_cli(['preview', str(REPO / 'bags' / 'nope'), str(tmp_path / 'w.mp4')])
    assert done.returncode == 1
    assert done.stderr.count('\n') == 1
