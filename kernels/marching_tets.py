"""Marching tetrahedra with edge-keyed vertices and a per-edge binary search (pure Warp + numpy).

Level-set convention: a point is **inside** when ``value >= level`` (high opacity is inside, GOF's
``sdf = 0.5 - O < 0``). Output triangles are wound so that their normal ``(p1 - p0) × (p2 - p0)``
points from inside (high) to outside (low), i.e. outwards for an opacity field.

Pipeline (host code in :mod:`gof_warp.mesh.marching`):

1. :func:`count_triangles` per tetrahedron → ``array_scan`` (inclusive) → number of faces.
2. :func:`write_triangle_edges` per tetrahedron: each face corner is the **key of the global edge** it
   lies on, ``key = min(i, j) * n_points + max(i, j)`` (int64). Faces of tetrahedron ``t`` come in the
   order of ``t``; the winding uses the sign of the tetrahedron's volume, so tetrahedra of either
   orientation give outward faces.
3. Deduplication: ``radix_sort_pairs(keys, slots)`` → :func:`mark_run_starts` → ``array_scan`` →
   :func:`scatter_vertex_ids` (face corner → vertex id, vertex id → edge key). Faces that share an edge
   share the vertex, so the mesh is connected.
4. :func:`init_edge_brackets` turns each edge key into a bracket ``[x_in, x_out]`` with
   ``f(x_in) >= level > f(x_out)``; :func:`bracket_midpoints` / :func:`update_brackets` halve it with
   field values at the midpoints (one step, one batch of field values from the caller), and
   :func:`bracket_tree_midpoints` / :func:`descend_bracket_tree` take ``d`` steps from one batch (every
   midpoint those steps can visit; ``d = 1`` is the one-step pair): the same brackets bit for bit. The host
   code (:mod:`gof_warp.mesh.marching`) uses the tree pair;
   :func:`interpolate_in_brackets` puts the vertex at the linear zero of the final bracket.

The field of step 4 is either host code filling a batch of values, or a user's ``@wp.func``
``field(x: wp.vec3[, params: P]) -> float`` turned into a kernel by :func:`make_field_kernel`: then every
bisection step is three launches on the device and nothing goes back to the host between steps.

Case tables are built (not typed) from the definition below and checked against a reference
tetrahedron, then stored as ``wp.constant`` matrices: they are compiled into the kernels, so nothing is
uploaded or cached per device.
"""

from __future__ import annotations

import itertools

import numpy as np
import warp as wp

# Local edges of a tetrahedron (vertex pairs), in kaolin / official-GOF order.
TET_EDGES = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
# Reference tetrahedron with positive volume: det[v1 - v0, v2 - v0, v3 - v0] = +1.
_REFERENCE_TET = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def _edge_id(a: int, b: int) -> int:
    return TET_EDGES.index((min(a, b), max(a, b)))


def build_case_tables() -> tuple[np.ndarray, np.ndarray]:
    """Marching-tetrahedra tables for case ``c = Σ_i [value_i >= level] 2^i``.

    Returns ``(num_triangles [16] int32, triangle_edges [16, 6] int32)``: triangle ``k`` of case ``c`` has
    its corners on local edges ``triangle_edges[c, 3k:3k+3]`` (``-1`` = unused), wound outwards
    (inside → outside) for a tetrahedron of positive volume.
    """
    num = np.zeros(16, np.int32)
    tris = -np.ones((16, 6), np.int32)
    mid = {e: _REFERENCE_TET[list(e)].mean(axis=0) for e in TET_EDGES}
    for case in range(16):
        inside = [v for v in range(4) if case >> v & 1]
        outside = [v for v in range(4) if not case >> v & 1]
        if len(inside) in (1, 3):
            lone = inside[0] if len(inside) == 1 else outside[0]
            others = [v for v in range(4) if v != lone]
            faces = [[_edge_id(lone, o) for o in others]]
        elif len(inside) == 2:
            (a, b), (c, d) = inside, outside
            quad = [_edge_id(a, c), _edge_id(a, d), _edge_id(b, d), _edge_id(b, c)]  # a cycle of edges
            faces = [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
        else:
            faces = []
        outward = _REFERENCE_TET[outside].mean(axis=0) - _REFERENCE_TET[inside].mean(axis=0) if faces else None
        for k, face in enumerate(faces):
            p = [mid[TET_EDGES[e]] for e in face]
            if np.dot(np.cross(p[1] - p[0], p[2] - p[0]), outward) < 0.0:
                face = [face[0], face[2], face[1]]
            tris[case, 3 * k : 3 * k + 3] = face
        num[case] = len(faces)
    return num, tris


_NUM_TRIS, _TRI_EDGES = build_case_tables()
MT_NUM_TRIANGLES = wp.constant(wp.types.vector(16, wp.int32)(*_NUM_TRIS.tolist()))
MT_TRIANGLE_EDGES = wp.constant(wp.types.matrix(shape=(16, 6), dtype=wp.int32)(*_TRI_EDGES.ravel().tolist()))
MT_EDGE_VERTICES = wp.constant(
    wp.types.matrix(shape=(6, 2), dtype=wp.int32)(*itertools.chain.from_iterable(TET_EDGES))
)


@wp.func
def tet_case(values: wp.array(dtype=wp.float32), tet: wp.vec4i, level: wp.float32) -> int:
    """Case index ``Σ_i [values[tet[i]] >= level] 2^i`` of one tetrahedron."""
    case = int(0)
    if values[tet[0]] >= level:
        case += 1
    if values[tet[1]] >= level:
        case += 2
    if values[tet[2]] >= level:
        case += 4
    if values[tet[3]] >= level:
        case += 8
    return case


@wp.func
def edge_key(i: int, j: int, n_points: wp.int64) -> wp.int64:
    """Key of the undirected edge ``{i, j}``: ``min * n_points + max`` (int64)."""
    lo = wp.min(i, j)
    hi = wp.max(i, j)
    return wp.int64(lo) * n_points + wp.int64(hi)


@wp.func
def tet_signed_volume6(points: wp.array(dtype=wp.vec3), tet: wp.vec4i) -> wp.float64:
    """Six times the signed volume, ``det[p1 - p0, p2 - p0, p3 - p0]``, in float64."""
    p0 = wp.vec3d(points[tet[0]])
    a = wp.vec3d(points[tet[1]]) - p0
    b = wp.vec3d(points[tet[2]]) - p0
    c = wp.vec3d(points[tet[3]]) - p0
    return wp.dot(wp.cross(a, b), c)


@wp.kernel
def count_triangles(
    tets: wp.array(dtype=wp.vec4i),
    values: wp.array(dtype=wp.float32),
    level: wp.float32,
    tri_count: wp.array(dtype=wp.int32),
):
    """``tri_count[t]`` = number of triangles (0, 1 or 2) of tetrahedron ``t``. ``tets [T]``, ``values [P]``."""
    t = wp.tid()
    tri_count[t] = MT_NUM_TRIANGLES[tet_case(values, tets[t], level)]


@wp.kernel
def write_triangle_edges(
    points: wp.array(dtype=wp.vec3),
    tets: wp.array(dtype=wp.vec4i),
    values: wp.array(dtype=wp.float32),
    level: wp.float32,
    tri_end: wp.array(dtype=wp.int32),
    face_base: int,
    n_points: wp.int64,
    trust_order: wp.int32,
    corner_keys: wp.array(dtype=wp.int64),
):
    """Write the edge keys of each face corner: ``corner_keys[3 f + s]`` for face ``f``, corner ``s``.

    ``tri_end [T]`` is the inclusive scan of :func:`count_triangles`; faces of this chunk start at
    ``face_base``. Faces are wound outwards; for a tetrahedron of negative volume corners 1 and 2 swap,
    unless ``trust_order`` is 1: the tetrahedra are known to be positively oriented (a Delaunay of perturbed
    points, whose slivers may be flat or inverted in the exact ``points``: their order is the consistent one).
    """
    t = wp.tid()
    tet = tets[t]
    case = tet_case(values, tet, level)
    n = MT_NUM_TRIANGLES[case]
    if n == 0:
        return
    first = face_base + tri_end[t] - n
    flip = trust_order == 0 and tet_signed_volume6(points, tet) < wp.float64(0.0)
    for k in range(n):
        for s in range(3):
            e = MT_TRIANGLE_EDGES[case, 3 * k + s]
            slot = s
            if flip and s > 0:
                slot = 3 - s
            key = edge_key(tet[MT_EDGE_VERTICES[e, 0]], tet[MT_EDGE_VERTICES[e, 1]], n_points)
            corner_keys[3 * (first + k) + slot] = key


@wp.kernel
def write_slot_ids(slots: wp.array(dtype=wp.int32)):
    """``slots[i] = i`` (the face-corner index carried through the key sort)."""
    i = wp.tid()
    slots[i] = i


@wp.func
def starts_run(sorted_keys: wp.array(dtype=wp.int64), i: int) -> bool:
    """Whether ``sorted_keys[i]`` is the first of its run of equal keys."""
    return i == 0 or sorted_keys[i] != sorted_keys[wp.max(i - 1, 0)]


@wp.kernel
def mark_run_starts(sorted_keys: wp.array(dtype=wp.int64), run_start: wp.array(dtype=wp.int32)):
    """``run_start[i] = 1`` where a new key starts in the sorted keys (launch over the count, not 2×)."""
    i = wp.tid()
    run_start[i] = wp.where(starts_run(sorted_keys, i), 1, 0)


@wp.kernel
def scatter_vertex_ids(
    sorted_keys: wp.array(dtype=wp.int64),
    sorted_slots: wp.array(dtype=wp.int32),
    run_end: wp.array(dtype=wp.int32),
    corner_vertex: wp.array(dtype=wp.int32),
    vertex_keys: wp.array(dtype=wp.int64),
):
    """Face corner ``sorted_slots[i]`` gets vertex ``run_end[i] - 1`` (inclusive scan of run starts)."""
    i = wp.tid()
    v = run_end[i] - 1
    corner_vertex[sorted_slots[i]] = v
    if starts_run(sorted_keys, i):
        vertex_keys[v] = sorted_keys[i]


@wp.kernel
def init_edge_brackets(
    vertex_keys: wp.array(dtype=wp.int64),
    n_points: wp.int64,
    points: wp.array(dtype=wp.vec3),
    values: wp.array(dtype=wp.float32),
    level: wp.float32,
    x_in: wp.array(dtype=wp.vec3),
    x_out: wp.array(dtype=wp.vec3),
    f_in: wp.array(dtype=wp.float32),
    f_out: wp.array(dtype=wp.float32),
):
    """Bracket of each crossing edge: the endpoint with ``value >= level`` is ``x_in``, the other ``x_out``."""
    v = wp.tid()
    key = vertex_keys[v]
    i = int(key // n_points)
    j = int(key - wp.int64(i) * n_points)
    if values[i] >= level:
        x_in[v] = points[i]
        f_in[v] = values[i]
        x_out[v] = points[j]
        f_out[v] = values[j]
    else:
        x_in[v] = points[j]
        f_in[v] = values[j]
        x_out[v] = points[i]
        f_out[v] = values[i]


@wp.kernel
def bracket_midpoints(x_in: wp.array(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3), x_mid: wp.array(dtype=wp.vec3)):
    """``x_mid = (x_in + x_out) / 2`` per edge."""
    v = wp.tid()
    x_mid[v] = 0.5 * (x_in[v] + x_out[v])


@wp.kernel
def update_brackets(
    x_mid: wp.array(dtype=wp.vec3),
    f_mid: wp.array(dtype=wp.float32),
    level: wp.array(dtype=wp.float32),
    x_in: wp.array(dtype=wp.vec3),
    x_out: wp.array(dtype=wp.vec3),
    f_in: wp.array(dtype=wp.float32),
    f_out: wp.array(dtype=wp.float32),
):
    """One bisection step: the midpoint replaces the end of the same side (``f_mid >= level`` → inside).

    Keeps the invariant ``f_in >= level > f_out``; ``level [V]`` is per edge (several level sets at once).
    """
    v = wp.tid()
    if f_mid[v] >= level[v]:
        x_in[v] = x_mid[v]
        f_in[v] = f_mid[v]
    else:
        x_out[v] = x_mid[v]
        f_out[v] = f_mid[v]


@wp.func
def tree_node(x_in: wp.array(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3), nodes: wp.array2d(dtype=wp.vec3),
              v: int, k: int, n: int) -> wp.vec3:
    """Position ``k`` of ``0 … n`` along bracket ``v``'s search tree: its ends (``x_in``, ``x_out``) or an inner node."""
    if k == 0:
        return x_in[v]
    if k == n:
        return x_out[v]
    return nodes[v, k - 1]


@wp.kernel
def bracket_tree_midpoints(x_in: wp.array(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3), depth: int,
                           nodes: wp.array2d(dtype=wp.vec3)):
    """Every midpoint that ``depth`` bisection steps of bracket ``v`` can visit, in order along it:
    ``nodes[v, k - 1]`` lies ``k / 2^depth`` of the way from ``x_in`` (``k = 1 … 2^depth − 1``). Each is computed as
    :func:`bracket_midpoints` computes it, ``0.5 (a + b)`` of the two nodes that bracket it one level up, so
    :func:`descend_bracket_tree` on the field at them reproduces ``depth`` steps of :func:`update_brackets` bit for bit.
    """
    v = wp.tid()
    n = 1 << depth
    span = n
    for _level in range(depth):
        half = span // 2
        j = int(0)
        while j < n:
            a = tree_node(x_in, x_out, nodes, v, j, n)
            b = tree_node(x_in, x_out, nodes, v, j + span, n)
            nodes[v, j + half - 1] = 0.5 * (a + b)
            j += span
        span = half


@wp.kernel
def descend_bracket_tree(
    nodes: wp.array2d(dtype=wp.vec3),
    f_nodes: wp.array2d(dtype=wp.float32),
    depth: int,
    level: wp.array(dtype=wp.float32),
    x_in: wp.array(dtype=wp.vec3),
    x_out: wp.array(dtype=wp.vec3),
    f_in: wp.array(dtype=wp.float32),
    f_out: wp.array(dtype=wp.float32),
):
    """``depth`` bisection steps at once, from the field ``f_nodes`` at :func:`bracket_tree_midpoints`' nodes: each step
    takes the middle node of the current bracket and replaces the end of the same side, as :func:`update_brackets`."""
    v = wp.tid()
    n = 1 << depth
    lo = int(0)  # the x_in end, as a position 0 … n along the tree
    hi = n  # the x_out end
    fi = f_in[v]
    fo = f_out[v]
    for _step in range(depth):
        mid = (lo + hi) // 2
        fm = f_nodes[v, mid - 1]
        if fm >= level[v]:
            lo = mid
            fi = fm
        else:
            hi = mid
            fo = fm
    xi = tree_node(x_in, x_out, nodes, v, lo, n)
    xo = tree_node(x_in, x_out, nodes, v, hi, n)
    x_in[v] = xi
    x_out[v] = xo
    f_in[v] = fi
    f_out[v] = fo


@wp.kernel
def interpolate_in_brackets(
    x_in: wp.array(dtype=wp.vec3),
    x_out: wp.array(dtype=wp.vec3),
    f_in: wp.array(dtype=wp.float32),
    f_out: wp.array(dtype=wp.float32),
    level: wp.array(dtype=wp.float32),
    vertices: wp.array(dtype=wp.vec3),
):
    """Vertex at the linear zero of ``f - level`` in the bracket: ``x_in + t (x_out - x_in)``,
    ``t = (f_in - level) / (f_in - f_out)`` clamped to ``[0, 1]`` (``f_in - f_out > 0`` by the invariant)."""
    v = wp.tid()
    denom = f_in[v] - f_out[v]
    t = float(0.5)
    if denom > 0.0:
        t = wp.clamp((f_in[v] - level[v]) / denom, 0.0, 1.0)
    vertices[v] = x_in[v] + t * (x_out[v] - x_in[v])


@wp.kernel
def count_nonfinite(values: wp.array(dtype=wp.float32), count: wp.array(dtype=wp.int32)):
    """``count[0] += 1`` for each NaN/inf of ``values [N]`` (``count`` zeroed by the caller)."""
    i = wp.tid()
    if not wp.isfinite(values[i]):
        wp.atomic_add(count, 0, 1)


def field_params_type(field: wp.Function):
    """The type of the ``params`` argument of a field function, or ``None`` when it takes only ``x``.

    A field function is a ``@wp.func`` ``field(x: wp.vec3) -> float`` or ``field(x: wp.vec3, params: P)
    -> float`` with ``P`` any concrete Warp type (a ``wp.struct`` holding arrays, a ``wp.uint64`` volume or
    mesh id, ...). Raises ``TypeError`` for anything else.
    """
    if not isinstance(field, wp.Function):
        raise TypeError(f"a field function must be a @wp.func, got {type(field).__name__}")
    args = list(field.input_types.items())
    if len(args) not in (1, 2):
        raise TypeError(f"field function {field.key} must take (x: wp.vec3) or (x: wp.vec3, params), "
                        f"it takes {len(args)} arguments")
    if args[0][1] is not wp.vec3:
        raise TypeError(f"field function {field.key}: the first argument must be wp.vec3, got {args[0][1]}")
    return args[1][1] if len(args) == 2 else None


def make_field_kernel(field: wp.Function) -> wp.Kernel:
    """A kernel filling ``values[i] = field(points[i][, params])`` for a user's field function.

    Args:
        field: ``@wp.func`` ``(x: wp.vec3) -> float`` or ``(x: wp.vec3, params: P) -> float`` (see
            :func:`field_params_type`); ``x`` in world units.
    Returns:
        ``wp.Kernel`` with the arguments ``(points: array(vec3) [M], [params: P,] values: array(float32) [M])``,
        launched with ``dim=M``. It lives in its own Warp module (``module="unique"``), so the same function
        gives the same compiled module (Warp hashes it): calling this again for the same field costs no
        compilation, and no cache of ours is kept.
    """
    params_type = field_params_type(field)
    if params_type is None:

        def fill_field_values(points, values):
            i = wp.tid()
            values[i] = wp.float32(field(points[i]))

        annotations = {"points": wp.array(dtype=wp.vec3), "values": wp.array(dtype=wp.float32)}
    else:

        def fill_field_values(points, params, values):
            i = wp.tid()
            values[i] = wp.float32(field(points[i], params))

        annotations = {"points": wp.array(dtype=wp.vec3), "params": params_type, "values": wp.array(dtype=wp.float32)}
    # set as objects, not strings: this module uses postponed annotations, and params_type is a local
    fill_field_values.__annotations__ = annotations
    fill_field_values.__doc__ = f"``values[i] = {field.key}(points[i]{'' if params_type is None else ', params'})``."
    return wp.kernel(fill_field_values, module="unique", enable_backward=False)
