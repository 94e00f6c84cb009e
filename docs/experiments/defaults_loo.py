"""Which matching cost carries to a camera it was not tuned on: every real pair with ground
truth this repository has, each clean and with a disagreeing right camera, scored by the
raw matcher's dense bad-2, and the setting chosen leave-one-out.

    .venv/bin/python docs/experiments/defaults_loo.py [--weights FILE.npz] [--paths 8]

The pairs: Middlebury 2003 Teddy and Cones (test/data, quarter size, 64 disparities) and
Middlebury 2014's motorcycle (scikit-image's data set, the ``train`` extra: 741x500, 80
disparities); each also with the right image 0.6 px lower (a rectification that is off),
JPEG at quality 60, and gamma 1.5 with gain 1.1. The settings: census (the shipped
default, P1 18, P2 220) and with its penalties scaled, and census+learned at several
``learned_weight``s and penalty scales (the learned term adds to the cost, so the same
penalties weigh less against it). A scene is one pair with its
three variants; leaving a scene out, the setting with the lowest geometric mean of
(bad-2 / census's bad-2) over the other scenes' variants is chosen and scored on the scene
left out. Prints the table of ratios, the leave-one-out rows and the choice on all scenes.
Half a minute on two cores.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from depth_nodes.core.groundtruth import read_disparity_file
from depth_nodes.core.metrics import disparity_errors
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.tools.train.photos import photo_folder

REPO = Path(__file__).resolve().parents[2]
WEIGHTS = (8, 12, 20)
#: P1 and P2 scaled from the shipped 18 and 220.
SCALES = (1.0, 1.25, 1.5, 2.0)
P1, P2 = 18, 220
VARIANTS = ('clean', 'vshift', 'jpeg', 'gamma')


def degrade(image: np.ndarray, kind: str) -> np.ndarray:
    """The right image as a disagreeing camera gives it."""
    if kind == 'clean':
        return image
    if kind == 'vshift':
        shift = np.float32([[1, 0, 0], [0, 1, 0.6]])
        return cv2.warpAffine(image, shift, image.shape[1::-1], borderMode=cv2.BORDER_REPLICATE)
    if kind == 'jpeg':
        return cv2.imdecode(cv2.imencode('.jpg', image, [cv2.IMWRITE_JPEG_QUALITY, 60])[1],
                            cv2.IMREAD_GRAYSCALE)
    return np.clip(255 * (image / 255.0) ** 1.5 * 1.1, 0, 255).astype(np.uint8)


def scenes() -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, int]]:
    """name -> (left, right, ground truth with NaN unknown, disparities searched)."""
    out = {}
    data = REPO / 'test' / 'data' / 'middlebury2003'
    for name in ('teddy', 'cones'):
        left = cv2.imread(str(data / name / 'im2.png'), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(data / name / 'im6.png'), cv2.IMREAD_GRAYSCALE)
        truth = read_disparity_file(data / name / 'disp2.pgm', scale=4.0)
        out[name] = (left, right, np.where(truth > 0, truth, np.nan).astype(np.float32), 64)
    folder = photo_folder()
    left = cv2.imread(str(folder / 'motorcycle_left.png'), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(folder / 'motorcycle_right.png'), cv2.IMREAD_GRAYSCALE)
    truth = np.load(folder / 'motorcycle_disp.npz')['arr_0'].astype(np.float32)
    out['motorcycle'] = (left, right, np.where(np.isfinite(truth) & (truth > 0), truth,
                                               np.nan).astype(np.float32), 80)
    return out


def bad2(params: SgmParams, left: np.ndarray, right: np.ndarray, truth: np.ndarray) -> float:
    """Dense bad-2 of the raw matcher over every pixel with ground truth."""
    disparity = SgmMatcher(params).match(left, right).disparity
    return float(disparity_errors(disparity, truth, n=2.0).bad_dense)


def geomean(values: list[float]) -> float:
    return float(np.exp(np.mean(np.log(values))))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--weights', default='', help='learned_weights (default: shipped)')
    parser.add_argument('--paths', type=int, default=8)
    args = parser.parse_args()
    settings = {'census': {'matching_cost': 'census'}}
    settings |= {f'census P x{k:g}': {'matching_cost': 'census', 'P1': round(P1 * k),
                                      'P2': round(P2 * k)} for k in SCALES[1:]}
    settings |= {f'census+learned w{w} P x{k:g}': {
        'matching_cost': 'census+learned', 'learned_weight': w, 'P1': round(P1 * k),
        'P2': round(P2 * k), 'learned_weights': args.weights}
        for w in WEIGHTS for k in SCALES}
    errors: dict[str, dict[tuple[str, str], float]] = {s: {} for s in settings}
    for scene, (left, right, truth, n) in scenes().items():
        for kind in VARIANTS:
            other = degrade(right, kind)
            for name, extra in settings.items():
                params = SgmParams(disparity_range=n, paths=args.paths, **extra)
                errors[name][(scene, kind)] = bad2(params, left, other, truth)
    cases = list(errors['census'])
    ratio = {s: {c: errors[s][c] / errors['census'][c] for c in cases} for s in settings}
    print('raw dense bad-2 (census) and each setting / census')
    print('setting'.ljust(28) + ''.join(f'{s[:5]}/{k[:6]}'.rjust(14) for s, k in cases) +
          '   geo-mean')
    print('census bad-2'.ljust(28) + ''.join(f'{errors["census"][c]:14.4f}' for c in cases))
    for s in settings:
        print(s.ljust(28) + ''.join(f'{ratio[s][c]:14.3f}' for c in cases) +
              f'{geomean(list(ratio[s].values())):11.3f}')
    print('\nleave one scene out: the setting chosen on the others, scored on it')
    names = sorted({scene for scene, _ in cases})
    for held in names:
        rest = [c for c in cases if c[0] != held]
        chosen = min(settings, key=lambda s: geomean([ratio[s][c] for c in rest]))
        own = [c for c in cases if c[0] == held]
        print(f'{held:12s} chosen: {chosen:28s} ' +
              ' '.join(f'{k}: {ratio[chosen][(held, k)]:.3f}' for _, k in own) +
              f'   geo-mean {geomean([ratio[chosen][c] for c in own]):.3f}')
    best = min(settings, key=lambda s: geomean(list(ratio[s].values())))
    print(f'\nchosen on every scene: {best} (geo-mean {geomean(list(ratio[best].values())):.3f})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
