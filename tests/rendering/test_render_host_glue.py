"""What a :class:`gof_warp.rendering.render.RenderScratch` keeps between renders to spend less host time (issue 14) must never
change a result: the spare scratch arrays of finished renders (``kernels.renderer.ScratchPool``), the shared camera /
settings structs and the stream wrappers. Renders through one scratch, interleaving image sizes, Gaussian counts, SH
degrees, statistics, settings and overlapping renders, are compared bit for bit with renders without one; what it
holds stays bounded whatever the sizes."""

from __future__ import annotations

import dataclasses

import pytest
import torch
import warp as wp

from gof_warp.core.camera import look_at
from gof_warp.kernels.renderer import GradScratch, PixelScratch, ScratchPool, SplatScratch
from gof_warp.rendering.render import DensifyStats, RenderConfig, RenderScratch, rasterize

OUTPUTS = ("rgb", "alpha", "depth", "accum_depth", "median_depth", "normal", "distortion", "radii")
STATS = ("grad2d", "grad2d_abs", "radii", "max_radii", "visible_count")
# On the CPU every kernel is deterministic: renders with and without a scratch agree bit for bit. On CUDA the backward
# adds the per-pixel gradients with float atomics, whose order varies from run to run (the forward stays exact). On an
# H100 (these renders three times over) two renders
# without a scratch differed by up to 1.8e-4 of an element (elements over 1e-3 of the largest) and 4.7e-6 of the
# gradient's largest element; with and without a scratch by 1.5e-4 and 6.4e-6.
CUDA_GRAD_RTOL = 1e-3
CUDA_GRAD_ATOL = 1e-4  # of the gradient's largest element


def _camera(width, height, eye=(0.0, -3.0, 0.0), near=0.0):
    cam = look_at(eye, (0.0, 0.0, 0.0), fx=0.9 * width, width=width, height=height)
    return dataclasses.replace(cam, near=near) if near else cam


def _params(n, seed, device, num_coeffs=16):
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g) - 0.5) * 1.6
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=1)
    scales = 0.05 + 0.25 * torch.rand(n, 3, generator=g)
    opacities = 0.1 + 0.8 * torch.rand(n, generator=g)
    sh = 0.3 * torch.randn(n, num_coeffs, 3, generator=g)
    return [p.to(device) for p in (means, quats, scales, opacities, sh)]


@dataclasses.dataclass
class Call:
    """One render: ``n`` Gaussians of ``seed`` with ``num_coeffs`` SH coefficients at ``sh_degree``, seen by
    ``camera`` under ``config``, with densification statistics when ``stats``."""

    n: int
    seed: int
    camera: object
    num_coeffs: int = 16
    sh_degree: int | None = None
    stats: bool = False
    config: RenderConfig | None = None

    def forward(self, device, scratch):
        leaves = [p.requires_grad_(True) for p in _params(self.n, self.seed, device, self.num_coeffs)]
        stats = DensifyStats(self.n, device) if self.stats else None
        out = rasterize(*leaves, self.camera, sh_degree=self.sh_degree, config=self.config, stats=stats,
                        scratch=scratch)  # fmt: skip
        return leaves, stats, out

    def render(self, device, scratch):
        return _backward(*self.forward(device, scratch))


def _backward(leaves, stats, out):
    """Back-propagate random weights of every map; ``(outputs, input gradients, statistics)``, copied."""
    w = torch.Generator().manual_seed(3)
    sum((out[k] * torch.randn(out[k].shape, generator=w).to(out[k].device)).sum() for k in OUTPUTS[:-1]).backward()
    kept = {k: getattr(stats, k).clone() for k in STATS} if stats is not None else {}
    return {k: v.detach().clone() for k, v in out.items()}, [p.grad for p in leaves], kept


def _assert_same(got, want, device):
    (out, grads, stats), (out_ref, grads_ref, stats_ref) = got, want
    for k in OUTPUTS:
        assert torch.equal(out[k], out_ref[k]), k
    assert stats.keys() == stats_ref.keys()
    for k in stats:
        if device == "cpu" or k not in ("grad2d", "grad2d_abs"):
            assert torch.equal(stats[k], stats_ref[k]), k
        else:
            torch.testing.assert_close(stats[k], stats_ref[k], rtol=CUDA_GRAD_RTOL, atol=0.0)
    for g, g_ref in zip(grads, grads_ref):
        if device == "cpu":
            assert torch.equal(g, g_ref)
        else:
            scale = float(g_ref.abs().max()) if g_ref.numel() else 0.0
            torch.testing.assert_close(g, g_ref, rtol=CUDA_GRAD_RTOL, atol=CUDA_GRAD_ATOL * scale)


def _mixed_calls() -> list[Call]:
    """Renders that change every size a spare is kept for, one thing at a time and several at once."""
    small, wide, odd = _camera(40, 30), _camera(33, 47, eye=(2.5, 0.5, 1.5)), _camera(24, 24, eye=(1.0, -2.0, 1.0))
    other_view = _camera(40, 30, eye=(0.0, 3.0, 0.5))
    return [
        Call(10, 1, small),
        Call(20, 2, wide, stats=True),  # another count and image size
        Call(10, 3, other_view, sh_degree=1),  # back to the first sizes: their spares, another view and degree
        Call(10, 4, small, num_coeffs=1, stats=True),  # degree 0 without higher coefficients
        Call(10, 5, _camera(24, 24, near=0.4), num_coeffs=4),  # the camera's own near plane
        Call(0, 6, small),  # no Gaussians
        Call(20, 7, small, sh_degree=2),
        Call(20, 8, small, config=RenderConfig(tile_size=8)),  # the same pixels in other tiles
        Call(20, 9, odd, stats=True, config=RenderConfig(distortion="paper", background=(0.2, 0.5, 1.0))),
        Call(10, 10, wide, sh_degree=0),
    ]


def test_scratch_follows_sizes_counts_degrees_and_statistics(device):
    """Renders through one scratch that change the number of Gaussians, the image size, the tiles, the SH degree and
    the statistics between them, in order, reversed and shuffled: each the same as a render without a scratch (a
    spare of other sizes is never handed out, one of the same sizes holds nothing over)."""
    calls = _mixed_calls()
    shuffled = torch.randperm(len(calls), generator=torch.Generator().manual_seed(0)).tolist()
    order = calls + calls[::-1] + [calls[i] for i in shuffled]
    scratch = RenderScratch()
    for call in order:
        _assert_same(call.render(device, scratch), call.render(device, None), device)


def test_spares_are_reused(device):
    """A forward + backward gives its arrays back, and the next render of the same sizes takes those very ones (the
    pool works, the tests above are not passing on fresh arrays)."""
    scratch = RenderScratch()
    call = Call(15, 1, _camera(40, 30), stats=True)
    call.render(device, scratch)
    kept = {id(s) for s in scratch.pool.spares()}
    assert {type(s) for s in scratch.pool.spares()} == {SplatScratch, PixelScratch, GradScratch}
    leaves, stats, out = Call(15, 2, _camera(40, 30, eye=(0.0, 3.0, 0.5))).forward(device, scratch)
    assert [type(s) for s in scratch.pool.spares()] == [GradScratch]  # the forward took the other two
    _backward(leaves, stats, out)
    assert {id(s) for s in scratch.pool.spares()} == kept


def test_overlapping_renders_and_renders_without_backward(device):
    """Several renders of the same sizes in flight before their backwards (as several views of a step could be),
    backwards in reverse order, and renders that are never back-propagated (``no_grad``, inputs without gradients)
    in between: each as a render without a scratch, so no forward was handed arrays another's backward still reads."""
    scratch = RenderScratch()
    cams = [_camera(40, 30), _camera(40, 30, eye=(0.0, 3.0, 0.5)), _camera(40, 30, eye=(2.5, 0.5, 1.5))]
    calls = [Call(30, seed, cam, stats=seed == 1) for seed, cam in enumerate(cams)]
    for _ in range(2):
        pending = [call.forward(device, scratch) for call in calls]
        params = _params(30, 5, device)
        with torch.no_grad():
            rasterize(*params, cams[1], scratch=scratch)
        rasterize(*params, cams[2], scratch=scratch)  # no input requires a gradient
        got = [_backward(*f) for f in reversed(pending)]
        for call, result in zip(reversed(calls), got):
            _assert_same(result, call.render(device, None), device)


def test_shared_settings_follow_the_config_and_the_camera(device):
    """The settings struct shared between renders is the one for the config's current values (changed in place
    between renders) and the camera's own near plane."""
    scratch = RenderScratch()
    config = RenderConfig()
    cam = _camera(40, 30)
    for change in ({}, {"background": (0.2, 0.5, 1.0)}, {"distortion": "paper", "tile_size": 8}, {"tile_cull": False},
                   {"background": [0.0, 0.0, 0.0], "distortion": "gof", "tile_size": 16}, {"near": 1.0}):
        for k, v in change.items():
            setattr(config, k, v)
        call = Call(30, 7, cam, config=config)
        _assert_same(call.render(device, scratch), dataclasses.replace(call, config=RenderConfig(**vars(config)))
                     .render(device, None), device)  # fmt: skip
    for near in (1.5, 0.0):
        call = Call(30, 7, _camera(40, 30, near=near))
        _assert_same(call.render(device, scratch), call.render(device, None), device)


def test_statistics_accumulate_the_same_with_a_scratch(device):
    """Densification statistics kept over several renders (as over a densification interval) that reuse spares."""
    params = _params(25, 8, device)
    cams = [_camera(40, 30), _camera(40, 30, eye=(0.0, 3.0, 0.5)), _camera(33, 47, eye=(2.5, 0.5, 1.5))]
    results = []
    for scratch in (RenderScratch(), None):
        stats = DensifyStats(25, device)
        for cam in cams + cams:
            leaves = [p.clone().requires_grad_(True) for p in params]
            out = rasterize(*leaves, cam, stats=stats, scratch=scratch)
            (out["rgb"].sum() + out["median_depth"].sum()).backward()
        results.append(stats)
    for k in STATS:
        if device == "cpu" or k not in ("grad2d", "grad2d_abs"):
            assert torch.equal(getattr(results[0], k), getattr(results[1], k)), k
        else:
            torch.testing.assert_close(getattr(results[0], k), getattr(results[1], k), rtol=CUDA_GRAD_RTOL, atol=0.0)


def _pixel_bytes(cam, tile_size=16) -> int:
    tiles = -(-cam.width // tile_size) * -(-cam.height // tile_size)
    return 20 * cam.width * cam.height + 8 * tiles


def test_what_a_scratch_holds_is_bounded():
    """Counts and image sizes that keep changing: the spares are those of the latest count (a forward's 172 and a
    backward's 76 bytes a Gaussian) and of the 4 latest image sizes, whatever came before; :meth:`clear` frees them;
    the struct caches keep ``max_views`` entries."""
    scratch = RenderScratch(max_views=3)
    sizes = [(w, h) for w in (16, 24, 40) for h in (16, 30)]
    recent = []  # image sizes, the least recently rendered first
    for i in range(14):
        n = 5 + 3 * i
        size = sizes[i % len(sizes)] if i < 10 else sizes[1]
        Call(n, i, _camera(*size, eye=(0.1 * i, -3.0, 0.0)), num_coeffs=1).render("cpu", scratch)
        recent = [s for s in recent if s != size] + [size]
        assert scratch.nbytes() == 268 * n + sum(_pixel_bytes(_camera(*s)) for s in recent[-4:])
        assert len(scratch.pool.spares()) == 2 + len(recent[-4:])
    assert scratch._camera_params.cache_info().currsize == 3
    assert scratch._raster_settings.cache_info().currsize == 3
    scratch.clear()
    assert scratch.nbytes() == 0 and not scratch.pool.spares()
    Call(5, 0, _camera(16, 16)).render("cpu", scratch)  # and it works on after a clear
    assert scratch.nbytes() == 268 * 5 + _pixel_bytes(_camera(16, 16))


def test_scratch_pool_rules():
    """Spares come back for the same kind and exact sizes only, holding no array of the render that gave them back; a
    scratch is given back once, to its own pool; at most ``max_spares`` of a size are kept, and only the latest
    ``kind.sizes_kept`` sizes."""
    device = wp.get_device("cpu")
    pool = ScratchPool(max_spares=2)
    a, b, c = (pool.take(SplatScratch, device, 10) for _ in range(3))
    a.splats.opacity = wp.zeros(10, dtype=float, device=device)  # as a render leaves it
    pool.give(a, b, c)
    assert a.splats.opacity is None
    assert len(pool.spares()) == 2  # max_spares
    with pytest.raises(ValueError, match="given back already"):
        pool.give(a)
    with pytest.raises(ValueError, match="not a scratch taken from this pool"):
        ScratchPool().give(pool.take(SplatScratch, device, 10))
    assert pool.take(SplatScratch, device, 11).mu_v.shape == (11,)  # another count: a new one, the 10s freed
    assert not pool.spares()
    px = pool.take(PixelScratch, device, 64, 4)
    px.lists.values = wp.zeros(3, dtype=wp.int32, device=device)
    pool.give(px)
    assert px.lists.values is None
    assert pool.take(PixelScratch, device, 64, 2) is not px  # same pixels, other tiles
    assert pool.take(PixelScratch, device, 64, 4) is px
    pool.give(px)
    for size in range(1, 5):  # four more image sizes: the first one's spare is dropped
        pool.give(pool.take(PixelScratch, device, size, 1))
    assert px not in pool.spares() and len(pool.spares()) == 4
    g = pool.take(GradScratch, device, 10)
    assert g.packed.shape == (10, 16) and g.packed.ptr % 16 == 0
    pool.give(g)
    assert pool.take(GradScratch, device, 10) is g
    empty = ScratchPool(max_spares=0)
    empty.give(empty.take(SplatScratch, device, 10))
    assert not empty.spares()


def test_a_scratch_is_checked():
    params = _params(4, 0, "cpu")
    with pytest.raises(TypeError, match="scratch must be a RenderScratch"):
        rasterize(*params, _camera(16, 16), scratch=ScratchPool())


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA (written for a GPU run; not run on the CPU)")
def test_spares_stay_on_their_stream():
    """Renders on a side stream and on the default stream, alternating, through one scratch: spares are filed per
    stream, and every result is that of a render without a scratch."""
    scratch = RenderScratch()
    side = torch.cuda.Stream()
    calls = [Call(30, seed, _camera(40, 30, eye=(0.3 * seed, -3.0, 0.5))) for seed in range(4)]
    for i, call in enumerate(calls + calls):
        stream = side if i % 2 else torch.cuda.current_stream()
        stream.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(stream):
            got = call.render("cuda", scratch)
            want = call.render("cuda", None)  # a short-lived Warp wrapper of the same stream
        torch.cuda.synchronize()
        _assert_same(got, want, "cuda")
    handles = {where[2] for where in scratch.pool._slots}
    assert handles == {side.cuda_stream, torch.cuda.default_stream().cuda_stream}
