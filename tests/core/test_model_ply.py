"""Gaussian model: activations, initialisation, 3DGS PLY interchange, bad input."""

import math
import struct

import numpy as np
import pytest
import torch

from gof_warp.core.errors import ModelError, PlyError
from gof_warp.core.model import SH_C0, Gaussians, num_sh_coeffs


def _random_gaussians(n=50, degree=3, seed=0, filter_3d=False):
    gen = torch.Generator().manual_seed(seed)
    k = num_sh_coeffs(degree)
    return Gaussians(
        means=torch.randn(n, 3, generator=gen),
        quats=torch.randn(n, 4, generator=gen),
        log_scales=torch.randn(n, 3, generator=gen) - 3,
        opacity_logits=torch.randn(n, generator=gen),
        sh_dc=torch.randn(n, 3, generator=gen),
        sh_rest=torch.randn(n, k - 1, 3, generator=gen),
        filter_3d=torch.rand(n, generator=gen) * 0.01 if filter_3d else None,
    )


@pytest.mark.parametrize("degree", [0, 1, 3])
@pytest.mark.parametrize("with_filter", [False, True])
def test_ply_round_trip_is_exact(tmp_path, degree, with_filter):
    g = _random_gaussians(degree=degree, filter_3d=with_filter)
    path = tmp_path / "pc.ply"
    g.save_ply(path)
    h = Gaussians.load_ply(path, device="cpu")
    assert h.max_sh_degree == degree
    for name in g.params:
        torch.testing.assert_close(h.params[name], g.params[name], rtol=0, atol=0)
    if with_filter:
        torch.testing.assert_close(h.filter_3d, g.filter_3d, rtol=0, atol=0)
    else:
        assert h.filter_3d is None
    assert not list(tmp_path.glob(".*.tmp")), "atomic write left a temporary file"


def _write_independent_ply(path, fmt, rows, names):
    """A 3DGS PLY written without our writer: explicit header text and struct packing."""
    header = f"ply\nformat {fmt} 1.0\ncomment written by the test\nelement vertex {len(rows)}\n"
    header += "".join(f"property float {n}\n" for n in names) + "end_header\n"
    with open(path, "wb") as f:
        f.write(header.encode())
        for r in rows:
            if fmt == "ascii":
                f.write((" ".join(repr(float(v)) for v in r) + "\n").encode())
            else:
                f.write(struct.pack(("<" if fmt == "binary_little_endian" else ">") + "f" * len(r), *r))


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_reads_ply_written_by_independent_code(tmp_path, fmt):
    # Degree 1: 9 f_rest values, channel-major as 3DGS writes them. Properties in a shuffled order.
    rng = np.random.default_rng(3)
    n = 7
    base = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + [f"f_rest_{i}" for i in range(9)] + [
        "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    order = list(rng.permutation(base))
    values = {name: rng.normal(size=n).astype(np.float32) for name in base}
    rows = [[values[name][i] for name in order] for i in range(n)]
    path = tmp_path / "other.ply"
    _write_independent_ply(path, fmt, rows, order)
    g = Gaussians.load_ply(path, device="cpu")
    assert len(g) == n and g.max_sh_degree == 1
    np.testing.assert_allclose(g.means.numpy()[:, 1], values["y"], rtol=1e-6)
    np.testing.assert_allclose(g.opacity_logits.numpy(), values["opacity"], rtol=1e-6)
    np.testing.assert_allclose(g.quats.numpy()[:, 0], values["rot_0"], rtol=1e-6)
    # f_rest_{c*3 + k} is coefficient k of channel c.
    np.testing.assert_allclose(g.sh_rest.numpy()[:, 2, 1], values["f_rest_5"], rtol=1e-6)
    np.testing.assert_allclose(g.sh_rest.numpy()[:, 0, 2], values["f_rest_6"], rtol=1e-6)
    # Activations follow the 3DGS definitions.
    np.testing.assert_allclose(g.scales.numpy()[:, 2], np.exp(values["scale_2"]), rtol=1e-5)
    np.testing.assert_allclose(g.opacities.numpy(), 1 / (1 + np.exp(-values["opacity"])), rtol=1e-5)


def test_truncated_and_corrupt_ply_name_the_file(tmp_path):
    g = _random_gaussians(n=20, degree=0)
    good = tmp_path / "good.ply"
    g.save_ply(good)
    data = good.read_bytes()
    trunc = tmp_path / "trunc.ply"
    trunc.write_bytes(data[:-10])
    with pytest.raises(PlyError, match=r"trunc\.ply.*truncated"):
        Gaussians.load_ply(trunc)
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"\x00\x01binary junk")
    with pytest.raises(PlyError, match="garbage.ply: not a PLY"):
        Gaussians.load_ply(garbage)
    no_end = tmp_path / "noend.ply"
    no_end.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n")
    with pytest.raises(PlyError, match="end_header"):
        Gaussians.load_ply(no_end)
    with pytest.raises(PlyError, match="not found"):
        Gaussians.load_ply(tmp_path / "missing.ply")


def test_mesh_ply_is_not_a_gaussian_ply(tmp_path):
    path = tmp_path / "mesh.ply"
    _write_independent_ply(path, "ascii", [[0, 0, 0], [1, 0, 0]], ["x", "y", "z"])
    with pytest.raises(PlyError, match="missing properties"):
        Gaussians.load_ply(path)


def test_bad_sh_count_and_nan_values_are_rejected(tmp_path):
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "f_rest_0", "f_rest_1", "opacity",
             "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    path = tmp_path / "badsh.ply"
    _write_independent_ply(path, "binary_little_endian", [[0.0] * len(names)], names)
    with pytest.raises(PlyError, match="SH degree"):
        Gaussians.load_ply(path)
    g = _random_gaussians(n=5, degree=0)
    g.params["log_scales"][3, 1] = float("-inf")  # zero scale
    path = tmp_path / "nan.ply"
    g.save_ply(path)
    with pytest.raises(PlyError, match=r"nan\.ply.*log_scales.*index \[3\]"):
        Gaussians.load_ply(path)


def test_activations_and_3d_filter():
    g = _random_gaussians(n=30, filter_3d=True)
    s = torch.exp(g.log_scales)
    phi = g.filter_3d[:, None]
    torch.testing.assert_close(g.scales, torch.sqrt(s**2 + phi**2))
    expected_o = torch.sigmoid(g.opacity_logits) * torch.sqrt(torch.prod(s**2, 1) / torch.prod(s**2 + phi**2, 1))
    torch.testing.assert_close(g.opacities, expected_o)
    torch.testing.assert_close(g.rotations.norm(dim=1), torch.ones(30))
    assert g.sh.shape == (30, 16, 3)
    torch.testing.assert_close(g.sh[:, 0], g.sh_dc)


def test_from_points_matches_brute_force_knn():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(200, 3))
    cols = rng.integers(0, 256, size=(200, 3)).astype(np.uint8)
    g = Gaussians.from_points(pts, cols, sh_degree=2, device="cpu")
    d2 = ((pts[:, None] - pts[None]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    expected = np.sqrt(np.sort(d2, axis=1)[:, :3].mean(axis=1))
    np.testing.assert_allclose(g.scales.numpy()[:, 0], expected, rtol=1e-5)
    np.testing.assert_allclose(g.opacities.numpy(), 0.1, rtol=1e-5)
    np.testing.assert_allclose(g.sh_dc.numpy() * SH_C0 + 0.5, cols / 255.0, atol=1e-6)
    assert g.active_sh_degree == 0 and g.max_sh_degree == 2 and g.sh_rest.shape == (200, 8, 3)


def test_from_activated_validates():
    m = np.zeros((3, 3))
    q = np.tile([1.0, 0, 0, 0], (3, 1))
    with pytest.raises(ModelError, match="positive"):
        Gaussians.from_activated(m, q, np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1.0]]), np.ones(3) * 0.5, device="cpu")
    with pytest.raises(ModelError, match=r"opacities must be \[N\] in \[0, 1\]"):
        Gaussians.from_activated(m, q, np.ones((3, 3)), np.array([0.5, 1.5, 0.5]), device="cpu")
    with pytest.raises(ModelError, match="NaN"):
        Gaussians.from_activated(m * np.nan, q, np.ones((3, 3)), np.ones(3) * 0.5, device="cpu")
    g = Gaussians.from_activated(m, q, np.full((3, 3), 0.2), np.array([0.0, 0.5, 1.0]), device="cpu")
    np.testing.assert_allclose(g.scales.numpy(), 0.2, rtol=1e-6)
    np.testing.assert_allclose(g.opacities.numpy(), [1e-6, 0.5, 1 - 1e-6], atol=1e-6)


def test_shape_errors_and_subset():
    with pytest.raises(ModelError, match="quats must have shape"):
        Gaussians(means=torch.zeros(4, 3), quats=torch.zeros(3, 4), log_scales=torch.zeros(4, 3),
                  opacity_logits=torch.zeros(4), sh_dc=torch.zeros(4, 3))
    g = _random_gaussians(n=10, degree=1)
    sub = g.subset(torch.arange(10) % 2 == 0)
    assert len(sub) == 5 and sub.max_sh_degree == 1
    torch.testing.assert_close(sub.means, g.means[::2])
    g.requires_grad_(True)
    loss = g.scales.sum() + g.opacities.sum() + g.rotations.sum()
    loss.backward()
    assert all(g.params[k].grad is not None for k in ("log_scales", "opacity_logits", "quats"))
    assert math.isclose(float(g.params["log_scales"].grad.sum()), float(g.raw_scales.detach().sum()), rel_tol=1e-5)


def test_mesh_ply_written_by_us_reads_back_exactly_in_trimesh_and_refuses_bad_meshes(tmp_path):
    import trimesh

    from gof_warp.core.ply import write_ply_mesh

    rng = np.random.default_rng(3)
    v = rng.normal(size=(50, 3)).astype(np.float32)
    f = rng.integers(0, 50, size=(70, 3))
    path = tmp_path / "m.ply"
    write_ply_mesh(path, v.astype(np.float64), f)
    m = trimesh.load(path, process=False, force="mesh")
    np.testing.assert_array_equal(np.asarray(m.vertices, np.float32), v)
    np.testing.assert_array_equal(np.asarray(m.faces), f)
    body = path.read_bytes().split(b"end_header\n", 1)[1]
    assert len(body) == 50 * 12 + 70 * 13, "float32 xyz per vertex, a uchar count and three int32 per face"
    assert struct.unpack("<B3i", body[600:613]) == (3, *f[0].tolist())
    write_ply_mesh(tmp_path / "empty.ply", np.zeros((0, 3)), np.zeros((0, 3), int))  # an empty mesh is a valid file
    assert len(trimesh.load(tmp_path / "empty.ply", process=False, force="mesh").faces) == 0
    before = path.read_bytes()
    for bad_v, bad_f, match in ((v[:, :2], f, "vertices"), (v, f[:, :2], "faces"), (v, f + 50, "outside"),
                                (v, -f - 1, "outside")):
        with pytest.raises(PlyError, match=match):
            write_ply_mesh(path, bad_v, bad_f)
    assert path.read_bytes() == before, "a refused mesh leaves the file already there as it was"


def _activation_grads(model, fn):
    """Activated parameters of ``model`` through ``model.activated(fn)`` and the raw parameters' gradients of a fixed
    weighted sum of them."""
    for p in model.params.values():
        p.grad = None
        p.requires_grad_(True)
    a = model.activated(fn)
    weights = [torch.linspace(-1.0, 2.0, t.numel()).reshape(t.shape) for t in (a.rotations, a.scales, a.opacities)]
    sum(((t * w).sum() for t, w in zip((a.rotations, a.scales, a.opacities), weights))).backward()
    return (a.rotations.detach(), a.scales.detach(), a.opacities.detach()), {
        k: p.grad.clone() for k, p in model.params.items() if p.grad is not None}


@pytest.mark.parametrize("with_filter", [False, True])
def test_activated_is_the_properties_bit_for_bit(with_filter):
    """``Gaussians.activated()`` (the trainer's render input) gives the properties' values, and gradients to the raw
    parameters equal to reading ``rotations``, ``scales`` and ``opacities`` one by one, bit for bit (same operations in
    the same order); it passes ``means``, the SH coefficients and the active degree through."""
    g = _random_gaussians(filter_3d=with_filter)
    a = g.activated()
    assert a.means is g.means and a.sh_dc is g.sh_dc and a.sh_rest is g.sh_rest
    assert a.active_sh_degree == g.active_sh_degree
    values, grads = _activation_grads(g, None)
    for p in g.params.values():
        p.grad = None
    props = (g.rotations, g.scales, g.opacities)
    weights = [torch.linspace(-1.0, 2.0, t.numel()).reshape(t.shape) for t in props]
    sum(((t * w).sum() for t, w in zip(props, weights))).backward()
    for got, want in zip(values, props):
        assert torch.equal(got, want.detach())
    assert set(grads) == {"quats", "log_scales", "opacity_logits"}
    for k, grad in grads.items():
        assert torch.equal(grad, g.params[k].grad), k


@pytest.mark.slow
def test_compiled_activation_follows_the_gaussian_count_without_recompiling():
    """``Activation(compiled=True)`` (``torch.compile`` with dynamic N; backend ``aot_eager`` here) gives the eager
    activations and gradients for models of different sizes, with and without the 3D filter, compiling one graph for
    each filter state and none more when densification changes N."""
    from gof_warp.core.model import Activation

    torch._dynamo.reset()
    torch._dynamo.utils.counters.clear()
    act = Activation(True, strict=True, backend="aot_eager")
    for n in (40, 57, 91):
        for with_filter in (True, False):
            g = _random_gaussians(n=n, seed=n, filter_3d=with_filter)
            got = _activation_grads(g, act)
            want = _activation_grads(g, None)
            for a, b in zip(got[0], want[0]):
                torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)
            assert set(got[1]) == set(want[1])
            for k in want[1]:
                torch.testing.assert_close(got[1][k], want[1][k], rtol=1e-5, atol=1e-7)
    assert act.compiled and act.fallback_reason is None
    assert torch._dynamo.utils.counters["stats"]["unique_graphs"] == 2  # filter set / not set; N is symbolic


@pytest.mark.slow
def test_activation_falls_back_to_eager_unless_strict(caplog):
    """A compiler failure: the non-strict activation warns, says why and computes the eager activations from then on;
    the strict one raises."""
    from gof_warp.core.model import Activation

    def broken(graph, example_inputs):
        raise RuntimeError("no compiler here")

    torch._dynamo.reset()
    g = _random_gaussians(filter_3d=True)
    with pytest.raises(Exception, match="no compiler here"):
        Activation(True, strict=True, backend=broken)(g.quats, g.log_scales, g.opacity_logits, g.filter_3d)
    torch._dynamo.reset()
    act = Activation(True, backend=broken)
    with caplog.at_level("WARNING"):
        values, _ = _activation_grads(g, act)
    assert not act.compiled and "no compiler here" in act.fallback_reason
    assert "torch.compile of the activations failed" in caplog.text
    for got, want in zip(values, (g.rotations, g.scales, g.opacities)):
        assert torch.equal(got, want.detach())


@pytest.mark.slow
def test_pointwise_activation_has_no_reduction_for_the_compiler():
    """``activate_pointwise`` (what ``Activation`` compiles) traces to forward and backward graphs without a reduction
    op, so inductor can fuse each into one pointwise kernel (``activate``'s ``F.normalize`` traces to a row reduction:
    the check below finds it there, so it can fail), and it gives ``activate``'s values to one float32 rounding."""
    from functorch.compile import make_boxed_func
    from torch._functorch.aot_autograd import aot_function

    from gof_warp.core.model import activate, activate_pointwise

    def ops_of(fn, g):
        seen = []

        def record(gm, _):
            seen.extend(str(n.target) for n in gm.graph.nodes if n.op == "call_function")
            return make_boxed_func(gm)

        out = aot_function(fn, fw_compiler=record, bw_compiler=record)(g.quats, g.log_scales, g.opacity_logits,
                                                                        g.filter_3d)
        sum(t.sum() for t in out).backward()
        return seen

    reductions = ("sum", "norm", "amax", "mean", "prod")
    g = _random_gaussians(filter_3d=True)
    for p in g.params.values():
        p.requires_grad_(True)
    assert any(r in op for op in ops_of(activate, g) for r in reductions)
    ops = ops_of(activate_pointwise, g)
    assert ops and not [op for op in ops if any(r in op for r in reductions)]
    for got, want in zip(activate_pointwise(g.quats, g.log_scales, g.opacity_logits, g.filter_3d),
                         activate(g.quats, g.log_scales, g.opacity_logits, g.filter_3d)):
        torch.testing.assert_close(got, want, rtol=3e-7, atol=1e-7)
