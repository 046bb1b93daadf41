"""Minimal, strict PLY vertex-table reader/writer (numpy only).

Used for 3D Gaussian Splatting point clouds, whose PLY files are one ``vertex`` element with many
scalar float properties. Reads ``binary_little_endian``, ``binary_big_endian`` and ``ascii``; writes
``binary_little_endian``. Every malformed input (bad header, unknown type, truncated data, list
properties where scalars are expected) raises :class:`~gof_warp.core.errors.PlyError` naming the file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .arrays import check_triangles
from .errors import PlyError
from .io_utils import atomic_path

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_MAX_HEADER_BYTES = 1 << 20


def _parse_header(path: Path, f):
    first = f.readline()
    if first.strip() != b"ply":
        raise PlyError(f"{path}: not a PLY file (first line is {first[:40]!r}, expected 'ply')")
    fmt = None
    elements = []  # [name, count, [(prop_name, dtype)]]
    consumed = len(first)
    while True:
        line = f.readline()
        consumed += len(line)
        if not line:
            raise PlyError(f"{path}: PLY header ends before 'end_header' (file truncated?)")
        if consumed > _MAX_HEADER_BYTES:
            raise PlyError(f"{path}: PLY header is larger than 1 MiB (corrupt file?)")
        words = line.decode("ascii", errors="replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        if words[0] == "format":
            if len(words) < 2 or words[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise PlyError(f"{path}: unsupported PLY format line {line.strip()!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise PlyError(f"{path}: malformed element line {line.strip()!r}")
            elements.append([words[1], int(words[2]), []])
        elif words[0] == "property":
            if not elements:
                raise PlyError(f"{path}: property before any element")
            if words[1] == "list":
                elements[-1][2].append((words[-1], None))  # list property: only allowed in skipped elements
            else:
                if len(words) != 3 or words[1] not in _PLY_TYPES:
                    raise PlyError(f"{path}: unsupported property line {line.strip()!r}")
                elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        else:
            raise PlyError(f"{path}: unexpected PLY header line {line.strip()!r}")
    if fmt is None:
        raise PlyError(f"{path}: PLY header has no format line")
    return fmt, elements


def read_ply_vertices(path) -> dict[str, np.ndarray]:
    """Read the ``vertex`` element of a PLY file into ``{property_name: [N] array}``.

    The vertex element must come first and hold scalar properties only (true of every 3DGS file).
    """
    path = Path(path)
    if not path.is_file():
        raise PlyError(f"{path}: file not found")
    try:
        with open(path, "rb") as f:
            fmt, elements = _parse_header(path, f)
            if not elements or elements[0][0] != "vertex":
                raise PlyError(f"{path}: the first PLY element must be 'vertex'")
            _, n, props = elements[0]
            if any(dt is None for _, dt in props):
                raise PlyError(f"{path}: vertex element has list properties; expected scalar properties only")
            names = [p for p, _ in props]
            if len(set(names)) != len(names):
                raise PlyError(f"{path}: duplicate vertex property names")
            if fmt == "ascii":
                have = path.stat().st_size - f.tell()
                if n * 2 * len(props) > have:  # each value needs a digit and a separator
                    raise PlyError(f"{path}: truncated: the header claims {n} vertices of {len(props)} values but the "
                                   f"file holds {have} bytes after its header")
                rows = []
                for i in range(n):
                    line = f.readline()
                    vals = line.split()
                    if len(vals) != len(props):
                        raise PlyError(f"{path}: vertex {i} has {len(vals)} values, expected {len(props)} (truncated?)")
                    rows.append(vals)
                table = np.array(rows, dtype=np.float64).reshape(n, len(props))
                return {p: table[:, k].astype(dt) for k, (p, dt) in enumerate(props)}
            endian = "<" if fmt == "binary_little_endian" else ">"
            dtype = np.dtype([(p, endian + dt) for p, dt in props])
            need = n * dtype.itemsize
            have = path.stat().st_size - f.tell()
            if need > have:  # before reading: a header claiming 1e13 vertices must not allocate for them
                raise PlyError(f"{path}: truncated: the header claims {n} vertices ({need} bytes of vertex data) but "
                               f"the file holds {have} bytes after its header")
            data = f.read(need)
            if len(data) != need:
                raise PlyError(f"{path}: truncated: expected {need} bytes of vertex data for {n} vertices, found {len(data)}")
            arr = np.frombuffer(data, dtype=dtype)
            return {p: arr[p].astype(arr[p].dtype.newbyteorder("=")) for p in names}
    except PlyError:
        raise
    except (OSError, ValueError) as e:
        raise PlyError(f"{path}: cannot read PLY: {e}") from None


def write_ply_vertices(path, columns: dict[str, np.ndarray]) -> None:
    """Write ``{name: [N] array}`` as a binary little-endian PLY vertex table, atomically."""
    names = list(columns)
    if not names:
        raise PlyError(f"{path}: nothing to write")
    n = len(next(iter(columns.values())))
    inv = {v: k for k, v in _PLY_TYPES.items() if k in ("char", "uchar", "short", "ushort", "int", "uint", "float", "double")}
    fields, header = [], ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    for name in names:
        a = np.asarray(columns[name])
        if a.shape != (n,):
            raise PlyError(f"{path}: column {name!r} has shape {a.shape}, expected ({n},)")
        code = a.dtype.str[1:]
        if code not in inv:
            a = a.astype(np.float32)
            code = "f4"
        fields.append((name, "<" + code))
        header.append(f"property {inv[code]} {name}")
    header.append("end_header")
    table = np.empty(n, dtype=np.dtype(fields))
    for name in names:
        table[name] = columns[name]
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(("\n".join(header) + "\n").encode("ascii"))
            f.write(table.tobytes())


def write_ply_mesh(path, vertices, faces, colours=None) -> None:
    """Write a triangle mesh as a binary little-endian PLY, atomically: ``vertices`` ``[V, 3]`` (stored as float32
    ``x y z``), ``faces`` ``[F, 3]`` vertex indices (a ``uchar`` count and three ``int`` per face, the layout every
    mesh tool reads), and optional ``colours`` ``[V, 3]`` uint8 (``uchar red green blue`` after each vertex's
    position). Raises :class:`~gof_warp.core.errors.PlyError` for wrong shapes or indices outside the vertices."""
    v, f = check_triangles(vertices, faces, path, PlyError)
    if len(v) > np.iinfo(np.int32).max:
        raise PlyError(f"{path}: {len(v)} vertices do not fit PLY int indices")
    colour_props = []
    if colours is None:
        vertex_bytes = np.ascontiguousarray(v, dtype="<f4").tobytes()
    else:
        c = np.asarray(colours)
        if c.shape != (len(v), 3) or c.dtype != np.uint8:
            raise PlyError(f"{path}: vertex colours must be uint8 [{len(v)}, 3], got {c.dtype} {list(c.shape)}")
        table = np.empty(len(v), dtype=np.dtype([("p", "<f4", (3,)), ("c", "u1", (3,))]))
        table["p"], table["c"] = v, c
        vertex_bytes = table.tobytes()
        colour_props = ["property uchar red", "property uchar green", "property uchar blue"]
    header = ["ply", "format binary_little_endian 1.0", "comment written by gof_warp", f"element vertex {len(v)}",
              "property float x", "property float y", "property float z", *colour_props, f"element face {len(f)}",
              "property list uchar int vertex_indices", "end_header"]
    table = np.empty(len(f), dtype=np.dtype([("n", "u1"), ("i", "<i4", (3,))]))
    table["n"] = 3
    table["i"] = f
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as out:
            out.write(("\n".join(header) + "\n").encode("ascii"))
            out.write(vertex_bytes)
            out.write(table.tobytes())
