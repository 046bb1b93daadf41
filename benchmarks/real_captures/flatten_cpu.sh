#!/usr/bin/env bash
# Does a flattening term (loss.lambda_flatten) thin the far shell's layer? A 2-core CPU version of the synthetic
# `background` scene (128x128, 60 train / 8 test views) trained with the `unbounded` preset's settings on GOF's
# schedule compressed 7.5x (flatten_cpu.yaml), once per weight, then meshed (the defaults) and scored: the
# ground-and-objects crop and the whole seen region (sampling inside each region, the floor beside each score),
# and the field along radial lines through the shell (shell_profile.py).
#   bash benchmarks/real_captures/flatten_cpu.sh OUTDIR [LAMBDA ...]      (default weights: 0 100)
set -eu
out=${1:?output folder}; shift
weights=${*:-0 100}
here=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$out"
[ -f "$out/scene/scene.json" ] || python -m gof_warp.synthetic --preset background --resolution 128 128 --views 60 \
    --out "$out/scene" --device cpu --quiet
for lam in $weights; do
  run=$out/flat$lam
  [ -f "$run/metrics.json" ] || python -m gof_warp.train "$out/scene" --out "$run" --config "$here/flatten_cpu.yaml" \
      --device cpu --quiet "loss.lambda_flatten=$lam"
  [ -f "$run/mesh_tetra.ply" ] || python -m gof_warp.extract "$run" --device cpu --quiet
  [ -f "$run/evaluate_seen.json" ] || python -m gof_warp.evaluate --mesh "$run/mesh_tetra.ply" \
      --gt "$out/scene/gt_mesh.ply" --scene "$out/scene" --json "$run/evaluate_seen.json" > /dev/null
  [ -f "$run/evaluate_crop.json" ] || python -m gof_warp.evaluate --mesh "$run/mesh_tetra.ply" \
      --gt "$out/scene/gt_mesh.ply" --scene "$out/scene" --crop -2 -2 -1.1 2 2 1.0 --json "$run/evaluate_crop.json" > /dev/null
  [ -f "$run/shell_profile.json" ] || python "$here/shell_profile.py" "$run/point_cloud.ply" "$out/scene" --radius 6 \
      --rays 300 --out "$run/shell_profile.json" > /dev/null
done
