#!/usr/bin/env bash
# colmap_can diagnosis on one GPU: short runs of the preset `train` picks, each with one change, at once.
#   bash benchmarks/real_captures/sweep_can.sh SCENE ITERATIONS  → $OUT/sweep_can/<variant>/{metrics.json,views.png}
# Runs share the GPU and the host, so their times are not comparable with runs that had it alone.
set -u
scene=$1; its=$2; R=$OUT/sweep_can; mkdir -p "$R"
declare -A V=(
  [base]=""
  [appearance]="appearance=true"
  [half_res]="data.downscale=2"
  [appearance_half_res]="appearance=true data.downscale=2"
  [grad_x2]="densify.grad_threshold=0.0004 densify.abs_grad_threshold=0.0004"
  [no_filter3d]="model.use_filter_3d=false"
)
for v in "${!V[@]}"; do
  python3 -m gof_warp.train "$scene" --out "/tmp/sweep_can/$v" --iterations "$its" checkpoint_every=100000 ${V[$v]} \
    > "$R/$v.log" 2>&1 &
done
wait
python3 - "$R" <<'PY'
import json, shutil, sys
from pathlib import Path
R = Path(sys.argv[1]); rows = {}
for log in sorted(R.glob("*.log")):
    v = log.stem; run = Path("/tmp/sweep_can") / v
    m = run / "metrics.json"
    if not m.is_file():
        rows[v] = {"error": log.read_text()[-1500:]}; continue
    d = json.loads(m.read_text())
    rows[v] = {"test_psnr": d["test"]["psnr"], "test_per_image": [round(x["psnr"], 2) for x in d["test"]["per_image"]],
               "train_psnr": d.get("final_train_psnr"), "gaussians": d["num_gaussians"], "time_s": d["train_time_s"]}
    (R / v).mkdir(exist_ok=True)
    for f in ("metrics.json", "config.yaml"):
        shutil.copy(run / f, R / v / f)
    if (run / "pictures" / "views.png").is_file():
        shutil.copy(run / "pictures" / "views.png", R / v / "views.png")
(R / "summary.json").write_text(json.dumps(rows, indent=1))
for v, r in rows.items():
    print(v, {k: r.get(k) for k in ("test_psnr", "train_psnr", "gaussians", "time_s")} if "error" not in r else r["error"][-400:])
PY
