"""Edge cases of the Warp renderer (``gof_warp.rendering.render``): empty and fully culled scenes, one Gaussian
covering the image, thousands of Gaussians in one tile, degenerate scales and opacities; the pure-Warp
``wp.Tape`` path against the torch path; input validation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import warp as wp

from gof_warp.core.camera import look_at
from gof_warp.kernels.render_types import camera_params_from, make_raster_settings
from gof_warp.kernels.renderer import RenderOutputs, render_backward, render_forward, render_gaussians, sh_parts
from gof_warp.rendering.render import DensifyStats, RenderConfig, rasterize
from reference_render import reference_render

OUTPUTS = ("rgb", "alpha", "depth", "accum_depth", "median_depth", "normal", "distortion")
FWD_TOL = 2e-5  # float32 kernel vs float64 reference: a few ulps per blended Gaussian on O(1) values
DEEP_TOL = 1e-3  # ~500 blends per pixel: float32 alpha errors (~3e-5 each, from the ray-distance cancellation) add up
TILED_VS_PLAIN = 1e-5  # identical per-entry code; only the order of the float atomic adds differs
TILED_VS_PLAIN_CUDA = 5e-5  # on CUDA the shared-memory kernels also use fast_math (approximate division, sqrt, exp2)
TAPE_VS_TORCH = 1e-5  # same kernels; the depth = accum/alpha chain is folded by hand here, by torch there


def _camera(width=37, height=29):
    return look_at((0.0, -3.0, 0.0), (0.0, 0.0, 0.0), fx=30.0, fy=28.0, cx=0.47 * width, cy=0.55 * height, width=width, height=height)


def _params(n, seed=0, degree=1, scale=(0.05, 0.3), spread=0.8, opacity=(0.1, 0.9)):
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g) - 0.5) * 2 * spread
    q = torch.randn(n, 4, generator=g)
    q = q / q.norm(dim=1, keepdim=True)
    scales = scale[0] + (scale[1] - scale[0]) * torch.rand(n, 3, generator=g)
    opac = opacity[0] + (opacity[1] - opacity[0]) * torch.rand(n, generator=g)
    sh = 0.3 * torch.randn(n, (degree + 1) ** 2, 3, generator=g)
    return [means, q, scales, opac, sh]


def _loss_weights(out):
    """Fixed random weights per output (the same on every call): the upstream gradients of :func:`_random_weighted_sum`."""
    w = torch.Generator().manual_seed(7)
    return {k: torch.randn(out[k].shape, generator=w) for k in OUTPUTS}


def _random_weighted_sum(out):
    """A loss touching every output with the weights of :func:`_loss_weights`."""
    return sum((out[k] * weight).sum() for k, weight in _loss_weights(out).items())


def _render_with_grads(params, cam, config=None, stats=None):
    leaves = [p.clone().requires_grad_(True) for p in params]
    out = rasterize(*leaves, cam, config=config, stats=stats)
    _random_weighted_sum(out).backward()
    return out, [p.grad for p in leaves]


def _assert_finite(out, grads):
    for k in OUTPUTS:
        assert torch.isfinite(out[k]).all(), k
    for g in grads:
        assert g is not None and torch.isfinite(g).all()


def _assert_matches_reference(out, params, cam, config, tol):
    ref = reference_render(*[p.double() for p in params], cam, config=config)
    for k in OUTPUTS:
        err = (out[k].double() - ref[k]).abs().max().item()
        assert err < tol * max(1.0, ref[k].abs().max().item()), (k, err)


def test_zero_gaussians_give_background():
    cam = _camera()
    cfg = RenderConfig(background=(0.2, 0.4, 0.6))
    out, grads = _render_with_grads(_params(0), cam, cfg)
    assert out["rgb"].shape == (cam.height, cam.width, 3) and out["normal"].shape == (cam.height, cam.width, 3)
    for k in ("alpha", "depth", "median_depth", "distortion"):
        assert out[k].shape == (cam.height, cam.width) and (out[k] == 0).all()
    assert torch.allclose(out["rgb"], torch.tensor([0.2, 0.4, 0.6]).expand_as(out["rgb"]))
    assert [g.shape[0] for g in grads] == [0] * 5


def test_all_culled_behind_or_at_near_plane():
    cam = _camera()
    params = _params(50)
    centre = torch.tensor(cam.center, dtype=torch.float32)
    forward = torch.tensor(cam.R[2], dtype=torch.float32)
    depth = torch.cat([torch.full((25,), -1.0), torch.full((25,), 0.15)])  # behind the camera / before near
    sideways = torch.tensor(cam.R[:2], dtype=torch.float32)  # camera x and y axes in world
    params[0] = centre + depth[:, None] * forward + 0.1 * params[0][:, :2] @ sideways
    params[2] = params[2] * 0.2
    stats = DensifyStats(50)
    out, grads = _render_with_grads(params, cam, stats=stats)
    _assert_finite(out, grads)
    assert (out["alpha"] == 0).all() and (out["rgb"] == 0).all()
    assert all((g == 0).all() for g in grads)
    assert (stats.radii == 0).all() and (stats.grad2d == 0).all()


def test_one_gaussian_covering_the_image():
    cam = _camera()
    params = [torch.zeros(1, 3), torch.tensor([[1.0, 0, 0, 0]]), torch.tensor([[3.0, 0.4, 3.0]]), torch.tensor([0.8]), torch.rand(1, 4, 3)]
    out, grads = _render_with_grads(params, cam)
    _assert_finite(out, grads)
    assert (out["alpha"] > 0.5).all()  # every pixel, including the partial border tiles
    _assert_matches_reference(out, params, cam, RenderConfig(), FWD_TOL)
    assert (out["radii"] > max(cam.width, cam.height) / 2).all()


def test_thousands_of_gaussians_in_one_tile():
    cam = _camera(width=13, height=11)  # one tile
    params = _params(3000, seed=3, scale=(0.02, 0.1), spread=0.8, opacity=(0.05, 0.5))
    out, grads = _render_with_grads(params, cam)
    _assert_finite(out, grads)
    assert (out["alpha"] > 0.99).all()  # opaque everywhere: the transmittance early stop is exercised
    _assert_matches_reference(out, params, cam, RenderConfig(), DEEP_TOL)


@pytest.mark.parametrize("scale", [1e-8, 1e3])
@pytest.mark.parametrize("opacity", [0.0, 1.0])
def test_degenerate_scales_and_opacities(scale, opacity):
    cam = _camera()
    params = _params(40, seed=5)
    params[2] = params[2].clone()
    params[2][::2] = scale  # half degenerate, half normal
    params[3] = params[3].clone()
    params[3][1::3] = opacity
    out, grads = _render_with_grads(params, cam, stats=DensifyStats(40))
    _assert_finite(out, grads)
    assert (out["alpha"] >= 0).all() and (out["alpha"] <= 1).all()
    _assert_matches_reference(out, params, cam, RenderConfig(), FWD_TOL)


def test_tape_path_matches_torch_path():
    cam = _camera()
    params = _params(30, seed=9, degree=2)
    stats = DensifyStats(30)
    out, grads = _render_with_grads(params, cam, stats=stats)
    # the same loss in pure Warp: upstream gradients set directly on the outputs
    wpar = [wp.array(p.numpy(), dtype=t, device="cpu", requires_grad=True) for p, t in zip(params, (wp.vec3, wp.vec4, wp.vec3, float, wp.vec3))]
    g2d, g2abs = wp.zeros(30, dtype=wp.vec2, device="cpu"), wp.zeros(30, dtype=float, device="cpu")
    tape = wp.Tape()
    wout = render_gaussians(*wpar, 2, camera_params_from(cam), make_raster_settings(cam.width, cam.height), tape=tape, grad2d=g2d, grad2d_abs=g2abs)
    upstream = _loss_weights(out)
    # depth = accum/alpha is a torch op: fold its gradient into accum_depth and alpha as torch would
    a = out["alpha"].detach()
    safe = torch.where(a > 0, a, torch.ones_like(a))
    g_accum = upstream["accum_depth"] + torch.where(a > 0, upstream["depth"] / safe, 0)
    g_alpha = upstream["alpha"] - torch.where(a > 0, upstream["depth"] * out["accum_depth"].detach() / safe**2, 0)
    seeds = dict(rgb=upstream["rgb"], alpha=g_alpha, accum_depth=g_accum, median_depth=upstream["median_depth"], normal=upstream["normal"], distortion=upstream["distortion"])
    for name, arr in zip(("rgb", "alpha", "accum_depth", "median_depth", "normal", "distortion"), wout.arrays()):
        assert np.allclose(arr.numpy().reshape(out[name].shape), out[name].detach().numpy())
        arr.grad.assign(seeds[name].numpy().reshape(arr.grad.numpy().shape))
    tape.backward()
    for p, g in zip(wpar, grads):
        assert np.abs(p.grad.numpy().reshape(g.shape) - g.numpy()).max() < TAPE_VS_TORCH * max(1.0, g.abs().max().item())
    assert np.allclose(g2d.numpy(), stats.grad2d.numpy(), atol=1e-5) and np.allclose(g2abs.numpy(), stats.grad2d_abs.numpy(), atol=1e-5)
    assert stats.grad2d_abs.sum() > 0


def _warp_forward_backward(params, cam, tiled, reduce_min_lanes=33, device="cpu"):
    wpar = [wp.array(p.numpy(), dtype=t, device=device, requires_grad=True) for p, t in zip(params, (wp.vec3, wp.vec4, wp.vec3, float, wp.vec3))]
    settings = make_raster_settings(cam.width, cam.height, reduce_min_lanes=reduce_min_lanes)
    out, state = render_forward(*wpar, 1, camera_params_from(cam), settings, tiled=tiled)
    rng = np.random.default_rng(0)
    grad_out = RenderOutputs(*[wp.array(rng.normal(size=a.numpy().shape).astype(np.float32), dtype=a.dtype, device=device) for a in out.arrays()])
    abs_stats = wp.zeros(len(params[0]), dtype=float, device=device)
    render_backward(state, grad_out, tuple(a.grad for a in wpar), wp.zeros(len(params[0]), dtype=wp.vec2, device=device), abs_stats)
    return [a.numpy() for a in out.arrays()] + [a.grad.numpy() for a in wpar] + [abs_stats.numpy()]


@pytest.mark.slow
def test_shared_memory_kernels_match_plain_kernels():
    """The CUDA shared-memory kernels, run on the CPU with emulated 256-thread blocks."""
    cam = _camera(width=37, height=29)
    params = _params(300, seed=3, degree=1)
    plain = _warp_forward_backward(params, cam, tiled=False)
    saved = wp.config.enable_cpu_blocks
    wp.config.enable_cpu_blocks = True
    try:  # without and with the warp-reduction path (a no-op on the CPU, where warps have one lane)
        runs = [_warp_forward_backward(params, cam, tiled=True, reduce_min_lanes=m) for m in (33, 1)]
    finally:
        wp.config.enable_cpu_blocks = saved
    for tiled in runs:
        for a, b in zip(plain, tiled):
            assert np.abs(a - b).max() <= TILED_VS_PLAIN * max(1.0, np.abs(a).max())
    assert np.abs(plain[6]).max() > 0  # gradients really flow



@pytest.mark.skipif(not wp.is_cuda_available(), reason="needs a CUDA device: the warp reductions and vector atomics run only there")
def test_shared_memory_kernels_match_plain_kernels_on_cuda():
    """On a GPU: the shared-memory kernels (fast_math, warp reductions by recursive halving, sm_90 vector atomics) against
    the plain per-pixel kernels (precise maths, one scalar atomic per value), with the reduction at every entry some lane
    blends, at half a warp, and never. Both kinds are within ~1e-5 of the float64 reference (``bench_render.py --check``),
    so they agree within a few times that."""
    cam = _camera(width=37, height=29)
    params = _params(300, seed=3, degree=1)
    plain = _warp_forward_backward(params, cam, tiled=False, device="cuda")
    for lanes in (1, 16, 33):
        tiled = _warp_forward_backward(params, cam, tiled=True, reduce_min_lanes=lanes, device="cuda")
        for a, b in zip(plain, tiled):
            assert np.abs(a - b).max() <= TILED_VS_PLAIN_CUDA * max(1.0, np.abs(a).max()), lanes
    assert np.abs(plain[6]).max() > 0  # gradients really flow

@pytest.mark.parametrize("degree", [0, 2])
def test_sh_pair_renders_as_one_array(degree):
    """A model's ``(sh_dc, sh_rest)`` pair (what ``render`` passes, no concatenation) gives the images and gradients
    of the one ``[N, K, 3]`` tensor, bit for bit, through torch and through the Warp tape."""
    cam = _camera()
    params = _params(40, seed=5, degree=degree)
    out, grads = _render_with_grads(params, cam)
    dc = params[4][:, 0].clone().requires_grad_(True)
    rest = params[4][:, 1:].clone().requires_grad_(True)
    leaves = [p.clone().requires_grad_(True) for p in params[:4]]
    pair_out = rasterize(*leaves, (dc, rest), cam)
    _random_weighted_sum(pair_out).backward()
    for k in OUTPUTS:
        assert torch.equal(out[k], pair_out[k]), k
    for a, b in zip(grads[:4], leaves):
        assert torch.equal(a, b.grad)
    assert torch.equal(grads[4], torch.cat([dc.grad[:, None], rest.grad], dim=1))
    assert dc.grad.abs().max() > 0
    # the Warp tape with two arrays against one
    settings, cp = make_raster_settings(cam.width, cam.height), camera_params_from(cam)
    results = []
    for as_pair in (False, True):
        wpar = [wp.array(p.numpy(), dtype=t, device="cpu", requires_grad=True) for p, t in zip(params[:4], (wp.vec3, wp.vec4, wp.vec3, float))]
        sh = params[4].numpy()
        sh_w = ((wp.array(sh[:, 0], dtype=wp.vec3, device="cpu", requires_grad=True),
                 wp.array(sh[:, 1:], dtype=wp.vec3, device="cpu", requires_grad=True)) if as_pair
                else wp.array(sh, dtype=wp.vec3, device="cpu", requires_grad=True))
        tape = wp.Tape()
        wout = render_gaussians(*wpar, sh_w, degree, cp, settings, tape=tape)
        wout.rgb.grad.fill_(1.0)
        tape.backward()
        sh_grad = (np.concatenate([sh_w[0].grad.numpy()[:, None], sh_w[1].grad.numpy()], axis=1) if as_pair
                   else sh_w.grad.numpy())
        results.append([wout.rgb.numpy(), sh_grad] + [a.grad.numpy() for a in wpar])
    for a, b in zip(*results):
        assert np.array_equal(a, b)
    assert np.abs(results[0][1]).max() > 0


def test_sh_parts_views_and_errors():
    sh = wp.array(np.arange(5 * 4 * 3, dtype=np.float32).reshape(5, 4, 3), dtype=wp.vec3, device="cpu")
    dc, rest = sh_parts(sh)
    assert dc.shape == (5,) and rest.shape == (5, 3)
    assert np.array_equal(dc.numpy(), sh.numpy()[:, 0]) and np.array_equal(rest.numpy(), sh.numpy()[:, 1:])
    assert sh_parts((dc, rest)) == (dc, rest)
    assert sh_parts(wp.zeros((3, 1), dtype=wp.vec3, device="cpu"))[1].shape == (3, 0)
    with pytest.raises(ValueError, match="sh_dc"):
        sh_parts((rest, dc))
    with pytest.raises(ValueError, match="vec3"):
        sh_parts(wp.zeros((3, 4), dtype=float, device="cpu"))
    with pytest.raises(ValueError, match="pair|2"):
        rasterize(*_params(4)[:4], (torch.zeros(4, 3),), _camera())


def test_validation_errors():
    cam = _camera()
    p = _params(4)
    with pytest.raises(ValueError, match="quats"):
        rasterize(p[0], p[1][:, :3], *p[2:], cam)
    with pytest.raises(ValueError, match="float32"):
        rasterize(p[0].double(), *p[1:], cam)
    with pytest.raises(ValueError, match="scales"):
        rasterize(p[0], p[1], -p[2], *p[3:], cam)
    with pytest.raises(ValueError, match="sh_degree"):
        rasterize(*p, cam, sh_degree=2)
    with pytest.raises(TypeError, match="camera"):
        rasterize(*p, object())
    with pytest.raises(ValueError, match="near"):
        rasterize(*p, cam, config=RenderConfig(near=0.0))
    with pytest.raises(ValueError, match="stats"):
        rasterize(*p, cam, stats=DensifyStats(5))
    assert math.isclose(RenderConfig().k_max, math.sqrt(2 * math.log(255)))


def test_render_reads_each_model_attribute_once():
    """A model's activated parameters are computed on every access (normalize, exp, sigmoid: torch ops on the GPU):
    ``render`` reads each once, and renders what the model holds, SH pair or one tensor."""
    from gof_warp.core.model import Gaussians
    from gof_warp.rendering.render import render

    torch.manual_seed(0)
    g = Gaussians.random_in_box(40, sh_degree=1)
    reads: dict[str, int] = {}

    class Counting:
        def __getattr__(self, name):
            reads[name] = reads.get(name, 0) + 1
            return getattr(g, name)

    cam = look_at((3.0, 0.0, 1.0), (0.0, 0.0, 0.0), fx=20.0, width=16, height=16)
    out = render(Counting(), cam)
    assert reads == {"means": 1, "rotations": 1, "scales": 1, "opacities": 1, "active_sh_degree": 1, "sh_dc": 1,
                     "sh_rest": 1}, reads
    assert torch.equal(out["rgb"], render(g, cam)["rgb"])

    class OneTensor:  # no sh_dc / sh_rest: the [N, K, 3] tensor
        def __init__(self):
            for name in ("means", "rotations", "scales", "opacities", "active_sh_degree"):
                setattr(self, name, getattr(g, name))
            self.sh = torch.cat([g.sh_dc[:, None], g.sh_rest], dim=1)

    assert torch.equal(render(OneTensor(), cam)["rgb"], out["rgb"])
    with pytest.raises(TypeError, match="neither 'sh_dc'/'sh_rest' nor 'sh'"):
        render(type("NoSH", (), {n: getattr(g, n) for n in ("means", "rotations", "scales", "opacities",
                                                           "active_sh_degree")})(), cam)
