#!/usr/bin/env bash
# A copy of the working tree (for ab_trees.sh) whose per-pixel CUDA kernels KERNELS (comma-separated) are compiled with at
# most REGS registers per thread (Warp's cuda_max_registers, i.e. __maxnreg__): more resident warps, maybe spills. Used to
# measure occupancy.
#   bash benchmarks/train/register_variant.sh .r80 80 [rasterize_backward_tiled,rasterize_forward_tiled]
set -eu
dest=$1; regs=$2; kernel=${3:-rasterize_backward_tiled}
rm -rf $dest; mkdir -p $dest/tests $dest/benchmarks
cp -r gof_warp kernels configs $dest/; rm -f $dest/gof_warp/kernels $dest/gof_warp/configs
cp tests/reference_render.py $dest/tests/; cp -r benchmarks/render benchmarks/train $dest/benchmarks/
python3 - $dest/kernels/rasterize_tiled.py $kernel $regs <<'PY'
import sys
path, kernels, regs = sys.argv[1:]
s = open(path).read()
for kernel in kernels.split(","):
    old = f"@wp.kernel\ndef {kernel}("
    assert old in s, f"{kernel} not found"
    s = s.replace(old, f"@wp.kernel(cuda_max_registers={regs})\ndef {kernel}(")
open(path, "w").write(s)
PY
echo "$dest: $kernel capped at $regs registers"
