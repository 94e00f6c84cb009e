"""The sheets of docs/tuning.md: what one stereo parameter does to the picture, on a real
pair with ground truth (Middlebury 2003 Teddy, test/data, quarter size), each value in a
column: the raw disparity, its error against the truth, the checked disparity
(cross_check as the shipped graph runs it) and its confidence; the parameter's other
settings are the shipped graph's. Also prints each value's dense bad-2 (raw) and the
checked output's density and bad-2.

    .venv/bin/python docs/experiments/tuning_sheets.py OUT_DIR
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from depth_nodes.core.cross_check import cross_check
from depth_nodes.core.groundtruth import read_disparity_file
from depth_nodes.core.metrics import disparity_errors
from depth_nodes.core.sgm import SgmMatcher
from depth_nodes.tools.evaluation.previews import MapView, sheet
from depth_nodes.tools.tune import _params, _shipped_settings

REPO = Path(__file__).resolve().parents[2]
#: parameter -> the values drawn (the shipped value among them)
SWEEPS = {
    'P2': (60, 220, 900),
    'uniqueness_ratio': (0.0, 10.0, 30.0),
    'disparity_range': (32, 64, 128),
    'matching_cost': ('census', 'census+learned'),
}


def main() -> int:
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    teddy = REPO / 'test' / 'data' / 'middlebury2003' / 'teddy'
    left = cv2.imread(str(teddy / 'im2.png'), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(teddy / 'im6.png'), cv2.IMREAD_GRAYSCALE)
    colour = cv2.imread(str(teddy / 'im2.png'))
    truth = read_disparity_file(teddy / 'disp2.pgm', scale=4.0)
    truth = np.where(truth > 0, truth, np.nan).astype(np.float32)
    shipped = {**_shipped_settings(), 'disparity_range': 64}
    top = float(np.nanmax(truth))
    for name, values in SWEEPS.items():
        views = []
        for value in values:
            label = f'{name} {value}'
            result = SgmMatcher(_params({**shipped, name: value})).match(left, right)
            checked = cross_check(result.disparity, result.disparity_right, result.cost_ratio,
                                  disp12_max_diff=1.0, fill=True, median_size=5)
            raw = disparity_errors(result.disparity, truth, n=2.0)
            dense = disparity_errors(checked.disparity, truth, n=2.0)
            print(f'{label:28s} raw bad-2 {raw.bad_dense:6.2%}  checked: density '
                  f'{np.isfinite(checked.disparity).mean():6.1%}, bad-2 '
                  f'{dense.bad_dense:6.2%}')
            views += [MapView(label, result.disparity, 0.0, top, kind='disparity'),
                      MapView(label, np.abs(result.disparity - truth), 0.0, 4.0,
                              cv2.COLORMAP_INFERNO, kind='error', missing=(160, 160, 160)),
                      MapView(label, checked.disparity, 0.0, top, kind='checked'),
                      MapView(label, checked.confidence, 0.0, 1.0, cv2.COLORMAP_VIRIDIS,
                              unit='', kind='confidence')]
        path = out / f'tuning_{name}.jpg'
        drawn = sheet(colour, views)
        cv2.imwrite(str(path), cv2.resize(drawn, None, fx=0.5, fy=0.5,
                                          interpolation=cv2.INTER_AREA),
                    [cv2.IMWRITE_JPEG_QUALITY, 85])
        print(f'  {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
