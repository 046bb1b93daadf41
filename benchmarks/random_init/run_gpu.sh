#!/usr/bin/env bash
# Random start vs triangulated points at full length (the `unbounded` preset, 30k iterations) on one GPU (issue 56):
#   bash benchmarks/random_init/run_gpu.sh SCENE OUT_DIR [RUN ...]      RUN: auto | random | random_box
# auto: points triangulated from the known poses (needs pycolmap, or the scene's sfm_known_poses/ cache);
# random: 100,000 random points as the preset draws them (half beyond the box, out to the far background, where two
# training cameras see them); random_box: 3DGS's box start (model.random_far_fraction=0 model.random_min_views=0).
# The runs train side by side (their times are not single-run times). A run with checkpoints in OUT_DIR/RUN resumes.
# Then: python benchmarks/random_init/summarise.py OUT_DIR RUN ...
set -uo pipefail
scene=${1:?scene folder}; out=${2:?output folder}; shift 2
runs=("$@"); [ ${#runs[@]} -gt 0 ] || runs=(auto random random_box)
mkdir -p "$out"
pids=()
for run in "${runs[@]}"; do
  case $run in
    auto) extra=(model.init=auto) ;;
    random) extra=(model.init=random) ;;
    random_box) extra=(model.init=random model.random_far_fraction=0 model.random_min_views=0) ;;
    *) echo "unknown run $run" >&2; exit 2 ;;
  esac
  resume=(--overwrite)
  ls "$out/$run"/checkpoints/ckpt_*.pt >/dev/null 2>&1 && [ ! -f "$out/$run/metrics.json" ] && resume=(--resume)
  [ -f "$out/$run/metrics.json" ] && continue
  "${PYTHON:-python}" -m gof_warp.train "$scene" --config unbounded --out "$out/$run" "${resume[@]}" --no-pictures \
    checkpoint_every=2500 "${extra[@]}" >> "$out/$run.log" 2>&1 &
  pids+=($!)
done
# a time limit's SIGTERM reaches the trainings, which checkpoint and stop (run again to resume)
trap 'kill -TERM "${pids[@]}" 2>/dev/null' TERM
rc=0
for p in "${pids[@]}"; do wait "$p" || rc=$?; done
for p in "${pids[@]}"; do wait "$p" 2>/dev/null; done
exit $rc
