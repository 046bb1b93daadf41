"""Accuracy against face count under quadric decimation (issue 11, "faces in proportion to detail").

Decimates one extracted mesh (``gof_warp.decimate.decimate``) to a list of face budgets, given as
fractions of its face count, and scores each against a ground-truth mesh with
``gof_warp.geometry_metrics.evaluate_mesh`` (default thresholds: τ = 0.5 % and 1 % of the GT diagonal;
the same seed for every budget, so differences are the decimation's). Writes JSON (per budget: faces,
decimation time, the decimation's own error — distance from the input's vertices to the result — and
Chamfer / F-score against GT) and a two-panel chart (Chamfer, F-score against faces), drawn with Pillow.

    python -m gof_warp.synthetic --preset default --out /tmp/s          # gt_mesh.ply
    python -m gof_warp.train ... && python -m gof_warp.extract RUN --binary-steps 4   # RUN/mesh_tetra.ply
    python benchmarks/extract/decimation_curve.py RUN/mesh_tetra.ply /tmp/s/gt_mesh.ply \\
        --machine "2-core CPU dev box" --out benchmarks/extract/results/decimation_default_cpu.json
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from gof_warp.curves import AXIS, BACKGROUND, GRID, PLOT_BACKGROUND, TEXT, Axes, _font, nice_ticks, tick_label
from gof_warp.decimate import decimate
from gof_warp.geometry_metrics import evaluate_mesh, load_geometry
from gof_warp.io_utils import write_json_atomic

FRACTIONS = (1.0, 0.5, 1 / 3, 0.25, 0.15, 0.10)
PANEL_W, PANEL_H = 380, 280
MARGIN = (62, 14, 26, 40)  # left, right, top, bottom


def run(mesh_path: Path, gt_path: Path, fractions, seed: int = 0) -> dict:
    import trimesh

    mesh = load_geometry(mesh_path)
    gt = load_geometry(gt_path)
    verts, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    rows = []
    for frac in fractions:
        budget = max(1, int(round(frac * len(faces))))
        t = time.perf_counter()
        v, f, info = decimate(verts, faces, max_faces=budget)
        wall = time.perf_counter() - t
        scores = evaluate_mesh(trimesh.Trimesh(v, f, process=False), gt, seed=seed)["metrics"]
        row = {"fraction": round(frac, 4), "budget": budget, "faces": len(f), "vertices": len(v),
               "decimate_s": round(wall, 3), "error_max": info["error_max"], "error_p95": info["error_p95"],
               "error_samples": info["error_samples"], "closed_after": info["closed_after"],
               "coincident_removed": info["coincident_removed"],
               "pinch_vertices_split": info["pinch_vertices_split"],
               "chamfer": scores["chamfer"], "accuracy": scores["accuracy"], "completeness": scores["completeness"],
               "tau": scores["tau"], "fscore": scores["fscore"], "precision": scores["precision"],
               "recall": scores["recall"]}
        rows.append(row)
        print(f"{frac:6.3f}  faces {len(f):8d}  {wall:6.2f} s  err max {info['error_max']:.4g} p95 "
              f"{info['error_p95']:.4g}  chamfer {scores['chamfer']:.5f}  F {[round(x, 4) for x in scores['fscore']]}",
              flush=True)
    # time per million faces of the decimation alone (no measurement), at the largest reduction
    budget = int(round(min(fractions) * len(faces)))
    t = time.perf_counter()
    import fast_simplification

    fast_simplification.simplify(verts, faces.astype(np.int32), target_count=budget)
    raw = time.perf_counter() - t
    return {"mesh": str(mesh_path), "gt": str(gt_path), "faces_input": int(len(faces)),
            "vertices_input": int(len(verts)), "closed_input": bool(rows[0]["closed_after"]),
            "decimate_only_s_per_mface": round(raw / len(faces) * 1e6, 3), "rows": rows}


def _panel(draw, left: int, title: str, xs, series, x_label: str, y_range=None) -> None:
    box = (left + MARGIN[0], MARGIN[2], left + PANEL_W - MARGIN[1], PANEL_H - MARGIN[3])
    x_lo, x_hi = 0.0, float(max(xs)) * 1.05
    ys = np.concatenate([np.asarray(s[1], float) for s in series])
    if y_range is None:
        lo, hi = float(ys.min()), float(ys.max())
        pad = 0.08 * (hi - lo) if hi > lo else 0.1 * abs(hi) + 1e-6
        y_range = (lo - pad, hi + pad)
    axes = Axes(box, (x_lo, x_hi), y_range)
    x0, y0, x1, y1 = box
    draw.text((x0, 6), title, fill=TEXT)
    draw.rectangle(box, fill=PLOT_BACKGROUND)
    for t in nice_ticks(*y_range):
        py = float(axes.to_pixel(x_lo, t)[1])
        draw.line([(x0, py), (x1, py)], fill=GRID)
        label = tick_label(t)
        draw.text((x0 - 5 - draw.textlength(label), py - 7), label, fill=TEXT)
    for t in nice_ticks(x_lo, x_hi, count=4):
        px = float(axes.to_pixel(t, y_range[0])[0])
        draw.line([(px, y0), (px, y1)], fill=GRID)
        label = tick_label(t)
        draw.text((px - draw.textlength(label) / 2, y1 + 4), label, fill=TEXT)
    draw.rectangle(box, outline=AXIS)
    draw.text(((x0 + x1) / 2 - draw.textlength(x_label) / 2, y1 + 20), x_label, fill=AXIS)
    for i, (name, values, colour) in enumerate(series):
        px, py = axes.to_pixel(xs, values)
        pts = [(float(a), float(b)) for a, b in zip(px, py)]
        draw.line(pts, fill=colour, width=2)
        for a, b in pts:
            draw.ellipse((a - 3, b - 3, a + 3, b + 3), fill=colour)
        draw.text((x0 + 8, y0 + 6 + 15 * i), name, fill=colour)


def chart(result: dict, path: Path) -> None:
    from PIL import Image, ImageDraw

    rows = result["rows"]
    xs = [r["faces"] for r in rows]
    img = Image.new("RGB", (2 * PANEL_W, PANEL_H), BACKGROUND)
    draw = ImageDraw.Draw(img)
    draw.font = _font()
    _panel(draw, 0, "Chamfer vs GT (lower is better)", xs,
           [("chamfer", [r["chamfer"] for r in rows], (255, 160, 60)),
            ("decimation error p95", [r["error_p95"] for r in rows], (180, 180, 180))], "faces")
    colours = [(80, 200, 255), (120, 220, 120), (230, 120, 200)]
    diag = result.get("gt_diagonal")
    series = []
    for k, tau in enumerate(rows[0]["tau"]):
        name = f"F-score tau={tau:.4g}" + (f" ({100 * tau / diag:.2g}% diag)" if diag else "")
        series.append((name, [r["fscore"][k] for r in rows], colours[k % len(colours)]))
    _panel(draw, PANEL_W, "F-score vs GT (higher is better)", xs, series, "faces")
    path.parent.mkdir(parents=True, exist_ok=True)
    img.save(path)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mesh", type=Path, help="the mesh to decimate (PLY)")
    ap.add_argument("gt", type=Path, help="the ground-truth mesh (PLY)")
    ap.add_argument("--fractions", type=float, nargs="+", default=list(FRACTIONS),
                    help="face budgets as fractions of the mesh's faces")
    ap.add_argument("--machine", default=platform.processor() or platform.machine())
    ap.add_argument("--note", default="", help="where the mesh came from")
    ap.add_argument("--out", type=Path, default=Path("decimation_curve.json"), help="JSON; the chart beside it (.png)")
    args = ap.parse_args(argv)
    from gof_warp.geometry_metrics import default_eval_params

    result = run(args.mesh, args.gt, args.fractions)
    result["gt_diagonal"] = default_eval_params(load_geometry(args.gt))["gt_diagonal"]
    result["machine"] = args.machine
    result["note"] = args.note
    write_json_atomic(args.out, result)
    chart(result, args.out.with_suffix(".png"))
    print(json.dumps({k: v for k, v in result.items() if k != "rows"}, indent=1))
    print(f"wrote {args.out} and {args.out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
