#!/usr/bin/env bash
# Data-parallel scaling at a fixed model size on one host (issue 17): the synthetic `garden` scene rendered at
# RES (SCENE_VIEWS train views, default 100; DTU has 49 at 800x600), a model of N random Gaussians that neither densifies nor
# prunes (so every run times the same model), regularisers on from the start (the late phase's step), trained IT
# steps of VIEWS views each on 1, 2, ... GPUs (torchrun, NCCL). The 1-GPU run compiles Warp's kernels in its
# warm-up, outside its timed loop; the later runs find them cached. Needs Warp staged, benchmarks/device_setup.sh
# sourced, and trimesh (the scene writer) among the carried wheels. Writes $OUT/dp_steady.json and prints a table.
#   N=1000000 IT=200 VIEWS=4 GPUS="1 2 4" bash benchmarks/distributed/dp_steady.sh
set -u
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1  # never NVLink multicast
N=${N:-1000000}; IT=${IT:-200}; VIEWS=${VIEWS:-4}; GPUS=${GPUS:-"1 2 4"}; RES=${RES:-"1024 768"}; DEV=${DEV:-cuda:0}
SCENE_VIEWS=${SCENE_VIEWS:-100}
W=/tmp/dp_steady; rm -rf $W; mkdir -p $W
t0=$(date +%s)
python3 -m gof_warp.synthetic --preset garden --resolution $RES --views $SCENE_VIEWS --out $W/scene --device $DEV --quiet \
  || { echo "scene generation failed"; exit 1; }
echo "scene at $(( $(date +%s) - t0 )) s"
COMMON=($W/scene --iterations "$IT" --no-pictures --quiet checkpoint_every=0 log_every=25 "views_per_step=$VIEWS" model.init=random
        "model.random_init_points=$N" densify.stop_iter=0 densify.near_camera_fraction=0 densify.late_prune_interval=0
        loss.regularization_from_iter=0)
for n in $GPUS; do
  if [ "$n" = 1 ]; then
    python3 -m gof_warp.train "${COMMON[@]}" --out $W/g1 > $W/g1.log 2>&1
  else
    python3 -m torch.distributed.run --standalone --nproc_per_node "$n" -m gof_warp.train "${COMMON[@]}" \
      --out $W/g$n > $W/g$n.log 2>&1
  fi
  echo "$n GPU(s) rc $? at $(( $(date +%s) - t0 )) s: $(grep -h 'done:' $W/g$n.log)"
  python3 - $W $OUT "$GPUS" "$N" "$IT" "$VIEWS" "$RES" "$SCENE_VIEWS" <<'PY'
import json, sys
from pathlib import Path
w, out, gpus, n, it, views, res, sv = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3].split(), *sys.argv[4:]
rows = {}
for g in gpus:
    m = w / f"g{g}" / "metrics.json"
    if m.is_file():
        d = json.loads(m.read_text())
        rows[g] = {k: d.get(k) for k in ("train_time_s", "its_per_s", "warmup_s", "num_gaussians", "processes",
                                          "views_per_step", "gpu_peak_allocated_mb", "gpu_peak_warp_pool_mb")}
        rows[g]["test_psnr"] = d["test"]["psnr"]
        rows[g]["ms_per_step"] = round(1000 * d["train_time_s"] / int(it), 2)
        h = {r["iteration"]: r["elapsed_s"] for r in d["history"]}  # every 25 steps: the rate past the first 25
        if 25 in h and int(it) in h and int(it) > 25:
            rows[g]["ms_per_step_after_25"] = round(1000 * (h[int(it)] - h[25]) / (int(it) - 25), 2)
base = rows.get("1", {}).get("train_time_s")
for g, r in rows.items():
    r["speedup_vs_1"] = round(base / r["train_time_s"], 3) if base else None
    b25, r25 = rows.get("1", {}).get("ms_per_step_after_25"), r.get("ms_per_step_after_25")
    r["speedup_after_25_vs_1"] = round(b25 / r25, 3) if b25 and r25 else None
import subprocess
try:
    gpu = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True, text=True).stdout
except FileNotFoundError:
    gpu = "no GPU (nvidia-smi absent)"
result = {"what": "data-parallel steps at a fixed model size (benchmarks/distributed/dp_steady.sh)",
          "scene": f"synthetic garden, {res.replace(' ', 'x')}, {sv} train views", "gaussians": int(n),
          "steps": int(it), "views_per_step": int(views), "gpus": gpu.strip().splitlines(), "runs": rows}
(out / "dp_steady.json").write_text(json.dumps(result, indent=1))
print(" | ".join(f"{g} GPU: {r['ms_per_step']} ms/step x{r['speedup_vs_1']}, past step 25 "
                 f"{r.get('ms_per_step_after_25')} x{r['speedup_after_25_vs_1']}" for g, r in rows.items()))
PY
done
for f in $W/g*.log; do echo "== $f"; tail -n 3 "$f"; done
