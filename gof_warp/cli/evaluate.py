"""``python -m gof_warp.evaluate``: score a reconstructed mesh against a ground-truth mesh or point cloud.

    python -m gof_warp.evaluate --mesh MESH.ply --gt GT.ply [--tau T ...] [--density D] [--max-dist M]
        [--crop xmin ymin zmin xmax ymax zmax] [--method points|triangles] [--truncate exclude|clamp]
        [--scene SCENE_DIR [--patch P] [--supersample S] [--min-views K]] [--json OUT.json]
    python -m gof_warp.evaluate --mesh MESH.glb --photos RUN [--split test|train]   # a coloured/textured mesh

Prints accuracy, completeness, Chamfer, precision/recall/F-score at each tau and both meshes'
statistics; ``--json`` writes the same (atomically). With ``--scene`` (a folder with
``transforms_train.json``, and for synthetic scenes ``scene.json``) the scores are taken on the region the
training cameras observe, sampled inside it, with the exact-vs-exact floor beside them and, when
``scene.json`` records a ground plane, the ground patch completeness and flatness
(:mod:`gof_warp.eval.region_metrics`; JSON keys ``region``, ``floor``, ``ground`` beside ``metrics``; ``--crop``
then sets the box of interest). Defaults relative to the GT's bounding-box
diagonal: tau = 0.5% and 1%, max-dist = 5%, density (sample spacing) for ~300k GT samples. The
definitions are in :mod:`gof_warp.eval.geometry_metrics`. With ``--photos RUN`` the mesh is rendered in its own
colours or texture from the run's test (``--split``) views and scored against their photos beside the Gaussians'
render (:mod:`gof_warp.viz.photo_fidelity`; JSON key ``photometric``); ``--gt`` is then optional. Rendering metrics of a trained run:
:func:`image_metrics` (from :mod:`gof_warp.eval.image_metrics`). Bad input: ``error: ...`` on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys

import numpy as np

from .common import HelpFormatter, run_command
from ..core.errors import GofError
from ..eval.geometry_metrics import evaluate_mesh, load_geometry
from ..eval.region_metrics import PATCH_SIZE, evaluate_region
from ..core.io_utils import write_json_atomic

__all__ = ["format_report", "image_metrics", "main", "tau_diagonal", "tau_fractions"]


def __getattr__(name):
    """``image_metrics`` (the trainer's test-view evaluation) is re-exported lazily: the mesh CLI needs no torch."""
    if name == "image_metrics":
        from ..eval.image_metrics import image_metrics

        return image_metrics
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


DESCRIPTION = ("Score a reconstructed mesh against a ground-truth mesh or point cloud, and a coloured or textured mesh "
               "against a run's photos.")
EPILOG = """\
Prints both meshes' statistics, accuracy, completeness and Chamfer distance, and a table of
precision, recall and F-score at each tau (also given as a fraction of the diagonal). --json
writes the same results to a file.

Defaults are relative to the diagonal of the ground truth's bounding box: tau = 0.5 % and 1 %,
max-dist = 5 %, and a sample spacing that puts about 300,000 samples on the ground truth.

With --scene (a folder with transforms_train.json, and for synthetic scenes scene.json) the scores
are taken on the region the training cameras observe, with the exact-vs-exact floor (the ground
truth scored against itself) beside each score; the diagonal is then that of the seen ground
truth, and --crop sets the box of interest. When scene.json records a ground plane, the ground's
patch completeness and flatness are printed too.

With --photos RUN (a training run folder) the mesh is rendered in its own colours or texture
(extract --color photos / --texture; no view dependence) from the run's held-out views and
scored against their photos: PSNR and SSIM over the whole image and over the pixels the mesh
covers, beside the Gaussians' render of the same views. --gt is then optional.

Bad input: "error: ..." on stderr, exit code 2."""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gof_warp.evaluate", description=DESCRIPTION, epilog=EPILOG,
                                formatter_class=HelpFormatter)
    p.add_argument("--mesh", required=True, help="reconstructed mesh (PLY, OBJ, ...)")
    p.add_argument("--gt", help="ground-truth mesh or point cloud (default: none; needed unless --photos is given)")
    p.add_argument("--photos", metavar="RUN",
                   help="a training run folder: render the mesh in its colours or texture from the run's views and "
                        "score it against their photos (PSNR, SSIM), beside the Gaussians' render (default: none)")
    p.add_argument("--split", choices=("test", "train"), default="test", help="with --photos: the views to score on")
    p.add_argument("--device", default="auto", help="with --photos: cpu, cuda, cuda:N or auto")
    p.add_argument("--tau", type=float, nargs="+",
                   help="F-score distance thresholds (default: 0.5 %% and 1 %% of the diagonal)")
    p.add_argument("--density", type=float,
                   help="surface sample spacing (default: the spacing that puts about 300,000 samples on the GT)")
    p.add_argument("--max-dist", type=float,
                   help="truncation distance: farther samples count as outliers (default: 5 %% of the diagonal)")
    p.add_argument("--crop", type=float, nargs=6, metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                   help="score only the samples inside this axis-aligned box (default: no box, every sample)")
    p.add_argument("--method", choices=("points", "triangles"), default="points",
                   help="distance to the nearest sample (DTU-style) or exact point-to-triangle distance")
    p.add_argument("--truncate", choices=("exclude", "clamp"), default="exclude",
                   help="distances >= max-dist: left out of the means (DTU) or clamped to max-dist")
    p.add_argument("--seed", type=int, default=0, help="surface sampling seed")
    p.add_argument("--scene",
                   help="scene folder (transforms_train.json, optionally scene.json): score only the region the "
                        "training cameras observe (default: none, score everything)")
    p.add_argument("--patch", type=float, default=PATCH_SIZE, help="with --scene: side of a ground patch")
    p.add_argument("--supersample", type=int, default=3,
                   help="with --scene: rays per pixel axis for deciding what the cameras see")
    p.add_argument("--min-views", type=int, default=1,
                   help="with --scene: score only what at least this many training cameras see (1: any camera)")
    p.add_argument("--json", metavar="OUT.json", help="also write the results to this JSON file (default: none)")
    return p


def _num(v) -> str:
    return "inf" if v is None else f"{v:.6g}"


def _percent(fraction) -> str:
    """``0.005`` -> ``0.50 %`` (two significant digits below 0.01 %); ``-`` for None."""
    if fraction is None:
        return "-"
    pct = 100.0 * fraction
    return f"{pct:.2f} %" if pct >= 0.01 or pct == 0 else f"{pct:.2g} %"


def _table(rows: list[list[str]], align: str = "l", indent: str = "") -> list[str]:
    """Rows of cells as aligned lines, two spaces apart; ``align[i]`` is column i's ``l`` (left) or ``r`` (right),
    its last letter applies to the remaining columns."""
    ncol = max(map(len, rows))
    align = align.ljust(ncol, align[-1] if len(align) > 1 else "r")
    widths = [max(len(r[i]) for r in rows if i < len(r)) for i in range(ncol)]
    return [indent + "  ".join(c.ljust(w) if align[i] == "l" else c.rjust(w)
                               for i, (c, w) in enumerate(zip(r, widths))).rstrip() for r in rows]


def _cell(v) -> str:
    return _num(v) if isinstance(v, float) else str(v)


def tau_diagonal(report: dict) -> tuple[float, str]:
    """The length the default taus are fractions of, and what it is the diagonal of: the seen GT's bounding box
    for a region score (``region.diagonal``), else the GT's bounding box (``gt_stats.bbox_diagonal``, the
    diagonal of :func:`~gof_warp.eval.geometry_metrics.default_eval_params`)."""
    if report.get("region"):
        return report["region"]["diagonal"], report["region"]["diagonal_of"]
    return report["gt_stats"]["bbox_diagonal"], "bounding box of the GT"


def tau_fractions(report: dict) -> list[float | None]:
    """Each tau of ``report["metrics"]`` divided by :func:`tau_diagonal` (None where the diagonal is 0)."""
    diag = tau_diagonal(report)[0]
    return [t / diag if diag else None for t in report["metrics"]["tau"]]


def format_report(report: dict) -> str:
    """The human-readable form of an :func:`~gof_warp.eval.geometry_metrics.evaluate_mesh` (or
    :func:`~gof_warp.eval.region_metrics.evaluate_region`) result: the meshes' statistics and the
    tau-independent scores as aligned key-value blocks, then one row per tau (with tau as a fraction of
    :func:`tau_diagonal`); with a region score the exact-vs-exact floor is a column beside each score."""
    m = report["metrics"]
    fl = report["floor"]["metrics"] if report.get("floor") else None
    diag, diag_of = tau_diagonal(report)
    ms, gs = report["mesh_stats"], report["gt_stats"]
    lines = _table([["mesh", str(report["mesh"])], ["gt", str(report["gt"])]], align="ll")
    keys = ("vertices", "faces", "connected_components", "watertight", "boundary_edges", "non_manifold_edges",
            "degenerate_faces", "area")
    lines += [""] + _table([["", "mesh", "gt"]] + [[k, _cell(ms[k]), _cell(gs[k])] for k in keys])
    rg = report.get("region")
    if rg:
        lines += ["", f"region: seen GT area {rg['gt_seen_area']:.4g} of {rg['gt_area']:.4g}, scored GT "
                  f"{rg['gt_scored_area']:.4g}, mesh {rg['pred_scored_area']:.4g} of {rg['pred_area']:.4g}"
                  + (f"; seen by at least {rg['min_views']} views" if rg.get("min_views", 1) > 1 else "")]
    lines += [""] + _table([
        ["diagonal", _num(diag), f"({diag_of})"],
        ["density", _num(m["density"]), "(sample spacing)"],
        ["max_dist", _num(m["max_dist"]), f"({m['truncate']})"],
        ["method", m["method"]],
        ["samples scored", f"mesh {m['num_pred_samples']}, gt {m['num_gt_samples']}"]], align="lrl")

    def score_rows(rows):  # [name, key, formatter]: the score, and with a region the floor beside it
        return [[name, fmt(m[key])] + ([fmt(fl[key])] if fl else []) for name, key, fmt in rows]

    lines += [""] + _table([["", "score"] + (["floor"] if fl else [])] + score_rows([
        ["accuracy", "accuracy", _num], ["accuracy median", "accuracy_median", _num],
        ["completeness", "completeness", _num], ["completeness median", "completeness_median", _num],
        ["chamfer", "chamfer", _num],
        ["mesh samples >= max_dist", "pred_outlier_fraction", _percent],
        ["gt samples >= max_dist", "gt_outlier_fraction", _percent]]))
    floor = ["floor"] if fl else []
    rows = [["tau", "tau / diagonal", "precision", *floor, "recall", *floor, "F-score", *floor]]
    for i, (t, frac) in enumerate(zip(m["tau"], tau_fractions(report))):
        row = [_num(t), _percent(frac)]
        for key in ("precision", "recall", "fscore"):
            row += [f"{m[key][i]:.4f}"] + ([f"{fl[key][i]:.4f}"] if fl else [])
        rows.append(row)
    lines += [""] + _table(rows, align="r")
    g = report.get("ground")
    if g:
        gf = report["floor"]["ground"]
        lines += ["", f"ground (z = {g['height']:.4g}, {g['patches']} patches of {g['patch']:.3g}, "
                  f"tolerance {_num(g['tau'])}):"]
        lines += _table([["", "score", "floor"]] + [
            [k, _num(g[k]) if g[k] is not None else "-", _num(gf[k]) if gf[k] is not None else "-"]
            for k in ("worst_patch_completeness", "patches_over_limit", "ground_completeness", "flat_fraction",
                      "height_error_p95")], indent="  ")
        lines.append(f"  targets: no patch > {g['missing_limit']:.0%} missing: {g['patch_target_met']}; "
                     f"{g['flat_target']:.0%} within {_num(g['flat_tolerance'])}: {g['flat_target_met']}")
    return "\n".join(lines)


def check_args(args: argparse.Namespace) -> None:
    """The options' values, before any file is read: a value that means nothing is a :class:`GofError` naming its
    flag."""
    for t in args.tau or ():
        if not (math.isfinite(t) and t > 0):
            raise GofError(f"--tau must be distances > 0, got {t:g}")
    if args.density is not None and not (math.isfinite(args.density) and args.density > 0):
        raise GofError(f"--density (sample spacing) must be a distance > 0, got {args.density:g}")
    if args.max_dist is not None and not args.max_dist > 0:  # inf: no truncation
        raise GofError(f"--max-dist must be a distance > 0 (inf: none), got {args.max_dist:g}")
    if args.crop is not None:
        lo, hi = args.crop[:3], args.crop[3:]
        if not all(math.isfinite(x) for x in args.crop) or any(a > b for a, b in zip(lo, hi)):
            raise GofError(f"--crop must be finite XMIN YMIN ZMIN XMAX YMAX ZMAX with each min <= max, got "
                           f"{' '.join(f'{x:g}' for x in args.crop)}")
    if not (math.isfinite(args.patch) and args.patch > 0):
        raise GofError(f"--patch must be a length > 0, got {args.patch:g}")
    if args.supersample < 1:
        raise GofError(f"--supersample must be an integer >= 1, got {args.supersample}")
    if args.min_views < 1:
        raise GofError(f"--min-views must be an integer >= 1, got {args.min_views}")
    if args.min_views != 1 and not args.scene:
        raise GofError("--min-views needs --scene (the training cameras decide what is seen)")


def load_inputs(mesh_path, gt_path):
    """The reconstruction (a mesh: it must have faces) and the ground truth (a mesh or a point cloud: it must have
    points), both with finite vertices, else a :class:`GofError` naming the file."""
    loaded = []
    for flag, path in (("--mesh", mesh_path), ("--gt", gt_path)):
        geom = load_geometry(path)
        v = np.asarray(geom.vertices)
        if len(v) and not np.isfinite(v).all():
            raise GofError(f"{flag} {path} has {int((~np.isfinite(v).all(axis=1)).sum())} vertices with NaN/inf "
                           "coordinates")
        loaded.append(geom)
    mesh, gt = loaded
    if len(getattr(mesh, "faces", ())) == 0:
        raise GofError(f"--mesh {mesh_path} has no faces: the reconstruction must be a triangle mesh")
    if len(gt.vertices) == 0:
        raise GofError(f"--gt {gt_path} has no faces and no points: nothing to score against")
    return mesh, gt


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")

    def body():
        crop = None if args.crop is None else (args.crop[:3], args.crop[3:])
        check_args(args)
        if not args.gt and not args.photos:
            raise GofError("nothing to score against: give --gt (a ground-truth mesh or point cloud) and/or --photos "
                           "RUN (the run's photos)")
        photo_report = None
        if args.photos:
            from ..viz.photo_fidelity import format_photo_report, mesh_photo_fidelity

            photo_report = mesh_photo_fidelity(args.photos, args.mesh, split=args.split, device=args.device)
            print(format_photo_report(photo_report))
        if not args.gt:
            if args.json:
                write_json_atomic(args.json, {"mesh": str(args.mesh), "photometric": photo_report})
                print(f"\nwrote {args.json}")
            return
        mesh, gt = load_inputs(args.mesh, args.gt)
        if args.scene:
            report = evaluate_region(mesh, gt, args.scene, tau=args.tau, density=args.density,
                                     max_dist=args.max_dist, bbox=crop, truncate=args.truncate, seed=args.seed,
                                     patch=args.patch, supersample=args.supersample,
                                     min_views=args.min_views)
        else:
            report = evaluate_mesh(mesh, gt, tau=args.tau, density=args.density, max_dist=args.max_dist,
                                   crop=crop, truncate=args.truncate, method=args.method, seed=args.seed)
        report["mesh"], report["gt"] = str(args.mesh), str(args.gt)
        report["metrics"]["tau_fraction_of_diagonal"] = tau_fractions(report)
        if photo_report is not None:
            report["photometric"] = photo_report
            print()
        print(format_report(report))
        if args.json:
            write_json_atomic(args.json, report)
            print(f"\nwrote {args.json}")

    return run_command(body)


if __name__ == "__main__":
    sys.exit(main())
