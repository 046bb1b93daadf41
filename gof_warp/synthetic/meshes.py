"""Procedural and file meshes with materials, for synthetic scenes.

Every builder returns a :class:`SyntheticMesh` in world coordinates (z up) with outward (or, for the
background shell, inward) faces wound counter-clockwise seen from the side the normals point to,
per-vertex shading normals (flat parts get their own unshared vertices) and, where a parametrisation
exists, per-corner UVs. Geometry is float64 here; the ray caster uses it as float32 and ``gt_mesh.ply``
stores exactly those float32 numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..core.arrays import used_vertices
from ..core.errors import SceneError


@dataclass(frozen=True, eq=False)
class Material:
    """Surface colour model (see ``kernels/raycast.py``).

    Attributes:
        kind: ``"constant"`` (albedo ``color_a``), ``"texture"`` (``color_a`` × image ``texture`` at the
            corner UVs) or ``"procedural"`` (per-channel 3D fBm noise of the world position between
            ``color_a`` and ``color_b``, times a 3D checker).
        noise_scale: noise features per world unit.
        checker_scale: checker squares per world unit (0 = no checker).
        checker_strength: darkening of the odd squares, 0..1.
        texture: ``[H, W, 3]`` float32 in ``[0, 1]``, row 0 at the top (``kind="texture"`` only).
    """

    kind: str = "procedural"
    color_a: tuple[float, float, float] = (0.08, 0.08, 0.08)
    color_b: tuple[float, float, float] = (0.9, 0.9, 0.9)
    noise_scale: float = 3.0
    checker_scale: float = 0.0
    checker_strength: float = 0.0
    texture: np.ndarray | None = None


@dataclass(eq=False)
class SyntheticMesh:
    """A triangle mesh with shading attributes.

    Attributes:
        name: part name (for messages and ``scene.json``).
        vertices: ``[V, 3]`` float64 world positions.
        faces: ``[F, 3]`` int64 vertex indices.
        vertex_normals: ``[V, 3]`` unit shading normals.
        material: its :class:`Material`.
        corner_uvs: ``[F, 3, 2]`` texture coordinates per face corner, or None.
        role: ``"object"`` (the thing to reconstruct) or ``"background"`` (ground, shell).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    vertex_normals: np.ndarray
    material: Material = field(default_factory=Material)
    corner_uvs: np.ndarray | None = None
    role: str = "object"

    def with_material(self, material: Material) -> "SyntheticMesh":
        return replace(self, material=material)

    def transformed(self, rotation=None, translation=(0.0, 0.0, 0.0), scale: float = 1.0) -> "SyntheticMesh":
        """``x -> scale * rotation @ x + translation`` (normals rotate)."""
        Rm = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
        return replace(
            self,
            vertices=scale * self.vertices @ Rm.T + np.asarray(translation, dtype=np.float64),
            vertex_normals=self.vertex_normals @ Rm.T,
        )


# ----------------------------------------------------------------------------------------- helpers
def rotation_about(axis, angle_rad: float) -> np.ndarray:
    """``[3, 3]`` rotation by ``angle_rad`` about ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1 - np.cos(angle_rad)) * K @ K


def _normalize(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``[F, 3]`` area vectors (not normalised) ``(p1 - p0) x (p2 - p0)``."""
    p = vertices[faces]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def smooth_vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals ``[V, 3]``."""
    n = np.zeros_like(vertices)
    fn = face_normals(vertices, faces)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    return _normalize(n)


def _orient(vertices, faces, normals, uvs=None):
    """Flip the winding of faces whose geometric normal opposes their vertices' shading normals."""
    flip = np.einsum("fi,fi->f", face_normals(vertices, faces), normals[faces].sum(axis=1)) < 0
    faces = faces.copy()
    faces[flip] = faces[flip][:, [0, 2, 1]]
    if uvs is not None:
        uvs = uvs.copy()
        uvs[flip] = uvs[flip][:, [0, 2, 1]]
    return faces, uvs


def _grid(P: np.ndarray, N: np.ndarray, wrap_u: bool, wrap_v: bool):
    """Triangulate a ``[nu, nv, 3]`` grid of points/normals; returns vertices, normals, faces, corner uvs."""
    nu, nv = P.shape[:2]
    cu = nu if wrap_u else nu - 1
    cv = nv if wrap_v else nv - 1
    i, j = np.meshgrid(np.arange(cu), np.arange(cv), indexing="ij")
    i, j = i.ravel(), j.ravel()
    i1, j1 = (i + 1) % nu, (j + 1) % nv
    a, b, c, d = i * nv + j, i1 * nv + j, i1 * nv + j1, i * nv + j1
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    ua, ub = i / cu, (i + 1) / cu
    va, vb = j / cv, (j + 1) / cv
    uv_abcd = [np.stack(x, 1) for x in ((ua, va), (ub, va), (ub, vb), (ua, vb))]
    uvs = np.concatenate([np.stack([uv_abcd[0], uv_abcd[1], uv_abcd[2]], 1),
                          np.stack([uv_abcd[0], uv_abcd[2], uv_abcd[3]], 1)])
    V, Nn = P.reshape(-1, 3), _normalize(N.reshape(-1, 3))
    faces, uvs = _orient(V, faces, Nn, uvs)
    return V, Nn, faces, uvs


def _part(name, V, Nn, faces, uvs, material, role="object") -> SyntheticMesh:
    return SyntheticMesh(name=name, vertices=np.asarray(V, np.float64), faces=np.asarray(faces, np.int64),
                         vertex_normals=np.asarray(Nn, np.float64), material=material, corner_uvs=uvs, role=role)


def concatenate(parts: list[SyntheticMesh], name: str, material: Material | None = None) -> SyntheticMesh:
    """Join parts into one mesh (no welding); keeps the first part's material unless one is given."""
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts])
    uvs = [p.corner_uvs if p.corner_uvs is not None else np.zeros((len(p.faces), 3, 2)) for p in parts]
    return SyntheticMesh(
        name=name,
        vertices=np.concatenate([p.vertices for p in parts]),
        faces=np.concatenate([p.faces + o for p, o in zip(parts, offsets)]),
        vertex_normals=np.concatenate([p.vertex_normals for p in parts]),
        material=material or parts[0].material,
        corner_uvs=np.concatenate(uvs),
        role=parts[0].role,
    )


# ----------------------------------------------------------------------------------------- primitives
def sphere(center=(0, 0, 0), radius=1.0, subdivisions=4, material=None, name="sphere", inward=False,
           role="object") -> SyntheticMesh:
    """Geodesic sphere (subdivided icosahedron, every vertex exactly on the sphere, float64).

    ``inward=True`` turns faces and normals inside (a background shell seen from within).
    """
    import trimesh

    ico = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    unit = _normalize(np.asarray(ico.vertices, dtype=np.float64))
    faces = np.asarray(ico.faces, dtype=np.int64)
    normals = -unit if inward else unit
    faces, _ = _orient(unit, faces, normals)
    return _part(name, radius * unit + np.asarray(center, float), normals, faces, None, material or Material(), role)


def box(center=(0, 0, 0), size=(1, 1, 1), rotation=None, material=None, name="box") -> SyntheticMesh:
    """Axis-aligned box (then rotated about its centre), flat shaded: 4 own vertices per side."""
    half = np.asarray(size, dtype=np.float64) / 2
    verts, norms, faces, uvs = [], [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            a1, a2 = [k for k in range(3) if k != axis]
            corners = []
            for s1, s2 in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = np.zeros(3)
                p[axis], p[a1], p[a2] = sign * half[axis], s1 * half[a1], s2 * half[a2]
                corners.append(p)
            base = len(verts)
            verts += corners
            norms += [n] * 4
            faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
            quad_uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
            uvs += [quad_uv[[0, 1, 2]], quad_uv[[0, 2, 3]]]
    V, Nn, F, UV = np.array(verts), np.array(norms), np.array(faces), np.array(uvs)
    F, UV = _orient(V, F, Nn, UV)
    part = _part(name, V, Nn, F, UV, material or Material())
    return part.transformed(rotation, center)


def torus(center=(0, 0, 0), major=0.5, minor=0.15, sections=(64, 24), rotation=None, material=None,
          name="torus") -> SyntheticMesh:
    """Torus around the z axis (then rotated), smooth shaded, UVs = (angle around z, angle around tube)."""
    phi = np.linspace(0, 2 * np.pi, sections[0], endpoint=False)[:, None]
    theta = np.linspace(0, 2 * np.pi, sections[1], endpoint=False)[None, :]
    ring = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], -1)
    N = np.cos(theta)[..., None] * ring + np.sin(theta)[..., None] * np.array([0, 0, 1.0])
    P = major * ring + minor * N
    return _part(name, *_grid(P, N, True, True), material or Material()).transformed(rotation, center)


def _transport_frames(curve: np.ndarray, closed: bool):
    """Tangents and parallel-transported normal/binormal frames along a polyline ``[n, 3]``."""
    if closed:
        T = _normalize(np.roll(curve, -1, 0) - np.roll(curve, 1, 0))
    else:
        T = _normalize(np.gradient(curve, axis=0))
    seed = np.array([0.0, 0.0, 1.0]) if abs(T[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    N = np.zeros_like(curve)
    N[0] = _normalize(np.cross(T[0], seed))
    for i in range(1, len(curve)):
        n = N[i - 1] - np.dot(N[i - 1], T[i]) * T[i]
        N[i] = n / np.linalg.norm(n)
    B = np.cross(T, N)
    if closed:  # spread the holonomy twist along the loop so the seam closes without a kink
        n_end = N[-1] - np.dot(N[-1], T[0]) * T[0]
        twist = np.arctan2(np.dot(np.cross(n_end, N[0]), T[0]), np.dot(n_end, N[0]))
        alpha = (twist * np.arange(len(curve)) / len(curve))[:, None]
        N, B = np.cos(alpha) * N + np.sin(alpha) * B, -np.sin(alpha) * N + np.cos(alpha) * B
    return T, N, B


def _cap(center, normal, rim, name, material) -> SyntheticMesh:
    V = np.concatenate([center[None], rim])
    k = np.arange(len(rim))
    F = np.stack([np.zeros_like(k), 1 + k, 1 + (k + 1) % len(rim)], 1)
    Nn = np.repeat(normal[None], len(V), 0)
    F, _ = _orient(V, F, Nn)
    return _part(name, V, Nn, F, np.zeros((len(F), 3, 2)), material)


def tube(curve, radius: float, sides: int = 16, closed: bool = False, material=None, name="tube") -> SyntheticMesh:
    """A tube of constant ``radius`` around the polyline ``curve`` ``[n, 3]``; open tubes get flat caps."""
    curve = np.asarray(curve, dtype=np.float64)
    material = material or Material()
    T, N, B = _transport_frames(curve, closed)
    ang = np.linspace(0, 2 * np.pi, sides, endpoint=False)[None, :, None]
    Nr = np.cos(ang) * N[:, None] + np.sin(ang) * B[:, None]
    side = _part(name, *_grid(curve[:, None] + radius * Nr, Nr, closed, True), material)
    if closed:
        return side
    caps = [_cap(curve[0], -T[0], curve[0] + radius * Nr[0], name, material),
            _cap(curve[-1], T[-1], curve[-1] + radius * Nr[-1], name, material)]
    return concatenate([side] + caps, name)


def cylinder(p0, p1, radius: float, sides: int = 16, material=None, name="cylinder") -> SyntheticMesh:
    """Capped cylinder from ``p0`` to ``p1`` (smooth side, flat caps)."""
    return tube(np.stack([np.asarray(p0, float), np.asarray(p1, float)]), radius, sides, False, material, name)


def torus_knot(p: int = 2, q: int = 3, major=0.6, minor=0.25, tube_radius=0.12, samples=240, sides=20,
               center=(0, 0, 0), material=None, name="torus_knot") -> SyntheticMesh:
    """A (p, q) torus knot tube: genus-1 surface with self-occlusions and concave regions."""
    s = np.linspace(0, 2 * np.pi, samples, endpoint=False)
    r = major + minor * np.cos(q * s)
    curve = np.stack([r * np.cos(p * s), r * np.sin(p * s), minor * np.sin(q * s)], 1) + np.asarray(center, float)
    return tube(curve, tube_radius, sides, True, material, name)


def helix(center=(0, 0, 0), radius=0.5, height=1.0, turns=3.0, wire_radius=0.02, samples=200, sides=8,
          material=None, name="helix") -> SyntheticMesh:
    """An open helical wire around the z axis, capped."""
    s = np.linspace(0, 1, samples)
    a = 2 * np.pi * turns * s
    curve = np.stack([radius * np.cos(a), radius * np.sin(a), height * (s - 0.5)], 1) + np.asarray(center, float)
    return tube(curve, wire_radius, sides, False, material, name)


def grid_plane(center=(0, 0, 0), half_size=4.0, cell=0.1, material=None, name="ground",
               role="background") -> SyntheticMesh:
    """A square facing +z tessellated into ``cell``-sized squares (two triangles each), so that per-face
    visibility (``gof_warp.eval.region_metrics.seen_faces``) resolves which parts of it the cameras see; the
    cell count per side is ``round(2 * half_size / cell)``."""
    n = max(1, int(round(2.0 * half_size / cell)))
    s = np.linspace(-half_size, half_size, n + 1)
    P = np.stack([*np.meshgrid(s, s, indexing="ij"), np.zeros((n + 1, n + 1))], -1) + np.asarray(center, float)
    N = np.broadcast_to(np.array([0.0, 0.0, 1.0]), P.shape).copy()
    return _part(name, *_grid(P, N, False, False), material or Material(), role)


def _without_unused_vertices(mesh: SyntheticMesh) -> SyntheticMesh:
    used, faces = used_vertices(mesh.faces, len(mesh.vertices))
    return replace(mesh, vertices=mesh.vertices[used], vertex_normals=mesh.vertex_normals[used], faces=faces)


def cut_below(mesh: SyntheticMesh, z0: float) -> SyntheticMesh:
    """The part of ``mesh`` at ``z >= z0``: faces below go (and the vertices no face uses), faces across the plane
    are cut on it (one or two triangles, winding kept; the new corners' normals and texture coordinates interpolated
    along the edge)."""
    V, F = mesh.vertices, mesh.faces
    uvs = mesh.corner_uvs if mesh.corner_uvs is not None else np.zeros((len(F), 3, 2))
    above = V[F][:, :, 2] >= z0  # [F, 3]
    n_above = above.sum(axis=1)
    out_v, out_n, out_f, out_uv = [V], [mesh.vertex_normals], [F[n_above == 3]], [uvs[n_above == 3]]
    base = len(V)

    def edge_point(f, uv, a, b):  # where corner a -> corner b crosses the plane, per face
        za, zb = V[f[:, a], 2], V[f[:, b], 2]
        t = ((z0 - za) / (zb - za))[:, None]
        na, nb = mesh.vertex_normals[f[:, a]], mesh.vertex_normals[f[:, b]]
        point = V[f[:, a]] + t * (V[f[:, b]] - V[f[:, a]])
        return point, _normalize(na + t * (nb - na)), uv[:, a] + t * (uv[:, b] - uv[:, a])

    for count in (1, 2):  # rotate each face so that its odd corner (the one on its own side) comes first
        sel = np.flatnonzero(n_above == count)
        if len(sel) == 0:
            continue
        odd = np.argmax(above[sel] == (count == 1), axis=1)
        roll = (odd[:, None] + np.arange(3)[None]) % 3
        f = np.take_along_axis(F[sel], roll, axis=1)
        uv = np.take_along_axis(uvs[sel], roll[:, :, None], axis=1)
        p01, n01, uv01 = edge_point(f, uv, 0, 1)
        p02, n02, uv02 = edge_point(f, uv, 0, 2)
        k = len(sel)
        i01, i02 = base + np.arange(k), base + k + np.arange(k)
        base += 2 * k
        out_v += [p01, p02]
        out_n += [n01, n02]
        if count == 1:  # corner 0 above: the triangle (0, p01, p02)
            out_f.append(np.stack([f[:, 0], i01, i02], 1))
            out_uv.append(np.stack([uv[:, 0], uv01, uv02], 1))
        else:  # corner 0 below: the quad (p01, 1, 2, p02) as two triangles
            out_f += [np.stack([i01, f[:, 1], f[:, 2]], 1), np.stack([i01, f[:, 2], i02], 1)]
            out_uv += [np.stack([uv01, uv[:, 1], uv[:, 2]], 1), np.stack([uv01, uv[:, 2], uv02], 1)]
    return _without_unused_vertices(replace(mesh, vertices=np.concatenate(out_v), vertex_normals=np.concatenate(out_n),
                                            faces=np.concatenate(out_f).astype(np.int64),
                                            corner_uvs=None if mesh.corner_uvs is None else np.concatenate(out_uv)))


def clip_to_convex(mesh: SyntheticMesh, hull: SyntheticMesh, center) -> SyntheticMesh:
    """``mesh`` cut to the inside of the convex closed mesh ``hull``: each vertex outside moves towards
    ``center`` (a point inside ``hull``) onto its boundary, and faces whose three vertices all moved are dropped
    (with the vertices no face uses any more).

    A ground that reaches a background shell this way meets it with no gap (up to the chords between moved
    vertices, ``cell**2 / (8 * radius)``) and has nothing behind it that a camera cannot see.
    """
    c = np.asarray(center, dtype=np.float64)
    area = face_normals(hull.vertices, hull.faces)
    v0 = hull.vertices[hull.faces[:, 0]]
    inner = hull.vertices.mean(axis=0)  # inside a convex closed mesh
    n = area * np.sign(np.einsum("ij,ij->i", area, v0 - inner))[:, None]  # outward whichever way hull is wound
    offset = np.einsum("ij,ij->i", n, v0 - c)  # > 0: c lies inside every face plane
    if np.any(offset <= 0):
        raise ValueError(f"clip_to_convex: center {c.tolist()} is not inside the hull {hull.name!r}")
    d = mesh.vertices - c
    reach = d @ n.T  # [V, F]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(reach > 0, offset[None] / reach, np.inf).min(axis=1)
    moved = t < 1.0
    vertices = mesh.vertices.copy()
    vertices[moved] = c + t[moved, None] * d[moved]
    keep = ~moved[mesh.faces].all(axis=1)
    return _without_unused_vertices(replace(mesh, vertices=vertices, faces=mesh.faces[keep],
                                            corner_uvs=None if mesh.corner_uvs is None else mesh.corner_uvs[keep]))


def plane(center=(0, 0, 0), half_size=4.0, material=None, name="ground", role="background") -> SyntheticMesh:
    """A square facing +z (visible from both sides: shading turns normals to the camera)."""
    h = float(half_size)
    V = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], float) + np.asarray(center, float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    return _part(name, V, np.tile([0, 0, 1.0], (4, 1)), F, uv[F], material or Material(), role)


# ----------------------------------------------------------------------------------------- files
def _read_mtl_texture(obj_path: Path, lines: list[str]) -> Path | None:
    for line in lines:
        if line.startswith("mtllib"):
            mtl = obj_path.parent / line.split(None, 1)[1].strip()
            if mtl.is_file():
                for m in mtl.read_text(errors="replace").splitlines():
                    if m.strip().startswith("map_Kd"):
                        return obj_path.parent / m.strip().split()[-1]
    return None


def load_textured_obj(obj_path, texture_path=None, name=None) -> SyntheticMesh:
    """Read an OBJ (``v``, ``vt``, ``f``; polygons fan-triangulated) with per-corner UVs and its texture.

    The texture comes from ``texture_path``, else the ``map_Kd`` of its ``mtllib``; without either the
    mesh gets a procedural material. Shading normals are area-weighted vertex normals.
    """
    from PIL import Image

    obj_path = Path(obj_path)
    if not obj_path.is_file():
        raise SceneError(f"mesh file {obj_path} does not exist")
    lines = obj_path.read_text(errors="replace").splitlines()
    v, vt, fv, ft = [], [], [], []
    try:
        for line in lines:
            tok = line.split()
            if not tok:
                continue
            if tok[0] == "v":
                v.append([float(x) for x in tok[1:4]])
            elif tok[0] == "vt":
                vt.append([float(x) for x in tok[1:3]])
            elif tok[0] == "f":
                corners = [c.split("/") for c in tok[1:]]
                iv = [int(c[0]) for c in corners]
                it = [int(c[1]) if len(c) > 1 and c[1] else 0 for c in corners]
                for k in range(1, len(corners) - 1):
                    fv.append([iv[0], iv[k], iv[k + 1]])
                    ft.append([it[0], it[k], it[k + 1]])
    except (ValueError, IndexError) as e:
        raise SceneError(f"mesh file {obj_path}: cannot parse line {line!r} ({e})") from None
    V = np.array(v, dtype=np.float64).reshape(-1, 3)
    fv, ft = np.array(fv, dtype=np.int64).reshape(-1, 3), np.array(ft, dtype=np.int64).reshape(-1, 3)
    F = np.where(fv < 0, fv + len(V), fv - 1)
    if len(F) == 0 or F.min() < 0 or F.max() >= len(V):
        raise SceneError(f"mesh file {obj_path}: no faces or face indices out of range")
    material = Material()
    uvs = None
    if vt and np.all(ft != 0):
        T = np.array(vt, dtype=np.float64)
        uvs = T[np.where(ft < 0, ft + len(T), ft - 1)]
        texture_path = Path(texture_path) if texture_path else _read_mtl_texture(obj_path, lines)
        if texture_path is not None:
            if not texture_path.is_file():
                raise SceneError(f"texture {texture_path} of mesh {obj_path} does not exist")
            with Image.open(texture_path) as im:
                tex = np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
            material = Material(kind="texture", color_a=(1.0, 1.0, 1.0), texture=tex)
    return SyntheticMesh(name=name or obj_path.stem, vertices=V, faces=F,
                         vertex_normals=smooth_vertex_normals(V, F), material=material, corner_uvs=uvs)


def fit_to_box(mesh: SyntheticMesh, size: float = 2.0, center=(0, 0, 0)) -> SyntheticMesh:
    """Scale uniformly and translate so the bounding box's longest side is ``size``, centred at ``center``."""
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    s = size / float((hi - lo).max())
    return mesh.transformed(None, np.asarray(center, float) - s * (lo + hi) / 2, s)
