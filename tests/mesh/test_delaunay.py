"""Delaunay backends: one Qhull call vs Qhull in parallel chunks (gof_warp.mesh.delaunay)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from gof_warp.mesh.delaunay import JITTER_REL, SPHERE_RTOL, delaunay, jittered, kd_boxes, tet_geometry
from gof_warp.core.errors import GofError
from gof_warp.mesh.tetra import tetra_points

SPHERE_SLACK = SPHERE_RTOL  # relative: a point nearer the centre than R (1 - this) is inside


def _packed(simplices: np.ndarray) -> np.ndarray:
    """One ``uint64`` per row of vertex ids, independent of the ids' order within the row: the sorted ids packed
    into ``64 // k`` bits each (every id here fits: asserted). Equal rows, and only they, give equal keys."""
    s = np.sort(np.asarray(simplices, np.int64), axis=1)
    bits = 64 // s.shape[1]
    assert s.size == 0 or (s.min() >= 0 and s.max() < (1 << bits)), "vertex ids too large to pack"
    key = np.zeros(s.shape[0], np.uint64)
    for j in range(s.shape[1]):
        key = (key << np.uint64(bits)) | s[:, j].astype(np.uint64)
    return key


def keys(tets: np.ndarray) -> np.ndarray:
    """The set of tetrahedra (vertex order ignored), as the sorted distinct packed keys (``_packed``): two
    tetrahedralisations are the same set exactly when their ``keys`` are equal arrays."""
    return np.unique(_packed(tets))


def same(a: np.ndarray, b: np.ndarray) -> bool:
    """``keys(a) == keys(b)`` as sets (both are sorted and distinct)."""
    return np.array_equal(a, b)


def assert_valid_delaunay_tets(tets: np.ndarray, p: np.ndarray) -> None:
    """Positive volume, no tetrahedron twice, no face shared by more than two, every circumsphere empty."""
    vol6, flat, centre, radius = tet_geometry(tets, p)
    assert not flat.any() and (vol6 > 0).all()
    assert len(keys(tets)) == tets.shape[0]
    _, count = np.unique(_packed(tets[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3)),
                         return_counts=True)
    assert count.max() <= 2
    dist, _ = cKDTree(p).query(centre, k=1)
    assert (dist >= radius * (1 - SPHERE_SLACK)).all(), "a kept tetrahedron's circumsphere holds a point"


def faces_once(tets: np.ndarray) -> np.ndarray:
    """Faces of ``tets`` that belong to one tetrahedron only, as sorted distinct packed keys (``_packed``)."""
    u, count = np.unique(_packed(tets[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3)),
                         return_counts=True)
    return u[count == 1]


def assert_exact(par: np.ndarray, one: np.ndarray, p: np.ndarray, stats: dict) -> None:
    """The chunked tetrahedralisation is one Qhull call's, tetrahedron for tetrahedron, and closed: its faces
    seen once are exactly the convex hull's."""
    from scipy.spatial import ConvexHull

    assert same(keys(par), keys(one))
    assert_valid_delaunay_tets(par, jittered(p))
    hull = np.unique(_packed(ConvexHull(jittered(p)).simplices))
    assert np.array_equal(faces_once(par), hull)
    assert stats["delaunay_unmatched_faces"] == 0 and stats["delaunay_volume_coverage"] == pytest.approx(1.0, abs=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("processes", [False, True])
def test_chunked_equals_one_call_in_general_position(processes):
    p = np.random.default_rng(0).normal(size=(15_000, 3))
    stats = {}
    par = delaunay(p, workers=2, chunks=6, stats=stats, processes=processes)
    assert stats["delaunay_chunks"] == 6 and stats["delaunay_processes"] == processes
    assert_exact(par, delaunay(p), p, stats)


@pytest.mark.slow
def test_chunked_fills_the_large_tets_no_chunk_sees():
    """Two dense clusters 20 apart: the tetrahedra spanning the gap are larger than any halo; the chunks leave
    them out (unmatched faces), the exact merge puts them back."""
    rng = np.random.default_rng(1)
    p = np.concatenate([rng.normal(size=(8000, 3)), rng.normal(size=(8000, 3)) + [20.0, 0, 0]])
    stats = {}
    par = delaunay(p, workers=2, chunks=8, stats=stats)
    assert stats["delaunay_chunk_unmatched_faces"] > 0 and stats["delaunay_filled_tets"] > 0
    assert_exact(par, delaunay(p), p, stats)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["clusters", "box_corners"])
def test_a_large_fill_is_chunked_itself_and_stays_exact(monkeypatch, kind):
    """The merge's fill (the points along the chunk borders) is triangulated in chunks too once it has
    ``FILL_SPLIT_POINTS``; lowered here so that small scenes take that path: the result is still one call's."""
    import gof_warp.mesh.delaunay as D

    calls = []
    monkeypatch.setattr(D, "FILL_SPLIT_POINTS", 500)
    real = D._fill_triangulation
    monkeypatch.setattr(D, "_fill_triangulation", lambda q, *a: calls.append(q.shape[0]) or real(q, *a))
    rng = np.random.default_rng(7)
    if kind == "clusters":
        p = np.concatenate([rng.normal(size=(8000, 3)), rng.normal(size=(8000, 3)) + [20.0, 0, 0]])
    else:
        g = torch.tensor(rng.normal(size=(1500, 3)), dtype=torch.float64)
        q = torch.nn.functional.normalize(torch.tensor(rng.normal(size=(1500, 4))), dim=1)
        p, _, _ = tetra_points(g, q, torch.full((1500, 3), 0.05, dtype=torch.float64))
        p = np.asarray(p, np.float64)
    stats = {}
    par = delaunay(p, workers=2, chunks=24, stats=stats)
    assert calls and max(calls) >= 500, "the fill took the chunked path"
    assert_exact(par, delaunay(p), p, stats)


@pytest.mark.slow
@pytest.mark.parametrize("chunks", [4, 9])
def test_chunked_equals_one_call_on_cospherical_box_corners(chunks):
    """GOF's points (3σ-box corners: cospherical octuples everywhere) and a regular lattice (every cube's corners
    cospherical): perturbed into general position, every chunk agrees with one call, and the result is closed."""
    g = torch.Generator().manual_seed(2)
    n = 2000
    means = torch.rand(n, 3, generator=g) * 3.0
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=1)
    scales = torch.rand(n, 3, generator=g) * 0.05 + 0.01
    p, owner, scale = tetra_points(means, quats, scales)
    stats = {}
    par = delaunay(p, workers=2, chunks=chunks, stats=stats)
    assert_exact(par, delaunay(p), p.astype(np.float64), stats)



@pytest.mark.parametrize("chunks", [4, 9])
def test_chunked_lattice_agrees_inside(chunks):
    """A regular lattice (every unit cube's 8 corners cospherical, and its hull faces exactly planar): every
    tetrahedron with volume (in the exact coordinates) and a circumsphere of the lattice's size agrees with one
    call. On the planar hull faces the
    perturbation leaves slivers with circumradius ~1e5-1e7 whose sphere test is rounding (documented; GOF's
    cell filter drops them: their edges are long)."""
    lattice = np.stack(np.meshgrid(*[np.arange(12.0)] * 3, indexing="ij"), -1).reshape(-1, 3)
    par, one = delaunay(lattice, workers=2, chunks=chunks), delaunay(lattice)
    q = jittered(lattice)
    inner = lambda t: t[(tet_geometry(t, q)[3] < 20.0) & (np.abs(tet_geometry(t, lattice)[0]) > 0.5)]  # noqa: E731
    assert same(keys(inner(par)), keys(inner(one)))
    assert tet_geometry(inner(par), lattice)[0].sum() / 6.0 == pytest.approx(11.0**3)  # they fill the cube


def test_jitter_is_tiny_seeded_and_keeps_duplicates():
    p = np.random.default_rng(7).random((100, 3)) * 10.0
    p[50] = p[3]
    q = jittered(p)
    diag = np.linalg.norm(p.max(0) - p.min(0))
    assert 0 < np.abs(q - p).max() <= JITTER_REL * diag
    np.testing.assert_array_equal(q[50], q[3])
    np.testing.assert_array_equal(q, jittered(p))


@pytest.mark.slow
def test_duplicates_merge_onto_lowest_index_in_both_paths():
    rng = np.random.default_rng(3)
    base = rng.normal(size=(5000, 3))
    p = np.concatenate([base[2500:], base, base[:100]])  # base[2500:] appear twice, base[:100] too
    first = {tuple(x): i for i, x in reversed(list(enumerate(p.tolist())))}
    canonical = np.array([first[tuple(x)] for x in p.tolist()])
    one, chunked = delaunay(p), delaunay(p, workers=2, chunks=4)
    for tets in (one, chunked):
        used = np.unique(tets)
        np.testing.assert_array_equal(canonical[used], used)
    assert np.isin(keys(chunked), keys(one)).all()  # a subset


def test_kd_boxes_partition_the_points():
    p = np.random.default_rng(4).random((1000, 3)) ** 3  # skewed
    lo, hi = kd_boxes(p, 7)
    assert lo.shape == hi.shape == (7, 3)
    inside = np.all((p[:, None] >= lo) & (p[:, None] < hi), axis=2)  # [P, K]
    np.testing.assert_array_equal(inside.sum(axis=1), 1)
    assert inside.sum(axis=0).min() >= 1000 // 16  # median cuts: balanced within 2x


@pytest.mark.parametrize("seed, n, k", [(0, 20_000, 24), (1, 5_000, 7), (2, 30_000, 60), (3, 2_000, 3)])
def test_halo_steps_from_nearby_cells_equal_the_full_scans(seed, n, k):
    """The chunk halos are found from the points of the cells near each box (`_CellIndex`): the same widths and
    the same ascending halo points as scanning every point, on clustered points, with ties on cut planes."""
    from gof_warp.mesh.delaunay import HALO_FRACTION, _CellIndex, _halo_width, _halo_width_near, _in_box, _kd_cells

    rng = np.random.default_rng(seed)
    c = rng.normal(size=(n // 9, 3)) * 2
    p = (c[:, None, :] + rng.normal(size=(len(c), 9, 3)) * 0.03).reshape(-1, 3)
    p[: n // 20, 2] = 0.5  # many equal values: points on the median cuts
    lo, hi, members = _kd_cells(p, k)
    cells = _CellIndex(p, members)
    full = np.array([_halo_width(p, lo[i], hi[i], HALO_FRACTION) for i in range(len(lo))])
    near = np.array([_halo_width_near(cells, i, lo[i], hi[i], HALO_FRACTION) for i in range(len(lo))])
    np.testing.assert_array_equal(near, full)
    assert (full > 0).all()
    for i in range(len(lo)):
        halo_lo, halo_hi = lo[i] - full[i], hi[i] + full[i]
        cand = cells.near(halo_lo, halo_hi)
        np.testing.assert_array_equal(cand[_in_box(p[cand], halo_lo, halo_hi, closed=True)],
                                      np.flatnonzero(_in_box(p, halo_lo, halo_hi, closed=True)))


def test_bad_arguments():
    p = np.random.default_rng(5).random((50, 3))
    with pytest.raises(GofError, match="workers and chunks"):
        delaunay(p, workers=0)
    with pytest.raises(GofError, match="workers and chunks"):
        delaunay(p, chunks=0)
    with pytest.raises(GofError, match="halo_fraction"):
        delaunay(p, halo_fraction=0.0)
