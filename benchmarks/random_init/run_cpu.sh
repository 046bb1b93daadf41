#!/usr/bin/env bash
# Random start vs triangulated points on a synthetic ground-and-background scene (issue 56), CPU-sized:
#   bash benchmarks/random_init/run_cpu.sh SCENE_PRESET OUT_DIR [extra overrides...]
# Three runs of unbounded_3k.yaml: triangulated points (model.init=auto), a random start as it was
# (model.init=random; 20,000 random points, not 3DGS's 100,000, to fit a CPU), and a random start whose cameras are bounded by the renders' agreed surfaces from
# iteration 300 (model.surface_points_iter=300). Then summarise.py OUT_DIR writes OUT_DIR/summary.json.
set -euo pipefail
preset=${1:?scene preset, e.g. background_full}; out=${2:?output folder}; shift 2
here=$(cd "$(dirname "$0")" && pwd)
[ -f "$out/scene/transforms_train.json" ] || python -m gof_warp.synthetic --preset "$preset" --out "$out/scene"
for run in auto random surface; do
  case $run in
    auto) extra=(model.init=auto) ;;
    random) extra=(model.init=random model.random_init_points=20000) ;;
    surface) extra=(model.init=random model.random_init_points=20000 model.surface_points_iter=300) ;;
  esac
  python -m gof_warp.train "$out/scene" --config "$here/unbounded_3k.yaml" --out "$out/$run" --overwrite \
    --no-pictures --quiet "${extra[@]}" "$@"
done
python "$here/summarise.py" "$out"
