#!/usr/bin/env bash
# The figures of docs/fusion.md, from the package's own commands:
#   docs/experiments/fusion_figures.sh OUT_DIR [GROUP ...]
# Groups: accuracy, weighting, sequences, temple, bench (default: all). Deterministic
# (seeded) except the times; about 15 minutes on two cores.
set -euo pipefail
OUT=${1:?usage: $0 OUT_DIR [GROUP ...]}
shift || true
WHICH=${*:-accuracy weighting sequences temple bench}
DN=${DN:-.venv/bin/depth-nodes}
PY=${PY:-.venv/bin/python}
mkdir -p "$OUT"

uncommented() {  # the graph file with its commented tsdf_fusion line made live
  sed -E 's/^([[:space:]]*)# (- \{name: tsdf_fusion)/\1\2/' "$1"
}

for group in $WHICH; do
  case $group in
    accuracy)  # raw depth of the depth camera, 2 cm, beside Open3D on the same frames
      $DN generate "$OUT/depth_orbit" --preset depth_orbit --force > /dev/null
      $DN process "$OUT/depth_orbit" "$OUT/depth_orbit.raw" \
        --config docs/experiments/fusion_raw.yaml --force > /dev/null
      $DN eval "$OUT/depth_orbit.raw" --open3d | tee "$OUT/accuracy.txt"
      # with voxblox's clearing rays (the free space before depths past 5 m cleared)
      printf 'tsdf_fusion:\n  ros__parameters: {allow_clear: true}\n' > "$OUT/clear.yaml"
      $DN process "$OUT/depth_orbit" "$OUT/depth_orbit.raw_clear" --force \
        --config docs/experiments/fusion_raw.yaml --params "$OUT/clear.yaml" > /dev/null
      $DN eval "$OUT/depth_orbit.raw_clear" | tee "$OUT/accuracy_clear.txt"
      # the shipped pipeline (depth_filter -> tsdf_fusion), Open3D fed the filtered depth,
      # and the filtered depth weighted by its sigma
      $DN process "$OUT/depth_orbit" "$OUT/depth_orbit.pipeline" \
        --config config/fusion_pipeline.yaml --force > /dev/null
      $DN eval "$OUT/depth_orbit.pipeline" --open3d | tee "$OUT/accuracy_pipeline.txt"
      printf 'tsdf_fusion:\n  ros__parameters: {weighting_mode: sigma}\n' > "$OUT/sigma.yaml"
      $DN process "$OUT/depth_orbit" "$OUT/depth_orbit.pipeline_sigma" --force \
        --config config/fusion_pipeline.yaml --params "$OUT/sigma.yaml" > /dev/null
      $DN eval "$OUT/depth_orbit.pipeline_sigma" | tee "$OUT/accuracy_pipeline_sigma.txt"
      ;;
    weighting)  # the stereo graph's depth, 5 cm, each weighting and Open3D
      $DN generate "$OUT/stereo_orbit" --preset stereo_orbit --force > /dev/null
      $DN process "$OUT/stereo_orbit" "$OUT/stereo_orbit.out" --force > /dev/null
      $PY docs/experiments/fusion_weighting.py "$OUT/stereo_orbit.out" | tee "$OUT/weighting.txt"
      ;;
    sequences)  # a box that leaves, a still scene over 300 frames, memory_mb
      $PY docs/experiments/fusion_sequences.py | tee "$OUT/sequences.txt"
      ;;
    temple)  # real views: the multi-view graph, then fusion
      T=test/data/middlebury_mvs/templeSparseRing
      $DN import-views $T/templeSR_par.txt "$OUT/temple" --force \
        --bbox -0.073568 0.021728 -0.012445 0.028855 0.181892 0.062736 > /dev/null
      uncommented config/multiview_pipeline.yaml > "$OUT/temple_graph.yaml"
      for weight in 0.0001 30.0; do
        cat > "$OUT/temple-$weight.yaml" <<YAML
multiview_stereo:
  ros__parameters: {min_depth: 0.45, max_depth: 0.8, planes: 128, delay: 1, uniqueness_ratio: 15.0}
tsdf_fusion:
  ros__parameters: {voxel_size: 0.002, min_integration_distance: 0.3, max_integration_distance: 0.8, min_weight: $weight, esdf_rate_hz: 0.0}
YAML
        $DN process "$OUT/temple" "$OUT/temple-$weight.out" --config "$OUT/temple_graph.yaml" \
          --namespace /views --params "$OUT/temple-$weight.yaml" --force > /dev/null
        $DN eval "$OUT/temple-$weight.out" | tee "$OUT/temple-$weight.txt"
        $DN export-mesh "$OUT/temple-$weight.out" "$OUT/temple-$weight.ply" --force --preview-up=-y \
          --preview "$OUT/temple-$weight.png"
      done
      ;;
    bench)
      $DN bench fusion | tee "$OUT/bench.txt"
      $DN bench fusion --busy 1 | tee "$OUT/bench_busy.txt"
      ;;
    *) echo "unknown group $group" >&2; exit 2 ;;
  esac
done
