#!/usr/bin/env bash
# The octree grid made and marched in pieces (OctreeConfig.piece_tets, `extract --piece-tets`) against the whole grid
# at once, on one GPU (issues 11 and 17: a grid larger than the GPU's memory is processed in pieces, not refused).
# The model is synthetic_run.py's: the 54,275 real Gaussians of gaussians_54k.npz (no copies), a ring of 48 cameras at
# 800x600; `--cell-factor` sets the grid's size (0.25: 34.5M tetrahedra, DTU scan 24's count). A 20k-Gaussian
# extraction compiles Warp's kernels first, outside the timed runs. Needs Warp staged and benchmarks/device_setup.sh
# sourced. Each run is the default command with the flags given; RUNS lists "TAG:FLAGS" (spaces in FLAGS as commas).
#   RUNS="f025_pieces:--cell-factor,0.25 f025_whole:--cell-factor,0.25,--piece-tets,2147483647" \
#     DATA=.bgdata/gaussians_54k.npz bash benchmarks/extract/pieces.sh
# Writes $OUT/pieces${TAG}.json (each run's <mesh>.json, command wall time, exit code, mesh sha256, log tail).
set -u
N=${N:-54275}; DATA=${DATA:-../shared/data/gaussians_54k.npz}; W=/tmp/pieces; TAG=${TAG:-}; LIMIT=${LIMIT:-540}
RUNS=${RUNS:-"f025_pieces:--cell-factor,0.25 f025_whole:--cell-factor,0.25,--piece-tets,2147483647"}
t0=$(date +%s)
if [ ! -f $W/run/point_cloud.ply ]; then source benchmarks/distributed/model_and_warmup.sh; fi
for spec in $RUNS; do
  name=${spec%%:*}; flags=$(echo "${spec#*:}" | tr ',' ' ')
  rm -rf $W/$name; mkdir -p $W/$name
  s=$(date +%s.%N)
  timeout "$LIMIT" python3 -m gof_warp.extract $W/run --out $W/$name/mesh.ply --no-pictures --quiet $flags \
    > $W/$name.log 2>&1
  echo $? > $W/$name.rc
  python3 -c "import sys; print(round(float(sys.argv[2]) - float(sys.argv[1]), 2))" "$s" "$(date +%s.%N)" > $W/$name.wall
  echo "$name ($flags): rc $(cat $W/$name.rc), command $(cat $W/$name.wall) s, at $(( $(date +%s) - t0 )) s"
  [ -f $W/$name/mesh.ply ] && sha256sum $W/$name/mesh.ply | cut -c1-64 > $W/$name.sha && rm -f $W/$name/mesh.ply
done
python3 - $W "$OUT" "$RUNS" "$TAG" <<'PY'
import json, subprocess, sys
from pathlib import Path
w, out, runs, tag = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3].split(), sys.argv[4]
result = {"what": "extract with the octree grid in pieces vs whole (benchmarks/extract/pieces.sh)",
          "model": "54,275 real Gaussians (gaussians_54k.npz), 48 ring cameras at 800x600", "runs": {}}
try:
    result["gpus"] = subprocess.run(["nvidia-smi", "--query-gpu=name,memory.total", "--format=csv,noheader"],
                                    capture_output=True, text=True).stdout.strip().splitlines()
except FileNotFoundError:
    result["gpus"] = ["no GPU (nvidia-smi absent)"]
for spec in runs:
    name, flags = spec.split(":", 1)
    d = {"flags": flags.replace(",", " "), "rc": int((w / f"{name}.rc").read_text()),
         "command_wall_s": float((w / f"{name}.wall").read_text())}
    j = w / name / "mesh.json"
    if j.is_file():
        d["mesh"] = json.loads(j.read_text())
    if (w / f"{name}.sha").is_file():
        d["mesh_sha256"] = (w / f"{name}.sha").read_text().strip()
    if d["rc"] != 0:
        d["log_tail"] = (w / f"{name}.log").read_text()[-2500:]
    result["runs"][name] = d
(out / f"pieces{tag}.json").write_text(json.dumps(result, indent=1))
for name, d in result["runs"].items():
    m = d.get("mesh")
    if not m:
        print(f"{name}: rc {d['rc']}, no mesh\n{d.get('log_tail', '')[-1200:]}")
        continue
    st = m["stages"]
    peaks = {k: (v.get("gpu_peak_allocated_mb"), v.get("gpu_warp_pool_high_mb"), v.get("host_peak_rss_mb"))
             for k, v in st.items() if isinstance(v, dict) and "time_s" in v}
    print(f"{name}: total {m.get('total_time_s')} s, command {d['command_wall_s']} s, faces {m['meshes'][0]['faces']}, "
          f"sha {d.get('mesh_sha256', '')[:12]}, counts { {k: v for k, v in st['counts'].items() if k != 'search'} }, "
          f"search {st['counts'].get('search', {}).get('steps_per_call')}; "
          + "; ".join(f"{k} {st[k]['time_s']} s, GPU {p[0]} + {p[1]} MB, host {p[2]} MB" for k, p in peaks.items()))
PY
