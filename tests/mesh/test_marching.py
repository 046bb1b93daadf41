"""Tetrahedral grid (points, Delaunay, cell filter), marching tetrahedra and marching cubes with binary search.

Float64 references here: crossing points of each tetrahedron edge (linear interpolation), bisection of a
bracket, quaternion rotations (scipy), the analytic sphere of one isotropic Gaussian.
"""

import itertools
import logging
import sys

import numpy as np
import pytest
import torch
import warp as wp
from scipy.spatial.transform import Rotation

from gof_warp.core.camera import look_at
from gof_warp.core.errors import GofError
from gof_warp.mesh.marching import marching_cubes, marching_tetrahedra, merge_keyed_pieces, search_edges
from gof_warp.mesh.delaunay import delaunay, orient_and_drop_degenerate
from gof_warp.mesh.tetra import (TetraConfig, filter_cells, level_band, tetra_points,
                            tetrahedral_grid)

EXACT_TOL = 2e-6  # float32 rounding of a point on a unit-size edge
SPHERE_TOL_8_STEPS = 2e-5  # radial error after 8 bisections: bracket/256, then linear, float32 positions
MC_TOL_6_STEPS = 2e-5  # same for marching cubes after 6 bisections of a 1/12 cell
BISECT_TOL = 1e-5  # float32 kernels vs float64 bisection reference on unit-size edges
TET = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], np.float32)
SIGMA, ALPHA = 0.5, 0.9  # the isotropic Gaussian of the analytic tests


def gaussian_field(x, level_sigma=SIGMA, alpha=ALPHA):
    """α exp(−r²/2σ²) of one isotropic Gaussian at the origin, seen from everywhere (numpy or torch)."""
    if isinstance(x, torch.Tensor):
        return alpha * torch.exp(-(x.double() ** 2).sum(1) / (2 * level_sigma**2))
    x = np.asarray(x, np.float64)
    return alpha * np.exp(-(x**2).sum(1) / (2 * level_sigma**2))


def sphere_radius(level, sigma=SIGMA, alpha=ALPHA):
    return sigma * np.sqrt(2 * np.log(alpha / level))


def reference_crossings(points, tet, values, level):
    """float64: {sorted edge: crossing point} of one tetrahedron, by linear interpolation."""
    out = {}
    for a, b in itertools.combinations(range(4), 2):
        i, j = tet[a], tet[b]
        fi, fj = float(values[i]), float(values[j])
        if (fi >= level) != (fj >= level):
            t = (fi - level) / (fi - fj)
            out[(min(i, j), max(i, j))] = (1 - t) * points[i].astype(np.float64) + t * points[j].astype(np.float64)
    return out


def edge_counts(faces):
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    und, n_und = np.unique(np.sort(directed, 1), axis=0, return_counts=True)
    _, n_dir = np.unique(directed, axis=0, return_counts=True)
    return n_und, n_dir


def assert_watertight_outward(v, f):
    n_und, n_dir = edge_counts(f)
    assert np.all(n_und == 2), "every edge must be shared by exactly two faces"
    assert np.all(n_dir == 1), "neighbouring faces must be wound consistently"
    vol = np.einsum("ij,ij->i", np.cross(v[f[:, 0]], v[f[:, 1]]), v[f[:, 2]]).sum() / 6
    assert vol > 0, "normals must point outwards (from high to low values)"
    return vol


# ---------------------------------------------------------------------------------------------- single tets
@pytest.mark.parametrize("flip", [False, True], ids=["positive", "negative"])
def test_single_tetrahedron_all_sign_patterns(device, flip):
    rng = np.random.default_rng(1)
    tet = np.array([[0, 1, 3, 2] if flip else [0, 1, 2, 3]], np.int32)
    level = 0.5
    for case in range(16):
        inside = np.array([case >> i & 1 for i in range(4)], bool)
        values = np.where(inside, rng.uniform(0.6, 1.0, 4), rng.uniform(0.0, 0.4, 4)).astype(np.float32)
        (v, f), = marching_tetrahedra(TET, tet, values, levels=[level], device=device)
        expected = reference_crossings(TET, tet[0], values, level)
        n_in = int(inside.sum())
        assert f.shape[0] == {0: 0, 1: 1, 2: 2, 3: 1, 4: 0}[n_in], case
        assert v.shape[0] == len(expected), case
        for p in expected.values():  # every expected crossing point is a vertex, exactly
            assert np.min(np.linalg.norm(v - p, axis=1)) < EXACT_TOL, case
        if f.shape[0] == 2:
            assert len(set(f[0]) & set(f[1])) == 2 and len(set(f.ravel())) == 4, case
        outward = TET[~inside].mean(0) - TET[inside].mean(0) if 0 < n_in < 4 else None
        for face in f:
            normal = np.cross(v[face[1]] - v[face[0]], v[face[2]] - v[face[0]])
            assert np.dot(normal, outward) > 0, f"case {case}: normal must point to the low side"


def test_two_tetrahedra_share_face_vertices(device):
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0.7, 0.7, 0.7]], np.float32)
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]], np.int32)  # share face (1, 2, 3)
    values = np.array([0.9, 0.8, 0.2, 0.1, 0.7], np.float32)
    (v, f), = marching_tetrahedra(points, tets, values, device=device)
    expected = {}
    for t in tets:
        expected.update(reference_crossings(points, t, values, 0.5))
    assert v.shape[0] == len(expected)  # shared edges (1,2), (1,3) give one vertex each
    for p in expected.values():
        assert np.min(np.linalg.norm(v - p, axis=1)) < EXACT_TOL
    assert f.shape[0] == 2 + 2  # two inside in both tets
    n_und, _ = edge_counts(f)
    assert n_und.max() == 2  # connected across the shared face


def test_binary_search_matches_float64_reference(device):
    rng = np.random.default_rng(2)
    points = rng.uniform(-1, 1, (60, 3)).astype(np.float32)
    tets = delaunay(points)
    level, steps = 0.5, 5
    field = lambda x: 0.5 + 0.4 * np.sin(2.0 * np.asarray(x, np.float64)).sum(1)  # noqa: E731
    values = field(points).astype(np.float32)
    (v, f), = marching_tetrahedra(points, tets, values, field, binary_steps=steps, device=device)
    ref = []
    for t in tets:
        for (i, j), _ in reference_crossings(points, t, values, level).items():
            a, b = (i, j) if values[i] >= level else (j, i)
            xa, xb = points[a].astype(np.float64), points[b].astype(np.float64)
            fa, fb = float(values[a]), float(values[b])
            for _ in range(steps):
                m = 0.5 * (xa + xb)
                fm = float(np.float32(field(m[None])[0]))
                xa, fa, xb, fb = (m, fm, xb, fb) if fm >= level else (xa, fa, m, fm)
            ref.append(xa + (fa - level) / (fa - fb) * (xb - xa))
    ref = np.unique(np.round(np.array(ref), 9), axis=0)
    assert v.shape[0] == ref.shape[0]
    dist = np.linalg.norm(v[:, None, :] - ref[None, :, :], axis=2).min(1)
    assert dist.max() < BISECT_TOL


def test_linear_field_search_is_exact():
    points = TET * 2.0
    field = lambda x: 1.0 - np.asarray(x, np.float64) @ np.array([0.3, 0.2, 0.1])  # noqa: E731
    values = field(points).astype(np.float32)
    tets = np.array([[0, 1, 2, 3]], np.int32)
    (v0, _), = marching_tetrahedra(points, tets, values, field, levels=[0.9], binary_steps=0, device="cpu")
    (v8, _), = marching_tetrahedra(points, tets, values, field, levels=[0.9], binary_steps=8, device="cpu")
    assert v0.shape[0] == 3 and np.abs(v0 - v8).max() < EXACT_TOL


# ---------------------------------------------------------------------------------------------- sphere
@pytest.fixture(scope="module")
def cloud():
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.2, 1.2, (1500, 3)).astype(np.float32)
    return points, delaunay(points)


def test_sphere_watertight_and_error_falls_with_steps(cloud, device):
    points, tets = cloud
    values = gaussian_field(points).astype(np.float32)
    r = sphere_radius(0.5)
    errors = []
    for steps in (0, 1, 3, 8):
        (v, f), = marching_tetrahedra(points, tets, values, gaussian_field, binary_steps=steps, device=device)
        vol = assert_watertight_outward(v, f)
        assert vol == pytest.approx(4 / 3 * np.pi * r**3, rel=0.3)  # coarse cloud, inscribed polyhedron
        errors.append(np.abs(np.linalg.norm(v, axis=1) - r).max())
    assert errors[-1] < SPHERE_TOL_8_STEPS
    assert errors[0] > 10 * errors[-1] and errors[1] < errors[0] and errors[2] < errors[1]


def test_several_levels_one_field_call_per_step(cloud):
    points, tets = cloud
    calls = []

    def field(x):
        calls.append(x.shape[0])
        return torch.as_tensor(gaussian_field(x))  # any array type may come back

    levels = (0.3, 0.5, 0.7)
    meshes = marching_tetrahedra(torch.from_numpy(points), tets, gaussian_field(points), field, levels=levels,
                                 binary_steps=4, device="cpu")
    assert len(calls) == 4 and calls[0] == sum(v.shape[0] for v, _ in meshes)
    for (v, f), lv in zip(meshes, levels):
        assert_watertight_outward(v, f)
        assert np.abs(np.linalg.norm(v, axis=1) - sphere_radius(lv)).max() < 1e-3


def test_chunked_equals_unchunked(cloud):
    points, tets = cloud
    values = gaussian_field(points)
    (v1, f1), = marching_tetrahedra(points, tets, values, device="cpu")
    (v2, f2), = marching_tetrahedra(points, torch.from_numpy(tets), values, chunk_size=777, device="cpu")
    np.testing.assert_array_equal(f1, f2)
    np.testing.assert_array_equal(v1, v2)
    # Warp arrays in, the field gets Warp arrays: same mesh as numpy in, numpy to the field
    (v3, f3), = marching_tetrahedra(points, tets, values, gaussian_field, binary_steps=2, device="cpu")
    (v4, f4), = marching_tetrahedra(wp.array(points, dtype=wp.vec3, device="cpu"),
                                    wp.array(tets, dtype=wp.vec4i, device="cpu"), wp.array(values, dtype=wp.float32),
                                    lambda x: gaussian_field(x.numpy()), binary_steps=2, device="cpu")
    np.testing.assert_array_equal(f3, f4)
    np.testing.assert_array_equal(v3, v4)


def test_pieces_marched_apart_join_into_the_whole_mesh(cloud):
    """Consecutive parts of the tetrahedra marched one by one (with their edge keys; each part searches only its own
    crossing edges, as a rank does) and joined by key give the mesh of all of them at once, bit for bit, for every
    level; an empty part, a part with no crossing and a one-part split included."""
    points, tets = cloud
    values = gaussian_field(points)
    levels = (0.3, 0.5)
    whole = marching_tetrahedra(points, tets, values, gaussian_field, levels=levels, binary_steps=3, device="cpu")
    for cuts in ([0, len(tets)], [0, 0, 5, 1000, 2345, len(tets)], [0, len(tets) // 3, len(tets) // 2, len(tets)]):
        parts = [marching_tetrahedra(points, tets[a:b], values, gaussian_field, levels=levels, binary_steps=3,
                                     device="cpu", return_keys=True) for a, b in zip(cuts[:-1], cuts[1:])]
        for level, (v, f) in enumerate(whole):
            vm, fm = merge_keyed_pieces([p[level] for p in parts])
            np.testing.assert_array_equal(fm, f)
            np.testing.assert_array_equal(vm, v)
    (v, f, keys), = marching_tetrahedra(points, tets, values, device="cpu", return_keys=True)
    n = len(points)
    assert keys.dtype == np.int64 and len(keys) == len(v) and np.all(np.diff(keys) > 0)
    i, j = keys // n, keys % n  # each vertex lies on the segment of its edge
    t = np.einsum("ij,ij->i", v - points[i], points[j] - points[i]) / np.einsum("ij,ij->i", points[j] - points[i],
                                                                                  points[j] - points[i])
    assert np.all(i < j) and np.all((t > -1e-5) & (t < 1 + 1e-5))
    assert merge_keyed_pieces([])[0].shape == (0, 3)


@pytest.mark.slow
def test_searching_given_edges_gives_the_marching_vertices(cloud):
    """search_edges on the edge keys of an unsearched marching (as the ranks of a torchrun extraction search the union
    of their pieces' edges) gives the vertices the marching's own search gives, bit for bit, level by level; it calls
    the field once per step even with no edge at all (a collective field must be called alike on every rank)."""
    points, tets = cloud
    values = gaussian_field(points)
    levels = (0.3, 0.5)
    searched = marching_tetrahedra(points, tets, values, gaussian_field, levels=levels, binary_steps=3, device="cpu",
                                   return_keys=True)
    linear = marching_tetrahedra(points, tets, values, levels=levels, device="cpu", return_keys=True)
    calls = []

    def counting_field(x):
        calls.append(len(x))
        return gaussian_field(x)

    got = search_edges(points, values, [k for _, _, k in linear], counting_field, levels=levels, binary_steps=3,
                       device="cpu")
    assert calls == [sum(len(k) for _, _, k in linear)] * 3  # every level's edges in one call a step
    for (v, _, k), (v_lin, _, k_lin), g in zip(searched, linear, got):
        np.testing.assert_array_equal(k_lin, k)
        np.testing.assert_array_equal(g, v)
        assert not np.array_equal(g, v_lin)  # the search moved the linear vertices
    calls.clear()
    empty = search_edges(points, values, [np.zeros(0, np.int64)] * 2, counting_field, levels=levels, binary_steps=3,
                         device="cpu")
    assert calls == [0, 0, 0] and [e.shape for e in empty] == [(0, 3), (0, 3)]
    with pytest.raises(GofError, match="2 key arrays for 1 levels"):
        search_edges(points, values, [k for _, _, k in linear], gaussian_field, levels=(0.5,), device="cpu")
    with pytest.raises(GofError, match="edge keys must lie"):
        search_edges(points, values, [np.array([-1])], gaussian_field, levels=(0.5,), device="cpu")


def test_several_steps_per_field_call_give_the_same_vertices(cloud):
    """steps_per_call = d evaluates every midpoint the next d bisection steps can visit in one call and descends
    through them: the same vertices bit for bit as one step per call, for any d (a last call with fewer steps
    included) and for d chosen per call from the edge count and the steps done, with 2^d - 1 points per edge."""
    points, tets = cloud
    values = gaussian_field(points)
    levels = (0.3, 0.5)
    one = marching_tetrahedra(points, tets, values, gaussian_field, levels=levels, binary_steps=7, device="cpu")
    edges = sum(len(v) for v, _ in one)
    for per_call, calls in ((2, [3, 3, 3, 1]), (3, [7, 7, 1]), (7, [127]), (12, [127]),
                            (lambda e, done: 4 if e == edges and done == 0 else 3, [15, 7])):
        sizes = []

        def counting_field(x):
            sizes.append(len(x))
            return gaussian_field(x)

        got = marching_tetrahedra(points, tets, values, counting_field, levels=levels, binary_steps=7, device="cpu",
                                  steps_per_call=per_call)
        assert sizes == [edges * c for c in calls], per_call
        for (v, f), (vg, fg) in zip(one, got):
            np.testing.assert_array_equal(fg, f)
            np.testing.assert_array_equal(vg, v)
    for bad in (0, 13, 2.0, True, lambda e, done: 0):
        with pytest.raises(GofError, match="steps_per_call must be an integer"):
            marching_tetrahedra(points, tets, values, gaussian_field, device="cpu", steps_per_call=bad)


@pytest.mark.parametrize("depth", [1, 3, 6])
def test_bracket_tree_descent_equals_that_many_bisection_steps(depth):
    """The search's tree kernels against the one-step bisection kernels (bracket_midpoints, update_brackets) on
    random brackets and a Gaussian field: after ``depth`` steps the same brackets and values, bit for bit."""
    from gof_warp.kernels import marching_tets as mt

    rng = np.random.default_rng(depth)
    n = 500
    a, b = rng.uniform(-0.6, 0.6, (n, 3)).astype(np.float32), rng.uniform(-0.6, 0.6, (n, 3)).astype(np.float32)
    fa, fb = gaussian_field(a), gaussian_field(b)
    lv = np.float32(0.5)
    inside = fa >= lv
    x_in, x_out = np.where(inside[:, None], a, b), np.where(inside[:, None], b, a)
    f_in, f_out = np.where(inside, fa, fb).astype(np.float32), np.where(inside, fb, fa).astype(np.float32)
    level = wp.array(np.full(n, lv, np.float32), dtype=wp.float32, device="cpu")

    def arrays():
        return [wp.array(x_in, dtype=wp.vec3, device="cpu"), wp.array(x_out, dtype=wp.vec3, device="cpu"),
                wp.array(f_in, dtype=wp.float32, device="cpu"), wp.array(f_out, dtype=wp.float32, device="cpu")]

    steps = arrays()
    x_mid = wp.empty(n, dtype=wp.vec3, device="cpu")
    for _ in range(depth):
        wp.launch(mt.bracket_midpoints, dim=n, inputs=steps[:2], outputs=[x_mid], device="cpu")
        f_mid = wp.array(gaussian_field(x_mid.numpy()).astype(np.float32), dtype=wp.float32, device="cpu")
        wp.launch(mt.update_brackets, dim=n, inputs=[x_mid, f_mid, level], outputs=steps, device="cpu")
    tree = arrays()
    nodes = wp.empty((n, (1 << depth) - 1), dtype=wp.vec3, device="cpu")
    wp.launch(mt.bracket_tree_midpoints, dim=n, inputs=[tree[0], tree[1], depth], outputs=[nodes], device="cpu")
    f_nodes = gaussian_field(nodes.numpy().reshape(-1, 3)).astype(np.float32).reshape(n, -1)
    wp.launch(mt.descend_bracket_tree, dim=n, inputs=[nodes, wp.array(f_nodes, dtype=wp.float32, device="cpu"), depth,
                                                      level], outputs=tree, device="cpu")
    for s_arr, t_arr in zip(steps, tree):
        np.testing.assert_array_equal(t_arr.numpy(), s_arr.numpy())
    assert not np.array_equal(steps[0].numpy(), x_in)  # the steps moved the brackets


def test_bracket_tree_nodes_and_descent_on_a_hand_made_edge():
    """One edge from x_in = (0,0,0) to x_out = (8,0,0) and a field falling linearly from 1 to 0 along it (level
    0.3, crossing at x = 5.6): the depth-3 nodes are x = 1 … 7 in order, and the descent keeps [5, 6]."""
    from gof_warp.kernels import marching_tets as mt

    x_in = wp.array([[0.0, 0.0, 0.0]], dtype=wp.vec3, device="cpu")
    x_out = wp.array([[8.0, 0.0, 0.0]], dtype=wp.vec3, device="cpu")
    nodes = wp.empty((1, 7), dtype=wp.vec3, device="cpu")
    wp.launch(mt.bracket_tree_midpoints, dim=1, inputs=[x_in, x_out, 3], outputs=[nodes], device="cpu")
    xs = nodes.numpy()[0]
    np.testing.assert_array_equal(xs[:, 0], np.arange(1.0, 8.0))
    f_nodes = wp.array((1.0 - xs[:, 0] / 8.0).astype(np.float32).reshape(1, 7), dtype=wp.float32, device="cpu")
    f_in, f_out = wp.array([1.0], dtype=wp.float32, device="cpu"), wp.array([0.0], dtype=wp.float32, device="cpu")
    level = wp.array([0.3], dtype=wp.float32, device="cpu")
    wp.launch(mt.descend_bracket_tree, dim=1, inputs=[nodes, f_nodes, 3, level], outputs=[x_in, x_out, f_in, f_out],
              device="cpu")
    assert x_in.numpy()[0, 0] == 5.0 and x_out.numpy()[0, 0] == 6.0
    assert f_in.numpy()[0] == np.float32(1 - 5 / 8) and f_out.numpy()[0] == np.float32(1 - 6 / 8)


@pytest.mark.parametrize("n", [1, 12])
def test_tetra_points_of_gaussians_pipeline(n):
    rng = np.random.default_rng(3)
    means = np.vstack([np.zeros(3), rng.uniform(-0.6, 0.6, (n - 1, 3))])  # Gaussian 0 makes the field
    scales = np.vstack([[SIGMA] * 3, rng.uniform(0.05, 0.2, (n - 1, 3))])
    quats = rng.normal(size=(n, 4))
    points, tets, owner, scale = tetrahedral_grid(means, quats, scales, config=TetraConfig(filter_cells=False))
    assert points.shape == (9 * n, 3) and tets.shape[1] == 4
    (v, f), = marching_tetrahedra(points, tets, gaussian_field(points), gaussian_field, device="cpu", oriented=True)
    assert_watertight_outward(v, f)
    assert np.abs(np.linalg.norm(v, axis=1) - sphere_radius(0.5)).max() < SPHERE_TOL_8_STEPS


def test_zero_gaussians_is_a_clear_error():
    with pytest.raises(GofError, match="at least 4 points, got 0"):
        tetrahedral_grid(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)))


# ---------------------------------------------------------------------------------------------- cubes
def test_marching_cubes_sphere(device):
    r = sphere_radius(0.5)
    errors = []
    for steps in (0, 2, 6):
        v, f = marching_cubes(gaussian_field, [[-0.8] * 3, [0.8] * 3], 17, binary_steps=steps, device=device)
        assert_watertight_outward(v, f)
        errors.append(np.abs(np.linalg.norm(v, axis=1) - r).max())
    assert errors[2] < MC_TOL_6_STEPS and errors[2] < errors[1] < errors[0]


def test_marching_cubes_search_on_another_field():
    """Grid values from one field, the bisection on another whose level crosses the same edges: the vertices
    land on the second field's level set (a baked volume's lattice refined on the exact field)."""
    r_grid, r_exact = sphere_radius(0.5), sphere_radius(0.5, alpha=ALPHA * 1.01)
    assert 0 < r_exact - r_grid < 0.2 * 1.6 / 16  # well inside one cell of the 17-node grid
    exact = lambda x: gaussian_field(x, alpha=ALPHA * 1.01)  # noqa: E731
    v, f = marching_cubes(gaussian_field, [[-0.8] * 3, [0.8] * 3], 17, binary_steps=12, device="cpu",
                          search_field=exact)
    v0, _ = marching_cubes(gaussian_field, [[-0.8] * 3, [0.8] * 3], 17, binary_steps=12, device="cpu")
    assert_watertight_outward(v, f)
    assert np.abs(np.linalg.norm(v, axis=1) - r_exact).max() < 1e-3 < np.abs(np.linalg.norm(v0, axis=1) - r_exact).max()


def test_marching_cubes_empty_and_bad_input(caplog):
    with caplog.at_level(logging.WARNING):
        v, f = marching_cubes(gaussian_field, [[2.0] * 3, [3.0] * 3], 4, device="cpu")
    assert v.shape == (0, 3) and f.shape == (0, 3) and "empty" in caplog.text
    with pytest.raises(GofError, match="bounds"):
        marching_cubes(gaussian_field, [[1.0] * 3, [0.0] * 3], 4, device="cpu")
    with pytest.raises(GofError, match="resolution"):
        marching_cubes(gaussian_field, [[0.0] * 3, [1.0] * 3], 1, device="cpu")


# ---------------------------------------------------------------------------------------------- tetra grid
def test_tetra_points_geometry_and_options():
    rng = np.random.default_rng(4)
    means = rng.normal(size=(5, 3))
    quats = rng.normal(size=(5, 4))  # wxyz, unnormalised
    scales = rng.uniform(0.01, 0.3, (5, 3))
    opac = np.array([0.9, 0.2, 0.8, 0.05, 0.6])
    points, owner, scale = tetra_points(means, quats, scales, opac)
    R = Rotation.from_quat(quats[:, [1, 2, 3, 0]]).as_matrix()  # scipy is xyzw
    signs = np.array(list(itertools.product((-1, 1), repeat=3)))
    ref = means[:, None, :] + np.einsum("nij,nkj->nki", R, signs[None] * (3 * scales)[:, None, :])
    np.testing.assert_allclose(points[:40], ref.reshape(-1, 3), atol=EXACT_TOL * 4)
    np.testing.assert_allclose(points[40:], means, atol=EXACT_TOL)
    np.testing.assert_array_equal(owner, np.r_[np.repeat(np.arange(5), 8), np.arange(5)])
    np.testing.assert_allclose(scale, np.r_[np.repeat(3 * scales.max(1), 8), 3 * scales.max(1)], rtol=1e-6)

    p2, o2, _ = tetra_points(means, quats, scales, torch.from_numpy(opac)[:, None], opacity_min=0.5)
    assert sorted(set(o2)) == [0, 2, 4] and p2.shape[0] == 27
    p3, o3, _ = tetra_points(means, quats, scales, corner_min_extent=float(np.median(3 * scales.max(1))))
    assert p3.shape[0] == 5 + 8 * int((3 * scales.max(1) >= np.median(3 * scales.max(1))).sum())
    cam = look_at(eye=(0, 0, -5), target=(0, 0, 0), up=(0, -1, 0), fx=100, width=64, height=64)
    front = np.array([[0.0, 0, 0], [0.0, 0, -10]])  # the second is behind the camera
    p4, o4, _ = tetra_points(front, np.tile([1.0, 0, 0, 0], (2, 1)), np.full((2, 3), 0.01), cameras=[cam])
    assert set(o4) == {0} and p4.shape[0] == 9
    empty = tetra_points(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)))
    assert all(a.shape[0] == 0 for a in empty)
    with pytest.raises(GofError, match="scales"):
        tetra_points(means, quats, -scales)
    with pytest.raises(GofError, match="opacities"):
        tetra_points(means, quats, scales, opacity_min=0.5)


def test_delaunay_orientation_and_degenerate_inputs():
    rng = np.random.default_rng(5)
    points = rng.uniform(size=(200, 3)).astype(np.float32)
    points[10] = points[3]  # a duplicate point
    tets = delaunay(points)
    p = points.astype(np.float64)
    vol6 = np.einsum("ij,ij->i", np.cross(p[tets[:, 1]] - p[tets[:, 0]], p[tets[:, 2]] - p[tets[:, 0]]),
                     p[tets[:, 3]] - p[tets[:, 0]])
    assert tets.dtype == np.int32 and np.all(vol6 > 0)
    assert 10 not in tets or 3 not in tets  # duplicates merged
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.5, 0.5, 0]], np.float32)
    with pytest.raises(GofError, match="degenerate"):
        delaunay(flat)
    with pytest.raises(GofError, match="at least 4"):
        delaunay(flat[:3])
    with pytest.raises(GofError, match="backend"):
        delaunay(points, backend="qhull")
    mixed = np.array([[0, 1, 2, 3], [0, 2, 1, 3], [0, 1, 2, 4]], np.int32)  # last one is flat
    pts5 = np.vstack([TET, [[0.3, 0.3, 0.0]]])
    out = orient_and_drop_degenerate(mixed, pts5)
    np.testing.assert_array_equal(out, [[0, 1, 2, 3], [0, 2, 3, 1]])  # flat one dropped, negative one flipped


def test_delaunay_cgal_matches_scipy():
    pytest.importorskip("CGAL", reason="optional GPLv3 extra gof_warp[cgal] is not installed")
    points = np.random.default_rng(6).uniform(size=(300, 3)).astype(np.float32)
    a, b = delaunay(points, "scipy"), delaunay(points, "cgal")
    assert set(map(tuple, np.sort(a, 1))) == set(map(tuple, np.sort(b, 1)))


def test_delaunay_without_cgal(monkeypatch):
    for mod in ("CGAL", "CGAL.CGAL_Kernel", "CGAL.CGAL_Triangulation_3"):
        monkeypatch.setitem(sys.modules, mod, None)  # import fails as when the extra is absent
    points = np.random.default_rng(7).uniform(size=(50, 3)).astype(np.float32)
    with pytest.raises(GofError, match=r"gof_warp\[cgal\]"):
        delaunay(points, "cgal")
    np.testing.assert_array_equal(delaunay(points, "auto"), delaunay(points, "scipy"))


def test_filter_cells_hand_built():
    points = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1],  # Gaussian 0
                       [1, 0, 0], [1, 0.1, 0], [5, 0, 0]], np.float32)  # Gaussian 1 (near), 2 (far)
    owner = np.array([0, 0, 0, 0, 1, 1, 2])
    scale = np.array([0.5] * 4 + [0.6, 0.6, 0.1], np.float32)
    tets = np.array([[0, 1, 2, 3],  # one Gaussian: kept
                     [1, 2, 3, 4],  # edge 0.9..1.0 < 0.5 + 0.6: kept
                     [1, 2, 3, 6]], np.int32)  # edge 4.9 > 0.5 + 0.1: dropped
    np.testing.assert_array_equal(filter_cells(tets, points, owner, scale), tets[:2])
    scale_small = scale.copy()
    scale_small[:4] = 100.0  # within one Gaussian even huge edges stay; across, the sum decides
    np.testing.assert_array_equal(filter_cells(tets, points, owner, scale_small), tets)


# ---------------------------------------------------------------------------------------------- validation
def test_marching_validation_and_empty(caplog):
    tets = np.array([[0, 1, 2, 3]], np.int32)
    vals = np.array([1.0, 0, 0, 0], np.float32)
    with caplog.at_level(logging.WARNING):
        meshes = marching_tetrahedra(np.zeros((0, 3), np.float32), np.zeros((0, 4), np.int32), np.zeros(0),
                                     levels=(0.5, 0.6), device="cpu")
    assert [m[0].shape[0] for m in meshes] == [0, 0] and "empty" in caplog.text
    with pytest.raises(GofError, match="NaN"):
        marching_tetrahedra(TET, tets, np.array([np.nan, 0, 0, 0]), device="cpu")
    with pytest.raises(GofError, match="outside"):
        marching_tetrahedra(TET, tets + 1, vals, device="cpu")
    with pytest.raises(GofError, match=r"\[P, 3\]|\[N, 3\]"):
        marching_tetrahedra(TET[:, :2], tets, vals, device="cpu")
    with pytest.raises(GofError, match="4 values"):
        marching_tetrahedra(TET, tets, vals[:3], device="cpu")
    with pytest.raises(GofError, match="binary_steps"):
        marching_tetrahedra(TET, tets, vals, binary_steps=-1, device="cpu")
    with pytest.raises(GofError, match="field values"):
        marching_tetrahedra(TET, tets, vals, lambda x: np.full(len(x), np.nan), device="cpu")
    with pytest.raises(GofError, match="field values"):
        marching_tetrahedra(TET, tets, vals, lambda x: np.zeros(len(x) + 1), device="cpu")
    (v, f), = marching_tetrahedra(TET, tets, np.zeros(4), device="cpu")  # no crossing: empty, no error
    assert v.shape == (0, 3) and f.shape == (0, 3)


def test_level_band_keeps_the_mesh_and_drops_the_far_points():
    """Many small Gaussians filling a ball around the analytic Gaussian's 0.5-level sphere: triangulating only
    the level band gives a watertight, consistently wound mesh on the sphere, from far fewer points, and no
    band point is far from the sphere."""
    rng = np.random.default_rng(11)
    n = 3000
    means = rng.uniform(-1.0, 1.0, (n, 3))
    means = means[np.linalg.norm(means, axis=1) < 1.0]
    scales = rng.uniform(0.02, 0.06, (len(means), 3))
    quats = rng.normal(size=(len(means), 4))
    points, owner, scale = tetra_points(means, quats, scales)
    values = gaussian_field(points)
    band = level_band(points, values, owner, scale, [0.5])
    r = sphere_radius(0.5)
    dist = np.abs(np.linalg.norm(points, axis=1) - r)
    assert band.sum() < 0.5 * len(points)
    assert np.mean(dist[band] < 2.5 * scale.max()) > 0.95  # within reach of a crossing (but whole Gaussians)
    assert dist[band].max() < 6.0 * scale.max()
    assert band[dist < 0.25 * scale.min()].mean() > 0.95  # points right at the level: nearly all kept
    pb, ob, sb = points[band], owner[band], scale[band]
    tets = filter_cells(delaunay(pb), pb, ob, sb)
    (v, f), = marching_tetrahedra(pb, tets, values[band], gaussian_field, device="cpu", oriented=True)
    assert_watertight_outward(v, f)
    assert np.abs(np.linalg.norm(v, axis=1) - r).max() < SPHERE_TOL_8_STEPS
    with pytest.raises(GofError, match="disagree"):
        level_band(points, values[:-1], owner, scale, [0.5])
