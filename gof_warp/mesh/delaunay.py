"""Delaunay tetrahedralisation of the tetrahedral-grid points: one Qhull call, CGAL, or Qhull in parallel chunks.

Delaunay dominates GOF's extraction (one Qhull call takes ~53 s per million points on one core). With
``workers > 1`` large point sets can be triangulated in **chunks on several threads** (scipy's Qhull
releases the GIL) and stitched:

1. The points are split into ``K`` cells by median cuts along the widest axis (a k-d tree). A cell's
   *core* owns the space of its box (half-open; cells on the outside reach to infinity); its *halo box*
   grows the core until it holds ``halo_fraction`` × the core's points more.
2. Each chunk triangulates the points of its halo box (Qhull). A local tetrahedron is kept by the chunk
   whose core holds its owner point — the circumcentre when the circumradius is at most ``rho`` (the
   smallest halo width), else the centroid; both are the same in every chunk, so no tetrahedron is kept
   twice — and only if it is a tetrahedron of the global Delaunay tetrahedralisation: its circumsphere
   lies in the halo box (then every point inside the sphere would be a local point, and there is none),
   or a KD-tree over all points finds no point inside the sphere.
3. **Exact merge.** The tetrahedra no chunk kept (large ones in empty space whose vertices no single halo
   holds, or ones owned by a core whose chunk did not see them) fill the region bounded by the faces left
   unmatched between chunks. One more Qhull call on the vertices of those faces plus the points no kept
   tetrahedron uses yields every one of them (``_fill_piece`` says why); the global Delaunay ones among its
   tetrahedra (KD-tree sphere test) that were not kept already are added. ``stats`` reports the unmatched
   faces before (``delaunay_chunk_unmatched_faces``) and after (``delaunay_unmatched_faces``, 0 when exact).

Before any of it the points are **perturbed** by 3e-7 of their bounding-box diagonal (seeded, the same for
equal points: :func:`jittered`): 3σ-box corners are cospherical octuples whose tetrahedralisation is not
unique, and each Qhull call would pick its own diagonals, so chunks would disagree with each other (holes,
overlaps). In general position the Delaunay tetrahedralisation is unique, and the chunked result equals one
Qhull call's (``tests/mesh/test_delaunay.py``). The perturbation only decides connectivity (the marching and
the bisection use the exact points); volumes, orientation and flatness are those of the perturbed points, so the 3σ-box cells that are flat in
the exact inputs come out as slivers rather than gaps. Duplicate points are merged onto their lowest index
and every tetrahedron is positively oriented (in the perturbed coordinates).

Memory (measured on a 2-core CPU): a chunk in flight holds ~4.9 KB per point of its halo box
(Qhull's own peak and the tetrahedra's geometry: ~740 B per local tetrahedron, ~6.6 per point), times the
chunks in flight (= ``workers``): with the default ``CHUNK_POINTS`` 25k (37.5k with the halo), ~0.18 GB per
worker. Around it ~200 B per point of the whole set: the perturbed points, the KD-tree (~40 B), the kept
tetrahedra (16 B each) and their concatenation.
"""

from __future__ import annotations

import logging
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .delaunay_cgal import delaunay_cgal as _delaunay_cgal
from ..core.errors import GofError
from ..core.forked import can_fork

log = logging.getLogger(__name__)

# A tetrahedron is degenerate (zero volume) when |6 V| <= this × (longest edge)³: Qhull's "Qt" output
# contains flat simplices whose float64 volume is a rounding residue (~1e-16 relative).
DEGENERATE_REL_VOLUME = 1e-10
# A point counts as inside a circumsphere when nearer its centre than R (1 - this); nearer to the sphere
# is cospherical to rounding. Measured on 3σ-box corners (tests/mesh/test_delaunay.py): unperturbed, Qhull keeps
# tetrahedra with points up to ~3e-9 R inside; perturbed by JITTER_REL, up to ~1e-10 R.
SPHERE_RTOL = 1e-9
BACKENDS = ("scipy", "cgal", "auto")
PARALLEL_MIN_POINTS = 200_000  # below this one Qhull call is as fast as the chunked path
CHUNK_POINTS = 25_000  # target points per chunk core (auto chunk count); ~1 s of Qhull on one core. Memory in flight
# is ∝ workers × chunk size: a 150k chunk holds 1.1 GB in flight (17.6 GB of DTU's host peak at 16 workers). On a
# 2-core CPU, 150k / 50k / 25k chunks take 3M points in 96 / 88 / 75 s, 2.33 / 1.36 / 1.21 GB above the start.
DUPLICATES_SEEN = 8  # the exact merge maps a point to the lowest index among this many exact copies
FILL_SPLIT_POINTS = 8 * CHUNK_POINTS  # a fill with this many points is triangulated in chunks itself
MAX_FILLS = 3  # passes of the exact merge (one suffices in general position; more only guard against rounding)
HALO_FRACTION = 0.5  # a chunk triangulates its core's points and this fraction more around it
_FACES = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])  # face i is opposite vertex i (Qhull's order)
# Symbolic-perturbation stand-in: every point moves by up to this × the points' bounding-box diagonal (a fixed,
# seeded draw). GOF's points are 3σ-box corners — cospherical octuples whose Delaunay tetrahedralisation is not
# unique — and Qhull's "Qt" would triangulate each such cell its own way in every chunk. Perturbed, the
# points are in general position, the tetrahedralisation is unique and every chunk agrees with one Qhull
# call. Measured on 3σ-box corners: 1e-8 and 3e-8 left chunks disagreeing on a few cells (Qhull's own
# rounding near cospherical points), 1e-7 at a 1e-8 sphere tolerance too; 3e-7 agreed at 1e-8 and 1e-9.
# It moves only the triangulation's connectivity decisions: the field and the bisection use the exact points.
JITTER_REL = 3e-7
JITTER_SEED = 0x60F


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


# ---------------------------------------------------------------------------------------------- geometry
def check_points(points) -> np.ndarray:
    """``points [P, 3]`` as float64, finite, at least 4 of them; ``GofError`` otherwise."""
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3:
        raise GofError(f"points must have shape [P, 3], got {p.shape}")
    p = p.astype(np.float64)
    if not np.all(np.isfinite(p)):
        raise GofError("points has NaN/inf entries")
    if p.shape[0] < 4:
        raise GofError(f"Delaunay needs at least 4 points, got {p.shape[0]}")
    return p


def jittered(p: np.ndarray, rel: float = JITTER_REL) -> np.ndarray:
    """``p [P, 3]`` float64 moved by a seeded uniform draw of at most ``rel`` × the bounding-box diagonal
    per coordinate; duplicates stay duplicates (the draw is a function of the coordinates' bytes)."""
    if rel <= 0 or p.shape[0] == 0:
        return p
    diag = float(np.linalg.norm(p.max(axis=0) - p.min(axis=0)))
    if diag == 0.0:
        return p
    # a hash of each point's coordinates, so that equal points get equal offsets (duplicates merge as before)
    h = np.ascontiguousarray(p + 0.0).view(np.uint64).reshape(-1, 3)  # + 0.0: -0.0 hashes as 0.0
    mix = (h[:, 0] * np.uint64(0x9E3779B97F4A7C15)) ^ (h[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F)) ^ (
        h[:, 2] * np.uint64(0x165667B19E3779F9)) ^ np.uint64(JITTER_SEED)
    offsets = np.empty_like(p)
    for axis in range(3):
        mix ^= mix >> np.uint64(31)
        mix *= np.uint64(0xBF58476D1CE4E5B9)
        mix ^= mix >> np.uint64(29)
        offsets[:, axis] = (mix >> np.uint64(11)).astype(np.float64) / float(1 << 53) - 0.5
    return p + (2.0 * rel * diag) * offsets


def _check_spans_volume(p: np.ndarray) -> None:
    """``GofError`` when the points lie on a plane or a line (thinnest extent <= 1e-9 of the widest)."""
    q = p - p.mean(axis=0)
    eig = np.linalg.eigvalsh(q.T @ q)
    if eig[-1] <= 0 or eig[0] <= 1e-18 * eig[-1]:
        raise GofError(f"Delaunay failed: the {p.shape[0]} points are degenerate (coplanar/collinear: they span no "
                       "volume)")


def tet_geometry(tets: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(6 × signed volume [T], flat [T] bool, circumcentre [T, 3], circumradius [T])`` (float64). Flat:
    ``|6V| <= DEGENERATE_REL_VOLUME × longest edge³``; their circumcentre is the centroid and radius inf."""
    a = p[tets[:, 0]]
    u, v, w = p[tets[:, 1]] - a, p[tets[:, 2]] - a, p[tets[:, 3]] - a
    vxw, wxu, uxv = np.cross(v, w), np.cross(w, u), np.cross(u, v)
    vol6 = np.einsum("ij,ij->i", u, vxw)
    edges2 = [np.einsum("ij,ij->i", e, e) for e in (u, v, w, v - u, w - u, w - v)]
    flat = np.abs(vol6) <= DEGENERATE_REL_VOLUME * np.max(edges2, axis=0) ** 1.5
    safe = np.where(flat, 1.0, vol6)
    rel = (edges2[0][:, None] * vxw + edges2[1][:, None] * wxu + edges2[2][:, None] * uxv) / (2.0 * safe[:, None])
    rel[flat] = (u[flat] + v[flat] + w[flat]) / 4.0
    radius = np.where(flat, np.inf, np.linalg.norm(rel, axis=1))
    return vol6, flat, a + rel, radius


def _orient(tets: np.ndarray, vol6: np.ndarray) -> np.ndarray:
    t = np.ascontiguousarray(tets, dtype=np.int32)
    neg = vol6 < 0
    t[neg] = t[neg][:, [0, 1, 3, 2]]
    return t


def orient_and_drop_degenerate(tets: np.ndarray, points: np.ndarray, chunk_size: int = 1 << 20) -> np.ndarray:
    """Drop zero-volume tetrahedra and swap two vertices of the negative ones, so every returned tetrahedron has
    positive volume. ``[T, 4]`` → ``[T', 4]`` int32."""
    p = np.asarray(points, np.float64)
    out = []
    for s in range(0, tets.shape[0], chunk_size):
        t = np.asarray(tets[s : s + chunk_size])
        vol6, flat, _, _ = tet_geometry(t, p)
        out.append(_orient(t[~flat], vol6[~flat]))
    result = np.concatenate(out) if out else np.zeros((0, 4), np.int32)
    if result.shape[0] < tets.shape[0]:
        log.info("delaunay: dropped %d degenerate tetrahedra", tets.shape[0] - result.shape[0])
    return result


# ---------------------------------------------------------------------------------------------- one call
def _qhull(p: np.ndarray):
    from scipy.spatial import Delaunay, QhullError

    try:
        return Delaunay(p)
    except QhullError as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        raise GofError(f"Delaunay failed: the {p.shape[0]} points are degenerate (coplanar/collinear?): {first}") from e


def _canonical_vertices(tri, p: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Global index of each local vertex, duplicates mapped to their lowest global index (Qhull keeps one
    copy of a duplicated point and lists the others as "coplanar", with the copy it kept)."""
    glob = ids.copy()
    cop = tri.coplanar
    if cop.shape[0]:
        pt, vtx = cop[:, 0], cop[:, 2]
        dup = np.all(p[ids[pt]] == p[ids[vtx]], axis=1)
        np.minimum.at(glob, vtx[dup], ids[pt[dup]])
    return glob


# ---------------------------------------------------------------------------------------------- chunks
def kd_boxes(p: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Split the points into ``k`` cells by median cuts along each cell's widest axis. Returns cores
    ``(lo [k, 3], hi [k, 3])`` (a point x is in a core when lo <= x < hi; outer sides are ±inf)."""
    lo, hi, _ = _kd_cells(p, k)
    return lo, hi


def _kd_cells(p: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """:func:`kd_boxes` and the (ascending) indices of each cell's points."""
    cells = [(np.arange(p.shape[0]), np.full(3, -np.inf), np.full(3, np.inf))]
    while len(cells) < k:
        cells.sort(key=lambda c: -c[0].shape[0])
        idx, lo, hi = cells.pop(0)
        q = p[idx]
        axis = int(np.argmax(q.max(0) - q.min(0)))
        cut = float(np.median(q[:, axis]))
        below = q[:, axis] < cut
        if below.all() or not below.any():  # all on one value along the widest axis: cannot split further
            cells.append((idx, lo, hi))
            break
        hi_a, lo_b = hi.copy(), lo.copy()
        hi_a[axis] = lo_b[axis] = cut
        cells += [(idx[below], lo, hi_a), (idx[~below], lo_b, hi)]
    return np.array([c[1] for c in cells]), np.array([c[2] for c in cells]), [c[0] for c in cells]


class _CellIndex:
    """The kd cells' points and tight bounding boxes, to visit only the cells near a box (the halo steps below
    would otherwise scan every point once per chunk: O(chunks × points), ~150 s at DTU's 7.2M points in 287
    chunks)."""

    def __init__(self, p: np.ndarray, members: list[np.ndarray]):
        self.p, self.members = p, members
        self.bmin = np.array([p[m].min(axis=0) if m.size else np.full(3, np.inf) for m in members])
        self.bmax = np.array([p[m].max(axis=0) if m.size else np.full(3, -np.inf) for m in members])

    def near(self, lo: np.ndarray, hi: np.ndarray, ordered: bool = True) -> np.ndarray:
        """Indices (ascending when ``ordered``) of the points of every cell whose points' bounding box meets the
        closed box ``[lo, hi]``: a superset of the points in that box."""
        hit = np.flatnonzero(np.all((self.bmax >= lo) & (self.bmin <= hi), axis=1))
        if hit.size == 0:
            return np.zeros(0, np.int64)
        ids = np.concatenate([self.members[c] for c in hit])
        return np.sort(ids) if ordered else ids


def _halo_width(p: np.ndarray, lo: np.ndarray, hi: np.ndarray, fraction: float) -> float:
    """The distance around a core box that takes in ``fraction`` × its own number of points more (L∞)."""
    outside = np.max(np.maximum(lo - p, p - hi), axis=1)  # <= 0 inside
    core = int(np.sum(outside < 0))
    dist = outside[outside >= 0]
    k = min(max(1, round(fraction * core)), dist.size) - 1
    return float(np.partition(dist, k)[k]) if dist.size else 0.0


def _halo_width_near(cells: _CellIndex, c: int, lo: np.ndarray, hi: np.ndarray, fraction: float) -> float:
    """:func:`_halo_width` of core ``c`` (the same number) from the points of the cells near it: the points
    within a trial width ``w`` of the core all lie in cells whose bounding boxes meet the core grown by ``w``,
    so once ``k + 1`` of them are found within ``w`` the ``k``-th smallest distance is the global one; else ``w``
    doubles (and at the points' bounding box the scan is the whole set)."""
    p, own = cells.p, cells.p[cells.members[c]]
    core = int(np.sum(np.max(np.maximum(lo - own, own - hi), axis=1) < 0))  # strictly inside: only c's points
    n_out = p.shape[0] - core
    if n_out == 0:
        return 0.0
    k = min(max(1, round(fraction * core)), n_out) - 1
    span = float(np.max(cells.bmax.max(axis=0) - cells.bmin.min(axis=0)))
    box = own.max(axis=0) - own.min(axis=0) if own.size else np.zeros(3)
    # first trial: the shell that holds `fraction` more points at the core's own density (a cube: (1 + 2w/L)³ =
    # 1 + fraction), doubled; clustered points may need more, and the loop doubles it
    w = max(float(np.min(box)) * ((1.0 + fraction) ** (1.0 / 3.0) - 1.0), span * 1e-6, 1e-12)
    lo_f, hi_f = np.maximum(lo, cells.bmin.min(axis=0)), np.minimum(hi, cells.bmax.max(axis=0))  # finite core
    while True:
        ids = cells.near(lo_f - w, hi_f + w, ordered=False)
        q = p[ids]
        outside = np.max(np.maximum(lo - q, q - hi), axis=1)
        dist = outside[outside >= 0]
        if np.sum(dist <= w) > k or w > 2.0 * span:
            if dist.size <= k:  # fewer points outside than asked: the largest distance (as the global rule)
                return _halo_width(p, lo, hi, fraction)
            return float(np.partition(dist, k)[k])
        w *= 2.0


def _in_box(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, closed: bool) -> np.ndarray:
    upper = x <= hi if closed else x < hi
    return np.all((x >= lo) & upper, axis=1)


@dataclass
class _Piece:
    """What one chunk contributes: kept tetrahedra (global ids, oriented, non-flat) and the faces of
    its kept tetrahedra (flat ones included) whose neighbour it did not keep."""

    tets: np.ndarray  # [T, 4] int32
    volume6: float  # sum of 6 V of the kept tetrahedra
    faces: np.ndarray  # [F, 3] sorted global ids
    on_hull: np.ndarray  # [F] bool: the face has no local neighbour (it lies on the piece's hull)
    apex: np.ndarray  # [F] global id of the kept tetrahedron's vertex opposite the face
    checked: int  # kept-by-ownership tetrahedra whose sphere left the halo (checked with the KD-tree)
    rejected: int  # of those, found not Delaunay


def _triangulate_piece(p: np.ndarray, ids: np.ndarray, core_lo, core_hi, halo_lo, halo_hi, tree, rho: float) -> _Piece:
    """Qhull on ``p[ids]``; keep the tetrahedra whose owner point lies in the core box (the circumcentre when the
    circumradius is <= ``rho``, else the centroid) and that are global Delaunay tetrahedra (circumsphere in
    the halo box, else checked with the KD-tree)."""
    tri = _qhull(p[ids])
    glob = _canonical_vertices(tri, p, ids)
    t = glob[tri.simplices]
    vol6, flat, centre, radius = tet_geometry(t, p)
    small = radius <= rho
    keep = _in_box(np.where(small[:, None], centre, p[t].mean(axis=1)), core_lo, core_hi, closed=False)
    inside = np.all((centre - radius[:, None] >= halo_lo) & (centre + radius[:, None] <= halo_hi), axis=1)
    check = np.flatnonzero(keep & ~flat & ~inside)
    rejected = 0
    if check.size:
        dist, _ = tree.query(centre[check], k=1)
        bad = check[dist < radius[check] * (1.0 - SPHERE_RTOL)]
        keep[bad] = False
        rejected = int(bad.size)
    return _piece(t, tri.neighbors, keep, vol6, flat, int(check.size), rejected)


def _piece(t: np.ndarray, nb: np.ndarray, keep: np.ndarray, vol6: np.ndarray, flat: np.ndarray, checked: int,
           rejected: int) -> _Piece:
    """The kept tetrahedra of one local triangulation ``t [T, 4]`` (global ids; ``nb [T, 4]`` its neighbours, -1 on
    its hull) and the faces between a kept tetrahedron and one not kept."""
    kept_nb = np.where(nb >= 0, keep[np.maximum(nb, 0)], False)
    border_t, border_f = np.nonzero(keep[:, None] & ~kept_nb)
    faces = np.sort(t[border_t[:, None], _FACES[border_f]], axis=1).astype(np.int32)
    solid = keep & ~flat
    return _Piece(_orient(t[solid], vol6[solid]), float(np.abs(vol6[solid]).sum()), faces,
                  nb[border_t, border_f] < 0, t[border_t, border_f], checked, rejected)


def _rows_in(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``[len(a)]`` bool: row i of ``a`` (sorted ids) occurs in ``b`` (sorted ids); both ``[*, k]`` int."""
    if a.shape[0] == 0 or b.shape[0] == 0:
        return np.zeros(a.shape[0], bool)
    c = np.concatenate([a, b])
    order = np.lexsort(c.T[::-1])
    same = np.all(c[order][1:] == c[order][:-1], axis=1)
    hit = np.zeros(c.shape[0], bool)
    # an a-row equal to its sorted neighbour that comes from b (b rows are unique, a rows are unique)
    from_b = order >= a.shape[0]
    hit[order[1:][same & from_b[:-1]]] = True
    hit[order[:-1][same & from_b[1:]]] = True
    return hit[: a.shape[0]]


def _neighbours(t: np.ndarray) -> np.ndarray:
    """``[T, 4]``: the tetrahedron across face ``i`` (opposite vertex ``i``) of each of ``t [T, 4]``, −1 where none
    shares it (Qhull's ``neighbors`` layout, for a tetrahedralisation that does not come from one Qhull call)."""
    f = np.sort(t[:, _FACES], axis=2).reshape(-1, 3)  # row 4 i + k: face k of tetrahedron i
    order = np.lexsort(f.T[::-1])
    same = np.all(f[order[1:]] == f[order[:-1]], axis=1)
    a, b = order[:-1][same], order[1:][same]
    nb = np.full(f.shape[0], -1, np.int64)
    nb[a], nb[b] = b // 4, a // 4
    return nb.reshape(-1, 4)


def _fill_triangulation(q: np.ndarray, workers: int, halo_fraction: float, processes: bool):
    """``(tets [T, 4] local ids, neighbours [T, 4], local → canonical local ids)``: the Delaunay tetrahedralisation of
    the fill's points ``q``. One Qhull call, or — from ``FILL_SPLIT_POINTS`` points on with several workers — the
    exact chunked path itself (the fill's points gather along every chunk border, so one call was the serial
    tail of the merge: 8.8 s of a 9.5 s stitch at 900k points in 144 chunks on 2 cores)."""
    if workers > 1 and q.shape[0] >= FILL_SPLIT_POINTS:
        chunks = max(2 * workers, round(q.shape[0] / CHUNK_POINTS))
        t = delaunay_chunked(q, chunks, workers, halo_fraction, processes=processes)
        return t, _neighbours(t), np.arange(q.shape[0])
    tri = _qhull(q)
    return tri.simplices, tri.neighbors, _canonical_vertices(tri, q, np.arange(q.shape[0]))


def _fill_piece(p: np.ndarray, pieces: list[_Piece], unmatched: np.ndarray, tree, workers: int = 1,
                halo_fraction: float = HALO_FRACTION, processes: bool = False) -> _Piece | None:
    """The global Delaunay tetrahedra no chunk kept. They fill the region bounded by the unmatched faces, and
    every vertex of one is a vertex of an unmatched face or a point no kept tetrahedron uses (around a vertex
    the tetrahedra are connected through faces that contain it, so a vertex with kept and missing tetrahedra
    lies on a face between the two kinds). The Delaunay tetrahedralisation of those points (one Qhull call, or
    chunked on ``workers`` when they are many: :func:`_fill_triangulation`) holds every missing tetrahedron
    (its circumsphere is empty of all points, so of these); of its tetrahedra, those with an empty
    circumsphere (KD-tree over all points) that were not kept already are added."""
    kept = np.concatenate([pc.tets for pc in pieces])
    used = np.zeros(p.shape[0], bool)
    used[kept.ravel()] = True
    s_mask = ~used
    s_mask[unmatched.ravel()] = True
    ids = np.flatnonzero(s_mask)
    if ids.size < 4:
        return None
    # unused points include the copies of duplicated points: map every point to its lowest-index copy in all
    # points (up to DUPLICATES_SEEN copies), so the new tetrahedra use the same vertex as the chunks did
    dist, nbr = tree.query(p[ids], k=min(DUPLICATES_SEEN, p.shape[0]), workers=workers)
    ids_canon = np.where(dist == 0.0, nbr, np.iinfo(np.int64).max).min(axis=1)
    local, nb, canon = _fill_triangulation(p[ids], workers, halo_fraction, processes)
    t = np.minimum(ids[canon], ids_canon)[local]
    vol6, flat, centre, radius = tet_geometry(t, p)
    keep = ~flat
    cand = np.flatnonzero(keep)
    dist, _ = tree.query(centre[cand], k=1, workers=workers)
    keep[cand[dist < radius[cand] * (1.0 - SPHERE_RTOL)]] = False
    near = kept[s_mask[kept].all(axis=1)]  # only these can equal a tetrahedron of the S-triangulation
    cand = np.flatnonzero(keep)
    keep[cand[_rows_in(np.sort(t[cand], axis=1), np.sort(near, axis=1))]] = False
    return _piece(t, nb, keep, vol6, flat, int(flat.size), int((~keep).sum()))


def _unmatched_faces(pieces: list[_Piece], p: np.ndarray, hull_vertices: np.ndarray) -> np.ndarray:
    """Border faces seen once that are not on the convex hull, ``[U, 3]``. Faces seen more than twice
    (overlapping pieces; should not happen) are counted in the log."""
    faces = np.concatenate([pc.faces for pc in pieces])
    on_hull = np.concatenate([pc.on_hull for pc in pieces])
    apex = np.concatenate([pc.apex for pc in pieces])
    if faces.shape[0] == 0:
        return faces
    order = np.lexsort(faces.T[::-1])
    f = faces[order]
    new = np.ones(f.shape[0], bool)
    new[1:] = np.any(f[1:] != f[:-1], axis=1)
    group = np.cumsum(new) - 1
    count = np.bincount(group)
    if np.any(count > 2):
        log.warning("delaunay: %d faces shared by more than two tetrahedra", int(np.sum(count > 2)))
    single = order[count[group] == 1]
    cand = single[on_hull[single]]
    if cand.size:  # a hull face has every point (all hull vertices) on its apex's side
        a, b, c = (p[faces[cand, i]] for i in range(3))
        n = np.cross(b - a, c - a)
        n *= np.sign(np.einsum("ij,ij->i", n, p[apex[cand]] - a))[:, None]
        scale = np.linalg.norm(n, axis=1) * np.max(np.ptp(p[hull_vertices], axis=0))
        beyond = (p[hull_vertices] @ n.T) - np.einsum("ij,ij->i", n, a)  # [H, C] (< 0: outside)
        is_hull = np.all(beyond >= -1e-9 * scale, axis=0)
        single = np.concatenate([single[~on_hull[single]], cand[~is_hull]])
    return faces[single]


def _chunk(p, lo, hi, halo_lo, halo_hi, tree, rho, cells: _CellIndex, c: int) -> _Piece:
    """Chunk ``c``: Qhull on the points of its halo box (ascending indices), the tetrahedra its core keeps."""
    near = cells.near(halo_lo[c], halo_hi[c])
    ids = near[_in_box(p[near], halo_lo[c], halo_hi[c], closed=True)]
    return _triangulate_piece(p, ids, lo[c], hi[c], halo_lo[c], halo_hi[c], tree, rho)


def delaunay_chunked(p: np.ndarray, chunks: int, workers: int, halo_fraction: float = HALO_FRACTION,
                     stats: dict | None = None, processes: bool = False) -> np.ndarray:
    """The exact global Delaunay tetrahedralisation of float64 ``p [P, 3]`` from ``chunks`` pieces on ``workers``
    threads, or forked processes with ``processes`` where the OS can fork (Linux; elsewhere threads: Qhull holds
    the GIL for part of its work, and the pieces' numpy post-processing too) — see the module docstring. Returns positively oriented non-flat
    ``tets [T, 4] int32``."""
    from scipy.spatial import ConvexHull, cKDTree

    stats = {} if stats is None else stats
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max(1, workers)) as pool:
        tree_job = pool.submit(cKDTree, p, balanced_tree=False, compact_nodes=False)
        lo, hi, members = _kd_cells(p, chunks)
        cells = _CellIndex(p, members)
        halo = np.array(list(pool.map(lambda c: _halo_width_near(cells, c, lo[c], hi[c], halo_fraction),
                                      range(lo.shape[0]))))
        rho = float(halo.min())  # tetrahedra with circumradius <= rho are owned by their circumcentre
        halo_lo, halo_hi = lo - halo[:, None], hi + halo[:, None]
        tree = tree_job.result()

        inputs = (p, lo, hi, halo_lo, halo_hi, tree, rho, cells)
        processes = processes and can_fork()
        if processes:
            from ..core.forked import map_forked

            pieces = map_forked(_chunk, inputs, lo.shape[0], workers)
        else:
            pieces = list(pool.map(lambda c: _chunk(*inputs, c), range(lo.shape[0])))
    t1 = time.perf_counter()
    hull = ConvexHull(p)
    unmatched = _unmatched_faces(pieces, p, hull.vertices)
    first_unmatched, fills, filled = int(unmatched.shape[0]), 0, 0
    while unmatched.shape[0] and fills < MAX_FILLS:
        fill = _fill_piece(p, pieces, unmatched, tree, workers, halo_fraction, processes)
        fills += 1
        if fill is None or fill.tets.shape[0] == 0:
            break
        pieces.append(fill)
        filled += int(fill.tets.shape[0])
        unmatched = _unmatched_faces(pieces, p, hull.vertices)
    tets = np.concatenate([pc.tets for pc in pieces])
    coverage = sum(pc.volume6 for pc in pieces) / 6.0 / hull.volume if hull.volume > 0 else 1.0
    stats.update(delaunay_chunks=int(lo.shape[0]), delaunay_workers=int(workers), delaunay_rho=rho,
                 delaunay_processes=bool(processes),
                 delaunay_checked=sum(pc.checked for pc in pieces[:lo.shape[0]]),
                 delaunay_rejected=sum(pc.rejected for pc in pieces[:lo.shape[0]]),
                 delaunay_chunk_unmatched_faces=first_unmatched, delaunay_fill_passes=fills,
                 delaunay_filled_tets=filled, delaunay_unmatched_faces=int(unmatched.shape[0]),
                 delaunay_volume_coverage=float(coverage), delaunay_chunks_s=round(t1 - t0, 3),
                 delaunay_stitch_s=round(time.perf_counter() - t1, 3))
    if unmatched.shape[0] or abs(coverage - 1.0) > 1e-6:
        log.info("delaunay: %d faces between chunks unmatched (holes); tetrahedra cover %.6f of the hull",
                 unmatched.shape[0], coverage)
    return tets


# ---------------------------------------------------------------------------------------------- public
def delaunay(points, backend: str = "scipy", *, workers: int | None = 1, chunks: int | None = None,
             halo_fraction: float = HALO_FRACTION, stats: dict | None = None, processes: bool = False) -> np.ndarray:
    """Delaunay tetrahedralisation of ``points [P, 3]`` → ``tets [T, 4] int32``, positively oriented,
    zero-volume tetrahedra dropped.

    ``backend``: ``"scipy"`` (Qhull, BSD, default), ``"cgal"`` (optional extra ``gof_warp[cgal]``, GPLv3;
    one call: its Python bindings export cells through a text file) or ``"auto"`` (CGAL if importable, else
    scipy). ``workers``: threads (``None``: every CPU this process may use); with scipy, more than one worker
    and ``P >= PARALLEL_MIN_POINTS`` the points are triangulated in chunks on the threads and merged exactly
    (module docstring: the same tetrahedra as one call on the perturbed points); ``chunks`` sets their number
    (default ~``CHUNK_POINTS`` per chunk, at least two per worker; 1: one call); ``processes``: the chunks run
    in forked worker processes instead of threads (Linux).
    Duplicate points are merged onto their lowest index. ``stats``: the parallel path's counters are written
    into it. Raises ``GofError`` for fewer than 4 points or points that span no volume (coplanar, collinear).
    """
    if backend not in BACKENDS:
        raise GofError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if workers is not None and workers < 1 or chunks is not None and chunks < 1:
        raise GofError(f"workers and chunks must be >= 1, got {workers} and {chunks}")
    if not 0.0 < halo_fraction:
        raise GofError(f"halo_fraction must be > 0, got {halo_fraction}")
    p = check_points(points)
    if backend == "auto":
        try:
            import CGAL.CGAL_Triangulation_3  # noqa: F401

            backend = "cgal"
        except ImportError:
            backend = "scipy"
    if backend != "cgal":  # CGAL perturbs symbolically itself; Qhull needs points in general position
        _check_spans_volume(p)  # before the perturbation, which would lift coplanar points into slivers
        p = jittered(p)
    workers = default_workers() if workers is None else workers
    if chunks is None:  # one call unless there are threads to share the work and enough points to split
        parallel = workers > 1 and p.shape[0] >= PARALLEL_MIN_POINTS
        chunks = max(2 * workers, round(p.shape[0] / CHUNK_POINTS)) if parallel else 1
    if backend == "cgal":
        tets = orient_and_drop_degenerate(_delaunay_cgal(p), p)
    elif chunks > 1:
        tets = delaunay_chunked(p, chunks, workers, halo_fraction, stats, processes=processes)
    else:
        tri = _qhull(p)
        tets = orient_and_drop_degenerate(_canonical_vertices(tri, p, np.arange(p.shape[0]))[tri.simplices], p)
    if tets.shape[0] == 0:
        raise GofError(f"Delaunay of {p.shape[0]} points gave no tetrahedron with volume (degenerate points)")
    log.info("delaunay (%s, %d chunk(s)): %d points → %d tetrahedra", backend, chunks, p.shape[0], tets.shape[0])
    return tets
