"""Quadric decimation (gof_warp.mesh.decimate): budget, error, closedness, borders, bad inputs."""

import numpy as np
import pytest
import trimesh

pytest.importorskip("fast_simplification")

from gof_warp.mesh.decimate import _clean, decimate, is_closed  # noqa: E402
from gof_warp.core.errors import GofError  # noqa: E402
from gof_warp.eval.geometry_metrics import point_mesh_distance  # noqa: E402


def _sphere(subdivisions=4):
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    return np.asarray(s.vertices), np.asarray(s.faces)


def _edge_lengths(v, f):
    e = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    e = np.unique(e, axis=0)
    return np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)


def _surface_samples(v, f, n=20):
    """Points on every face at a barycentric grid (vertices, edges and interior)."""
    bary = np.array([(i, j, n - i - j) for i in range(n + 1) for j in range(n + 1 - i)], float) / n
    tri = v[f]
    return np.einsum("bk,fkd->fbd", bary, tri).reshape(-1, 3)


def _plane(n=41, wave=0.0):
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    v = np.stack([x.ravel(), y.ravel(), wave * np.sin(3 * x.ravel()) * np.cos(2 * y.ravel())], 1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    return v, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def test_face_budget_honoured_and_close():
    v, f = _sphere(4)  # 5120 faces
    for budget in (2560, 1280, 500):
        v2, f2, info = decimate(v, f, max_faces=budget)
        assert len(f2) <= budget
        assert len(f2) >= 0.95 * budget, (budget, len(f2))
        assert info["faces_before"] == len(f) and info["faces_after"] == len(f2)
        assert info["vertices_after"] == len(v2)
        assert v2.dtype == np.float32 and f2.dtype == np.int32 and f2.shape[1] == 3
        assert f2.min() >= 0 and f2.max() < len(v2)


def test_error_small_on_smooth_sphere():
    v, f = _sphere(4)
    h = _edge_lengths(v, f).max()
    v2, f2, info = decimate(v, f, max_faces=len(f) // 4)
    assert len(f2) <= len(f) // 4
    # 4x fewer faces -> edges about 2x longer. A triangle of edge L inscribed in the unit sphere sags by
    # about L^2/6 (its circumradius L/sqrt(3) squared over 2); allow edges up to 3h: 1.5 h^2 (~0.006
    # here, 9x the input's own sag h^2/6). A decimation that moves the surface by a cell fails it.
    bound = 1.5 * h**2
    pts = _surface_samples(v2.astype(np.float64), f2.astype(np.int64))
    off = np.abs(np.linalg.norm(pts, axis=1) - 1.0)
    assert off.max() < bound, (off.max(), bound)  # measured: 0.005 (vertices sit just outside), bound 0.010
    # info's error (input vertices to the result) agrees with an independent measurement
    d = point_mesh_distance(v, v2, f2)
    assert info["error_max"] == pytest.approx(d.max(), rel=1e-4, abs=1e-7)
    assert info["error_p95"] <= info["error_max"] < bound


def test_closed_mesh_stays_closed():
    v, f = _sphere(4)
    assert is_closed(f)
    for budget in (2000, 300, 60):
        v2, f2, info = decimate(v, f, max_faces=budget)
        assert info["closed_before"] and info["closed_after"]
        assert is_closed(f2), budget
        assert trimesh.Trimesh(v2, f2, process=False).is_watertight


def test_pinched_closed_surface_is_split_back_to_closed():
    # two tetrahedra touching along the edge (0, 1): 4 faces on that edge, as a collapse can leave it
    v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0.2], [0.5, 0.3, 1], [0.5, -1, 0.2], [0.5, -0.3, -1]], float)
    tet1 = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    tet2 = np.array([[0, 1, 4], [0, 5, 1], [1, 5, 4], [0, 4, 5]])
    f = np.concatenate([tet1, tet2])
    assert not is_closed(f)
    v2, f2, repairs = _clean(v, f)
    assert is_closed(f2) and len(f2) == 8
    assert repairs["pinch_vertices_split"] == 2 and len(v2) == 8
    np.testing.assert_array_equal(v2[f2], v[f])  # geometry untouched


def test_coincident_pairs_removed():
    v, f = _sphere(1)
    extra = np.array([[0, 1, 2], [0, 2, 1], [3, 3, 4]])  # a coincident pair and a degenerate face
    v2, f2, repairs = _clean(v, np.concatenate([f, extra]))
    assert repairs["coincident_removed"] == 2 and repairs["degenerate_removed"] == 1
    assert len(f2) == len(f) and is_closed(f2)


def test_open_border_outline_kept():
    v, f = _plane(41, wave=0.02)  # spacing 0.025
    outline = (v[:, 0] == 0) | (v[:, 0] == 1) | (v[:, 1] == 0) | (v[:, 1] == 1)
    v2, f2, info = decimate(v, f, max_faces=len(f) // 8)
    assert len(f2) <= len(f) // 8 and info["border_kept"]
    assert point_mesh_distance(v[outline], v2, f2).max() < 1e-6
    assert trimesh.Trimesh(v2, f2, process=False).area == pytest.approx(trimesh.Trimesh(v, f).area, rel=2e-3)
    # letting the border collapse still keeps the outline within about one grid spacing
    v3, f3, info3 = decimate(v, f, max_faces=len(f) // 8, keep_border=False)
    assert not info3["border_kept"]
    assert point_mesh_distance(v[outline], v3, f3).max() < 0.03


def test_border_only_mesh_falls_back_to_meet_budget():
    v, f = _plane(41)
    row = np.concatenate([f[:40], f[1600:1640]])  # the first row of quads: every vertex is on the border
    v2, f2, info = decimate(v, row, max_faces=20)
    assert len(f2) <= 20 and not info["border_kept"]


def test_max_error_bound():
    v, f = _sphere(4)
    loose, tight = 0.01, 0.002
    v1, f1, info1 = decimate(v, f, max_error=loose)
    v2, f2, info2 = decimate(v, f, max_error=tight)
    for vv, ff, info, bound in ((v1, f1, info1, loose), (v2, f2, info2, tight)):
        assert info["error_bound_met"] and info["error_max"] <= bound
        assert point_mesh_distance(v, vv, ff).max() <= bound
    assert len(f1) < len(f2) < len(f)  # a looser bound buys fewer faces
    assert len(f1) < len(f) / 4
    # with a budget too tight for the bound: the budget wins, and info says the bound was missed
    v3, f3, info3 = decimate(v, f, max_faces=40, max_error=1e-4)
    assert len(f3) <= 40 and info3["error_bound_met"] is False and info3["error_max"] > 1e-4


def test_noop_under_budget():
    v, f = _sphere(2)
    v2, f2, info = decimate(v, f, max_faces=len(f))
    np.testing.assert_array_equal(f2, f)
    np.testing.assert_allclose(v2, v, rtol=1e-6)
    assert info["faces_after"] == info["faces_before"] == len(f) and info["error_max"] == 0.0
    v3, f3, _ = decimate(v, f, max_faces=10 * len(f))
    assert len(f3) == len(f)
    v4, f4, _ = decimate(v, f)  # no target at all: unchanged
    assert len(f4) == len(f)


@pytest.mark.parametrize("kwargs, match", [
    (dict(verts=np.zeros((4, 2)), faces=np.array([[0, 1, 2]])), "shape"),
    (dict(verts=np.zeros((4, 3)), faces=np.array([0, 1, 2])), "shape"),
    (dict(verts=np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]), faces=np.array([[0, 1, 2]])), "NaN"),
    (dict(verts=np.eye(3), faces=np.array([[0, 1, 3]])), "indices"),
    (dict(verts=np.eye(3), faces=np.array([[0, -1, 2]])), "indices"),
    (dict(verts=np.eye(3), faces=np.array([[0.0, 1.0, 2.0]])), "integer"),
    (dict(verts=np.eye(3), faces=np.array([[0, 1, 2]]), max_faces=-5), "max_faces"),
    (dict(verts=np.eye(3), faces=np.array([[0, 1, 2]]), max_faces=0), "max_faces"),
    (dict(verts=np.eye(3), faces=np.array([[0, 1, 2]]), max_faces=2.5), "max_faces"),
    (dict(verts=np.eye(3), faces=np.array([[0, 1, 2]]), max_error=-0.1), "max_error"),
    (dict(verts=np.eye(3), faces=np.array([[0, 1, 2]]), max_error=float("nan")), "max_error"),
])
def test_bad_inputs_raise(kwargs, match):
    verts, faces = kwargs.pop("verts"), kwargs.pop("faces")
    with pytest.raises(GofError, match=match):
        decimate(verts, faces, **kwargs)


def test_budget_alone_can_skip_the_error_measurement():
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=3)
    _, f, info = decimate(m.vertices, m.faces, max_faces=len(m.faces) // 2, measure=False)
    assert len(f) <= len(m.faces) // 2 and info["error_max"] is None and info["error_p95"] is None
    _, _, info = decimate(m.vertices, m.faces, max_faces=len(m.faces) // 2)
    assert info["error_max"] is not None and info["error_max"] > 0


@pytest.mark.parametrize("shape, high", [((2000, 2), 60), ((3000, 3), 25), ((9, 3), 1), ((40, 3), 2 ** 40)])
def test_row_groups_equal_numpy_unique_on_rows(shape, high):
    """The packed-key grouping (and its lexsort fallback when the key would overflow: high = 2**40, three
    columns) gives numpy's row-wise unique: same group order, inverse and counts."""
    from gof_warp.mesh.decimate import _edge_counts, _row_groups

    rows = np.random.default_rng(shape[0]).integers(0, high, size=shape)
    rows[1::7] = rows[::7][: len(rows[1::7])]  # repeated rows
    _, inverse, counts = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
    got_inverse, got_counts = _row_groups(rows)
    np.testing.assert_array_equal(got_inverse, inverse.reshape(-1))
    np.testing.assert_array_equal(got_counts, counts)
    if shape[1] == 3:
        edges = np.sort(rows[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        np.testing.assert_array_equal(_edge_counts(rows), np.unique(edges, axis=0, return_counts=True)[1])
