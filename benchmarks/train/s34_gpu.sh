#!/usr/bin/env bash
# Session 34 on a two-GPU host, after the two DTU trainings of ../real_captures/hidden_prune_gpu.sh. Ran at c91a684, whose
# FlatAdam (optim.adam) and channel-last appearance network were measured slower and reverted (f0d14df): the "cl" and
# "new" variants name that commit's options and need its tree.
#   1. the step profile, code before this session (.s34/before, a git archive of 6f0f107) against the appearance
#      network channel-last with torch's Adam ("cl": optim.adam=torch) and both changes ("new": FlatAdam), on session
#      32's DTU model; start 20,000 on GPU 0 and 12,000 on GPU 1 at once, variants alternating on each GPU, REPS times;
#   2. adam_roofline.py (GPU 0) while the CUDA tests of the touched modules run (GPU 1);
#   3. the default extract command on session 32's DTU model, the code before the field's early reject (.s33/before, a
#      git archive of d876290) against today's, alternated three times on GPU 0.
# Needs Warp staged, benchmarks/device_setup.sh sourced, /tmp/gofdata/s32 (the packed model parts, cameras.json,
# config.yaml) and /tmp/gofdata/dtu_scan24. Writes $OUT/s34/ (and $OUT/ab/ from ab_trees.sh).
set -u
R=$OUT/s34; mkdir -p $R /tmp/dtugeo
cp /tmp/gofdata/s32/*.npz /tmp/dtugeo/ 2>/dev/null
mkdir -p .s34data && ln -sfn /tmp/gofdata/dtu_scan24 .s34data/dtu_scan24  # ab_trees.sh takes the scene relative
DTU=.s34data/dtu_scan24; REPS=${REPS:-1}
V=${V:-"old:.s34/before cl:.::optim.adam=torch new:."}
if [ "${SKIP_PROFILE:-0}" != 1 ]; then
  CUDA_VISIBLE_DEVICES=0 EX=/tmp/ex0 STEP="model profile" STARTS=20000 REPS=$REPS VARIANTS="$V" DTU=$DTU \
    bash benchmarks/train/ab_trees.sh > $R/profile_20000.txt 2>&1 &
  CUDA_VISIBLE_DEVICES=1 EX=/tmp/ex1 STEP="model profile" STARTS=12000 REPS=$REPS VARIANTS="$V" DTU=$DTU \
    bash benchmarks/train/ab_trees.sh > $R/profile_12000.txt 2>&1 &
  wait
fi
if [ "${SKIP_TESTS:-0}" != 1 ]; then
  CUDA_VISIBLE_DEVICES=0 python3 benchmarks/train/adam_roofline.py --out $R/adam_roofline.json > $R/adam_roofline.txt 2>&1 &
  CUDA_VISIBLE_DEVICES=1 python3 -m pytest -q -p no:cacheprovider -k cuda tests/test_flat_adam.py tests/test_losses.py \
    tests/test_early_reject.py tests/test_render_host_glue.py > $R/cuda_tests.txt 2>&1 &
  wait
fi
# 3. the extract command before/after the field's early reject
D=/tmp/dturun; mkdir -p $D
[ -f $D/point_cloud.ply ] || { cp /tmp/gofdata/s32/cameras.json /tmp/gofdata/s32/config.yaml $D/ &&
  python3 benchmarks/extract/pack_model.py unpack /tmp/gofdata/s32/dtu_s32_geometry.part0.npz $D/point_cloud.ply; }
OLD=${OLD_TREE:-$PWD/.s33/before}; ln -sfn ../kernels $OLD/gof_warp/kernels; ln -sfn ../configs $OLD/gof_warp/configs
t() {  # name, tree: one whole extract command run from that tree, on GPU 0
  local name=$1 dir=$2; local a=$(date +%s.%N)
  (cd $dir && CUDA_VISIBLE_DEVICES=0 PYTHONPATH=$dir:/tmp/site python3 -m gof_warp.extract $D > /tmp/$name.log 2>&1)
  echo "$name rc $? wall $(python3 -c "print(round($(date +%s.%N) - $a, 2))") s" | tee -a $R/extract_times.txt
  cp $D/mesh_tetra.json $R/extract_$name.json; sha256sum $D/mesh_tetra.ply | sed "s|^|$name |" >> $R/extract_times.txt
}
t warm_up $PWD
for k in 1 2 3; do t before_$k $OLD; t after_$k $PWD; done
(cd $OUT && tar czf s34.tgz s34 ab && rm -rf s34 ab)
