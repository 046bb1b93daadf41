"""Level-set meshes of a scalar field: marching tetrahedra and marching cubes, each refined by a binary
search along the crossing edges (GOF Sec. 5, "binary search of the level set").

The field is either

* host code: any callable ``field(x) -> values``: ``x`` is ``[M, 3]`` float32 (a numpy array, a torch
  tensor on the working device, or a ``wp.array`` of ``vec3``; see ``field_input``), the result has ``M``
  values (numpy, torch or Warp). It is called once per search step with the midpoints of **all** crossing
  edges (all level sets at once), so an expensive field (GOF's opacity field) is evaluated in large batches;
* or a Warp field function: a ``@wp.func`` ``field(x: wp.vec3[, params: P]) -> float`` (``params`` given as
  ``field_params``), evaluated by a kernel made once per call with
  :func:`gof_warp.kernels.marching_tets.make_field_kernel`; each search step is then three launches on the
  device, with no host round-trip.

Both go through the same marching (count → scan → write → deduplicate) and the same bisection
(:func:`_refine`); only the batch evaluation differs (``FieldCaller`` or ``WarpField``).

Torch is optional: this module imports it only when the caller's data is torch (a tensor, or
``field_input="torch"``), so a pure Warp program can use it. Without torch loaded, ``device=None``
means Warp's current device (``wp.ScopedDevice`` is respected) and launches go to Warp's current stream.

Conventions: *inside* means ``value >= level`` (high opacity); triangles are wound so their normals
point from inside to outside (from high to low values: outwards for an opacity field). Outputs are
numpy: ``vertices [V, 3] float32``, ``faces [F, 3] int32``.

Search: each crossing edge starts as the bracket ``[x_in, x_out]`` of its endpoints
(``f(x_in) >= level > f(x_out)``); each step evaluates the midpoint and replaces the end on the same side;
the vertex is finally put at the linear zero inside the last bracket. ``binary_steps=0`` (or no field) is
plain linear interpolation. (The official code returns the last midpoint instead; the paper interpolates.)

Memory (device), marching tetrahedra, with ``T`` tetrahedra, ``F`` faces, ``V`` vertices, ``P`` points:

* resident: points + values 16 B/point; with host (numpy) tetrahedra only one chunk is on the device;
* per tetrahedron of a chunk: 24 B (16 B indices + 4 B count + 4 B scan), so ``chunk_size`` bounds it;
* per face while deduplicating: 108 B (corner keys 2×24 B for the radix sort, slots 2×12 B, run marks,
  scan and corner→vertex 3×12 B); output 12 B/face;
* per vertex: 72 B (edge key 8, bracket 36, midpoint + value 16, output 12).

Marching cubes on ``N`` grid nodes: 4 B/node for the values on the device plus Warp's own extraction
(about 44 B/node: counts, scans and edge→vertex ids) and, on the host, 4 B/node values + 4 B/node
masks.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import warp as wp
import warp.geometry

from ..core.arrays import used_vertices
from ..core.errors import GofError
from ..kernels import marching_tets as mt
from .marching_inputs import (FIELD_KINDS, Field, FieldCaller, StepsPerCall, TetSource, WarpField,  # noqa: F401
                              as_float_array, as_vec3_array, check_finite, check_levels, check_steps,
                              check_steps_per_call, field_kind, make_field, resolve_device, torch_stream)

log = logging.getLogger(__name__)

DEFAULT_CHUNK_TETS = 1 << 23  # 8.4M tetrahedra × 24 B ≈ 200 MB of working memory per chunk
DEFAULT_CHUNK_NODES = 1 << 22  # grid nodes evaluated per field call in marching cubes
# Warp's marching-cubes vertices must lie on the grid edges we attribute them to (float32 rounding only).
MC_EDGE_MATCH_TOL = 1e-3  # in cell sizes


def compact_mesh(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keep only the vertices some face uses. Returns ``(verts [V', 3], faces [F, 3] int32, kept [V'] indices)``."""
    used, faces = used_vertices(faces, len(verts))
    return verts[used], faces.astype(np.int32), used


def _empty_mesh() -> tuple[np.ndarray, np.ndarray]:
    return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)



# ---------------------------------------------------------------------------------------------- search
@dataclass
class _Brackets:
    """Per crossing edge: ``x_in, x_out [V] vec3``, ``f_in, f_out, level [V] float32``."""

    x_in: wp.array
    x_out: wp.array
    f_in: wp.array
    f_out: wp.array
    level: wp.array

    @classmethod
    def empty(cls, n: int, device: str) -> "_Brackets":
        v3 = [wp.empty(n, dtype=wp.vec3, device=device) for _ in range(2)]
        f = [wp.empty(n, dtype=wp.float32, device=device) for _ in range(3)]
        return cls(*v3, *f)

    def outputs(self, a: int, b: int) -> list:
        return [self.x_in[a:b], self.x_out[a:b], self.f_in[a:b], self.f_out[a:b]]


def _refine(br: _Brackets, call_field: FieldCaller | WarpField | None, steps: int, always_call: bool = False,
            steps_per_call: StepsPerCall = 1) -> np.ndarray:
    """Bisect every bracket ``steps`` times, then interpolate: ``[V, 3]`` numpy. Each field call serves ``d`` steps
    (``steps_per_call``: an int, or a function of the number of brackets and the steps done, asked before each
    call): the ``2^d − 1`` midpoints those steps can visit per bracket (``d = 1``: the midpoint), then the descent
    through them; the vertices are the same for any ``d``. With no brackets no call is made, unless
    ``always_call``: then the same calls, empty."""
    n = br.x_in.shape[0]
    device = br.x_in.device
    if call_field is not None and (n or always_call):
        done = 0
        while done < steps:
            d = min(check_steps_per_call(steps_per_call(n, done) if callable(steps_per_call) else steps_per_call),
                    steps - done)
            m = (1 << d) - 1
            nodes = wp.empty((n, m), dtype=wp.vec3, device=device)
            if n:
                wp.launch(mt.bracket_tree_midpoints, dim=n, inputs=[br.x_in, br.x_out, d], outputs=[nodes],
                          device=device)
            what = f"binary search step {done}" if d == 1 else f"binary search steps {done}-{done + d - 1}"
            f_nodes = call_field(nodes.flatten(), what)
            if n:
                wp.launch(mt.descend_bracket_tree, dim=n, inputs=[nodes, f_nodes.reshape((n, m)), d, br.level],
                          outputs=[br.x_in, br.x_out, br.f_in, br.f_out], device=device)
            done += d
    vertices = wp.empty(n, dtype=wp.vec3, device=device)
    wp.launch(mt.interpolate_in_brackets, dim=n, inputs=[br.x_in, br.x_out, br.f_in, br.f_out, br.level],
              outputs=[vertices], device=device)
    return vertices.numpy().reshape(n, 3).astype(np.float32, copy=False)


# ---------------------------------------------------------------------------------------------- tetrahedra
def _count_and_scan(tets: wp.array, values: wp.array, level: float) -> tuple[wp.array, int]:
    n = tets.shape[0]
    count = wp.empty(n, dtype=wp.int32, device=tets.device)
    wp.launch(mt.count_triangles, dim=n, inputs=[tets, values, level], outputs=[count], device=tets.device)
    tri_end = wp.empty(n, dtype=wp.int32, device=tets.device)
    wp.utils.array_scan(count, tri_end, inclusive=True)
    return tri_end, int(tri_end[n - 1 : n].numpy()[0])


def _deduplicate_corners(keys: wp.array, n: int, n_points: int) -> tuple[wp.array, wp.array]:
    """Sort the ``n`` corner edge keys (``keys`` has room for 2n) → (corner→vertex ``[n]``, vertex keys)."""
    device = keys.device
    slots = wp.empty(2 * n, dtype=wp.int32, device=device)
    wp.launch(mt.write_slot_ids, dim=n, inputs=[], outputs=[slots], device=device)
    end_bit = max(1, (n_points * n_points - 1).bit_length())  # keys < P², skip the zero high bits
    wp.utils.radix_sort_pairs(keys, slots, n, end_bit=end_bit)
    run_start = wp.empty(n, dtype=wp.int32, device=device)
    wp.launch(mt.mark_run_starts, dim=n, inputs=[keys], outputs=[run_start], device=device)
    run_end = wp.empty(n, dtype=wp.int32, device=device)
    wp.utils.array_scan(run_start, run_end, inclusive=True)
    n_vertices = int(run_end[n - 1 : n].numpy()[0])
    corner_vertex = wp.empty(n, dtype=wp.int32, device=device)
    vertex_keys = wp.empty(n_vertices, dtype=wp.int64, device=device)
    wp.launch(mt.scatter_vertex_ids, dim=n, inputs=[keys, slots, run_end], outputs=[corner_vertex, vertex_keys],
              device=device)
    return corner_vertex, vertex_keys


def _level_topology(points: wp.array, tets: TetSource, values: wp.array, level: float, chunk_size: int,
                    oriented: bool = False):
    """Faces (as corner→vertex ids) and the edge key of each vertex for one level, tetrahedra in chunks."""
    device, n_points = points.device, points.shape[0]
    ranges = [(s, min(s + chunk_size, tets.count)) for s in range(0, tets.count, chunk_size)]
    counts, cached = [], None
    for s, e in ranges:  # pass 1: faces per chunk (kept on the device only when there is one chunk)
        chunk = tets.chunk(s, e)
        tri_end, n_faces = _count_and_scan(chunk, values, level)
        counts.append(n_faces)
        if len(ranges) == 1:
            cached = (chunk, tri_end)
    n_corners = 3 * sum(counts)
    if n_corners >= 2**31:  # face corners are indexed with int32 (scan, slots)
        raise GofError(f"level {level}: {n_corners // 3} faces exceed the int32 limit of the face arrays")
    if n_corners == 0:
        return wp.empty(0, dtype=wp.int32, device=device), wp.empty(0, dtype=wp.int64, device=device)
    keys = wp.empty(2 * n_corners, dtype=wp.int64, device=device)
    base = 0
    for (s, e), n_faces in zip(ranges, counts):  # pass 2: write corner edge keys at the chunk's offset
        if n_faces:
            if cached is None:
                chunk = tets.chunk(s, e)
                tri_end = _count_and_scan(chunk, values, level)[0]
            else:
                chunk, tri_end = cached
            wp.launch(mt.write_triangle_edges, dim=e - s,
                      inputs=[points, chunk, values, level, tri_end, base, wp.int64(n_points), wp.int32(oriented)],
                      outputs=[keys],
                      device=device)
        base += n_faces
    return _deduplicate_corners(keys, n_corners, n_points)


def marching_tetrahedra(points, tets, values=None, field: Field | None = None, *, levels: Sequence[float] = (0.5,),
                        binary_steps: int = 8, chunk_size: int = DEFAULT_CHUNK_TETS, field_input: str | None = None,
                        device=None, oriented: bool = False, field_params=None,
                        return_keys: bool = False, steps_per_call: StepsPerCall = 1) -> list[tuple[np.ndarray, ...]]:
    """Marching tetrahedra on a tetrahedral grid, with binary search on the crossing edges.

    Args:
        points: ``[P, 3]`` grid points (numpy, torch or ``wp.array``).
        tets: ``[T, 4]`` integer point indices, any orientation (numpy, torch or ``wp.array``; numpy
            tetrahedra stay on the host and go to the device ``chunk_size`` at a time).
        values: ``[P]`` field values at ``points`` (precomputed); ``None`` only with a Warp field
            function, which then evaluates them on the device.
        field: the field, for the search (see the module docstring): a callable evaluating it at
            ``[M, 3]`` points, or a ``@wp.func`` ``(x: wp.vec3[, params]) -> float``; ``None`` → linear
            interpolation only.
        levels: level sets to extract (default GOF's 0.5); one mesh per level.
        binary_steps: bisection steps per crossing edge (official: 8; 0 = linear interpolation).
        chunk_size: tetrahedra per device chunk (24 B each, see the module docstring).
        field_input: kind of array passed to ``field`` (``"numpy"``, ``"torch"``, ``"warp"``); default the
            kind of ``points``.
        device: Warp device; default CUDA when available, else CPU.
        oriented: the tetrahedra are positively oriented (as :func:`gof_warp.mesh.delaunay.delaunay` returns them):
            faces are wound by their vertex order, not by their volume in ``points`` (which is zero or
            negative for the slivers a perturbed Delaunay leaves on cospherical points).
        field_params: the ``params`` argument of a Warp field function that takes one (a ``wp.struct``
            instance, a volume id, ...); ``None`` otherwise.
        return_keys: also return each vertex's edge key ``i·P + j`` (``int64 [V]``, ascending: the vertices'
            order), ``i < j`` the edge's point indices in ``points``: the pieces marched from parts of one grid's
            tetrahedra then join into the whole grid's mesh (:func:`merge_keyed_pieces`).
        steps_per_call: search steps served by one field call (an int ≥ 1, or a function
            ``(crossing edges, steps done) -> int`` asked before each call; the last call takes what is left): ``d > 1`` evaluates every midpoint the next ``d`` steps can visit (``2^d − 1`` per
            edge) in one call and descends through them, for a field whose cost per call outweighs its cost per
            point (GOF's opacity field on many Gaussians and few edges). The vertices are the same bit for bit.

    Returns:
        one ``(vertices [V, 3] float32, faces [F, 3] int32)`` per level (``(vertices, faces, keys)`` with
        ``return_keys``). Vertices are shared between faces on the same tetrahedron edge; normals point from high
        to low values. Closed level sets inside the grid give watertight meshes.
    """
    if field_input == "torch":
        import torch  # noqa: F401  (before the device rule: torch and Warp must agree)
    device = resolve_device(device)
    levels = check_levels(levels)
    steps = check_steps(binary_steps)
    if int(chunk_size) < 1:
        raise GofError(f"chunk_size must be >= 1, got {chunk_size!r}")
    kind = field_input or field_kind(points)
    evaluator = make_field(field, field_params, kind, device) if field is not None else None
    call_field = evaluator if steps > 0 else None
    pts = as_vec3_array(points, "points", device)
    n_points = pts.shape[0]
    if values is None:
        if not isinstance(evaluator, WarpField):
            raise GofError("values may be None only with a Warp field function (@wp.func) as field")
        vals = check_finite(evaluator(pts, "points"), "field values at points")
    else:
        vals = as_float_array(values, n_points, "values", device)
    tet_src = TetSource(tets, n_points, device)
    if n_points == 0 or tet_src.count == 0:
        log.warning("marching_tetrahedra: %d points, %d tetrahedra: returning empty meshes", n_points, tet_src.count)
        return [(*_empty_mesh(), np.zeros(0, np.int64)) if return_keys else _empty_mesh() for _ in levels]

    with torch_stream(device):
        return _marching_tetrahedra(pts, tet_src, vals, levels, call_field, steps, int(chunk_size), oriented,
                                    return_keys, steps_per_call)


def merge_keyed_pieces(pieces: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """One mesh from pieces that :func:`marching_tetrahedra` (``return_keys=True``) marched from consecutive parts of
    one grid's tetrahedra: ``(vertices [V, 3] float32, faces [F, 3] int32)``.

    A vertex on an edge that tetrahedra of several pieces share comes once (the same key); its position is taken
    from the first piece that has it (the pieces computed it from the same bracket and field: the same value). The
    vertices come in ascending key order and the faces piece after piece, so the parts ``tets[0:a], tets[a:b], …``
    give exactly the mesh of ``tets`` marched at once."""
    pieces = [p for p in pieces if len(p[2])]
    if not pieces:
        return _empty_mesh()
    keys = np.concatenate([np.asarray(k, np.int64) for _, _, k in pieces])
    verts = np.concatenate([np.asarray(v, np.float32) for v, _, _ in pieces])
    unique, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    offsets = np.cumsum([0] + [len(k) for _, _, k in pieces[:-1]])
    faces = np.concatenate([inverse[np.asarray(f, np.int64) + o] for (_, f, _), o in zip(pieces, offsets)])
    return verts[first], faces.astype(np.int32)


def search_edges(points, values, keys: Sequence, field: Field, *, levels: Sequence[float] = (0.5,),
                 binary_steps: int = 8, field_input: str | None = None, device=None,
                 steps_per_call: StepsPerCall = 1) -> list[np.ndarray]:
    """The search of :func:`marching_tetrahedra` on given crossing edges: the vertex of each edge key, per level.

    Args:
        points, values: the grid's ``[P, 3]`` points and ``[P]`` field values (as for :func:`marching_tetrahedra`).
        keys: one ``int64`` array of edge keys ``i·P + j`` per level (as ``return_keys`` gives them), each edge
            crossing its level (one endpoint ``>= level``, the other below).
        field: the field for the search (a callable or a ``@wp.func``, see the module docstring).

    It makes exactly the field calls of ``binary_steps`` steps at ``steps_per_call`` (as :func:`marching_tetrahedra`:
    ``binary_steps`` calls at 1), each with the midpoints of every level's edges together (also when there are none), so a field that is a collective over processes (the opacity field with its views shared
    out among ranks) is called alike on every rank that passes the same keys. Each vertex depends only on its edge
    and the field there: the same keys give :func:`marching_tetrahedra`'s vertices bit for bit.

    Returns:
        ``[len(keys[l]), 3]`` float32 vertices per level, in the order of ``keys[l]``.
    """
    if field_input == "torch":
        import torch  # noqa: F401  (before the device rule: torch and Warp must agree)
    device = resolve_device(device)
    levels = check_levels(levels)
    steps = check_steps(binary_steps)
    if len(keys) != len(levels):
        raise GofError(f"search_edges: {len(keys)} key arrays for {len(levels)} levels")
    pts = as_vec3_array(points, "points", device)
    n_points = pts.shape[0]
    vals = as_float_array(values, n_points, "values", device)
    key_arrays = []
    for k in keys:
        k = np.asarray(k, np.int64).reshape(-1)
        if len(k) and (k.min() < 0 or k.max() >= n_points * n_points):
            raise GofError(f"search_edges: edge keys must lie in [0, P²) for P = {n_points} points")
        key_arrays.append(wp.array(k, dtype=wp.int64, device=device))
    call_field = make_field(field, None, field_input or field_kind(points), device) if steps > 0 else None
    with torch_stream(device):
        vertices = _search(pts, vals, key_arrays, levels, call_field, steps, always_call=True,
                           steps_per_call=steps_per_call)
    out, offset = [], 0
    for k in key_arrays:
        out.append(vertices[offset : offset + k.shape[0]])
        offset += k.shape[0]
    return out


def _search(pts, vals, key_arrays, levels, call_field, steps, always_call=False, steps_per_call: StepsPerCall = 1
            ) -> np.ndarray:
    """Brackets from each level's edge keys, bisected together: the ``[ΣV, 3]`` vertices, level after level."""
    device, n_points = pts.device, pts.shape[0]
    sizes = [k.shape[0] for k in key_arrays]
    br = _Brackets.empty(sum(sizes), device)
    offset = 0
    for keys, lv, n in zip(key_arrays, levels, sizes):
        if n:
            wp.launch(mt.init_edge_brackets, dim=n, inputs=[keys, wp.int64(n_points), pts, vals, lv],
                      outputs=br.outputs(offset, offset + n), device=device)
            br.level[offset : offset + n].fill_(lv)
        offset += n
    return _refine(br, call_field, steps, always_call, steps_per_call)


def _marching_tetrahedra(pts, tet_src, vals, levels, call_field, steps, chunk_size, oriented=False, return_keys=False,
                         steps_per_call: StepsPerCall = 1):
    topo = [_level_topology(pts, tet_src, vals, lv, chunk_size, oriented) for lv in levels]
    sizes = [keys.shape[0] for _, keys in topo]
    vertices = _search(pts, vals, [keys for _, keys in topo], levels, call_field, steps, steps_per_call=steps_per_call)
    meshes, offset = [], 0
    for (corner_vertex, keys), n, lv in zip(topo, sizes, levels):
        faces = corner_vertex.numpy().reshape(-1, 3).astype(np.int32, copy=False)
        meshes.append((vertices[offset : offset + n], faces) + ((keys.numpy(),) if return_keys else ()))
        log.info("marching_tetrahedra: level %g: %d vertices, %d faces", lv, n, faces.shape[0])
        offset += n
    return meshes


# ---------------------------------------------------------------------------------------------- cubes
def _grid_spec(bounds, resolution) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int]]:
    b = np.asarray(bounds, dtype=np.float64)
    if b.shape != (2, 3) or not np.all(np.isfinite(b)) or not np.all(b[1] > b[0]):
        raise GofError(f"bounds must be [[x0, y0, z0], [x1, y1, z1]] with x1 > x0 etc., got {bounds!r}")
    res = tuple(int(r) for r in np.broadcast_to(np.asarray(resolution), (3,)))
    if min(res) < 2:
        raise GofError(f"resolution (grid nodes per axis) must be >= 2, got {resolution!r}")
    lower = b[0].astype(np.float32)
    delta = (b[1].astype(np.float32) - lower) / (np.asarray(res, np.float32) - np.float32(1.0))
    return lower, delta.astype(np.float32), res


def _node_positions(idx: np.ndarray, lower: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Positions of grid nodes ``idx [M, 3]`` as Warp computes them: ``lower + float32(i) * delta``."""
    return lower + idx.astype(np.float32) * delta


def _sample_grid(call_field: FieldCaller, lower, delta, res, chunk_nodes: int) -> np.ndarray:
    nx, ny, nz = res
    grid = np.empty(res, np.float32)
    jk = np.stack(np.meshgrid(np.arange(ny), np.arange(nz), indexing="ij"), -1).reshape(-1, 2)
    slab = max(1, chunk_nodes // (ny * nz))
    for i0 in range(0, nx, slab):
        i1 = min(i0 + slab, nx)
        ii = np.repeat(np.arange(i0, i1), ny * nz)
        idx = np.column_stack([ii, np.tile(jk, (i1 - i0, 1))])
        x = wp.array(_node_positions(idx, lower, delta), dtype=wp.vec3, device=call_field.device)
        grid[i0:i1] = call_field(x, "grid").numpy().reshape(i1 - i0, ny, nz)
    return grid


def _crossing_grid_edges(grid: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """Crossing grid edges in Warp's vertex order (flat ``((i ny + j) nz + k) 3 + axis``): (node ``[V,3]``, axis)."""
    inside = grid >= np.float32(level)
    cross = np.zeros(grid.shape + (3,), bool)
    cross[:-1, :, :, 0] = inside[:-1] != inside[1:]
    cross[:, :-1, :, 1] = inside[:, :-1] != inside[:, 1:]
    cross[:, :, :-1, 2] = inside[:, :, :-1] != inside[:, :, 1:]
    flat = np.flatnonzero(cross)
    node = np.stack(np.unravel_index(flat // 3, grid.shape), -1)
    return node, (flat % 3).astype(np.int64)


def marching_cubes(field: Field, bounds, resolution, *, level: float = 0.5, binary_steps: int = 0,
                   field_input: str = "numpy", chunk_size: int = DEFAULT_CHUNK_NODES,
                   device=None, field_params=None, search_field: Field | None = None,
                   search_params=None) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes on a dense grid (Warp's ``IsoSurfaceMarchingCubes``), then binary search on each
    vertex's grid edge.

    Args:
        field: callable, ``[M, 3]`` points → ``[M]`` values, or a ``@wp.func`` (see the module docstring);
            sampled on the grid in batches of ``chunk_size`` nodes, then once per search step on all
            crossing edges.
        bounds: ``[[x0, y0, z0], [x1, y1, z1]]``, the positions of the first and last grid nodes.
        resolution: grid nodes per axis, an int or three ints (>= 2).
        level: the level set (inside = ``value >= level``).
        binary_steps: bisection steps per vertex (0 = Warp's linear interpolation).
        field_input: ``"numpy"`` (default), ``"torch"`` or ``"warp"``: what ``field`` receives.
        device: Warp device; default CUDA when available, else CPU.
        field_params: the ``params`` argument of a Warp field function that takes one.
        search_field: the field the bisection refines on (same kinds as ``field``, same ``field_input``;
            ``search_params`` its params); default ``field``. E.g. grid values from a cheap approximation
            (a baked volume) and the search on the exact field: a crossing edge's ends carry the exact
            values, so the exact field crosses the level on it and the search converges to that crossing.

    Returns:
        ``(vertices [V, 3] float32, faces [F, 3] int32)``, normals from high to low values.
    """
    if field_input == "torch":
        import torch  # noqa: F401  (before the device rule: torch and Warp must agree)
    device = resolve_device(device)
    lower, delta, res = _grid_spec(bounds, resolution)
    steps = check_steps(binary_steps)
    level = check_levels([level])[0]
    call_field = make_field(field, field_params, field_input, device)
    search = call_field if search_field is None else make_field(search_field, search_params, field_input, device)
    with torch_stream(device):
        return _marching_cubes(call_field, lower, delta, res, level, steps, max(1, int(chunk_size)), search)


def _marching_cubes(call_field: FieldCaller | WarpField, lower, delta, res, level: float, steps: int, chunk_nodes: int,
                    search: FieldCaller | WarpField):
    device = call_field.device
    grid = _sample_grid(call_field, lower, delta, res, chunk_nodes)
    upper = lower + delta * (np.asarray(res, np.float32) - 1)
    verts_wp, tris_wp = warp.geometry.IsoSurfaceMarchingCubes.extract(
        wp.array(grid, dtype=wp.float32, device=device), level, lower=wp.vec3(*lower), upper=wp.vec3(*upper))
    warp_verts = verts_wp.numpy().reshape(-1, 3)
    faces = tris_wp.numpy().reshape(-1, 3)[:, [0, 2, 1]].astype(np.int32)  # Warp winds toward high values
    if warp_verts.shape[0] == 0:
        log.warning("marching_cubes: level %g does not cross the grid: empty mesh", level)
        return _empty_mesh()

    node, axis = _crossing_grid_edges(grid, level)
    if node.shape[0] != warp_verts.shape[0]:
        raise RuntimeError(f"marching_cubes: {node.shape[0]} crossing edges but Warp made {warp_verts.shape[0]} vertices")
    other = node + np.eye(3, dtype=np.int64)[axis]
    f_a, f_b = grid[tuple(node.T)], grid[tuple(other.T)]
    a_in = (f_a >= np.float32(level))[:, None]
    x_a, x_b = _node_positions(node, lower, delta), _node_positions(other, lower, delta)
    br = _Brackets(*(wp.array(a, dtype=dt, device=device) for a, dt in (
        (np.where(a_in, x_a, x_b), wp.vec3), (np.where(a_in, x_b, x_a), wp.vec3),
        (np.where(a_in[:, 0], f_a, f_b), wp.float32), (np.where(a_in[:, 0], f_b, f_a), wp.float32),
        (np.full(node.shape[0], level, np.float32), wp.float32))))
    linear = _refine(br, None, 0)
    off_edge = np.abs(linear - warp_verts).max() / float(delta.min())
    if off_edge > MC_EDGE_MATCH_TOL:  # guards our reading of Warp's vertex order
        raise RuntimeError(f"marching_cubes: Warp's vertices are {off_edge:.2g} cells off their grid edges")
    vertices = _refine(br, search, steps) if steps else linear
    return vertices, faces
