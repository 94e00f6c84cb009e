#!/usr/bin/env bash
# The multi-view figures of docs/multiview.md, from the package's own commands:
#   docs/experiments/multiview_figures.sh OUT_DIR [GROUP ...]
# Groups: motions, delay, paths, rig, noise, filters, costs, temple (default: all). Each run is
# generate -> process (config/multiview_pipeline.yaml, or the rig's) -> eval; the eval
# reports land in OUT_DIR/*.txt. Deterministic (seeded); about an hour on two cores.
set -euo pipefail
OUT=${1:?usage: $0 OUT_DIR [GROUP ...]}
shift || true
WHICH=${*:-motions delay paths rig noise filters costs temple}
DN=${DN:-.venv/bin/depth-nodes}
mkdir -p "$OUT"

run() {  # run NAME PRESET FRAMES SIZE CONFIG [generate options] -- [parameter file lines]
  local name=$1 preset=$2 frames=$3 size=$4 config=$5; shift 5
  local gen=() params=()
  while [ $# -gt 0 ] && [ "$1" != -- ]; do gen+=("$1"); shift; done
  [ $# -gt 0 ] && shift
  params=("$@")
  local bag=$OUT/bags/${preset}_${size}_${frames}${gen[*]:+_$(echo "${gen[*]}" | tr ' ' '_')}
  [ -d "$bag" ] || $DN generate "$bag" --preset "$preset" --frames "$frames" --size "$size" \
    "${gen[@]}" > /dev/null
  local args=(--config "$config")
  if [ ${#params[@]} -gt 0 ]; then
    printf '/**:\n  ros__parameters:\n' > "$OUT/$name.yaml"
    for p in "${params[@]}"; do printf '    %s\n' "$p" >> "$OUT/$name.yaml"; done
    args+=(--params "$OUT/$name.yaml")
  fi
  $DN process "$bag" "$OUT/$name.out" "${args[@]}" --force > "$OUT/$name.process.txt"
  $DN eval "$OUT/$name.out" > "$OUT/$name.txt"
  tail -1 "$OUT/$name.txt"
}

for group in $WHICH; do
  case $group in
    motions)
      for size in 320x240 640x480; do
        planes=$([ $size = 320x240 ] && echo 64 || echo 128)
        for motion in sideways forward orbit; do
          run "$motion-$size" "mvs_$motion" 24 $size config/multiview_pipeline.yaml -- \
            "planes: $planes"
        done
      done ;;
    delay)
      for size in 320x240 640x480; do
        planes=$([ $size = 320x240 ] && echo 64 || echo 128)
        for delay in 2; do
          run "sideways-$size-delay$delay" mvs_sideways 24 $size config/multiview_pipeline.yaml \
            -- "planes: $planes" "delay: $delay"
        done
      done ;;
    paths)
      run sideways-640x480-paths5 mvs_sideways 24 640x480 config/multiview_pipeline.yaml -- \
        'planes: 128' 'paths: 5' 'label_sigma: 0.55' ;;
    rig)
      for size in 320x240 640x480; do
        planes=$([ $size = 320x240 ] && echo 64 || echo 128)
        run "rig-$size" mvs_rig 12 $size config/multiview_rig.yaml -- "planes: $planes"
        # the stereo graph on the same bag: its pair is the middle camera and the right one
        # (at 320x240 with 64 disparities, as many labels as the sweep's planes)
        stereo=(); [ $size = 320x240 ] && stereo=(--params config/disparity_64.yaml)
        $DN process "$OUT/rig-$size.out" "$OUT/rig-$size.both" "${stereo[@]}" --force > /dev/null
        $DN eval "$OUT/rig-$size.both" > "$OUT/rig-$size.txt"
        tail -8 "$OUT/rig-$size.txt"
      done ;;
    noise)
      # independent noise on every reported pose; "told": the node given its size
      # (pose_sigma_deg, pose_sigma_m) for the standard deviation
      for noise in "0.1 0.0025" "0.2 0.005" "0.4 0.01"; do
        run "noise-${noise// /_}" mvs_sideways 24 640x480 config/multiview_pipeline.yaml \
          --pose-noise $noise -- 'planes: 128'
      done
      for noise in "0.1 0.0025" "0.2 0.005"; do
        set -- $noise
        run "noise-${noise// /_}-told" mvs_sideways 24 640x480 config/multiview_pipeline.yaml \
          --pose-noise $noise -- 'planes: 128' "pose_sigma_deg: $1" "pose_sigma_m: $2"
      done ;;
    filters)
      # kalman, the default, is the motions group's sideways-640x480
      for filter in gauss_uniform none; do
        run "filter-$filter" mvs_sideways 24 640x480 config/multiview_pipeline.yaml -- \
          'planes: 128' "temporal_filter: $filter"
      done ;;
    costs)
      run cost-census mvs_sideways 24 640x480 config/multiview_pipeline.yaml -- \
        'planes: 128' 'intensity_weight: 0'
      run cost-zncc mvs_sideways 24 640x480 config/multiview_pipeline.yaml -- \
        'planes: 128' 'matching_cost: zncc' ;;
    temple)
      T=test/data/middlebury_mvs/templeSparseRing
      $DN import-views $T/templeSR_par.txt "$OUT/temple" --force \
        --bbox -0.073568 0.021728 -0.012445 0.028855 0.181892 0.062736 > /dev/null
      # delay 1: each view is swept against both ring neighbours; uniqueness 15: the
      # background is dark and textureless
      for cost in census zncc; do
        printf '/**:\n  ros__parameters: {min_depth: 0.45, max_depth: 0.8, planes: 128, delay: 1, uniqueness_ratio: 15.0, matching_cost: %s}\n' \
          $cost > "$OUT/temple-$cost.yaml"
        $DN process "$OUT/temple" "$OUT/temple-$cost.out" --config config/multiview_pipeline.yaml \
          --namespace /views --params "$OUT/temple-$cost.yaml" --force > /dev/null
        $DN eval "$OUT/temple-$cost.out" > "$OUT/temple-$cost.txt"
        tail -1 "$OUT/temple-$cost.txt"
      done ;;
    *) echo "unknown group $group" >&2; exit 2 ;;
  esac
done
