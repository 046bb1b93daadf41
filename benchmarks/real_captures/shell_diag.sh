#!/usr/bin/env bash
# Where the whole-seen-region precision of a trained `background`-family model goes (session 17), on the GPU machine:
#   bash benchmarks/real_captures/shell_diag.sh SCENE RUN [RADIUS]
# For the mesh `extract` made (RUN/mesh_tetra.ply) and for two finer grids of the same model (octree x0.25 and the
# Delaunay grid): `evaluate --scene` on the whole seen region and seen_offsurface.py (false surface by nearest GT part,
# the shell's radial offsets); then the field along radial lines through the shell (shell_profile.py). Results in
# $OUT/shell_diag/. Steps already done are skipped.
set -u
scene=$1; run=$2; radius=${3:-6}
R=$OUT/shell_diag; mkdir -p "$R"
[ -f "$run/mesh_tetra.ply" ] || python3 -m gof_warp.extract "$run" --quiet --no-pictures
for v in default cf025 delaunay; do
  mesh=$run/mesh_$v.ply
  case $v in
    default) mesh=$run/mesh_tetra.ply ;;
    cf025) [ -f "$mesh" ] || python3 -m gof_warp.extract "$run" --cell-factor 0.25 --out "$mesh" --quiet --no-pictures ;;
    delaunay) [ -f "$mesh" ] || python3 -m gof_warp.extract "$run" --grid delaunay --out "$mesh" --quiet --no-pictures ;;
  esac
  [ -f "${mesh%.ply}.json" ] && cp "${mesh%.ply}.json" "$R/extract_$v.json"
  python3 -m gof_warp.evaluate --mesh "$mesh" --gt "$scene/gt_mesh.ply" --scene "$scene" --json "$R/evaluate_seen_$v.json" \
    > /dev/null 2>&1 || echo "evaluate $v failed"
  python3 benchmarks/real_captures/seen_offsurface.py "$mesh" "$scene" --shell-radius "$radius" \
    --out "$R/offsurface_$v.json" > "$R/offsurface_$v.log" 2>&1 || { echo "offsurface $v failed"; tail -5 "$R/offsurface_$v.log"; }
done
python3 benchmarks/real_captures/shell_profile.py "$run" "$scene" --radius "$radius" --device cuda:0 \
  --out "$R/shell_profile.json" > /dev/null 2>&1 || echo "shell_profile failed"
python3 - "$R" <<'PY'
import json, sys
from pathlib import Path
R = Path(sys.argv[1])
for v in ("default", "cf025", "delaunay"):
    try:
        e = json.loads((R / f"evaluate_seen_{v}.json").read_text())["metrics"]
        o = json.loads((R / f"offsurface_{v}.json").read_text())
        x = json.loads((R / f"extract_{v}.json").read_text()) if (R / f"extract_{v}.json").is_file() else {}
    except (OSError, KeyError, ValueError) as err:
        print(v, "missing", err); continue
    faces = sum(m["faces"] for m in x.get("meshes", [])) or None
    print(v, "faces", faces, "F", [round(f, 4) for f in e["fscore"]], "P", [round(f, 4) for f in e["precision"]],
          "R", [round(f, 4) for f in e["recall"]], {k: (p["pred_area"], p["off_area"]) for k, p in o["parts"].items()},
          o.get("shell_offset", {}).get("area"), o.get("shell_missing"))
p = R / "shell_profile.json"
print(p.read_text() if p.is_file() else "no profile")
PY
