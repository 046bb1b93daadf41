#!/usr/bin/env bash
# Resumable variants of one scene's training, all at once on one GPU, cut to fit 10-minute device calls:
#   bash benchmarks/real_captures/variants.sh SCENE ITERATIONS BUDGET_S NAME="k=v k=v" NAME2="..." ...
# Each variant is `python -m gof_warp.train SCENE --resume` with its overrides (the preset `train` picks, plus
# them) in /tmp/variants/NAME; at BUDGET_S it gets SIGINT (it checkpoints its iteration and stops) and the next
# call resumes it. A variant whose metrics.json exists is done. Results: $OUT/variants/NAME/{metrics.json,
# config.yaml,views.png,spike_*.jpg} and $OUT/variants/summary.json. Runs share the GPU and the host: their times are not
# comparable with runs that had it alone.
set -u
scene=$1; its=$2; budget=$3; shift 3
R=$OUT/variants; W=/tmp/variants; mkdir -p "$R" "$W"
for spec in "$@"; do
  name=${spec%%=*}; over=${spec#*=}
  [ -f "$W/$name/metrics.json" ] && continue
  # shellcheck disable=SC2086  # the overrides are separate words on purpose
  timeout -s INT -k 45 "$budget" python3 -m gof_warp.train "$scene" --out "$W/$name" --iterations "$its" \
    checkpoint_every=2500 $over --resume >> "$W/$name.log" 2>&1 &
done
wait
python3 - "$R" "$W" "$@" <<'PY'
import json, shutil, sys
from pathlib import Path
R, W = Path(sys.argv[1]), Path(sys.argv[2]); rows = {}
for spec in sys.argv[3:]:
    v, over = spec.split("=", 1)
    run = W / v; m = run / "metrics.json"
    if not m.is_file():
        log = (W / f"{v}.log").read_text() if (W / f"{v}.log").is_file() else ""
        rows[v] = {"overrides": over, "state": "unfinished", "log_tail": log[-600:]}; continue
    d = json.loads(m.read_text())
    rows[v] = {"overrides": over, "test_psnr": d["test"]["psnr"], "test_ssim": d["test"].get("ssim"),
               "test_per_image": [round(x["psnr"], 2) for x in d["test"]["per_image"]],
               "train_psnr": d.get("final_train_psnr"), "gaussians": d["num_gaussians"], "time_s": d["train_time_s"],
               "loss_spikes": d.get("loss_spikes"), "late_pruned": d.get("late_pruned")}
    (R / v).mkdir(exist_ok=True)
    for f in ("metrics.json", "config.yaml", "pictures/views.png"):
        if (run / f).is_file():
            shutil.copy(run / f, R / v / Path(f).name)
    try:  # the spike pictures, as JPEG at most 1600 px wide (the PNGs of a 720x1280 capture are several MB each)
        from PIL import Image
        for png in sorted((run / "pictures").glob("spike_*.png"))[:12]:
            im = Image.open(png).convert("RGB")
            if im.width > 1600:
                im = im.resize((1600, round(im.height * 1600 / im.width)))
            im.save(R / v / (png.stem + ".jpg"), quality=85)
    except ImportError:
        pass
(R / "summary.json").write_text(json.dumps(rows, indent=1))
for v, r in rows.items():
    print(v, {k: r.get(k) for k in ("test_psnr", "train_psnr", "gaussians", "time_s", "state")})
PY
