"""Ground probe: where the GOF opacity field's 0.5 level set meets vertical lines over a synthetic ground.

A diagnostic of the *field* (what any mesh extracted from it inherits), independent of tetrahedra and
marching: over the seen, unoccluded ground of a synthetic scene with a ground plane ``z = z_g``, columns on
a 2.5 cm grid are sampled every 5 mm from ``z_g + band`` down to ``z_g − band``; the first crossing of
``O = 0.5`` going down is the surface height there (linear interpolation). A column whose top sample is
already ≥ 0.5 has a surface (a floater or a raised ground) above the band; one with no crossing has a
hole. "Seen ground" = ground points that some train camera sees unoccluded (GT depth maps).

Reported: fraction of seen columns within 2 mm / 1 cm / 2 cm of the plane, p50/p95 of |height error|
(holes and columns over the band count as errors of ``band``), hole fraction, and 10 × 10 cm patches
with more than 10 % of their columns missing or off by more than 2 cm.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def unoccluded_views(scene_dir: Path, scene, points: np.ndarray):
    """For each train view of a synthetic scene: ``(view, index [K], pixel [K, 2])`` of the ``points`` it sees
    unoccluded (in the image and within 1 % of the GT z-depth map at their pixel)."""
    frames = {f["file_path"].replace("/", "_"): f for f in json.loads((scene_dir / "transforms_train.json").read_text())["frames"]}
    for v in scene.train:
        depth = np.load(scene_dir / frames[v.name]["depth_path"])
        uv, z, ok = v.camera.in_image(points)
        idx = np.where(ok)[0]
        ij = np.floor(uv[idx]).astype(int)
        vis = np.abs(depth[ij[:, 1], ij[:, 0]] - z[idx]) < 0.01 * z[idx]
        yield v, idx[vis], ij[vis]


def seen_ground_columns(scene_dir: Path, ground_z: float, half: float, spacing: float = 0.025):
    """``[C, 2]`` xy of ground columns some train camera sees unoccluded (from the GT z-depth maps)."""
    from gof_warp.data import DataConfig, load_scene

    scene = load_scene(scene_dir, DataConfig())
    xs = np.arange(-half + spacing / 2, half, spacing)
    xy = np.stack(np.meshgrid(xs, xs, indexing="ij"), -1).reshape(-1, 2)
    pts = np.concatenate([xy, np.full((len(xy), 1), ground_z)], 1)
    seen = np.zeros(len(pts), bool)
    for _, idx, _ in unoccluded_views(scene_dir, scene, pts):
        seen[idx] = True
    return xy[seen], scene


def probe(gaussians, cameras, xy: np.ndarray, ground_z: float, *, band: float = 0.25, step: float = 0.005,
          render_config=None, chunk: int = 2_000_000) -> np.ndarray:
    """``[C]`` height of the first 0.5 crossing above ``ground_z`` minus ``ground_z`` (NaN: no crossing; +inf:
    surface above the band)."""
    import torch

    from gof_warp.opacity_field import opacity_field

    zs = np.arange(ground_z + band, ground_z - band - 1e-9, -step)
    pts = np.concatenate([np.repeat(xy, len(zs), 0), np.tile(zs, len(xy))[:, None]], 1)
    vals = []
    for a in range(0, len(pts), chunk):
        vals.append(opacity_field(gaussians, cameras, pts[a:a + chunk], render_config=render_config).cpu().numpy())
    O = np.concatenate(vals).reshape(len(xy), len(zs))
    inside = O >= 0.5
    first = np.argmax(inside, axis=1)
    has = inside.any(axis=1)
    h = np.full(len(xy), np.nan)
    top = has & (first == 0)
    h[top] = np.inf
    k = np.where(has & (first > 0))[0]
    j = first[k]
    o0, o1 = O[k, j - 1], O[k, j]
    frac = np.clip((0.5 - o0) / np.maximum(o1 - o0, 1e-9), 0, 1)
    h[k] = zs[j - 1] + frac * (zs[j] - zs[j - 1]) - ground_z
    del torch
    return h


def summarise(xy: np.ndarray, h: np.ndarray, band: float = 0.25, patch: float = 0.10) -> dict:
    err = np.where(np.isfinite(h), np.abs(h), band)
    out = {"columns": int(len(h)), "holes": round(float(np.isnan(h).mean()), 4),
           "above_band": round(float(np.isinf(h).mean()), 4)}
    for tol in (0.002, 0.005, 0.01, 0.02):
        out[f"within_{tol * 1000:.0f}mm"] = round(float((err <= tol).mean()), 4)
    out["abs_err_p50_m"] = round(float(np.percentile(err, 50)), 5)
    out["abs_err_p95_m"] = round(float(np.percentile(err, 95)), 5)
    key = np.floor(xy / patch).astype(int)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    bad = np.bincount(inv.ravel(), weights=(err > 0.02)) / np.bincount(inv.ravel())
    out["patches"] = int(len(bad))
    out["patches_over_10pct_bad"] = int((bad > 0.10).sum())
    out["worst_patch_bad_fraction"] = round(float(bad.max()), 4)
    return out
