#!/usr/bin/env bash
# Random start vs triangulated points on a synthetic ground-and-background scene (issue 56), CPU-sized:
#   bash benchmarks/random_init/run_cpu.sh SCENE_PRESET OUT_DIR [RUN ...]      RUN: auto | random | random_box
# unbounded_3k.yaml (the unbounded preset on GOF's schedule compressed to 3,000 iterations) from: points triangulated
# from the known poses (auto); 20,000 random points as the preset draws them (random: half beyond the box, out to the
# far background, all where two training cameras see them, and Gaussians fewer than two see pruned); the box-only
# start as 3DGS draws it (random_box: model.random_far_fraction=0 model.random_min_views=0).
# Then: python benchmarks/random_init/summarise.py OUT_DIR RUN ...
set -euo pipefail
preset=${1:?scene preset, e.g. background_full}; out=${2:?output folder}; shift 2
runs=("$@"); [ ${#runs[@]} -gt 0 ] || runs=(auto random random_box)
here=$(cd "$(dirname "$0")" && pwd)
[ -f "$out/scene/transforms_train.json" ] || python -m gof_warp.synthetic --preset "$preset" --out "$out/scene"
for run in "${runs[@]}"; do
  case $run in
    auto) extra=(model.init=auto) ;;
    random) extra=(model.init=random model.random_init_points=20000) ;;
    random_box) extra=(model.init=random model.random_init_points=20000 model.random_far_fraction=0
                       model.random_min_views=0) ;;
    *) echo "unknown run $run" >&2; exit 2 ;;
  esac
  python -m gof_warp.train "$out/scene" --config "$here/unbounded_3k.yaml" --out "$out/$run" --overwrite \
    --no-pictures --quiet "${extra[@]}"
done
python "$here/summarise.py" "$out" "${runs[@]}"
