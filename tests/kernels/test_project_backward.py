"""The renderer's gradient of ``preprocess_gaussians``: Warp's adjoint of ``project_frames`` plus the written-out
``sh_colour_backward``, against Warp's automatic adjoint of the whole kernel (which the float64 renderer tests check)
and against float64 central differences of the colour."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from gof_warp.kernels.gaussian_math import sh_basis
from gof_warp.kernels.project import SH_LANES, preprocess_gaussians, project_frames, sh_colour_backward

N, K = 65, 16  # odd: on CUDA the last warp holds one Gaussian's 16 lanes only
REL32 = 2e-5  # float32 sums of up to 16 products in another order


def _inputs(seed: int):
    rng = np.random.default_rng(seed)
    means = rng.normal(0.0, 1.0, (N, 3)) + np.array([0.0, 0.0, 4.0])
    quats = rng.normal(size=(N, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    scales = np.exp(rng.normal(-1.0, 0.5, (N, 3)))
    sh = rng.normal(0.0, 2.0, (N, K, 3))  # many channels clamped at 0: their colour passes no gradient
    angles = rng.normal(0.0, 0.2, 3)
    R = _rotation(angles)
    t = rng.normal(0.0, 0.3, 3)
    centre = -R.T @ t
    means[0] = centre  # at the camera centre: no view direction, no gradient through it (and no NaN)
    return means, quats, scales, sh, R, t, centre


def _rotation(a):
    cx, cy, cz, sx, sy, sz = *np.cos(a), *np.sin(a)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _arrays(means, quats, scales, sh, device):
    def arr(a, dtype):
        return wp.array(np.ascontiguousarray(a).astype(np.float32), dtype=dtype, device=device)

    dc, rest = arr(sh[:, 0], wp.vec3), arr(sh[:, 1:], wp.vec3)
    return arr(means, wp.vec3), arr(quats, wp.vec4), arr(scales, wp.vec3), dc, rest


def _grads(degree, means, quats, scales, sh, R, t, c, adj, split: bool, device="cpu", accumulate: int = 0, start=0.0):
    """Input gradients (means, quats, scales, sh_dc, sh_rest) for output gradients ``adj`` (mu_v, P, o_g, colour),
    added to arrays that hold ``start`` (``sh_colour_backward`` writes the SH rows unless ``accumulate``)."""
    m, q, s, dc, rest = _arrays(means, quats, scales, sh, device)
    outs = [wp.zeros(N, dtype=d, device=device) for d in (wp.vec3, wp.mat33, wp.vec3, wp.vec3)]
    Rm, tv, cv = wp.mat33(*R.astype(np.float32).ravel()), wp.vec3(*t), wp.vec3(*c)
    wp.launch(preprocess_gaussians, N, inputs=[m, q, s, dc, rest, degree, Rm, tv, cv], outputs=outs, device=device)
    grads = [wp.zeros_like(a) for a in (m, q, s, dc, rest)]
    for g in grads:
        g.fill_(start)
    adj_arrays = [wp.array(a.astype(np.float32), dtype=d, device=device)
                  for a, d in zip(adj, (wp.vec3, wp.mat33, wp.vec3, wp.vec3))]
    if split:
        wp.launch(project_frames, N, inputs=[m, q, s, Rm, tv], outputs=outs[:3],
                  adj_inputs=[*grads[:3], wp.mat33(), wp.vec3()], adj_outputs=adj_arrays[:3], adjoint=True,
                  device=device)
        wp.launch(sh_colour_backward, N * SH_LANES, inputs=[m, rest, degree, cv, outs[3], adj_arrays[3]],
                  outputs=[grads[0], grads[3], grads[4], accumulate], device=device)
    else:
        wp.launch(preprocess_gaussians, N, inputs=[m, q, s, dc, rest, degree, Rm, tv, cv], outputs=outs,
                  adj_inputs=[*grads, 0, wp.mat33(), wp.vec3(), wp.vec3()], adj_outputs=adj_arrays, adjoint=True,
                  device=device)
    return [g.numpy() for g in grads], outs[3].numpy()


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_split_backward_equals_the_automatic_adjoint(degree, device):
    means, quats, scales, sh, R, t, c = _inputs(degree)
    rng = np.random.default_rng(10 + degree)
    adj = (rng.normal(size=(N, 3)), rng.normal(size=(N, 3, 3)), rng.normal(size=(N, 3)), rng.normal(size=(N, 3)))
    split, colour = _grads(degree, means, quats, scales, sh, R, t, c, adj, split=True, device=device)
    auto, _ = _grads(degree, means, quats, scales, sh, R, t, c, adj, split=False, device=device)
    added, _ = _grads(degree, means, quats, scales, sh, R, t, c, adj, split=True, device=device, accumulate=1,
                      start=0.5)
    assert (colour == 0).any() and (colour > 0).any()  # both sides of the clamp are exercised
    for name, a, b, a_added in zip(("means", "quats", "scales", "sh_dc", "sh_rest"), split, auto, added):
        scale = max(np.abs(b).max(), 1e-12)
        np.testing.assert_allclose(a, b, atol=REL32 * scale, err_msg=name)
        np.testing.assert_allclose(a_added, b + 0.5, atol=REL32 * (scale + 0.5), err_msg=f"{name}, added into 0.5")
    if degree:  # the highest band's coefficients get gradients
        assert np.abs(split[4][:, (degree + 1) ** 2 - 2]).max() > 0
    assert np.isfinite(split[0]).all()


def _basis64(d):
    """3DGS's 16 SH basis functions (float64 closed forms, as ``sh_to_color`` applies them) at the rows of ``d [n, 3]``
    (not normalised here: the gradient tests differentiate them as polynomials); a list of 16 ``[n]`` arrays."""
    from gof_warp.kernels import gaussian_math as gm

    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    xx, yy, zz = x * x, y * y, z * z
    C = {n: float(getattr(gm, n)) for n in dir(gm) if n.startswith("SH_C")}
    return [np.full_like(x, C["SH_C0"]), -C["SH_C1"] * y, C["SH_C1"] * z, -C["SH_C1"] * x,
            C["SH_C2_0"] * x * y, C["SH_C2_1"] * y * z, C["SH_C2_2"] * (2 * zz - xx - yy), C["SH_C2_3"] * x * z,
            C["SH_C2_4"] * (xx - yy), C["SH_C3_0"] * y * (3 * xx - yy), C["SH_C3_1"] * x * y * z,
            C["SH_C3_2"] * y * (4 * zz - xx - yy), C["SH_C3_3"] * z * (2 * zz - 3 * xx - 3 * yy),
            C["SH_C3_4"] * x * (4 * zz - xx - yy), C["SH_C3_5"] * z * (xx - yy), C["SH_C3_6"] * x * (xx - 3 * yy)]


def _colour64(means, sh, degree, c):
    """float64 colour of every Gaussian (3DGS's SH basis), as sh_to_color."""
    d = means - c
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    basis = _basis64(d)
    col = sum(basis[j][:, None] * sh[:, j] for j in range((degree + 1) ** 2)) + 0.5
    return np.maximum(col, 0.0)


@wp.kernel
def _sh_basis_at(dirs: wp.array(dtype=wp.vec3), out: wp.array2d(dtype=wp.vec4)):
    """``out[i, j] = sh_basis(j, dirs[i])``; launch ``(n, 16)``."""
    i, j = wp.tid()
    out[i, j] = sh_basis(j, dirs[i])


def test_sh_basis_against_float64_closed_forms(device):
    """``sh_basis`` (branch-free: it computes every function and selects ``j``'s) gives each of the 16 functions and
    its gradient, against the float64 closed forms and their central differences, at random unit directions."""
    rng = np.random.default_rng(5)
    d = rng.normal(size=(257, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    out = wp.zeros((len(d), 16), dtype=wp.vec4, device=device)
    wp.launch(_sh_basis_at, out.shape, inputs=[wp.array(d, dtype=wp.vec3, device=device)], outputs=[out],
              device=device)
    got = out.numpy()  # [n, 16, 4]: (∂b/∂x, ∂b/∂y, ∂b/∂z, b)
    d64, h = d.astype(np.float64), 1e-5
    value = np.stack(_basis64(d64), axis=1)
    grad = np.stack([(np.stack(_basis64(d64 + h * e), axis=1) - np.stack(_basis64(d64 - h * e), axis=1)) / (2 * h)
                     for e in np.eye(3)], axis=-1)  # [n, 16, 3]; exact to ~1e-10 for these cubics
    # float32 rounding of terms no larger than ~4 stays under 1e-6 (2e-7 seen); a wrong term or sign is off by > 1e-3
    np.testing.assert_allclose(got[..., 3], value, rtol=0, atol=2e-6)
    np.testing.assert_allclose(got[..., :3], grad, rtol=0, atol=2e-6)


def test_colour_gradient_against_float64_central_differences():
    degree = 3
    means, quats, scales, sh, R, t, c = _inputs(7)
    rng = np.random.default_rng(8)
    w = rng.normal(size=(N, 3))
    zeros = (np.zeros((N, 3)), np.zeros((N, 3, 3)), np.zeros((N, 3)))
    (g_means, _, _, g_dc, g_rest), _ = _grads(degree, means, quats, scales, sh, R, t, c, (*zeros, w), split=True)
    h = 1e-6

    def loss(m, shc):  # Gaussian 0 sits at the camera centre: left out
        return float((w[1:] * _colour64(m[1:], shc[1:], degree, c)).sum())

    for i in range(1, 6):  # Gaussians 1..5, every coordinate and a few coefficients
        for a in range(3):
            e = np.zeros_like(means)
            e[i, a] = h
            fd = (loss(means + e, sh) - loss(means - e, sh)) / (2 * h)
            assert g_means[i, a] == pytest.approx(fd, rel=1e-3, abs=1e-4)
        for j, ch in ((0, 0), (3, 1), (9, 2), (15, 0)):
            e = np.zeros_like(sh)
            e[i, j, ch] = h
            fd = (loss(means, sh + e) - loss(means, sh - e)) / (2 * h)
            got = g_dc[i, ch] if j == 0 else g_rest[i, j - 1, ch]
            assert got == pytest.approx(fd, rel=1e-3, abs=1e-5)
