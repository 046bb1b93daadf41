"""Warp renderer forward (float32) vs the float64 brute-force reference, every output, production
thresholds on (alpha_min, transmittance stop, k_max), on random scenes that hit the awkward cases:
anisotropic rotated Gaussians, some behind the camera, some straddling the near plane, some over the
image border, off-centre (even outside) principal points, fx ≠ fy, sizes that are not multiples of 16,
SH degrees 0 / 3 / partially active, non-black backgrounds, depth ties.

Discrete decisions (skip, stop, median choice) are taken on float32 values by the renderer and on float64
values by the reference; where one lies within float32 noise of its threshold the two may legitimately
differ in that pixel. The reference reports, per pixel, the smallest relative distance of any decision
from its threshold (``margin``); pixels below ``MARGIN_MIN`` are excluded and their share is bounded.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gof_warp.core.camera import Camera
from gof_warp.rendering.render import DensifyStats, RenderConfig, rasterize
from reference_render import OUTPUT_NAMES, make_camera, random_scene, reference_render, reference_screen_boxes

# A decision within 0.1% of its threshold may flip: float32 α, T, t*, d² carry relative errors up to
# ~1e-5 (accumulated over ~20 Gaussians), so 1e-3 is a 100x safety factor.
MARGIN_MIN = 1e-3
# At most this share of pixels may be excluded by MARGIN_MIN, so the comparison still covers the image.
MAX_EXCLUDED = 0.05
# Max abs error on kept pixels, float32 vs float64: ~10x the measured worst case (1e-6 at depth scale).
# Colours, alpha, normals are O(1) sums of ≤ 20 products of float32 factors (relative error ~1e-7 each,
# measured ≤ 7e-7); depths are O(5) scene units (measured ≤ 2e-6); the distortion sums O(N) terms
# w·w·Δt (measured ≤ 2e-6); the expected depth divides by alpha, which is a convex combination of t*
# and so stays as accurate as the weights.
TOL = dict(rgb=5e-6, alpha=5e-6, normal=5e-6, accum_depth=2e-5, depth=2e-5, median_depth=2e-5, distortion=2e-5)

BACKGROUND = (0.3, 0.6, 0.1)
CASES = {  # camera kwargs, scene kwargs, config kwargs, active SH degree
    "sh0_offcentre": (dict(width=37, height=29), dict(n=16, sh_degree=0, seed=1), {}, None),
    "paper_distortion": (dict(width=37, height=29), dict(n=16, sh_degree=0, seed=5), dict(distortion="paper"), None),
    # m(t) continued by its tangent beyond depth 2 (the scene spans 0.3-4.8; the distortion differs by ~28 %)
    "linear_far_distortion": (dict(width=37, height=29), dict(n=16, sh_degree=0, seed=5),
                              dict(distortion_linear_from=2.0), None),
    "sh3_nonsquare_pp_far": (
        dict(width=45, height=22, fx=30.0, fy=44.0, cx=36.0, cy=4.4),
        dict(n=16, sh_degree=3, seed=2),
        dict(background=BACKGROUND),
        None,
    ),
    "sh3_active1_pp_outside": (
        dict(width=17, height=35, fx=28.0, fy=33.0, cx=-2.0, cy=21.0),
        dict(n=14, sh_degree=3, seed=3, spread=2.0, n_behind=2, n_near=2),
        dict(background=BACKGROUND),
        1,
    ),
    "dense_stop_and_clamp": (
        dict(width=33, height=31),
        dict(n=20, sh_degree=3, seed=4, spread=0.5, opacity_range=(0.8, 0.9999), scale_factor=2.0),
        dict(background=(1.0, 1.0, 1.0), alpha_max=0.8),  # a lower clamp so that it bites often
        2,
    ),
}


def as_renderer_inputs(scene):
    """(float32 tensors for the renderer, their exact float64 values for the reference)."""
    f32 = {k: v.detach().float() for k, v in scene.items()}
    return f32, {k: v.double() for k, v in f32.items()}


def run_case(case):
    cam_kw, scene_kw, cfg_kw, degree = CASES[case]
    cam = make_camera(**cam_kw)
    scene = random_scene(cam, **scene_kw)
    cfg = RenderConfig(**cfg_kw)
    f32, f64 = as_renderer_inputs(scene)
    out = rasterize(**f32, camera=cam, sh_degree=degree, config=cfg)
    ref = reference_render(**f64, camera=cam, sh_degree=degree, config=cfg)
    return cam, f64, cfg, degree, out, ref


def max_error(out, ref, name, keep):
    err = (out[name].double() - ref[name]).abs()
    if err.dim() == 3:
        err = err.amax(-1)
    return err[keep].max().item()


@pytest.mark.parametrize("case", list(CASES))
def test_forward_matches_reference(case):
    cam, f64, cfg, degree, out, ref = run_case(case)
    keep = ref["margin"] >= MARGIN_MIN
    assert (~keep).double().mean().item() <= MAX_EXCLUDED, "scene too close to thresholds to compare"
    for name in OUTPUT_NAMES:
        assert out[name].dtype == torch.float32 and out[name].shape == ref[name].shape, name
        assert max_error(out, ref, name, keep) <= TOL[name], (name, max_error(out, ref, name, keep))
    # the scene exercises what it claims: culled, straddling and off-image Gaussians all present
    w = ref["weights"].reshape(-1, ref["weights"].shape[-1])
    z = (f64["means"] @ torch.tensor(cam.R).T + torch.tensor(cam.t))[:, 2]
    assert (z < 0).any() and ((z > cfg.near) & (z < 0.6) & (w > 0).any(0)).any()
    uv, _ = cam.project(f64["means"].numpy())
    outside = (uv[:, 0] < 0) | (uv[:, 0] > cam.width) | (uv[:, 1] < 0) | (uv[:, 1] > cam.height)
    if CASES[case][1].get("spread", 1.3) > 1:
        assert (torch.from_numpy(outside) & (z > cfg.near) & (w > 0).any(0)).any()


def test_dense_scene_really_stops_and_clamps():
    """Guard that the dense case exercises the transmittance stop, alpha_max clamp and alpha_min skip."""
    cam, f64, cfg, degree, out, ref = run_case("dense_stop_and_clamp")
    for field, off in (("transmittance_min", 0.0), ("alpha_max", 0.9999), ("alpha_min", 0.0)):
        other = reference_render(**f64, camera=cam, sh_degree=degree, config=RenderConfig(**{**cfg.__dict__, field: off}))
        changed = ((other["weights"] > 0) != (ref["weights"] > 0)).any(-1) | (other["alpha"] != ref["alpha"])
        assert changed.double().mean().item() > 0.02, field


def test_radii_match_reference_boxes():
    """radii > 0 exactly for Gaussians whose exact box covers a pixel centre, ≈ its half-extent."""
    cam, f64, cfg, degree, out, ref = run_case("sh3_active1_pp_outside")
    stats = DensifyStats(f64["means"].shape[0])
    rasterize(**{k: v.float() for k, v in f64.items()}, camera=cam, sh_degree=degree, config=cfg, stats=stats)
    assert torch.equal(stats.radii, out["radii"])
    box, status = reference_screen_boxes(f64["means"], f64["quats"], f64["scales"], f64["opacities"], cam, cfg)
    radii = out["radii"].long()
    influences = (ref["weights"] > 0).flatten(0, 1).any(0)
    assert (radii[influences] > 0).all()  # binning never drops a Gaussian that is blended somewhere
    assert (radii[status == 0] == 0).all() and (radii[status == 2] > 0).all()
    assert (status == 0).any() and (status == 2).any() and (status == 1).any()
    for k in torch.nonzero(status == 1).flatten().tolist():
        u0, u1, v0, v1 = box[k].tolist()
        covers = np.ceil(u0 - 0.5) <= min(np.floor(u1 - 0.5), cam.width - 1) and max(np.ceil(u0 - 0.5), 0) <= np.floor(u1 - 0.5)
        covers &= np.ceil(v0 - 0.5) <= min(np.floor(v1 - 0.5), cam.height - 1) and max(np.ceil(v0 - 0.5), 0) <= np.floor(v1 - 0.5)
        if not covers:
            assert radii[k] == 0, k
        else:
            assert abs(radii[k].item() - np.ceil(max(u1 - u0, v1 - v0) / 2)) <= 1, k


def test_only_culled_gaussians_give_the_background():
    cam = make_camera(width=19, height=13)
    scene = random_scene(cam, 5, 1, seed=5, n_behind=5, n_near=0)
    out = rasterize(**as_renderer_inputs(scene)[0], camera=cam, config=RenderConfig(background=BACKGROUND))
    assert torch.equal(out["rgb"], torch.tensor(BACKGROUND, dtype=torch.float32).expand(13, 19, 3))
    for name in OUTPUT_NAMES[1:]:
        assert out[name].abs().max() == 0, name
    assert (out["radii"] == 0).all()


def test_equal_depths_blend_in_index_order():
    """Two overlapping Gaussians at exactly the same camera depth: the lower index is in front."""
    cam = Camera(R=np.eye(3), t=np.zeros(3), fx=20.0, fy=20.0, cx=10.0, cy=8.0, width=21, height=17)
    means = torch.tensor([[0.05, 0.0, 2.0], [-0.05, 0.02, 2.0]])
    quats = torch.tensor([[1.0, 0, 0, 0], [1.0, 0, 0, 0]])
    scales = torch.full((2, 3), 0.3)
    sh = torch.tensor([[[1.5, -1.5, -1.5]], [[-1.5, 1.5, -1.5]]])
    for order in ([0, 1], [1, 0]):
        p = dict(means=means[order], quats=quats, scales=scales, opacities=torch.tensor([0.8, 0.8]), sh=sh[order])
        out = rasterize(**p, camera=cam)
        ref = reference_render(**{k: v.double() for k, v in p.items()}, camera=cam)
        assert (out["rgb"].double() - ref["rgb"]).abs().max() <= TOL["rgb"], order


def test_camera_near_plane_clips_and_keeps_the_ndc_depth():
    """A camera with its own near plane (``Camera.near``, as ``render.near_from_points`` sets it) clips Gaussians
    with ``t* ≤`` that depth and culls centres in front of it, exactly as the reference does with that ``near``;
    the distortion's NDC depth m(t) keeps ``render.near`` (0.2), so the clip does not rescale the distortion."""
    import dataclasses
    from types import SimpleNamespace

    cam0 = make_camera(width=37, height=29)
    scene = random_scene(cam0, n=16, sh_degree=0, seed=1)
    f32, f64 = as_renderer_inputs(scene)
    cfg = RenderConfig()
    cam = dataclasses.replace(cam0, near=2.5)
    out = rasterize(**f32, camera=cam, config=cfg)
    ref = reference_render(**f64, camera=cam, config=SimpleNamespace(**{**cfg.__dict__, "near": 2.5, "ndc_near": 0.2}))
    keep = ref["margin"] >= MARGIN_MIN
    assert (~keep).double().mean().item() <= MAX_EXCLUDED
    for name in OUTPUT_NAMES:
        # the expected depth is Σ w t* / α: where the clip leaves only a faint tail (α < 1 %), float32 rounding of
        # that ratio exceeds the tolerance written for whole surfaces, so those pixels are left to the others
        where = keep & (ref["alpha"] >= 0.01) if name == "depth" else keep
        assert max_error(out, ref, name, where) <= TOL[name], (name, max_error(out, ref, name, where))
    unclipped = reference_render(**f64, camera=cam0, config=cfg)
    assert (unclipped["alpha"] - ref["alpha"]).abs().max() > 0.05  # the clip removed something
    rescaled = reference_render(**f64, camera=cam, config=SimpleNamespace(**{**cfg.__dict__, "near": 2.5}))
    # Δm scales with m's near plane, the distortion with its square: (2.5 / 0.2)² ≈ 156 times larger
    assert rescaled["distortion"].max() > 20 * out["distortion"].double().max() > 0
