#!/usr/bin/env bash
# CPU A/B: three variants x three seeds of the README main job (benchmarks/train/README.md, session 6):
#   bash benchmarks/train/ab_cpu/ab_seeds.sh RUN/scene [OUT]      (RUN: the README main job's run folder)
# base = the code as it is; fused = optim.fused=true (torch's fused Adam); prod = the 3D filter's opacity
# compensation with torch.prod as before session 5 (run_variant.py patches it in). Appends to OUT/summary.txt.
set -eu
scene=$(realpath "${1:?scene folder}"); out=${2:-/tmp/ab_cpu}; mkdir -p "$out"; out=$(realpath "$out")
cd "$(dirname "$0")/../../.."
run() {  # variant seed mode extra
  python benchmarks/train/ab_cpu/run_variant.py "$3" "$scene" --config quick --out "$out/$1_s$2" --device cpu \
    --no-pictures --quiet seed="$2" $4 > "$out/$1_s$2.log" 2>&1
  python3 -c "import json;d=json.load(open('$out/$1_s$2/metrics.json'));print('$1', $2, round(d['test']['psnr'],3), d['num_gaussians'], d['train_time_s'])" >> "$out/summary.txt"
}
for seed in 0 1 2; do
  run base "$seed" none ""
  run fused "$seed" none "optim.fused=true"
  run prod "$seed" prod ""
done
cat "$out/summary.txt"
