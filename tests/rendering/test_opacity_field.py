"""Opacity field: tile-binned Warp evaluation vs a float64 brute force; the analytic isotropic case."""

import dataclasses
import math

import numpy as np
import pytest
import torch
import warp as wp

from gof_warp.core.camera import look_at
from gof_warp.core.model import Gaussians
from gof_warp import kernels as K
from gof_warp.rendering.opacity_field import OpacityFieldConfig, _min_over_views, _view_inputs, opacity_field
from gof_warp.rendering.render import RenderConfig, render

# float32 kernel vs float64 reference: sums of ≤ 30 terms of O(1) → ~1e-6; decisions near the alpha_min
# threshold can flip a ≤ 1/255 contribution, which the scenes below avoid by construction (see _scene).
FIELD_TOL = 2e-5


def _rotation(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def reference_field(means, quats, scales, opac, cameras, points, cfg: RenderConfig, unseen=1.0):
    """float64 brute force: every point against every Gaussian, per view, min over the views that see it."""
    out = np.full(len(points), np.inf)
    k2 = cfg.k_max**2
    for cam in cameras:
        clip = max(cfg.near, cam.near)  # the camera's own clip culls Gaussians; points are seen from cfg.near on
        mu_v = means @ cam.R.T + cam.t
        order = np.argsort(mu_v[:, 2], kind="stable")
        Ps = [np.diag(1 / scales[k]) @ (cam.R @ _rotation(quats[k])).T for k in range(len(means))]
        for i, x in enumerate(points):
            xv = cam.R @ x + cam.t
            z = xv[2]
            if z <= cfg.near:
                continue
            u, v = cam.fx * xv[0] / z + cam.cx, cam.fy * xv[1] / z + cam.cy
            if not (0 <= u < cam.width and 0 <= v < cam.height):
                continue
            r = xv / z
            T, O = 1.0, 0.0
            for k in order:
                if mu_v[k, 2] <= clip:
                    continue
                og, rg = -Ps[k] @ mu_v[k], Ps[k] @ r
                A, B, C = rg @ rg, og @ rg, og @ og
                ts = -B / A
                if ts <= clip or C - B * B / A > k2:
                    continue
                xg = og + min(ts, z) * rg
                alpha = min(cfg.alpha_max, opac[k] * math.exp(-0.5 * xg @ xg))
                if alpha < cfg.alpha_min:
                    continue
                O += alpha * T
                T *= 1 - alpha
                if T < cfg.transmittance_min:
                    break
            out[i] = min(out[i], O)
    return np.where(np.isinf(out), unseen, out)


def _cameras(n=5, w=37, h=29):
    cams = []
    for a in range(n):
        ang = 2 * np.pi * a / n
        cams.append(look_at([2.5 * np.cos(ang), 2.5 * np.sin(ang), 0.6 * (-1) ** a], [0, 0, 0], fx=40, fy=44,
                            cx=w / 2 + 1.7, cy=h / 2 - 2.2, width=w, height=h, name=f"c{a}"))
    return cams


def _scene(n=25, seed=0):
    rng = np.random.default_rng(seed)
    means = rng.uniform(-0.5, 0.5, (n, 3))
    quats = rng.normal(size=(n, 4))
    scales = np.exp(rng.uniform(np.log(0.03), np.log(0.25), (n, 3)))
    opac = rng.uniform(0.2, 0.95, n)
    return means, quats, scales, opac


def test_field_matches_float64_brute_force():
    means, quats, scales, opac = _scene()
    g = Gaussians.from_activated(means, quats, scales, opac, device="cpu")
    cams = _cameras()
    rng = np.random.default_rng(1)
    points = np.concatenate([rng.uniform(-0.8, 0.8, (300, 3)), means + 0.05 * rng.normal(size=means.shape),
                             [[0, 0, 30.0], [5, 5, 5]]])  # the last two are outside every view
    cfg = RenderConfig()
    got, seen = opacity_field(g, cams, points, render_config=cfg, return_seen=True)
    ref = reference_field(means, g.rotations.numpy().astype(np.float64), g.scales.numpy().astype(np.float64),
                          g.opacities.numpy().astype(np.float64), cams, points, cfg)
    np.testing.assert_allclose(got.numpy(), ref, atol=FIELD_TOL)
    assert seen[-1] == 0 and seen[-2] == 0 and got[-1] == 1.0
    # another value for unseen points changes only those points
    zero = opacity_field(g, cams, points, config=OpacityFieldConfig(unseen_value=0.0), render_config=cfg)
    np.testing.assert_array_equal(zero.numpy()[seen.numpy() > 0], got.numpy()[seen.numpy() > 0])
    assert zero[-1] == 0.0 and zero[-2] == 0.0
    assert (ref > 0.05).sum() > 50 and (ref < 0.01).sum() > 50, "the scene must exercise both regimes"


def _field_and_reference(means, quats, scales, opac, cams, points, **kwargs):
    """``(field, seen)`` of the Warp kernels and the float64 reference on the activated parameters."""
    g = Gaussians.from_activated(means, quats, scales, opac, device="cpu")
    cfg = RenderConfig()
    field, seen = opacity_field(g, cams, points, render_config=cfg, return_seen=True, **kwargs)
    ref = reference_field(np.asarray(means, dtype=np.float64), g.rotations.numpy().astype(np.float64),
                          g.scales.numpy().astype(np.float64), g.opacities.numpy().astype(np.float64), cams, points, cfg)
    return field.numpy(), seen.numpy(), ref


def test_cameras_with_their_own_clip_match_float64_brute_force():
    """Cameras with near planes of their own (the trainer's, from the SfM points): Gaussians closer than the clip are
    left out of that view, points between the scene's near plane and the clip are still seen by it."""
    means, quats, scales, opac = _scene(30, seed=4)
    cams = [dataclasses.replace(cam, near=clip) for cam, clip in zip(_cameras(), (2.4, 0.0, 2.1, 2.6, 1.0))]
    rng = np.random.default_rng(5)
    pts = np.concatenate([rng.uniform(-0.7, 0.7, (150, 3)),
                          rng.uniform(-2.2, 2.2, (150, 3))])  # the second half reaches the cameras' clips
    got, seen, want = _field_and_reference(means, quats, scales, opac, cams, pts)
    np.testing.assert_allclose(got, want, atol=FIELD_TOL)
    assert (seen > 0).sum() > 200 and (want > 0.05).sum() > 30 and (want < 0.01).sum() > 30


def test_space_in_front_of_a_cameras_clip_is_not_closed_off():
    """Golden case: two cameras facing each other through an opaque blob; a point 0.5 in front of camera A, whose own
    clip is at 1.5. B sees the point behind the blob (opacity ~1); A looked through it (opacity ~0). The field is
    the minimum of the two, so the point is free space and no surface closes around camera A."""
    A = dataclasses.replace(look_at([3.0, 0, 0], [0, 0, 0], fx=40, fy=40, cx=20, cy=20, width=40, height=40), near=1.5)
    B = look_at([-3.0, 0, 0], [0, 0, 0], fx=40, fy=40, cx=20, cy=20, width=40, height=40)
    means, quats = np.zeros((1, 3)), np.array([[1.0, 0, 0, 0]])
    scales, opac = np.full((1, 3), 0.4), np.array([0.99])
    pts = np.array([[2.5, 0.0, 0.0], [-2.5, 0.0, 0.0]])  # 0.5 in front of A; 0.5 in front of B
    field, seen, ref = _field_and_reference(means, quats, scales, opac, [A, B], pts)
    np.testing.assert_allclose(field, ref, atol=FIELD_TOL)
    assert seen.tolist() == [2, 2]
    assert field[0] < 0.05 and field[1] < 0.05
    only_b, _, _ = _field_and_reference(means, quats, scales, opac, [B], pts)
    assert only_b[0] > 0.9  # what the field was when A did not count: the point closed inside


def test_isotropic_gaussian_field_is_closed_form():
    sigma, alpha0 = 0.2, 0.9
    g = Gaussians.from_activated(np.zeros((1, 3)), [[1.0, 0, 0, 0]], np.full((1, 3), sigma), [alpha0], device="cpu")
    cams = _cameras(n=8, w=64, h=64)
    rng = np.random.default_rng(2)
    dirs = rng.normal(size=(400, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    radii = rng.uniform(0.0, 0.6, 400)
    points = dirs * radii[:, None]
    cfg = RenderConfig(alpha_min=0.0, k_max=10.0)
    got = opacity_field(g, cams, points, render_config=cfg).numpy()
    expected = alpha0 * np.exp(-(radii**2) / (2 * sigma**2))
    # Min over views = the view whose ray passes closest to the centre at the point's depth: not exactly
    # the radial value unless some view looks straight through the point; with 8 views the min is within
    # a few percent of it and never below it (the field of one view is >= its value at the point itself).
    assert np.all(got >= expected - 1e-5)
    assert np.median(got - expected) < 0.02


def test_field_far_along_a_pixel_ray_equals_rendered_alpha():
    means, quats, scales, opac = _scene(seed=3)
    g = Gaussians.from_activated(means, quats, scales, opac, device="cpu")
    cam = _cameras(n=1)[0]
    out = render(g, cam)
    o, d = cam.pixel_rays()
    far_points = (o + 20.0 * d).reshape(-1, 3)
    got = opacity_field(g, [cam], far_points).numpy().reshape(cam.height, cam.width)
    np.testing.assert_allclose(got, out["alpha"].numpy(), atol=2e-5)


def test_empty_inputs():
    g = Gaussians.from_activated(np.zeros((0, 3)), np.zeros((0, 4)) + [1, 0, 0, 0], np.ones((0, 3)), np.zeros(0),
                                 device="cpu")
    cams = _cameras(n=2)
    got, seen = opacity_field(g, cams, np.array([[0.0, 0, 0], [50, 50, 50]]), return_seen=True)
    assert got.tolist() == [0.0, 1.0] and seen.tolist() == [2, 0]
    assert opacity_field(g, cams, np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ValueError, match="points"):
        opacity_field(g, cams, torch.full((2, 3), float("nan")))


@pytest.mark.slow
def test_the_point_tile_size_changes_speed_not_values():
    """The per-view lists the points read are binned on tiles of any size (CPU default 4 px, the renderer's 16 on a
    GPU): the field is bit-identical for every tile size, and matches the float64 reference; bad sizes are errors."""
    means, quats, scales, opac = _scene(seed=3)
    g = Gaussians.from_activated(means, quats, scales, opac, device="cpu")
    cams = _cameras()
    points = np.random.default_rng(4).uniform(-0.8, 0.8, (400, 3))
    cfg = RenderConfig()
    values = {t: opacity_field(g, cams, points, config=OpacityFieldConfig(tile_size=t), render_config=cfg).numpy()
              for t in (16, 8, 4, 2, 1)}
    for t in (8, 4, 2, 1):
        np.testing.assert_array_equal(values[t], values[16])
    np.testing.assert_array_equal(opacity_field(g, cams, points, render_config=cfg).numpy(), values[16])
    ref = reference_field(means, g.rotations.numpy().astype(np.float64), g.scales.numpy().astype(np.float64),
                          g.opacities.numpy().astype(np.float64), cams, points, cfg)
    np.testing.assert_allclose(values[4], ref, atol=FIELD_TOL)
    for bad in (0, -4, 2.5):
        with pytest.raises(ValueError, match="tile_size"):
            opacity_field(g, cams, points, config=OpacityFieldConfig(tile_size=bad), render_config=cfg)


def test_bounding_the_walk_by_the_running_minimum_changes_no_value():
    """A view stops compositing once its opacity reaches the minimum of the views before it; the opacity never
    falls along the walk, so the field is bit for bit the one of whole walks (dense scene: many walks do stop)."""
    means, quats, scales, opac = _scene(n=60, seed=7)
    g = Gaussians.from_activated(means, quats, scales, opac, device="cpu")
    cams = _cameras(n=7)
    rng = np.random.default_rng(8)
    points = np.concatenate([rng.uniform(-0.8, 0.8, (400, 3)), means + 0.1 * rng.normal(size=means.shape)])
    cfg = RenderConfig()
    got, got_seen = opacity_field(g, cams, points, render_config=cfg, config=OpacityFieldConfig(cpu_processes=1),
                                  return_seen=True)
    arrays, views = _view_inputs(g, cams, cfg)
    full, seen = wp.ones(len(points), dtype=float, device="cpu"), wp.zeros(len(points), dtype=wp.int32, device="cpu")
    _min_over_views(arrays, views, wp.array(points.astype(np.float32), dtype=wp.vec3, device="cpu"), full, seen,
                    kernel=K.opacity_min_over_view_whole)
    np.testing.assert_array_equal(got_seen.numpy(), seen.numpy())
    np.testing.assert_array_equal(got.numpy(), full.numpy())
    assert ((got.numpy() > 0.05) & (got.numpy() < 0.95)).sum() > 100, "the scene must exercise partial opacities"


def test_forked_processes_give_the_one_process_field():
    """On the CPU the points are shared out to forked processes (Warp runs a CPU kernel on one core): the field
    and the seen counts are the one-process ones bit for bit, for 1, 2 and 3 processes and several chunks."""
    means, quats, scales, opac = _scene(seed=5)
    g = Gaussians.from_activated(means, quats, scales, opac, device="cpu")
    cams = _cameras()
    points = np.random.default_rng(6).uniform(-0.8, 0.8, (301, 3))
    one, seen_one = opacity_field(g, cams, points, config=OpacityFieldConfig(cpu_processes=1), return_seen=True)
    for workers in (2, 3):
        cfg = OpacityFieldConfig(cpu_processes=workers, cpu_split_min_points=1, chunk_size=64)
        field, seen = opacity_field(g, cams, points, config=cfg, return_seen=True)
        assert torch.equal(field, one) and torch.equal(seen, seen_one), workers
    assert (seen_one > 0).any() and (one < 1).any()  # the scene is seen and not empty


RANK_CASES = ((3, 2), (2, 5))  # (ranks, cameras): a rank with no view (3 ranks, 2 cameras), and several views per rank


def _views_split_rank(rank, init_dir, result):
    """Spawned with 3 processes: each case of RANK_CASES in turn, in a gloo group of its first ``world`` processes (one
    set of interpreter start-ups for both cases)."""
    import torch.distributed as dist

    from gof_warp.training.distributed import Ranks, join_process_group

    means, quats, scales, opac = _scene(seed=8)
    g = Gaussians.from_activated(means, quats, scales, opac, device="cpu")
    points = np.random.default_rng(9).uniform(-0.8, 0.8, (203, 3))
    for world, cams_n in RANK_CASES:
        if rank >= world:
            continue
        # joined as the commands join theirs: a group that outlives its destroy call can abort the process at exit
        join_process_group(backend="gloo", init_method=f"file://{init_dir}/init_{world}", rank=rank, world_size=world)
        try:
            field, seen = opacity_field(g, _cameras(cams_n), points, config=OpacityFieldConfig(cpu_processes=1),
                                        return_seen=True, ranks=Ranks(rank=rank, world=world))
            result[(world, rank)] = (field.numpy().tobytes(), seen.numpy().tobytes())
        finally:
            dist.destroy_process_group()


@pytest.mark.slow
def test_views_shared_out_among_ranks_give_the_one_process_field(tmp_path):
    """torch.distributed (gloo) ranks each evaluate every world-th view and reduce (minimum, summed view counts):
    every rank ends with the one-process field and seen counts bit for bit, also when a rank has no view
    (3 ranks, 2 cameras)."""
    import torch.multiprocessing as mp

    means, quats, scales, opac = _scene(seed=8)
    g = Gaussians.from_activated(means, quats, scales, opac, device="cpu")
    points = np.random.default_rng(9).uniform(-0.8, 0.8, (203, 3))
    with mp.Manager() as manager:
        result = manager.dict()
        mp.spawn(_views_split_rank, args=(str(tmp_path), result), nprocs=max(w for w, _ in RANK_CASES), join=True)
        got = dict(result)
    for world, cams_n in RANK_CASES:
        one, seen_one = opacity_field(g, _cameras(cams_n), points, config=OpacityFieldConfig(cpu_processes=1),
                                      return_seen=True)
        assert (seen_one > 1).any() and (one < 1).any()  # several views see points: the reduction has work to do
        for rank in range(world):
            field = np.frombuffer(got[(world, rank)][0], np.float32)
            seen = np.frombuffer(got[(world, rank)][1], np.int32)
            np.testing.assert_array_equal(field, one.numpy(), err_msg=f"{world} ranks, rank {rank}")
            np.testing.assert_array_equal(seen, seen_one.numpy(), err_msg=f"{world} ranks, rank {rank}")
