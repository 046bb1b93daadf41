"""``python -m gof_warp.evaluate``: score a reconstructed mesh against a ground-truth mesh or point cloud.

    python -m gof_warp.evaluate --mesh MESH.ply --gt GT.ply [--tau T ...] [--density D] [--max-dist M]
        [--crop xmin ymin zmin xmax ymax zmax] [--method points|triangles] [--truncate exclude|clamp]
        [--scene SCENE_DIR [--patch P] [--supersample S] [--min-views K]] [--json OUT.json]

Prints accuracy, completeness, Chamfer, precision/recall/F-score at each tau and both meshes'
statistics; ``--json`` writes the same (atomically). With ``--scene`` (a folder with
``transforms_train.json``, and for synthetic scenes ``scene.json``) the scores are taken on the region the
training cameras observe, sampled inside it, with the exact-vs-exact floor beside them and, when
``scene.json`` records a ground plane, the ground patch completeness and flatness
(:mod:`gof_warp.region_metrics`; JSON keys ``region``, ``floor``, ``ground`` beside ``metrics``; ``--crop``
then sets the box of interest). Defaults relative to the GT's bounding-box
diagonal: tau = 0.5% and 1%, max-dist = 5%, density (sample spacing) for ~300k GT samples. The
definitions are in :mod:`gof_warp.geometry_metrics`. Rendering metrics of a trained run:
:func:`image_metrics` (from :mod:`gof_warp.metrics`). Bad input: ``error: ...`` on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import logging
import sys

from .common import run_command
from ..core.errors import GofError
from ..eval.geometry_metrics import evaluate_mesh
from ..eval.region_metrics import PATCH_SIZE, evaluate_region
from ..core.io_utils import write_json_atomic

__all__ = ["format_report", "image_metrics", "main"]


def __getattr__(name):
    """``image_metrics`` (the trainer's test-view evaluation) is re-exported lazily: the mesh CLI needs no torch."""
    if name == "image_metrics":
        from ..eval.image_metrics import image_metrics

        return image_metrics
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gof_warp.evaluate", description=__doc__.split("\n")[0])
    p.add_argument("--mesh", required=True, help="reconstructed mesh (PLY/OBJ/...)")
    p.add_argument("--gt", required=True, help="ground-truth mesh or point cloud")
    p.add_argument("--tau", type=float, nargs="+", help="F-score thresholds (default: 0.5%% and 1%% of the GT diagonal)")
    p.add_argument("--density", type=float, help="surface sample spacing (default: ~300k samples on the GT)")
    p.add_argument("--max-dist", type=float, help="truncation distance (default: 5%% of the GT diagonal)")
    p.add_argument("--crop", type=float, nargs=6, metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                   help="score only samples inside this axis-aligned box")
    p.add_argument("--method", choices=("points", "triangles"), default="points",
                   help="nearest sample (DTU-style, default) or exact point-to-triangle distances")
    p.add_argument("--truncate", choices=("exclude", "clamp"), default="exclude",
                   help="drop distances >= max-dist from the means (DTU, default) or clamp them")
    p.add_argument("--seed", type=int, default=0, help="sampling seed")
    p.add_argument("--scene", help="scene folder (transforms_train.json [+ scene.json]): score the observed region")
    p.add_argument("--patch", type=float, default=PATCH_SIZE, help="ground patch side (with --scene; default 0.1)")
    p.add_argument("--supersample", type=int, default=3, help="rays per pixel axis for the seen test (--scene)")
    p.add_argument("--min-views", type=int, default=1,
                   help="with --scene: score only what at least this many training cameras see (default 1: any)")
    p.add_argument("--json", help="write the results to this JSON file")
    return p


def _num(v) -> str:
    return "inf" if v is None else f"{v:.6g}"


def format_report(report: dict) -> str:
    """The human-readable table of an :func:`~gof_warp.geometry_metrics.evaluate_mesh` result."""
    m = report["metrics"]
    lines = [f"mesh: {report['mesh']}", f"gt:   {report['gt']}",
             f"density {_num(m['density'])}  max_dist {_num(m['max_dist'])} ({m['truncate']})  method {m['method']}",
             f"samples scored: mesh {m['num_pred_samples']}, gt {m['num_gt_samples']}", "",
             f"{'':14s}{'mean':>12s}{'median':>12s}{'outliers':>10s}",
             f"{'accuracy':14s}{_num(m['accuracy']):>12s}{_num(m['accuracy_median']):>12s}{m['pred_outlier_fraction']:>10.2%}",
             f"{'completeness':14s}{_num(m['completeness']):>12s}{_num(m['completeness_median']):>12s}{m['gt_outlier_fraction']:>10.2%}",
             f"{'chamfer':14s}{_num(m['chamfer']):>12s}", "",
             f"{'tau':>12s}{'precision':>11s}{'recall':>9s}{'F-score':>9s}"]
    lines += [f"{_num(t):>12s}{p:>11.4f}{r:>9.4f}{f:>9.4f}" for t, p, r, f in zip(m["tau"], m["precision"], m["recall"], m["fscore"])]
    if report.get("floor"):
        fl, rg = report["floor"]["metrics"], report["region"]
        lines += ["", f"region: seen GT area {rg['gt_seen_area']:.4g} of {rg['gt_area']:.4g}, scored GT {rg['gt_scored_area']:.4g}, "
                  f"mesh {rg['pred_scored_area']:.4g} of {rg['pred_area']:.4g}; diagonal {rg['diagonal']:.4g} ({rg['diagonal_of']})"
                  + (f"; seen by at least {rg['min_views']} views" if rg.get("min_views", 1) > 1 else ""),
                  f"{'':14s}{'score':>12s}{'floor':>12s}"]
        lines += [f"{k:14s}{_num(m[k]):>12s}{_num(fl[k]):>12s}" for k in ("accuracy", "completeness", "chamfer")]
        lines += [f"{'F@' + _num(t):14s}{f:>12.4f}{g:>12.4f}" for t, f, g in zip(m["tau"], m["fscore"], fl["fscore"])]
    g = report.get("ground")
    if g:
        gf = report["floor"]["ground"]
        lines += ["", f"ground (z = {g['height']:.4g}, {g['patches']} patches of {g['patch']:.3g}, tolerance {_num(g['tau'])}):"
                  f"{'':2s}score / floor"]
        for k in ("worst_patch_completeness", "patches_over_limit", "ground_completeness", "flat_fraction",
                  "height_error_p95"):
            lines.append(f"  {k:26s}{_num(g[k]) if g[k] is not None else '-':>12s}{_num(gf[k]) if gf[k] is not None else '-':>12s}")
        lines.append(f"  targets: no patch > {g['missing_limit']:.0%} missing: {g['patch_target_met']}; "
                     f"{g['flat_target']:.0%} within {_num(g['flat_tolerance'])}: {g['flat_target_met']}")
    keys = ("vertices", "faces", "connected_components", "watertight", "boundary_edges", "non_manifold_edges",
            "degenerate_faces", "area")
    lines += ["", f"{'':22s}{'mesh':>14s}{'gt':>14s}"]
    lines += [f"{k:22s}{report['mesh_stats'][k]!s:>14.14s}{report['gt_stats'][k]!s:>14.14s}" for k in keys]
    return "\n".join(lines)


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")

    def body():
        crop = None if args.crop is None else (args.crop[:3], args.crop[3:])
        if args.min_views != 1 and not args.scene:
            raise GofError("--min-views needs --scene (the training cameras decide what is seen)")
        if args.scene:
            report = evaluate_region(args.mesh, args.gt, args.scene, tau=args.tau, density=args.density,
                                     max_dist=args.max_dist, bbox=crop, truncate=args.truncate, seed=args.seed,
                                     patch=args.patch, supersample=args.supersample,
                                     min_views=args.min_views)
        else:
            report = evaluate_mesh(args.mesh, args.gt, tau=args.tau, density=args.density, max_dist=args.max_dist,
                                   crop=crop, truncate=args.truncate, method=args.method, seed=args.seed)
        print(format_report(report))
        if args.json:
            write_json_atomic(args.json, report)
            print(f"\nwrote {args.json}")

    return run_command(body)


if __name__ == "__main__":
    sys.exit(main())
