"""The octree grid (gof_warp.mesh.octree_tets): a hand-counted tree, conformity, balance, cover, watertight marching."""

import numpy as np
import pytest
import torch

from gof_warp.core.arrays import even_split
from gof_warp.core.errors import GofError
from gof_warp.mesh.marching import marching_tetrahedra
from gof_warp.mesh.octree_tets import (OctreeConfig, build_octree, octree_grid, octree_grid_tets, octree_tetrahedra, octree_tets,
                                  unpack)


def _all_occupied(tree):
    tree.occupied = [torch.ones_like(k, dtype=torch.bool) for k in tree.leaves]
    return tree


def _leaf_boxes(tree):
    """Per leaf: (level, lo [3], hi [3]) in world units, float64."""
    out = []
    for level, keys in enumerate(tree.leaves):
        h = tree.size / 2**level
        for c in unpack(keys).tolist():
            lo = tree.lo.numpy() + np.array(c) * h
            out.append((level, lo, lo + h))
    return out


def _unique_rows(rows):
    """``torch.unique(rows, dim=0, return_counts=True)`` for an integer ``[N, k]`` tensor: the distinct rows in
    lexicographic order and how often each occurs, by one ``lexsort`` of the columns (``unique(dim=0)`` sorts rows
    as slowly as seconds here)."""
    r = rows.numpy()
    r = r[np.lexsort(r.T[::-1])]
    new = np.ones(len(r), bool)
    new[1:] = (r[1:] != r[:-1]).any(axis=1)
    start = np.flatnonzero(new)
    return torch.from_numpy(r[start]), torch.from_numpy(np.diff(np.append(start, len(r))))


def _triangles(tets):
    t = tets.long()
    f = torch.cat([t[:, [0, 1, 2]], t[:, [0, 1, 3]], t[:, [0, 2, 3]], t[:, [1, 2, 3]]]).sort(dim=1).values
    return _unique_rows(f)


def _volumes(points, tets):
    p = points.double()
    t = tets.long()
    return torch.linalg.det(p[t[:, 1:]] - p[t[:, :1]]) / 6


def test_one_refined_octant_gives_the_hand_counted_tetrahedra():
    """Root [0, 4]^3, one Gaussian asks for level-2 cells in the octant [0, 2]^3. Counted by hand:
    the 8 level-2 leaves have no finer neighbour: Kuhn's 6 each = 48; the 3 level-1 leaves sharing a face with the
    octant are cones: that face as 4 diagonal-split sub-faces (8) + 4 faces fanned around one hanging vertex (5 each)
    + 1 plain face (2) = 30 each; the 3 sharing an edge: 2 fans (5) + 4 plain (2) = 18 each; the one sharing a corner
    only has no hanging vertex: Kuhn's 6. Total 48 + 90 + 54 + 6 = 198.
    Points: 27 corners of the fine octant + 27 of the coarse grid − 8 shared = 46, 6 cone centres, 12 fan centres."""
    tree = _all_occupied(build_octree(torch.tensor([[0.6, 0.6, 0.6]], dtype=torch.float64),
                                      torch.tensor([0.5], dtype=torch.float64), depth=2, cell_factor=1.0,
                                      lo=torch.zeros(3, dtype=torch.float64), size=4.0))
    assert [int(k.numel()) for k in tree.leaves] == [0, 7, 8]
    points, tets = octree_tetrahedra(tree)
    assert tets.shape == (198, 4)
    assert points.shape == (46 + 6 + 12, 3)
    v = _volumes(points, tets)
    assert bool((v > 0).all())
    assert float(v.sum()) == pytest.approx(64.0, rel=1e-6)


def test_grid_is_conforming_and_fills_the_root_cube():
    """Random boxes of many sizes: every tetrahedron positive, volumes sum to the cube, every triangle is shared by
    two tetrahedra except those on the root cube's faces (no hanging vertex, no crack)."""
    g = torch.Generator().manual_seed(3)
    centres = torch.rand(200, 3, generator=g, dtype=torch.float64)
    radii = torch.exp(torch.randn(200, generator=g, dtype=torch.float64)) * 0.02
    tree = _all_occupied(build_octree(centres, radii, depth=8))
    assert sum(1 for k in tree.leaves if k.numel()) >= 4  # several levels meet
    points, tets = octree_tetrahedra(tree)
    v = _volumes(points, tets)
    assert bool((v > 0).all())
    assert float(v.sum()) == pytest.approx(tree.size ** 3, rel=1e-5)
    tri, count = _triangles(tets)
    assert int(count.max()) == 2
    x = points.double()[tri[count == 1]]  # [K, 3 corners, 3]
    lo, hi = tree.lo, tree.lo + tree.size
    tol = 1e-5 * tree.size
    on_face = (((x - lo).abs() < tol).all(dim=1) | ((x - hi).abs() < tol).all(dim=1)).any(dim=1)
    assert bool(on_face.all())


def test_touching_leaves_differ_by_at_most_one_level_and_boxes_get_small_cells():
    g = torch.Generator().manual_seed(5)
    centres = torch.rand(40, 3, generator=g, dtype=torch.float64)
    radii = torch.exp(torch.randn(40, generator=g, dtype=torch.float64)) * 0.03
    tree = build_octree(centres, radii, depth=7, cell_factor=1.0)
    boxes = _leaf_boxes(tree)
    lv = np.array([b[0] for b in boxes])
    lo = np.stack([b[1] for b in boxes])
    hi = np.stack([b[2] for b in boxes])
    eps = 1e-9
    touch = np.all((lo[:, None] <= hi[None] + eps) & (lo[None] <= hi[:, None] + eps), axis=2)
    assert np.abs(lv[:, None] - lv[None])[touch].max() <= 1  # faces, edges and corners
    # a leaf overlapping a box's interior is no larger than cell_factor × its width (or the deepest level)
    occ = np.concatenate([o.numpy() for o in tree.occupied])
    for c, r in zip(centres.numpy(), radii.numpy()):
        inter = np.all((lo < c + r) & (hi > c - r), axis=1)
        side = hi[inter, 0] - lo[inter, 0]
        assert np.all((side <= 2 * r + eps) | (lv[inter] == tree.depth))
        assert occ[inter].all()  # and the box's leaves are occupied


def test_leaves_outside_every_box_get_no_tetrahedra():
    centres = torch.tensor([[0.2, 0.2, 0.2], [0.8, 0.8, 0.8]], dtype=torch.float64)
    radii = torch.tensor([0.05, 0.05], dtype=torch.float64)
    points, tets, tree = octree_grid(centres, radii, OctreeConfig(depth=6))
    occ = np.concatenate([o.numpy() for o in tree.occupied])
    assert 0 < occ.sum() < occ.size
    p = points.double()[tets.long()].mean(dim=1)  # tetrahedron centroids
    near = torch.cdist(p, centres).min(dim=1).values
    # occupied cells are those of the two boxes: at most a cell diagonal beyond the radius
    assert float(near.max()) < 0.05 + 2 * 0.1 * np.sqrt(3)


def test_marching_on_the_octree_grid_is_watertight_on_a_sphere():
    """Boxes along a sphere of radius 0.3: the level set of a radial field meshed on the octree grid is closed
    (every edge in two faces) and on the sphere after 8 bisection steps."""
    g = torch.Generator().manual_seed(7)
    d = torch.randn(400, 3, generator=g, dtype=torch.float64)
    centres = 0.5 + 0.3 * d / d.norm(dim=1, keepdim=True)
    radii = torch.full((400,), 0.06, dtype=torch.float64)
    points, tets, _ = octree_grid(centres, radii, OctreeConfig(depth=8))

    def field(x):
        x = torch.as_tensor(x, dtype=torch.float32)
        return torch.sigmoid((0.3 - (x - 0.5).norm(dim=1)) * 40.0)

    (verts, faces), = marching_tetrahedra(points, tets, field(points), field, levels=(0.5,), binary_steps=8,
                                          oriented=True, device="cpu")
    assert len(faces) > 100
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, count = np.unique(e, axis=0, return_counts=True)
    assert np.all(count == 2)
    r = np.linalg.norm(verts - 0.5, axis=1)
    assert np.abs(r - 0.3).max() < 1e-3


def _random_tree(seed=11, n=30, depth=6):
    g = torch.Generator().manual_seed(seed)
    centres = torch.rand(n, 3, generator=g, dtype=torch.float64)
    radii = torch.exp(torch.randn(n, generator=g, dtype=torch.float64)) * 0.04
    return build_octree(centres, radii, depth=depth, cell_factor=0.5)


def test_pieces_are_consecutive_ranges_of_the_whole_grid():
    """``OctreeTets.pieces``: any number of pieces, taken all or any range of them, are the consecutive slices
    ``count · k // n`` of the tetrahedra made at once, so pieces marched apart join into the whole grid's mesh."""
    grid = octree_tets(_random_tree(), chunk=256)  # small chunks: pieces cut through chunks and chunks through pieces
    whole = grid.all()
    assert whole.shape == (grid.count, 4) and grid.count > 1000
    for n in (1, 2, 7, 23):
        got = list(grid.pieces(n))
        assert [k for k, _ in got] == list(range(n))
        b = even_split(grid.count, n)
        assert all(torch.equal(t, whole[b[k]:b[k + 1]]) for k, t in got)
        assert max(t.shape[0] for _, t in got) - min(t.shape[0] for _, t in got) <= 1
    mid = list(grid.pieces(7, 2, 5))  # a rank's share alone
    b = even_split(grid.count, 7)
    assert [k for k, _ in mid] == [2, 3, 4] and torch.equal(torch.cat([t for _, t in mid]), whole[b[2]:b[5]])
    assert list(grid.pieces(7, 3, 3)) == []
    with pytest.raises(GofError, match="n_pieces"):
        next(grid.pieces(0))
    with pytest.raises(GofError, match="do not lie"):
        next(grid.pieces(3, 2, 4))


@pytest.mark.slow
def test_chunk_size_changes_only_the_order_of_the_tetrahedra():
    """The chunks (leaves and face records made at once, which bound the memory) reorder the tetrahedra but make the
    same points and the same set of tetrahedra, each positively oriented."""
    tree = _random_tree(seed=12)
    a, b = octree_tets(tree), octree_tets(tree, chunk=64)
    assert torch.equal(a.keys, b.keys) and torch.equal(a.points, b.points) and a.count == b.count
    ta, tb = a.all(), b.all()
    assert not torch.equal(ta, tb)  # the chunks did change the order (else this test shows nothing)
    assert torch.equal(_unique_rows(ta)[0], _unique_rows(tb)[0])
    assert bool((_volumes(b.points, tb) > 0).all())


def test_no_piece_holds_more_than_its_share():
    """``octree_grid_tets`` keeps the points and makes tetrahedra only when asked: one piece of 1/n of them."""
    g = torch.Generator().manual_seed(13)
    centres = torch.rand(60, 3, generator=g, dtype=torch.float64)
    radii = torch.full((60,), 0.05, dtype=torch.float64)
    grid = octree_grid_tets(centres, radii, OctreeConfig(depth=6))
    points, tets, _ = octree_grid(centres, radii, OctreeConfig(depth=6))
    assert torch.equal(grid.points, points) and grid.count == tets.shape[0]
    assert max(t.shape[0] for _, t in grid.pieces(4)) <= -(-grid.count // 4)
    with pytest.raises(GofError, match="piece_tets"):
        OctreeConfig(piece_tets=0).validate()


@pytest.mark.parametrize("kwargs, match", [
    (dict(cell_factor=0.0), "cell_factor"), (dict(cell_factor=float("nan")), "cell_factor"),
    (dict(depth=0), "depth"), (dict(depth=20), "depth"), (dict(box_percentile=50), "box_percentile"),
    (dict(small_leaves=-1), "small_leaves"), (dict(small_leaves=True), "small_leaves")])
def test_bad_settings_are_clear_errors(kwargs, match):
    with pytest.raises(GofError, match=match):
        octree_grid(torch.zeros(1, 3), torch.ones(1), OctreeConfig(**kwargs))


def test_a_small_grid_is_built_at_the_finer_factor_unless_a_factor_is_given():
    """cell_factor None: DEFAULT_CELL_FACTOR, or SMALL_CELL_FACTOR when the default grid has fewer than small_leaves
    leaves; a given factor is used as it is."""
    from gof_warp.mesh.octree_tets import DEFAULT_CELL_FACTOR, SMALL_CELL_FACTOR

    gen = torch.Generator().manual_seed(3)
    centres = torch.rand(40, 3, generator=gen, dtype=torch.float64)
    radii = torch.full((40,), 0.04, dtype=torch.float64)  # cells of level 5 at 0.5, of level 6 at 0.35

    def built(**kw):
        stats = {}
        grid = octree_grid_tets(centres, radii, OctreeConfig(depth=8, **kw), stats=stats)
        return stats["octree_cell_factor"], stats["octree_leaves"], grid.count

    coarse = built(cell_factor=DEFAULT_CELL_FACTOR)
    fine = built(cell_factor=SMALL_CELL_FACTOR)
    assert coarse[0] == DEFAULT_CELL_FACTOR and fine[0] == SMALL_CELL_FACTOR and fine[1] > coarse[1]
    assert built(small_leaves=coarse[1] + 1) == fine  # under the limit: the finer grid
    assert built(small_leaves=coarse[1]) == coarse  # at it: the default
    assert built(small_leaves=0, cell_factor=0.7)[0] == 0.7 and built(small_leaves=10**9, cell_factor=0.7)[0] == 0.7


def test_the_far_corner_of_the_deepest_lattice_keeps_its_key():
    """depth = MAX_DEPTH: the root cube's far corner (2^(depth+1) lattice units) packs and unpacks unchanged, so the
    cells on the far faces keep their corners."""
    from gof_warp.mesh.octree_tets import MAX_DEPTH, pack

    far = torch.tensor([[1 << (MAX_DEPTH + 1)] * 3], dtype=torch.int64)
    assert torch.equal(unpack(pack(far)), far)
    tree = _all_occupied(build_octree(torch.tensor([[0.999, 0.999, 0.999]], dtype=torch.float64),
                                      torch.tensor([1e-6], dtype=torch.float64), depth=MAX_DEPTH,
                                      lo=torch.zeros(3, dtype=torch.float64), size=1.0))
    points, tets = octree_tetrahedra(tree)
    assert float(points.max()) == 1.0 and float(_volumes(points, tets).sum()) == pytest.approx(1.0, rel=1e-5)


def test_far_outliers_that_coarsen_the_grid_are_named(caplog):
    centres = torch.cat([torch.rand(200, 3, dtype=torch.float64), torch.tensor([[1e7, 0.0, 0.0]])])
    radii = torch.full((201,), 1e-2, dtype=torch.float64)
    with caplog.at_level("WARNING", logger="gof_warp.mesh.octree_tets"):
        octree_grid(centres, radii, OctreeConfig(depth=8))
    assert "finer than the octree's deepest level" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING", logger="gof_warp.mesh.octree_tets"):
        octree_grid(centres, radii, OctreeConfig(depth=8, box_percentile=1.0))
    assert "deepest level" not in caplog.text


def test_bad_boxes_are_clear_errors():
    with pytest.raises(GofError, match="positive"):
        octree_grid(torch.zeros(2, 3), torch.tensor([1.0, 0.0]))
    with pytest.raises(GofError, match="finite"):
        octree_grid(torch.tensor([[0.0, float("nan"), 0.0]]), torch.ones(1))
    with pytest.raises(GofError, match="disagree"):
        octree_grid(torch.zeros(2, 3), torch.ones(3))


@pytest.mark.slow
@pytest.mark.parametrize("device", ["cpu"] + (["cuda"] if torch.cuda.is_available() else []))
def test_same_grid_on_every_device(device):
    g = torch.Generator().manual_seed(11)
    centres = torch.rand(100, 3, generator=g, dtype=torch.float64)
    radii = torch.exp(torch.randn(100, generator=g, dtype=torch.float64)) * 0.03
    ref_p, ref_t, _ = octree_grid(centres, radii)
    p, t, _ = octree_grid(centres.to(device), radii.to(device))
    assert ref_t.shape[0] > 0
    assert torch.equal(p.cpu(), ref_p) and torch.equal(t.cpu(), ref_t)


def test_key_set_merges_batches_into_the_distinct_sorted_keys(monkeypatch):
    """``_KeySet`` (the octree's cells, corners and points gathered chunk by chunk): batches merged whenever they
    outnumber the set, here every few batches, end as ``torch.unique`` of all of them."""
    from gof_warp.mesh import octree_tets as ot

    monkeypatch.setattr(ot, "KEYSET_MERGE_MIN", 50)
    g = torch.Generator().manual_seed(17)
    batches = [torch.randint(0, 400, (int(n),), generator=g) for n in torch.randint(0, 90, (40,), generator=g)]
    keys, merges = ot._KeySet(torch.device("cpu")), 0
    for b in batches:
        before = len(keys.pending)
        keys.add(b)
        merges += len(keys.pending) < before + 1
    assert merges >= 5  # the merges did happen along the way
    assert torch.equal(keys.sorted(), torch.unique(torch.cat(batches)))
