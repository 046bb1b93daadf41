"""Quadric decimation of triangle meshes: fewer faces where the surface is simple.

Tetrahedral GOF meshes spend their faces evenly (one vertex per crossing Delaunay edge), about 3x the
faces marching cubes needs for the same accuracy. :func:`decimate` collapses edges in order of their
quadric error (Garland-Heckbert) with the ``fast-simplification`` package (pyvista's wrapper of
Sp4cerat's Fast-Quadric-Mesh-Simplification, C++), then repairs what the collapses can break and
measures how far the result moved from the input.

What the library does and does not do (read from its source, ``Simplify.h``, version 0.2.0):

* It stops at ``target_count`` faces or earlier. It has no error bound of its own: each pass collapses
  every edge whose quadric error is below a threshold ``1e-9 * (pass + 3) ** agg`` until the face count is
  reached (at most 100 passes), so ``max_error`` here is implemented outside it (see below).
* It checks collapses only for flipped or needle triangles, not for the link condition. On a closed
  mesh a collapse can pinch a thin part into two coincident triangles of opposite orientation, or make
  two parts of the surface touch along an edge (edges then shared by 4 faces: about one edge per 4,000
  faces at 10% of a GOF mesh). :func:`decimate` removes coincident pairs (and faces with a repeated
  vertex), and splits each vertex of an edge used by more than two faces into one copy per fan of faces
  (fans joined through two-face edges, and across the bad edge in one of two rotational senses: the
  clean-up tries none / both and keeps the result with fewest non-two-face edges, one choice for all
  pinches). On the default scene's mesh at 50% to 2% of its faces that leaves every edge of a closed input shared by
  exactly two faces again; where the surface touches itself it now has coincident vertices
  (``info["pinch_vertices_split"]``), and a part pinched to a coincident pair disappears.
* Border vertices (on an edge used by one face) never merge with inner ones. With ``keep_border=True``
  (the default) they are not moved at all, so an open mesh keeps its outline exactly; when that alone
  stops the face budget being met, it is run again letting border edges collapse (the outline then moves
  by about one edge length: border edges collapse to an end point or their midpoint), and
  ``info["border_kept"]`` says so. Non-manifold input edges are not treated as borders.
* It keeps its mesh in module-level C++ state, so calls are serialised by a lock here.

Error means the one-sided distance from the input's vertices to the decimated surface (exact point-to-
triangle distance, :func:`gof_warp.eval.geometry_metrics.point_mesh_distance`), in world units: max and 95th
percentile. Above ``error_samples`` vertices it is measured on a seeded random subset of that size, so
the max is the sample's max. It does not see the other direction (the decimated surface bulging away
from a region with no input vertex), which quadric collapses keep small on smooth parts.

``max_error``: the fewest faces (down to ``max_faces`` or the input's count) whose measured error is at
most ``max_error``, found by bisection on the face count in log space (about 8 decimations and
measurements; it stops when the bracket is within 5%). Error is not strictly monotone in the face
count, so this is the smallest count found, not the global one; the result returned was always
measured to meet the bound (on the sample), or, when even the face budget cannot, is the budget's mesh
with ``info["error_bound_met"] = False``.

Cost, measured on the 2-core CPU dev box (the 166k-face mesh of the default scene): the decimation
itself about 1.2 s per million input faces; measuring the error on 50,000 vertices about 1-2 s more; a
``max_error`` search about 8 times (decimation + measurement).
"""

from __future__ import annotations

import logging
import math
import threading
import time

import numpy as np

from ..core.arrays import check_triangles
from ..core.errors import GofError

log = logging.getLogger(__name__)

_LOCK = threading.Lock()  # fast_simplification keeps one mesh in global C++ state


def _library():
    try:
        import fast_simplification
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise GofError("mesh decimation needs the 'fast-simplification' package: pip install fast-simplification") from exc
    return fast_simplification


def _check(verts, faces, max_faces, max_error, error_samples) -> tuple[np.ndarray, np.ndarray]:
    v, f = check_triangles(verts, faces, "decimate", GofError)
    if not np.issubdtype(v.dtype, np.number) or np.issubdtype(v.dtype, np.complexfloating):
        raise GofError(f"decimate: verts must be real numbers, got dtype {v.dtype}")
    if f.size and not np.issubdtype(f.dtype, np.integer):
        raise GofError(f"decimate: faces must be integer indices, got dtype {f.dtype}")
    v = v.astype(np.float64)
    if not np.isfinite(v).all():
        raise GofError(f"decimate: verts hold {int((~np.isfinite(v)).any(axis=1).sum())} vertices with NaN or inf")
    f = f.astype(np.int64)
    if max_faces is not None:
        if isinstance(max_faces, bool) or not isinstance(max_faces, (int, np.integer)) or max_faces < 1:
            raise GofError(f"decimate: max_faces must be a positive integer, got {max_faces!r}")
    if max_error is not None:
        if isinstance(max_error, bool) or not isinstance(max_error, (int, float, np.floating, np.integer)) \
                or not math.isfinite(max_error) or max_error <= 0:
            raise GofError(f"decimate: max_error must be a positive finite distance, got {max_error!r}")
    if isinstance(error_samples, bool) or not isinstance(error_samples, (int, np.integer)) or error_samples < 1:
        raise GofError(f"decimate: error_samples must be a positive integer, got {error_samples!r}")
    return v, f


def _row_keys(rows: np.ndarray) -> np.ndarray | None:
    """One int64 per row of a non-negative integer array ``[R, C]`` whose order is the rows' lexicographic
    order (mixed radix ``max + 1``), or None when the radix does not fit 63 bits."""
    base = int(rows.max()) + 1
    if base ** rows.shape[1] > np.iinfo(np.int64).max:
        return None
    key = rows[:, 0].astype(np.int64)
    for c in range(1, rows.shape[1]):
        key = key * base + rows[:, c]
    return key


def _row_groups(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(inverse [R], counts [G])`` of the distinct rows of a non-negative integer array ``[R, C]``, groups in
    lexicographic row order: what ``np.unique(rows, axis=0, return_inverse=True, return_counts=True)`` gives,
    through one int64 key per row (``np.unique`` on whole rows sorts a byte view: ~5x slower here)."""
    rows = np.asarray(rows, np.int64)
    if rows.shape[0] == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    key = _row_keys(rows)
    if key is not None:
        _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
        return inverse.reshape(-1), counts
    order = np.lexsort(rows.T[::-1])  # too many distinct values to pack: sort by the columns, first major
    ordered = rows[order]
    new = np.ones(len(rows), bool)
    new[1:] = (ordered[1:] != ordered[:-1]).any(axis=1)
    group = np.cumsum(new) - 1
    inverse = np.empty(len(rows), np.int64)
    inverse[order] = group
    return inverse, np.bincount(group)


def _edge_counts(faces: np.ndarray) -> np.ndarray:
    """How many faces use each distinct undirected edge."""
    if len(faces) == 0:
        return np.zeros(0, np.int64)
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1).astype(np.int64)
    key = _row_keys(e)
    return _row_groups(e)[1] if key is None else np.unique(key, return_counts=True)[1]  # counts only: no argsort


def is_closed(faces) -> bool:
    """Every edge shared by exactly two faces (closed and edge-manifold; orientation not checked)."""
    counts = _edge_counts(np.asarray(faces, np.int64).reshape(-1, 3))
    return bool(len(counts)) and bool((counts == 2).all())


def _clean(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    """Drop faces with a repeated vertex and coincident face pairs (same three vertices: both faces of
    each pair, one of an odd leftover), then the vertices no face uses."""
    f = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    degenerate = len(faces) - len(f)
    key = np.sort(f, axis=1)
    inverse, counts = _row_groups(key)
    keep = counts[inverse] == 1
    # a triple that occurs an odd number of times (>1) keeps one face
    odd = np.where((counts > 1) & (counts % 2 == 1))[0]
    if len(odd):
        first = np.full(len(counts), -1, np.int64)
        order = np.arange(len(f))[::-1]
        first[inverse[order]] = order
        keep[first[odd]] = True
    f = f[keep]
    used = np.zeros(len(verts), bool)
    used[f.reshape(-1)] = True
    remap = np.cumsum(used) - 1
    verts, f = verts[used], remap[f]
    # the fans of a pinch can be chosen three ways (see _split_pinches); keep the first that closes it
    # (in order; the first with the fewest edges not shared by two faces wins, so one that leaves none ends the search)
    best, best_bad = None, None
    for turn in (0, 1, -1):
        tried = _split_pinches(verts, f, turn)
        bad = int((_edge_counts(tried[1]) != 2).sum())
        if best is None or bad < best_bad:
            best, best_bad = tried, bad
        if bad == 0:
            break
    verts, f, split = best
    return verts, f, {"degenerate_removed": int(degenerate), "coincident_removed": int((~keep).sum()),
                      "pinch_vertices_split": split}


def _split_pinches(verts: np.ndarray, faces: np.ndarray, turn: int = 0) -> tuple[np.ndarray, np.ndarray, int]:
    """Give each fan of faces around a vertex of a non-manifold edge (used by more than two faces) its
    own copy of the vertex, the fans being the faces connected through edges used by exactly two faces
    and, across a non-manifold edge, each face running a -> b with the next face around the edge in the
    sense ``turn`` (+1 / -1; 0: faces are not joined across such edges).

    Where a collapse pinched two parts of a closed surface together along an edge, the edge's faces
    belong to two fans at its end points, so each end point splits and the edge becomes two edges of two
    faces each: the surface is closed again, with coincident vertices where it touches itself."""
    if len(faces) == 0:
        return verts, faces, 0
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    nf = len(faces)
    ends = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)  # edge k of face f: f[k] -> f[k+1]
    key = np.sort(ends, axis=1)
    edge_id, counts = _row_groups(key)
    bad = counts > 2
    if not bad.any():
        return verts, faces, 0
    on_bad = np.zeros(len(verts), bool)
    on_bad[key[bad[edge_id]].reshape(-1)] = True
    # corners (3 f + k) of the same vertex, joined across every edge used by exactly two faces
    occ = np.where(counts[edge_id] == 2)[0]
    order = occ[np.argsort(edge_id[occ], kind="stable")]
    first, second = order[0::2], order[1::2]  # the two occurrences of each such edge
    f1, k1 = first // 3, first % 3
    f2, k2 = second // 3, second % 3

    def corner_of(fi, vert):
        return 3 * fi + np.argmax(faces[fi] == vert[:, None], axis=1)

    a, b = ends[first, 0], ends[first, 1]
    rows = [3 * f1 + k1, 3 * f1 + (k1 + 1) % 3]
    cols = [corner_of(f2, a), corner_of(f2, b)]
    # across an edge of more faces: pair each face running a -> b with the next face around the edge
    # (by the angle of its third vertex), which runs b -> a where the surface is consistently oriented
    occ_bad = np.where(bad[edge_id])[0]
    occ_bad = occ_bad[np.argsort(edge_id[occ_bad], kind="stable")]
    for group in (np.split(occ_bad, np.flatnonzero(np.diff(edge_id[occ_bad])) + 1) if turn else []):
        fi, ki = group // 3, group % 3
        ea, eb = key[group[0]]
        forward = ends[group, 0] == ea
        third = faces[fi, (ki + 2) % 3]
        axis = verts[eb] - verts[ea]
        w = verts[third] - verts[ea]
        w = w - np.outer(w @ axis / max(axis @ axis, 1e-300), axis)
        e1 = w[0] / max(np.linalg.norm(w[0]), 1e-300)
        e2 = np.cross(axis, e1)
        order = np.argsort(np.arctan2(turn * (w @ e2), w @ e1))
        fwd = forward[order]
        if len(group) % 2 or fwd.sum() * 2 != len(group):
            continue  # not a consistently oriented touch: leave this edge as it is
        start = int(np.argmax(fwd))
        rolled = np.roll(order, -start)
        if not (forward[rolled[0::2]].all() and not forward[rolled[1::2]].any()):
            continue
        for end in (ea, eb):
            rows.append(corner_of(fi[rolled[0::2]], np.full(len(group) // 2, end)))
            cols.append(corner_of(fi[rolled[1::2]], np.full(len(group) // 2, end)))
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    # corners of vertices off the bad edges are joined to their vertex's first corner: they stay one vertex
    corner_vert = faces.reshape(-1)
    off = np.where(~on_bad[corner_vert])[0]
    first_corner = np.full(len(verts), -1, np.int64)
    first_corner[corner_vert[::-1]] = np.arange(3 * nf)[::-1]
    rows = np.concatenate([rows, off])
    cols = np.concatenate([cols, first_corner[corner_vert[off]]])
    graph = coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(3 * nf, 3 * nf))
    _, comp = connected_components(graph, directed=False)
    # one output vertex per component (its corners all hold the same input vertex)
    uniq, new_index = np.unique(comp, return_inverse=True)
    src = np.zeros(len(uniq), np.int64)
    src[new_index] = corner_vert
    return verts[src], new_index.reshape(-1, 3), int(len(uniq) - len(np.unique(corner_vert)))


def _measure(orig: np.ndarray, verts: np.ndarray, faces: np.ndarray) -> tuple[float, float]:
    from ..eval.geometry_metrics import point_mesh_distance

    if len(orig) == 0:
        return 0.0, 0.0
    d = point_mesh_distance(orig, verts, faces)
    return float(d.max()), float(np.percentile(d, 95))


def _simplify(v: np.ndarray, f: np.ndarray, target: int, agg: float, keep_border: bool):
    fs = _library()
    with _LOCK:
        out_v, out_f = fs.simplify(v, f.astype(np.int32), target_count=int(target), agg=float(agg),
                                   preserve_border=bool(keep_border))
    return np.asarray(out_v, np.float64), np.asarray(out_f, np.int64).reshape(-1, 3)


def _decimate_to(v, f, target, agg, keep_border):
    """One decimation to at most ``target`` faces (when reachable) and the clean-up."""
    border_kept = keep_border
    out_v, out_f = _simplify(v, f, target, agg, keep_border)
    if keep_border and len(out_f) > target:
        counts = _edge_counts(f)
        if (counts == 1).any():  # the outline held it back: let border edges collapse
            log.warning("decimate: keeping the open border exactly leaves %d faces > %d; "
                        "letting border edges collapse", len(out_f), target)
            out_v, out_f = _simplify(v, f, target, agg, False)
            border_kept = False
    out_v, out_f, repairs = _clean(out_v, out_f)
    return out_v, out_f, repairs, border_kept


def decimate(verts, faces, *, max_faces: int | None = None, max_error: float | None = None,
             keep_border: bool = True, agg: float = 7.0, error_samples: int = 50_000,
             seed: int = 0, measure: bool = True) -> tuple[np.ndarray, np.ndarray, dict]:
    """Quadric-decimate a triangle mesh to a face budget and/or an error bound.

    Args:
        verts: ``[V, 3]`` float vertex positions (world units).
        faces: ``[F, 3]`` integer vertex indices.
        max_faces: at most this many faces in the result (the library stops at or just under it; the
            clean-up of pinched parts may remove a few more). No-op when the mesh already has
            ``<= max_faces`` faces and ``max_error`` is not given.
        max_error: the largest allowed distance (world units) from an input vertex to the result, as
            measured (see the module note): the result is the fewest faces found that meet it.
        keep_border: keep open-border vertices in place (see the module note).
        agg: the library's aggressiveness (its default 7; lower is slower and more careful).
        error_samples: measure the error on at most this many input vertices (seeded subset).
        seed: seed of that subset.
        measure: with ``max_faces`` alone, measure the error of the result (``False``: ``error_max`` and
            ``error_p95`` are None). The measurement prunes triangles by the largest one's size, so on meshes
            with a few huge triangles (a GOF mesh's far background) its memory grows with the whole mesh per
            sample: the extraction's ``--max-faces`` skips it.

    Returns:
        ``(verts [V', 3] float32, faces [F', 3] int32, info)`` with ``info``: ``faces_before``,
        ``faces_after``, ``vertices_before``, ``vertices_after``, ``time_s``, ``error_max``,
        ``error_p95`` (world units), ``error_samples`` (vertices measured), ``closed_before`` /
        ``closed_after`` (every edge shared by two faces), ``border_kept``, ``degenerate_removed`` /
        ``coincident_removed`` / ``pinch_vertices_split`` (the clean-up), ``decimations`` (how many runs), and with ``max_error``
        ``max_error`` and ``error_bound_met``.

    Raises:
        GofError: bad shapes, NaN/inf vertices, indices out of range, non-positive targets, or the
            ``fast-simplification`` package missing.
    """
    v, f = _check(verts, faces, max_faces, max_error, error_samples)
    t0 = time.perf_counter()
    n_faces = len(f)
    info: dict = {"faces_before": n_faces, "vertices_before": len(v), "closed_before": is_closed(f)}
    rng = np.random.default_rng(seed)
    sample = v if len(v) <= error_samples else v[rng.choice(len(v), error_samples, replace=False)]
    info["error_samples"] = len(sample)

    budget = n_faces if max_faces is None else min(int(max_faces), n_faces)
    repairs = {"degenerate_removed": 0, "coincident_removed": 0, "pinch_vertices_split": 0}
    border_kept = keep_border
    decimations = 0

    def finish(out_v, out_f, err, extra):
        info.update(extra)
        info.update(faces_after=len(out_f), vertices_after=len(out_v), closed_after=is_closed(out_f),
                    border_kept=border_kept, decimations=decimations, time_s=round(time.perf_counter() - t0, 4),
                    error_max=err[0], error_p95=err[1], **repairs)
        if info["closed_before"] and not info["closed_after"]:
            log.warning("decimate: the closed input is no longer closed after decimation")
        return out_v.astype(np.float32), out_f.astype(np.int32), info

    if n_faces == 0 or (budget >= n_faces and max_error is None):
        return finish(v, f, (0.0, 0.0), {})

    if max_error is None:
        out_v, out_f, repairs, border_kept = _decimate_to(v, f, budget, agg, keep_border)
        decimations = 1
        return finish(out_v, out_f, _measure(sample, out_v, out_f) if measure else (None, None), {})

    # max_error: bisection on the face count in log space; `best` is the fewest faces measured to meet it.
    best = None
    if budget >= n_faces:
        best = (v, f, dict(repairs), keep_border, (0.0, 0.0))
        hi = n_faces
    else:
        out = _decimate_to(v, f, budget, agg, keep_border)
        decimations += 1
        err = _measure(sample, out[0], out[1])
        if err[0] > max_error:  # even the budget's mesh misses the bound: return it, saying so
            _, _, repairs, border_kept = out
            log.warning("decimate: %d faces give error %.4g > max_error %.4g", len(out[1]), err[0], max_error)
            return finish(out[0], out[1], err, {"max_error": float(max_error), "error_bound_met": False})
        best = (*out, err)
        hi = budget
    lo = min(4, hi)
    while hi > lo * 1.05 and hi - lo > 1 and decimations < 16:
        mid = int(round(math.sqrt(lo * hi)))
        mid = min(max(mid, lo + 1), hi - 1)
        out = _decimate_to(v, f, mid, agg, keep_border)
        decimations += 1
        err = _measure(sample, out[0], out[1])
        if err[0] <= max_error:
            best, hi = (*out, err), mid
        else:
            lo = mid
    out_v, out_f, repairs, border_kept, err = best
    return finish(out_v, out_f, err, {"max_error": float(max_error), "error_bound_met": True})
