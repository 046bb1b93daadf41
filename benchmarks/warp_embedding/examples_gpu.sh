#!/usr/bin/env bash
# On the GPU machine (after Warp's install.sh and benchmarks/device_setup.sh): bake the trained default scene
# carried in .rdef (the README's main job) into a NanoVDB volume, then run the torch-free examples on cuda:0 at
# the CI sizes (stand-in volume) and at GPU sizes (the baked volume). Results in $OUT/warp_examples/.
set -euo pipefail
R=$OUT/warp_examples; mkdir -p "$R"
RUN=${RUN:-/tmp/rdef}; [ -d "$RUN" ] || cp -r .rdef "$RUN"
python3 benchmarks/warp_embedding/bake_volume.py "$RUN" --device cuda --nvdb /tmp/default_scene.nvdb \
  --out "$R/bake_default.json" | tail -3
python3 benchmarks/warp_embedding/run_examples.py --device cuda:0 --size small --work "$R/small" \
  --out "$R/examples_small.json" | tail -2
python3 benchmarks/warp_embedding/run_examples.py --device cuda:0 --size large --nvdb /tmp/default_scene.nvdb \
  --work "$R/large" --out "$R/examples_large.json" | tail -2
