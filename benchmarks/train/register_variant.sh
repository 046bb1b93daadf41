#!/usr/bin/env bash
# A copy of the working tree (for ab_trees.sh) whose per-pixel CUDA kernels (kernels/rasterize_tiled.py) are compiled
# with at most REGS registers per thread (MAX_REGISTERS, Warp's cuda_max_registers: more resident warps, maybe spills;
# 0 keeps the tree's value) and, with FAST_MATH=0 or 1, Warp's fast_math off or on (approximate division and square
# root, denormals flushed; unset keeps the tree's setting). Used to measure occupancy and instruction cost tree against
# tree.
#   [FAST_MATH=0|1] bash benchmarks/train/register_variant.sh .r64 64
set -eu
dest=$1; regs=$2
rm -rf $dest; mkdir -p $dest/tests $dest/benchmarks
cp -r gof_warp kernels configs $dest/; rm -f $dest/gof_warp/kernels $dest/gof_warp/configs
cp tests/reference_render.py $dest/tests/; cp -r benchmarks/render benchmarks/train $dest/benchmarks/
python3 - $dest/kernels/rasterize_tiled.py $regs ${FAST_MATH:-keep} <<'PY'
import re, sys
path, regs, fast = sys.argv[1:]
s = open(path).read()
if fast != "keep":
    s, n = re.subn(r'wp\.set_module_options\(\{"enable_backward": False(, "fast_math": (True|False))?\}\)',
                   f'wp.set_module_options({{"enable_backward": False, "fast_math": {fast == "1"}}})', s)
    assert n == 1, "the module options line not found"
if regs != "0":
    s, n = re.subn(r"^MAX_REGISTERS = \d+", f"MAX_REGISTERS = {regs}", s, flags=re.M)
    assert n == 1, "MAX_REGISTERS not found"
open(path, "w").write(s)
PY
echo "$dest: registers $regs, fast_math ${FAST_MATH:-as in the tree}"
