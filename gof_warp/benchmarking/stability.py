"""Where each extraction method breaks: degenerate models and hard scenes, one report per (case, method).

Every case builds a model and cameras, then runs render (every view), the opacity field (at the
Gaussian centres and a grid) and each extraction method, and reports per method:

* ``outcome``: ``"ok"``, ``"error"`` (a clear :class:`~gof_warp.core.errors.GofError`: acceptable) or
  ``"crash"`` (any other exception: a bug), with the message;
* ``nan_inf``: any non-finite value in the render outputs, the field or the mesh;
* ``faces``, ``components`` (floaters/fragmentation), the mesh's bounding box, ``faces_far`` (faces
  beyond ``far_radius``, e.g. Gaussians far outside the cameras leaking into the mesh);
* for trained synthetic presets: completeness, F-score and Chamfer against the exact mesh (holes).

Bad inputs (broken scene folders, Gaussian PLYs, settings) are tried through the commands themselves by
:mod:`gof_warp.benchmarking.stability_inputs`; ``stability.json``'s ``summary`` counts, per kind tried, the clear errors,
warnings, crashes and NaN/inf.

Hand-made cases (no training, seconds; run in CI): a good blob of Gaussians on a sphere, and that blob
with degenerate Gaussians mixed in (scales 1e-8, 1e3, flat 1e-7), all opacities 0 or 1, Gaussians far
outside every camera's frustum, Gaussians far away but in view (occluded by the blob from the other side),
and an empty half-space the cameras look at. Trained cases (minutes on a CPU):
the ``thin``, ``background``, ``garden``, ``sparse`` and ``textureless`` presets, trained briefly.
"""

from __future__ import annotations

import logging
import math
import traceback
from pathlib import Path

import numpy as np
import torch

from ..core.errors import GofError
from .stability_scenes import BLOB_RADIUS, CAMERA_DISTANCE, _blob, ring_cameras  # noqa: F401 - public here too

log = logging.getLogger(__name__)

FAR_RADIUS = 2.0  # the blob (stability_scenes.BLOB_RADIUS 0.5) gives no mesh face beyond this (cameras sit at 2.5)
STABILITY_METHODS = ("tetra", "cubes", "tsdf")
TRAINED_PRESETS = ("thin", "background", "garden", "sparse", "textureless")


# ----------------------------------------------------------------------------------------- hand-made cases
def _with_extra(means, scales, opacities=None, n_blob: int = 300):
    """The blob plus extra Gaussians (identity rotation, opacity 0.9 unless given)."""
    bm, bq, bs, bo = _blob(n_blob)
    m = np.asarray(means, float).reshape(-1, 3)
    k = len(m)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (k, 1))
    s = np.broadcast_to(np.asarray(scales, float), (k, 3))
    o = np.full(k, 0.9) if opacities is None else np.broadcast_to(opacities, (k,))
    return np.concatenate([bm, m]), np.concatenate([bq, q]), np.concatenate([bs, s]), np.concatenate([bo, o])


def _case_arrays(name: str):
    rng = np.random.default_rng(1)

    def inner(k):  # inside the blob, seen by every camera
        return rng.uniform(-0.3, 0.3, size=(k, 3))

    if name == "good":
        return _blob()
    if name == "tiny_scales":
        return _with_extra(inner(50), 1e-8)
    if name == "huge_scales":
        return _with_extra(inner(3), 1e3, 0.05)
    if name == "flat_scales":
        return _with_extra(inner(50), (0.05, 0.05, 1e-7))
    if name == "opacity_0":
        m, q, s, _ = _blob()
        return m, q, s, np.zeros(len(m))
    if name == "opacity_1":
        m, q, s, _ = _blob()
        return m, q, s, np.ones(len(m))
    if name == "far_outside":  # far above/below the scene, outside every camera's frustum (they look within ±65°)
        d = np.concatenate([rng.normal(scale=0.1, size=(40, 2)), rng.choice([-1.0, 1.0], size=(40, 1))], 1)
        return _with_extra(1e3 * d / np.linalg.norm(d, axis=1, keepdims=True), 0.5)
    if name == "far_in_view":  # far away in every direction: some views see them (behind the blob from others)
        d = rng.normal(size=(40, 3))
        return _with_extra(1e3 * d / np.linalg.norm(d, axis=1, keepdims=True), 0.5)
    if name == "empty_region":  # only the half x > 0 of the blob: the cameras on the -x side see empty space
        m, q, s, o = _blob()
        keep = m[:, 0] > 0.05
        return m[keep], q[keep], s[keep], o[keep]
    raise GofError(f"unknown stability case {name!r}; cases: {', '.join(CASES)}")


CASES = ("good", "tiny_scales", "huge_scales", "flat_scales", "opacity_0", "opacity_1", "far_outside", "far_in_view",
         "empty_region")


def make_case(name: str, device: str = "cpu"):
    """``(gaussians, cameras)`` of a hand-made case (see :data:`CASES`)."""
    from ..core.model import Gaussians

    m, q, s, o = _case_arrays(name)
    colours = np.random.default_rng(2).uniform(0.2, 0.9, size=(len(m), 3))
    return Gaussians.from_activated(m, q, s, o, colours, device=device), ring_cameras()


# ----------------------------------------------------------------------------------------- probes
def _nonfinite(*tensors) -> bool:
    return any(not bool(torch.isfinite(torch.as_tensor(t)).all()) for t in tensors if t is not None)


def _probe(fn):
    """``(result, outcome, message)``: run ``fn``, classifying a failure as a clear error or a crash."""
    try:
        return fn(), "ok", None
    except GofError as e:
        return None, "error", str(e)
    except Exception as e:  # noqa: BLE001 — the point is to catch and report what breaks
        log.debug("crash: %s", traceback.format_exc())
        return None, "crash", f"{type(e).__name__}: {e}"


def probe_render_and_field(gaussians, cameras, render_config=None) -> dict:
    """Render every view and evaluate the opacity field at the centres and on a grid; NaN/inf and crashes."""
    from ..rendering.opacity_field import opacity_field
    from ..rendering.render import render

    def go():
        bad = False
        for cam in cameras:
            out = render(gaussians, cam, config=render_config)
            bad |= _nonfinite(*(v for v in out.values() if torch.is_tensor(v)))
        g = np.linspace(-1.0, 1.0, 9)
        grid = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
        pts = np.concatenate([gaussians.means.detach().cpu().numpy(), grid])
        f = opacity_field(gaussians, cameras, pts, render_config=render_config)
        bad |= _nonfinite(f) or bool(((f < 0) | (f > 1)).any())
        return bad

    bad, outcome, msg = _probe(go)
    return {"outcome": outcome, "message": msg, "nan_inf": bool(bad)}


def probe_extraction(gaussians, cameras, method: str, *, render_config=None, views=None, gt=None, eval_kw=None,
                     far_radius: float | None = FAR_RADIUS) -> dict:
    """Extract with ``method`` (cheap settings) and describe the mesh; scored against ``gt`` when given.
    ``faces_far`` counts faces beyond ``far_radius`` from the origin (``None``: not counted)."""
    from ..mesh.extraction import MeshConfig, extract_mesh
    from ..eval.geometry_metrics import evaluate_mesh, mesh_statistics

    cfg = MeshConfig(method=method, binary_steps=2, cubes_resolution=32)
    cfg.tsdf.resolution = 48

    def go():
        return extract_mesh(gaussians, cameras, cfg, render_config=render_config, views=views)[0]

    mesh, outcome, msg = _probe(go)
    report = {"method": method, "outcome": outcome, "message": msg, "nan_inf": False, "faces": 0, "components": 0,
              "faces_far": 0, "bbox_min": None, "bbox_max": None}
    if mesh is None:
        return report
    v, f = mesh
    st = mesh_statistics((v, f))
    far = np.linalg.norm(v, axis=1) > (far_radius or np.inf)
    report.update(nan_inf=_nonfinite(v), faces=st["faces"], components=st["connected_components"],
                  faces_far=None if far_radius is None else int(far[f].any(axis=1).sum()) if len(f) else 0,
                  bbox_min=st["bbox_min"] if len(f) else None, bbox_max=st["bbox_max"] if len(f) else None)
    if gt is not None:
        m = evaluate_mesh((v, f), gt, **(eval_kw or {}))["metrics"]
        report.update(chamfer=m["chamfer"], completeness=m["completeness"], accuracy=m["accuracy"],
                      fscore=m["fscore"][0], recall=m["recall"][0])
    return report


def _failed(case: str, methods, outcome: str, message: str) -> list[dict]:
    return [{"case": case, "method": m, "outcome": outcome, "message": message, "nan_inf": False} for m in methods]


def _method_reports(case: str, gaussians, cameras, methods, **extract_kw) -> list[dict]:
    """The render/field probe, then one extraction report per method with the probe's result folded in."""
    field = probe_render_and_field(gaussians, cameras, extract_kw.get("render_config"))
    reports = []
    for m in methods:
        r = probe_extraction(gaussians, cameras, m, **extract_kw)
        if field["outcome"] != "ok" and r["outcome"] == "ok":
            r.update(outcome=field["outcome"], message=f"render/opacity field: {field['message']}")
        r.update(case=case, num_gaussians=len(gaussians), nan_inf=r["nan_inf"] or field["nan_inf"])
        reports.append(r)
    return reports


def run_case(name: str, device: str = "cpu", methods=STABILITY_METHODS) -> list[dict]:
    """Reports for one hand-made case (see :data:`CASES`), one per method."""
    model, outcome, msg = _probe(lambda: make_case(name, device))
    if model is None:
        return _failed(name, methods, outcome, f"building the case: {msg}")
    return _method_reports(name, *model, methods)


def trained_run(preset: str):
    """The :class:`~gof_warp.benchmarking.runs.Run` of a trained case: ``preset`` at 40×40, the bench's ``tiny``
    schedule (200 iterations, at most 2,000 Gaussians) and the preset's own overrides (checked on definition)."""
    from .runs import Run, _merge, preset_overrides, scaled_schedule

    return Run(f"stability_{preset}", preset, (40, 40), None,
               overrides=_merge(scaled_schedule(200, 2000, 1000), preset_overrides(preset)))


def run_trained_case(preset: str, out: Path, device: str = "cpu", methods=STABILITY_METHODS) -> list[dict]:
    """A synthetic preset trained briefly (:func:`trained_run`), every method scored against its GT."""
    from .runs import _train_or_load
    from ..eval.geometry_metrics import load_geometry

    run = trained_run(preset)
    trained, outcome, msg = _probe(lambda: _train_or_load(run, out / run.name, device))
    if trained is None:
        return _failed(preset, methods, outcome, f"training: {msg}")
    gaussians, scene, render_config, _, scene_dir = trained
    gt = load_geometry(scene_dir / "gt_mesh.ply")
    return _method_reports(preset, gaussians, scene.train_cameras, methods, render_config=render_config,
                           views=scene.train, gt=gt, eval_kw={"density": math.sqrt(float(gt.area) / 30_000)},
                           far_radius=None)  # the scenes have their own extents; holes and floaters are the GT scores


def run_stability(out, device: str = "cpu", trained: bool = True) -> list[dict]:
    """Every hand-made case, the bad-input cases (:mod:`gof_warp.benchmarking.stability_inputs`) and, when ``trained``, the
    trained presets. Writes ``out/stability.json``: ``reports`` (model cases × methods), ``inputs`` and
    ``summary`` (counts per kind tried: ok, clear errors, warnings, crashes, NaN/inf). Returns the model
    and input reports together (each has ``case``, ``method``, ``outcome``)."""
    from ..core.io_utils import ensure_writable_dir, write_json_atomic
    from .stability_inputs import run_input_cases, summarise

    out = ensure_writable_dir(out)
    reports = [r for c in CASES for r in run_case(c, device)]
    inputs = run_input_cases(out)

    def save():
        write_json_atomic(out / "stability.json", {"summary": summarise(reports, inputs), "reports": reports,
                                                   "inputs": inputs})

    if trained:
        for preset in TRAINED_PRESETS:
            reports += run_trained_case(preset, out, device)
            save()
    save()
    for r in reports:
        log.info("%-14s %-6s %-5s faces %6s components %4s far %4s%s", r["case"], r["method"], r["outcome"],
                 r.get("faces"), r.get("components"), r.get("faces_far"),
                 f"  F {r['fscore']:.3f}" if r.get("fscore") is not None else "")
    for r in inputs:
        log.info("%-24s %-7s %-7s%s %s", r["case"], r["kind"], r["outcome"],
                 "" if r["as_expected"] else " (UNEXPECTED)", r["message"])
    for kind, c in summarise(reports, inputs).items():
        log.info("%-6s %s", kind, ", ".join(f"{k} {v}" for k, v in c.items()))
    return reports + inputs
