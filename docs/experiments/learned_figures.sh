#!/usr/bin/env bash
# The figures of docs/learned.md, from the package's own commands:
#   docs/experiments/learned_figures.sh OUT_DIR
# For Teddy and Cones (test/data), Middlebury's motorcycle pair (scikit-image's data set,
# the train extra), the same three pairs with a disagreeing right camera (0.6 px lower,
# JPEG quality 60, gamma 1.5) and the three simulator bags: the shipped graph with census
# and the hand-made confidence, then with config/learned.yaml's settings (census+learned
# cost with doubled penalties, learned confidence), then with the learned confidence
# alone; `eval` reports land in OUT_DIR/*.txt. About 3 minutes on two cores.
set -euo pipefail
OUT=${1:?usage: $0 OUT_DIR}
DN=${DN:-.venv/bin/depth-nodes}
PY=${PY:-.venv/bin/python}
mkdir -p "$OUT/pairs"

# the real pairs as PNG files, and their degraded right images
$PY - "$OUT/pairs" <<'EOF'
import sys
from pathlib import Path

import cv2
import numpy as np

from depth_nodes.core.groundtruth import write_pfm
from depth_nodes.tools.train.photos import photo_folder

out = Path(sys.argv[1])
data = Path('test/data/middlebury2003')
pairs = {name: (cv2.imread(str(data / name / 'im2.png')), cv2.imread(str(data / name / 'im6.png')))
         for name in ('teddy', 'cones')}
sk = photo_folder()
pairs['motorcycle'] = (cv2.imread(str(sk / 'motorcycle_left.png')),
                       cv2.imread(str(sk / 'motorcycle_right.png')))
disp = np.load(sk / 'motorcycle_disp.npz')['arr_0']
write_pfm(out / 'motorcycle_gt.pfm', np.where(np.isfinite(disp), disp, np.inf))


def degrade(img: np.ndarray, kind: str) -> np.ndarray:
    if kind == 'vshift':
        shift = np.float32([[1, 0, 0], [0, 1, 0.6]])
        return cv2.warpAffine(img, shift, img.shape[1::-1], borderMode=cv2.BORDER_REPLICATE)
    if kind == 'jpeg':
        return cv2.imdecode(cv2.imencode('.jpg', img, [cv2.IMWRITE_JPEG_QUALITY, 60])[1], 1)
    return np.clip(255 * (img / 255.0) ** 1.5 * 1.1, 0, 255).astype(np.uint8)


for name, (left, right) in pairs.items():
    cv2.imwrite(str(out / f'{name}_left.png'), left)
    cv2.imwrite(str(out / f'{name}_right.png'), right)
    for kind in ('vshift', 'jpeg', 'gamma'):
        cv2.imwrite(str(out / f'{name}_right_{kind}.png'), degrade(right, kind))
EOF

params() {  # params NAME RANGE [sgm_stereo line] [cross_check line]
  local file=$OUT/$1.yaml
  printf '/stereo/sgm_stereo:\n  ros__parameters:\n    disparity_range: %s\n' "$2" > "$file"
  [ -n "${3:-}" ] && printf '    %s\n' "$3" >> "$file"
  printf '/stereo/cross_check:\n  ros__parameters:\n    queue_size: 5\n' >> "$file"
  [ -n "${4:-}" ] && printf '    %s\n' "$4" >> "$file"
  echo "$file"
}

score() {  # score BAG NAME RANGE
  local bag=$1 name=$2 range=$3
  for setting in census learned confidence; do
    case $setting in
      census) file=$(params "$name.$setting" "$range") ;;
      learned) file=$(params "$name.$setting" "$range" \
                             $'matching_cost: census+learned\n    P1: 36.0\n    P2: 440.0' \
                             'confidence_model: learned') ;;
      confidence) file=$(params "$name.$setting" "$range" '' 'confidence_model: learned') ;;
    esac
    $DN process "$bag" "$OUT/$name.$setting.out" --params "$file" --force > /dev/null
    $DN eval "$OUT/$name.$setting.out" --no-baseline > "$OUT/$name.$setting.txt"
  done
}

T=test/data/middlebury2003
for name in teddy cones motorcycle; do
  case $name in
    motorcycle) gt=(--gt "$OUT/pairs/motorcycle_gt.pfm"); range=80 ;;
    *) gt=(--gt "$T/$name/disp2.pgm" --gt-scale 4 --gt-right "$T/$name/disp6.pgm"); range=64 ;;
  esac
  for right in '' _vshift _jpeg _gamma; do
    bag=$OUT/bags/$name$right
    [ -d "$bag" ] || $DN import-pair "$OUT/pairs/${name}_left.png" \
      "$OUT/pairs/${name}_right$right.png" "$bag" "${gt[@]}" > /dev/null
    score "$bag" "$name$right" "$range"
  done
done
for bag in stereo_vga stereo_qvga_color stereo_qvga_fisheye; do
  case $bag in stereo_vga) range=128 ;; *) range=64 ;; esac
  score "bags/$bag" "$bag" "$range"
done
grep -H -E '^/stereo/disparity(_checked)? ' "$OUT"/*.txt
