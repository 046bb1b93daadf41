#!/usr/bin/env bash
# Extraction of an N-Gaussian model on 1, 2, ... GPUs of one host (issue 17): `python -m gof_warp.extract RUN` on one
# GPU, `torchrun --nproc_per_node n -m gof_warp.extract RUN` on n (the field's views shared out, the marching split by
# space). The model is synthetic_run.py's (the 54k real Gaussians, jittered copies beyond 54k, a ring of 48 cameras
# at 800x600). A 20k-Gaussian extraction first compiles Warp's kernels, outside the timed runs. Every run is the
# default command (octree grid, 8 search steps). Needs Warp staged and benchmarks/device_setup.sh sourced.
# Writes $OUT/extract_split.json (each run's <mesh>.json: stages, per-rank time and memory) and prints a table.
#   N=3000000 GPUS="1 2 4" DATA=.bgdata/gaussians_54k.npz bash benchmarks/distributed/extract_split.sh
# Again for the same model without building it (RUN_ONLY=1) and other flags, into another JSON:
#   RUN_ONLY=1 GPUS=1 EXTRA="--search-steps-per-call 1" TAG=_d1 bash benchmarks/distributed/extract_split.sh
set -u
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1  # never NVLink multicast
N=${N:-3000000}; GPUS=${GPUS:-"1 2"}; DATA=${DATA:-../shared/data/gaussians_54k.npz}; EXTRA=${EXTRA:-}  # extract flags
W=/tmp/extract_split; TAG=${TAG:-}
t0=$(date +%s)
if [ -z "${RUN_ONLY:-}" ]; then source benchmarks/distributed/model_and_warmup.sh; fi
for n in $GPUS; do
  mkdir -p $W/g$n
  s=$(date +%s.%N)
  if [ "$n" = 1 ]; then
    python3 -m gof_warp.extract $W/run --out $W/g1/mesh.ply --no-pictures --quiet $EXTRA > $W/g1.log 2>&1
  else
    python3 -m torch.distributed.run --standalone --nproc_per_node "$n" -m gof_warp.extract $W/run \
      --out $W/g$n/mesh.ply --no-pictures --quiet $EXTRA > $W/g$n.log 2>&1
  fi
  rc=$?; python3 -c "import sys; print(round(float(sys.argv[2]) - float(sys.argv[1]), 2))" "$s" "$(date +%s.%N)" > $W/g$n.wall
  echo "$n GPU(s) rc $rc at $(( $(date +%s) - t0 )) s: command $(cat $W/g$n.wall) s"
done
python3 - $W "$OUT" "$GPUS" "$N" "$EXTRA" "$TAG" <<'PY'
import hashlib, json, subprocess, sys
from pathlib import Path
w, out, gpus, n, extra, tag = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3].split(), int(sys.argv[4]), *sys.argv[5:]
runs = {}
for g in gpus:
    j = w / f"g{g}" / "mesh.json"
    if not j.is_file():
        runs[g] = {"failed": (w / f"g{g}.log").read_text()[-3000:]}
        continue
    d = json.loads(j.read_text())
    d["command_wall_s"] = float((w / f"g{g}.wall").read_text())  # the whole command: start-up, load, writing
    d["mesh_sha256"] = hashlib.sha256((w / f"g{g}" / "mesh.ply").read_bytes()).hexdigest()
    runs[g] = d
try:
    gpu = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True, text=True).stdout
except FileNotFoundError:
    gpu = "no GPU (nvidia-smi absent)"
result = {"what": "extract on 1..n GPUs (benchmarks/distributed/extract_split.sh)", "gaussians": n, "flags": extra,
          "gpus": gpu.strip().splitlines(), "runs": runs}
(out / f"extract_split{tag}.json").write_text(json.dumps(result, indent=1))
for g, d in runs.items():
    if "failed" in d:
        print(f"{g} GPU(s): failed\n{d['failed']}")
        continue
    st = d["stages"]
    per = "; ".join(f"rank {r['rank']}: {r.get('gpu_peak_allocated_mb')} + {r.get('gpu_warp_pool_high_mb')} MB GPU, "
                    f"{r.get('host_peak_rss_mb')} MB host" for r in d.get("ranks", []))
    print(f"{g} GPU(s): total {d['total_time_s']} s (command {d['command_wall_s']} s), faces {d['meshes'][0]['faces']}, "
          f"sha {d['mesh_sha256'][:12]}; search {d['stages']['counts'].get('search')}; stages " + ", ".join(f"{k} {v['time_s']}" for k, v in st.items()
                                                              if isinstance(v, dict) and "time_s" in v) + f"; {per}")
PY
