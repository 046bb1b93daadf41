#!/usr/bin/env bash
# Inputs for run_gpu.sh and ../texture/dtu_gpu.sh on a GPU machine without pycolmap, made here (CPU, ~1 min):
#   bash benchmarks/random_init/stage_gpu_inputs.sh DEST [DTU_SCENE]
# DEST/{bf,garden}: the synthetic background_full and garden scenes (training photos, held-out photos and their exact
# depths; the other depth/normal maps and the ground-truth meshes left out to travel light) with their
# sfm_known_poses/ caches; DEST/dtu_scan24: a copy of DTU_SCENE (default ../shared/data/dtu_scan24) with the cache of
# its 42-view training split (data.test_every=8). A 1-iteration training of each makes the cache; its run is discarded.
set -euo pipefail
dest=${1:?destination folder, e.g. .bench_data}; dtu=${2:-../shared/data/dtu_scan24}
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
mkdir -p "$dest"
for pair in bf:background_full garden:garden; do
  name=${pair%%:*}; preset=${pair#*:}
  [ -d "$dest/$name/sfm_known_poses" ] && continue
  rm -rf "$dest/$name"
  python -m gof_warp.synthetic --preset "$preset" --out "$dest/$name"
  rm -rf "$dest/$name/train/depth" "$dest/$name/train/normal" "$dest/$name/test/normal" "$dest/$name"/gt_*.ply
  python -m gof_warp.train "$dest/$name" --config unbounded --iterations 1 --out "$tmp/$name" --quiet --no-pictures
done
if [ ! -d "$dest/dtu_scan24/sfm_known_poses" ]; then
  cp -r "$dtu" "$dest/dtu_scan24"
  python -m gof_warp.train "$dest/dtu_scan24" --config dtu --iterations 1 data.test_every=8 --out "$tmp/dtu" --quiet \
    --no-pictures
fi
du -sh "$dest"/*
