#!/usr/bin/env bash
# Where a data-parallel step's time goes on 1, 2, ... GPUs (issue 17): benchmarks/train/profile_train.py under torchrun
# on dp_steady.sh's model and scene (N random Gaussians, no densification, regularisers on, VIEWS views a step on the
# synthetic garden at RES), every rank profiling its own share of the step (train.render/loss/backward/all_reduce/
# densify/optimizer, host and device time, the costliest kernels). Reuses dp_steady.sh's scene if it is there.
# Needs Warp staged and benchmarks/device_setup.sh sourced. Writes $OUT/profile_dp/g<n>/rank<r>.json and a table.
# EXTRA: further overrides (e.g. compile_loss=on); TAG: a suffix for the output folder (profile_dp$TAG).
#   N=1000000 VIEWS=4 GPUS="1 2 4" bash benchmarks/distributed/profile_dp.sh
set -u
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1  # never NVLink multicast
N=${N:-1000000}; VIEWS=${VIEWS:-4}; GPUS=${GPUS:-"1 2 4"}; RES=${RES:-"1024 768"}; SCENE_VIEWS=${SCENE_VIEWS:-48}
IT=${IT:-100}; TRACE=${TRACE:-20}; EXTRA=${EXTRA:-}; TAG=${TAG:-}; P="$OUT/profile_dp$TAG"
S=/tmp/dp_steady/scene; W=/tmp/profile_dp; rm -rf $W; mkdir -p $W "$P"
t0=$(date +%s)
if [ ! -f $S/transforms_train.json ]; then
  python3 -m gof_warp.synthetic --preset garden --resolution $RES --views $SCENE_VIEWS --out $S --device cuda:0 --quiet \
    || { echo "scene generation failed"; exit 1; }
fi
ARGS=($S --config unbounded --start-iteration 20000 --iterations "$IT" --trace "$TRACE" model.init=random
      "model.random_init_points=$N" densify.stop_iter=0 densify.near_camera_fraction=0 densify.late_prune_interval=0
      loss.regularization_from_iter=0 "views_per_step=$VIEWS" $EXTRA)
for n in $GPUS; do
  python3 -m torch.distributed.run --standalone --nproc_per_node "$n" benchmarks/train/profile_train.py "${ARGS[@]}" \
    --out $W/g$n > $W/g$n.log 2>&1
  echo "$n GPU(s) rc $? at $(( $(date +%s) - t0 )) s"
  mkdir -p "$P/g$n"
  for r in $W/g$n/rank*; do cp "$r/profile.json" "$P/g$n/$(basename $r).json" 2>/dev/null; done
  [ -f $W/g$n/profile.json ] && cp $W/g$n/profile.json "$P/g$n/rank0.json"  # one process: no rank folder
  [ "$n" = "${GPUS##* }" ] && [ -z "${NO_TRACE_FILE:-}" ] && cp $W/g$n/rank0/trace.json.gz "$P/g$n/rank0_trace.json.gz" 2>/dev/null
  tail -n 2 $W/g$n.log
done
python3 - "$P" <<'PY'
import json, sys
from pathlib import Path
for g in sorted(Path(sys.argv[1]).glob("g*"), key=lambda p: int(p.name[1:])):
    for f in sorted(g.glob("rank*.json")):
        d = json.loads(f.read_text())
        st = " ".join(f"{k.split('.')[1]} {v['host_ms_per_it']}/{v['device_ms_per_it']}" for k, v in d["stages"].items())
        print(f"{g.name} {f.stem}: wall {d['wall_ms_per_it']} ms/step (traced {d['wall_ms_per_it_traced']}), device busy "
              f"{d['device_busy_ms_per_it']}, syncs {d['syncs_per_it']} ({d['sync_wait_ms_per_it']} ms); host/device ms: {st}")
    top = json.loads((g / "rank0.json").read_text())["top_kernels"][:8] if (g / "rank0.json").is_file() else []
    for k in top:
        print(f"    {k['ms_per_it']:7.3f} ms x{k['calls_per_it']:<5} {k['name'][:90]}")
PY
