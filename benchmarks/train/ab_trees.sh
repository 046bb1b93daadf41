#!/usr/bin/env bash
# A/B of the renderer and the trainer step between source trees on one GPU (issue 14). A tree is a folder holding
# gof_warp/, kernels/, configs/, tests/reference_render.py and benchmarks/{render,train}/: "." (the working tree) or a
# snapshot of an earlier commit, e.g.
#   git archive HEAD gof_warp kernels configs tests/reference_render.py benchmarks/render benchmarks/train | tar -x -C .before
# Needs Warp staged and benchmarks/device_setup.sh sourced; the DTU scene in DTU.
#   STEP=check   the CUDA kernels of CHECK_TREE (default the working tree) against the float64 reference (bench_render.py --check)
#   STEP=render  bench_render.py --one N SIZE for each of POINTS ("N:SIZE ...") and each tree of RENDER_TREES
#   STEP=model   trains the DTU model the profiles use: MODEL_ITERS iterations of the dtu preset (working tree) → $EX/dtu.ply
#   STEP=profile profile_train.py at each of STARTS on $EX/dtu.ply for each of VARIANTS
#                ("label:tree[:reduce_min_lanes[:override,override...]]", e.g. "cl:.::compile_loss=on"), REPS times alternating;
#                densification is paused (densify.interval=100000) unless a variant's overrides say otherwise
#   STEP=model with /tmp/dtugeo/*.part0.npz present (pack_model.py parts of a trained run) unpacks that model instead
# Writes everything under $OUT/ab/.
set -u
EX=${EX:-/tmp/ex}; DTU=${DTU:-.s18/dtu_scan24}; REPS=${REPS:-1}; MODEL_ITERS=${MODEL_ITERS:-7000}
POINTS=${POINTS:-"1000000:1920x1080 1000000:800x600"}; STARTS=${STARTS:-"20000 5000"}
RENDER_TREES=${RENDER_TREES:-".before ."}; VARIANTS=${VARIANTS:-"old:.before new:."}
mkdir -p "$OUT/ab" $EX
run_tree() {  # run_tree TREE CMD...: CMD from TREE's folder with TREE's sources first on the path
  local tree=$1; shift
  if [ "$tree" != . ]; then ln -sfn ../kernels $tree/gof_warp/kernels; ln -sfn ../configs $tree/gof_warp/configs; fi
  (cd $tree && PYTHONPATH="$PWD:/tmp/site" "$@")
}
for step in ${STEP:-check render model profile}; do
  case $step in
  check)
    run_tree ${CHECK_TREE:-.} python3 benchmarks/render/bench_render.py --check --out "$OUT/ab/check_$(basename ${CHECK_TREE:-working})" 2>&1 \
      | tail -n 40 ;;
  render)
    for rep in $(seq 1 $REPS); do for p in $POINTS; do for tree in $RENDER_TREES; do
      IFS=: read -r n size <<< "$p"
      run_tree $tree python3 benchmarks/render/bench_render.py --one $n $size --iters 9 2>/dev/null \
        | grep '^RESULT ' | sed "s|^RESULT |{\"tree\": \"$tree\", \"rep\": $rep, \"r\": |; s|\$|}|" >> "$OUT/ab/render.jsonl"
      tail -n 1 "$OUT/ab/render.jsonl" | python3 -c "import json,sys; d=json.loads(sys.stdin.read()); r=d['r'];
print(d['tree'], r['n'], r['size'], 'fwd', round(r['fwd_ms'],2), 'fwd+bwd train', round(r['fwd_bwd_train_ms'],2),
      'stages', {k: round(v,2) for k,v in r['stages_tiled_ms'].items()}, 'bwd by reduce threshold',
      {k: {m: round(v,2) for m,v in t.items()} for k,t in r.items() if k.startswith('raster_backward_ms_by')})"
    done; done; done ;;
  model)
    if [ ! -f $EX/dtu.ply ] && ls /tmp/dtugeo/*.part0.npz >/dev/null 2>&1; then EX=$EX source benchmarks/extract/dtu_model.sh; fi
    if [ ! -f $EX/dtu.ply ]; then
      t0=$(date +%s)
      python3 -m gof_warp.train $DTU --config dtu --iterations $MODEL_ITERS --out $EX/dtu_run --no-pictures --quiet \
        > $EX/model.log 2>&1; echo "model rc $? in $(( $(date +%s) - t0 )) s"; tail -n 3 $EX/model.log
      cp $EX/dtu_run/point_cloud.ply $EX/dtu.ply && cp $EX/dtu_run/metrics.json "$OUT/ab/model_metrics.json"
    fi ;;
  profile)
    for rep in $(seq 1 $REPS); do for start in $STARTS; do for v in $VARIANTS; do
      IFS=: read -r label tree lanes overrides <<< "$v"
      extra=(); [ -n "$lanes" ] && extra=(--reduce-min-lanes $lanes)
      [ -n "$overrides" ] && extra+=(${overrides//,/ })
      d=$EX/prof_${label}_${start}_$rep
      run_tree $tree python3 benchmarks/train/profile_train.py $PWD/$DTU --config dtu --ply $EX/dtu.ply --start $start \
        --iterations 300 --trace 20 --out $d --label $label model.init=random densify.interval=100000 "${extra[@]}" > $d.log 2>&1
      echo "$label start $start rep $rep rc $?: $(grep -E 'wall_ms|busy' $d.log | tr '\n' ' ') bwd $(grep -o '"rasterize_backward[^}]*' $d/profile.json | grep -o 'ms_per_it": [0-9.]*')"
      cp $d/profile.json "$OUT/ab/profile_${label}_${start}_$rep.json" 2>/dev/null || tail -n 20 $d.log
    done; done; done ;;
  esac
done
