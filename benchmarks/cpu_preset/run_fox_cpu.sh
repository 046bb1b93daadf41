#!/usr/bin/env bash
# The fox with the cpu preset, end to end, on the CPU: training, extraction and a mesh picture, with the load of the
# machine at each end, wall and CPU seconds of each command, and the run's numbers gathered into one JSON.
#   bash benchmarks/cpu_preset/run_fox_cpu.sh [FOX_FOLDER] [WORK_FOLDER] [RESULT_JSON]
# The fox is copied into WORK_FOLDER first: the triangulated points are cached beside the scene, never in shared data.
set -euo pipefail
FOX=${1:-../shared/data/fox}
WORK=${2:-/tmp/fox_cpu_bench}
RESULT=${3:-benchmarks/cpu_preset/fox_cpu_metrics.json}
PY=${PYTHON:-python}
mkdir -p "$WORK"
[ -d "$WORK/fox" ] || cp -r "$FOX" "$WORK/fox"
RUN="$WORK/run"
rm -rf "$RUN"
timed() {  # timed NAME CMD...: wall and CPU seconds (children included) of CMD into $WORK/NAME.time
  local name=$1; shift
  /usr/bin/time -f '{"wall_s": %e, "user_s": %U, "sys_s": %S, "max_rss_kb": %M}' -o "$WORK/$name.time" "$@"
}
uptime > "$WORK/load_start.txt"
timed train $PY -m gof_warp.train "$WORK/fox" --config cpu --device cpu --out "$RUN" 2>&1 | tee "$WORK/train.log"
uptime > "$WORK/load_mid.txt"
timed extract $PY -m gof_warp.extract "$RUN" 2>&1 | tee "$WORK/extract.log"
uptime > "$WORK/load_end.txt"
$PY -m gof_warp.pictures "$RUN" --mesh "$RUN/mesh_tetra.ply" --views 3 --device cpu
$PY - "$WORK" "$RUN" "$RESULT" <<'PYEOF'
import json, sys, platform, os
from pathlib import Path
work, run, result = map(Path, sys.argv[1:])
m = json.loads((run / "metrics.json").read_text())
import trimesh
mesh = trimesh.load(run / "mesh_tetra.ply", process=False)
cfg = (run / "config.yaml").read_text()
import yaml
c = yaml.safe_load(cfg)
times = {k: json.loads((work / f"{k}.time").read_text()) for k in ("train", "extract")}
out = {
    "scene": "fox (67 photos 540x960, instant-ngp, distortion)", "command": "train --config cpu; extract",
    "machine": f"{os.cpu_count()}-core CPU ({platform.processor() or platform.machine()}), shared with other jobs: "
               "timings are upper bounds",
    "load_start": (work / "load_start.txt").read_text().strip(), "load_after_train": (work / "load_mid.txt").read_text().strip(),
    "load_end": (work / "load_end.txt").read_text().strip(),
    "iterations": m["iterations"], "downscale": c["data"]["downscale"], "train_time_s": m["train_time_s"],
    "train_command": times["train"], "extract_command": times["extract"],
    "whole_wall_s": round(times["train"]["wall_s"] + times["extract"]["wall_s"], 1),
    "whole_cpu_s": round(sum(t["user_s"] + t["sys_s"] for t in times.values()), 1),
    "num_gaussians": m["num_gaussians"], "test": m["test"], "initial_points": m.get("initial_points"),
    "mesh_faces": int(len(mesh.faces)), "mesh_vertices": int(len(mesh.vertices)),
}
result.write_text(json.dumps(out, indent=2) + "\n")
print(json.dumps(out, indent=2))
PYEOF
