"""Delaunay backends: one Qhull call vs Qhull in parallel chunks (gof_warp.delaunay)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from gof_warp.delaunay import delaunay, kd_boxes, tet_geometry
from gof_warp.errors import GofError
from gof_warp.tetra import filter_cells, tetra_points

SPHERE_SLACK = 1e-7  # relative: = SPHERE_RTOL; one Qhull call keeps tets with points ~3e-9 R inside (rounding)


def keys(tets: np.ndarray) -> set:
    return set(map(tuple, np.sort(tets, axis=1).tolist()))


def assert_valid_delaunay_tets(tets: np.ndarray, p: np.ndarray) -> None:
    """Positive volume, no tetrahedron twice, no face shared by more than two, every circumsphere empty."""
    vol6, flat, centre, radius = tet_geometry(tets, p)
    assert not flat.any() and (vol6 > 0).all()
    assert len(keys(tets)) == tets.shape[0]
    faces = np.sort(tets[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3), axis=1)
    _, count = np.unique(faces, axis=0, return_counts=True)
    assert count.max() <= 2
    dist, _ = cKDTree(p).query(centre, k=1)
    assert (dist >= radius * (1 - SPHERE_SLACK)).all(), "a kept tetrahedron's circumsphere holds a point"


def longest_edge(t: np.ndarray, p: np.ndarray) -> np.ndarray:
    return np.max([np.linalg.norm(p[t[:, i]] - p[t[:, j]], axis=1) for i, j in itertools.combinations(range(4), 2)],
                  axis=0)


def test_chunked_keeps_every_tet_smaller_than_the_halo():
    """General position: the chunked tetrahedra are Delaunay ones, and every tetrahedron of one call whose longest
    edge is at most the smallest halo width (stats' ``delaunay_rho``) is there."""
    p = np.random.default_rng(0).normal(size=(30_000, 3))
    stats = {}
    one = delaunay(p)
    par = delaunay(p, workers=2, chunks=6, stats=stats)
    assert stats["delaunay_chunks"] == 6
    assert_valid_delaunay_tets(par, p)
    assert keys(par) <= keys(one)
    small = one[longest_edge(one, p) <= stats["delaunay_rho"]]
    assert small.shape[0] > 0.2 * one.shape[0]
    assert keys(small) <= keys(par)
    assert par.shape[0] > 0.99 * one.shape[0]  # the missing ones: slivers on the sparse hull
    assert 0.5 < stats["delaunay_volume_coverage"] <= 1.0 + 1e-9


def test_chunked_misses_only_large_tets_in_empty_space():
    """Two dense clusters 20 apart: the tetrahedra spanning the gap are larger than any halo; every kept one is
    still a true Delaunay tetrahedron, the small ones are all there, and the missing ones are reported."""
    rng = np.random.default_rng(1)
    p = np.concatenate([rng.normal(size=(8000, 3)), rng.normal(size=(8000, 3)) + [20.0, 0, 0]])
    stats = {}
    one, par = delaunay(p), delaunay(p, workers=2, chunks=8, stats=stats)
    assert_valid_delaunay_tets(par, p)
    assert keys(par) <= keys(one)
    missing = np.array(sorted(keys(one) - keys(par)))
    assert missing.size, "the gap's tetrahedra should be missing"
    assert longest_edge(missing, p).min() > stats["delaunay_rho"]
    assert stats["delaunay_unmatched_faces"] > 0
    assert 0.0 < stats["delaunay_volume_coverage"] < 1.0


def test_chunked_gaussian_grid_keeps_what_the_cell_filter_keeps():
    """GOF's points (3σ box corners: cocircular quadruples everywhere): after the paper's cell filter the chunked
    tetrahedra cover what one call's cover, up to other diagonals of degenerate (cocircular) faces."""
    g = torch.Generator().manual_seed(2)
    n = 4000
    means = torch.rand(n, 3, generator=g) * 4.0
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=1)
    scales = torch.rand(n, 3, generator=g) * 0.05 + 0.01
    p, owner, scale = tetra_points(means, quats, scales)
    one = filter_cells(delaunay(p), p, owner, scale)
    par = filter_cells(delaunay(p, workers=2, chunks=8), p, owner, scale)
    assert_valid_delaunay_tets(par, p.astype(np.float64))
    vol = lambda t: tet_geometry(t, p.astype(np.float64))[0].sum() / 6.0  # noqa: E731
    assert vol(par) == pytest.approx(vol(one), rel=1e-3)
    assert len(keys(one) & keys(par)) > 0.995 * one.shape[0]


def test_duplicates_merge_onto_lowest_index_in_both_paths():
    rng = np.random.default_rng(3)
    base = rng.normal(size=(5000, 3))
    p = np.concatenate([base[2500:], base, base[:100]])  # base[2500:] appear twice, base[:100] too
    first = {tuple(x): i for i, x in reversed(list(enumerate(p.tolist())))}
    canonical = np.array([first[tuple(x)] for x in p.tolist()])
    for tets in (delaunay(p), delaunay(p, workers=2, chunks=4)):
        used = np.unique(tets)
        np.testing.assert_array_equal(canonical[used], used)
    assert keys(delaunay(p, workers=2, chunks=4)) <= keys(delaunay(p))


def test_kd_boxes_partition_the_points():
    p = np.random.default_rng(4).random((1000, 3)) ** 3  # skewed
    lo, hi = kd_boxes(p, 7)
    assert lo.shape == hi.shape == (7, 3)
    inside = np.all((p[:, None] >= lo) & (p[:, None] < hi), axis=2)  # [P, K]
    np.testing.assert_array_equal(inside.sum(axis=1), 1)
    assert inside.sum(axis=0).min() >= 1000 // 16  # median cuts: balanced within 2x


def test_bad_arguments():
    p = np.random.default_rng(5).random((50, 3))
    with pytest.raises(GofError, match="workers and chunks"):
        delaunay(p, workers=0)
    with pytest.raises(GofError, match="workers and chunks"):
        delaunay(p, chunks=0)
    with pytest.raises(GofError, match="halo_fraction"):
        delaunay(p, halo_fraction=0.0)
