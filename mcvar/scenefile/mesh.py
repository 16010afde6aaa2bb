"""Triangle meshes for scene files: OBJ and PLY readers and Mitsuba's built-in shapes (layer 3.5).

Every function returns triangles as an ``(T, 3, 3)`` float64 array of
vertex positions in the shape's own space (before ``to_world``), wound so
that ``cross(v1 - v0, v2 - v0)`` is the shape's outward (front) normal, as
:class:`mcvar.scene.Scene` expects.

* :func:`read_obj`: ``v`` and ``f`` statements (``f 1 2 3``, ``1/1``,
  ``1//1``, ``1/1/1``; negative indices count back from the last vertex);
  polygons are fan-triangulated ``(0, i, i + 1)``. ``vt``, ``vn``, ``o``,
  ``g``, ``s``, ``usemtl``, ``mtllib`` are read past (materials come from
  the XML; mcvar shades with face normals). Any other statement is an error
  naming its line.
* :func:`read_ply`: ``ascii 1.0``, ``binary_little_endian 1.0`` and
  ``binary_big_endian 1.0``; a ``vertex`` element with ``x, y, z`` and a
  ``face`` element with a list property ``vertex_indices`` (or
  ``vertex_index``); other properties and elements are read past.
* :func:`rectangle`, :func:`cube`, :func:`disk`: Mitsuba's ``rectangle``
  ([-1, 1]^2 in z = 0, normal +z, 2 triangles), ``cube`` ([-1, 1]^3, normals
  out, 12 triangles) and ``disk`` (unit disk in z = 0, normal +z) as
  triangles. The disk is a regular polygon of :data:`DISK_SEGMENTS` sides
  whose circumradius is chosen so that its *area* is exactly pi: an emitting
  disk keeps its power, and its outline is within ``5.1e-5`` of the unit
  circle at N = 256 (vertices ``(2 pi / N)^2 / 12`` outside, edge midpoints
  half that inside).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["MeshError", "read_obj", "read_ply", "read_mesh", "rectangle", "cube", "disk", "DISK_SEGMENTS",
           "split_by_checker", "CHECKER_MAX_TRIANGLES"]

#: Sides of the polygon that stands in for Mitsuba's analytic ``disk``.
DISK_SEGMENTS = 256


class MeshError(ValueError):
    """A mesh file mcvar cannot read (the message names the file and line)."""


# --------------------------------------------------------------------------
# built-in shapes (Mitsuba 3's rectangle, cube, disk)

def rectangle() -> np.ndarray:
    """Mitsuba's ``rectangle``: [-1, 1]^2 in z = 0, front +z, as triangles (0, 1, 2), (0, 2, 3)."""
    p = np.array([(-1.0, -1.0, 0.0), (1.0, -1.0, 0.0), (1.0, 1.0, 0.0), (-1.0, 1.0, 0.0)])
    return p[np.array([(0, 1, 2), (0, 2, 3)])]


def cube() -> np.ndarray:
    """Mitsuba's ``cube``: [-1, 1]^3, 6 faces of 2 triangles each, normals outward.

    Face ``k`` is triangles ``2k`` and ``2k + 1``; each face is the
    parallelogram ``(v0, v1, v2, v3)`` split as (0, 1, 2), (0, 2, 3).
    """
    faces = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u, v = (axis + 1) % 3, (axis + 2) % 3
            quad = np.zeros((4, 3))
            quad[:, axis] = sign
            # (u, v) corners counter-clockwise seen from outside the face
            corners = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
            if sign < 0:
                corners = corners[::-1]
            for i, (a, b) in enumerate(corners):
                quad[i, u], quad[i, v] = a, b
            faces.append(quad[np.array([(0, 1, 2), (0, 2, 3)])])
    tris = np.concatenate(faces)
    return tris


def disk(segments: int = DISK_SEGMENTS) -> np.ndarray:
    """The unit disk in z = 0 (front +z) as a fan of ``segments`` triangles of total area pi."""
    n = int(segments)
    radius = math.sqrt(math.pi / (0.5 * n * math.sin(2.0 * math.pi / n)))
    phi = 2.0 * math.pi * np.arange(n + 1) / n
    ring = np.stack([radius * np.cos(phi), radius * np.sin(phi), np.zeros(n + 1)], axis=1)
    tris = np.empty((n, 3, 3))
    tris[:, 0] = 0.0
    tris[:, 1] = ring[:-1]
    tris[:, 2] = ring[1:]
    return tris


# --------------------------------------------------------------------------
# OBJ

_OBJ_SKIP = {"vt", "vn", "vp", "o", "g", "s", "usemtl", "mtllib"}


def read_obj(path) -> np.ndarray:
    """Triangles ``(T, 3, 3)`` of a Wavefront OBJ file (see the module docstring).

    Examples
    --------
    >>> import tempfile, os
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = os.path.join(d, "quad.obj")
    ...     _ = open(p, "w").write("v 0 0 0\\nv 1 0 0\\nv 1 1 0\\nv 0 1 0\\nf 1 2 3 4\\n")
    ...     read_obj(p).shape
    (2, 3, 3)
    """
    path = Path(path)
    text = _read_text(path)
    vertices, faces = [], []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        key, *rest = line.split()
        if key == "v":
            if len(rest) < 3:
                raise MeshError(f"{path}:{lineno}: 'v' needs x y z; got {raw.strip()!r}")
            try:
                vertices.append([float(x) for x in rest[:3]])
            except ValueError:
                raise MeshError(f"{path}:{lineno}: 'v' coordinates are not numbers: {raw.strip()!r}") from None
        elif key == "f":
            if len(rest) < 3:
                raise MeshError(f"{path}:{lineno}: a face needs at least 3 vertices; got {raw.strip()!r}")
            idx = []
            for item in rest:
                head = item.split("/", 1)[0]
                try:
                    i = int(head)
                except ValueError:
                    raise MeshError(f"{path}:{lineno}: face index {item!r} is not an integer") from None
                n = len(vertices)
                j = i - 1 if i > 0 else n + i
                if i == 0 or not 0 <= j < n:
                    raise MeshError(f"{path}:{lineno}: face index {i} refers to no vertex "
                                    f"({n} defined above this line)")
                idx.append(j)
            for k in range(1, len(idx) - 1):
                faces.append((idx[0], idx[k], idx[k + 1]))
        elif key in _OBJ_SKIP:
            continue
        else:
            raise MeshError(f"{path}:{lineno}: OBJ statement {key!r} is not supported "
                            f"(supported: v, f; read past: {', '.join(sorted(_OBJ_SKIP))})")
    if not faces:
        raise MeshError(f"{path}: no faces ('f' statements)")
    return np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]


# --------------------------------------------------------------------------
# PLY

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def _ply_header(data: bytes, path: Path):
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise MeshError(f"{path}: not a PLY file (no 'ply' magic line or no 'end_header')")
    nl = data.find(b"\n", end)
    body = nl + 1 if nl >= 0 else len(data)
    header = data[:end].decode("ascii", errors="replace").splitlines()
    fmt, elements = None, []
    for lineno, line in enumerate(header, start=1):
        words = line.split()
        if not words or words[0] in ("ply", "comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) < 2 or words[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise MeshError(f"{path}:{lineno}: PLY format {line.strip()!r} is not supported "
                                "(ascii, binary_little_endian, binary_big_endian)")
            fmt = words[1]
        elif words[0] == "element":
            try:
                elements.append([words[1], int(words[2]), []])
            except (IndexError, ValueError):
                raise MeshError(f"{path}:{lineno}: malformed element line {line.strip()!r}") from None
        elif words[0] == "property":
            if not elements:
                raise MeshError(f"{path}:{lineno}: property before any element")
            try:
                if words[1] == "list":
                    prop = (words[4], _PLY_TYPES[words[2]], _PLY_TYPES[words[3]])
                else:
                    prop = (words[2], None, _PLY_TYPES[words[1]])
            except (IndexError, KeyError):
                raise MeshError(f"{path}:{lineno}: malformed or unknown property type {line.strip()!r}") from None
            elements[-1][2].append(prop)
        else:
            raise MeshError(f"{path}:{lineno}: unknown PLY header line {line.strip()!r}")
    if fmt is None:
        raise MeshError(f"{path}: PLY header has no 'format' line")
    return fmt, elements, body


_UV_NAMES = (("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))


def read_ply(path, *, uv: bool = False):
    """Triangles ``(T, 3, 3)`` of a PLY file (see the module docstring); polygons fan-triangulated.

    With ``uv=True`` returns ``(triangles, uv)``, ``uv`` of shape ``(T, 3, 2)``
    from the vertex properties ``u, v`` (or ``s, t``, ``texture_u,
    texture_v``), None when the file has none.
    """
    path = Path(path)
    data = _read_bytes(path)
    fmt, elements, body = _ply_header(data, path)
    names = [e[0] for e in elements]
    if "vertex" not in names or "face" not in names:
        raise MeshError(f"{path}: a PLY mesh needs 'vertex' and 'face' elements; got {names}")
    if fmt == "ascii":
        tokens = data[body:].split()
        pos = 0
        parsed = {}
        for name, count, props in elements:
            rows = []
            for _ in range(count):
                row = []
                for pname, ltype, vtype in props:
                    if ltype is not None:
                        k = int(tokens[pos]); pos += 1
                        row.append([float(t) for t in tokens[pos:pos + k]]); pos += k
                    else:
                        row.append(float(tokens[pos])); pos += 1
                rows.append(row)
            if pos > len(tokens):
                raise MeshError(f"{path}: PLY body ends before element {name!r} is complete")
            parsed[name] = (props, rows)
        vprops, vrows = parsed["vertex"]
        col = {p[0]: i for i, p in enumerate(vprops)}
        _need_xyz(col, path)
        verts = np.array([[r[col["x"]], r[col["y"]], r[col["z"]]] for r in vrows], dtype=np.float64)
        names = next((pair for pair in _UV_NAMES if set(pair) <= set(col)), None)
        coords = None if names is None else np.array([[r[col[names[0]]], r[col[names[1]]]] for r in vrows],
                                                     dtype=np.float64)
        fprops, frows = parsed["face"]
        fcol = _face_column(fprops, path)
        polys = [[int(i) for i in r[fcol]] for r in frows]
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        pos = body
        verts = polys = coords = None
        for name, count, props in elements:
            if all(p[1] is None for p in props):
                dtype = np.dtype([(p[0], order + p[2]) for p in props])
                need = dtype.itemsize * count
                if pos + need > len(data):
                    raise MeshError(f"{path}: PLY body ends before element {name!r} is complete")
                arr = np.frombuffer(data, dtype=dtype, count=count, offset=pos)
                pos += need
                if name == "vertex":
                    _need_xyz(arr.dtype.names, path)
                    verts = np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(np.float64)
                    names = next((pair for pair in _UV_NAMES if set(pair) <= set(arr.dtype.names)), None)
                    if names is not None:
                        coords = np.stack([arr[names[0]], arr[names[1]]], axis=1).astype(np.float64)
            else:
                rows, pos = _binary_lists(data, pos, count, props, order, path, name)
                if name == "face":
                    polys = rows[_face_column(props, path)]
                elif name == "vertex":
                    raise MeshError(f"{path}: list properties in 'vertex' are not supported")
    faces = []
    n = verts.shape[0]
    for k, poly in enumerate(polys):
        poly = [int(i) for i in poly]
        if len(poly) < 3 or min(poly) < 0 or max(poly) >= n:
            raise MeshError(f"{path}: face {k} {poly} needs >= 3 indices into the {n} vertices")
        faces.extend((poly[0], poly[i], poly[i + 1]) for i in range(1, len(poly) - 1))
    if not faces:
        raise MeshError(f"{path}: no faces")
    index = np.asarray(faces, dtype=np.int64)
    if uv:
        return verts[index], (None if coords is None else coords[index])
    return verts[index]


def _binary_lists(data, pos, count, props, order, path, name):
    """Rows of a binary element with list properties: the fast path when every
    list has the length of the first (all triangles), else one row at a time."""
    cols = [[] for _ in props]
    # fast path: constant list lengths
    first = pos
    dtype_fields, lengths = [], []
    try:
        for pname, ltype, vtype in props:
            if ltype is None:
                dtype_fields.append((pname, order + vtype))
                first += np.dtype(vtype).itemsize
            else:
                k = int(np.frombuffer(data, dtype=order + ltype, count=1, offset=first)[0])
                dtype_fields += [(pname + "#n", order + ltype), (pname, order + vtype, (k,))]
                first += np.dtype(ltype).itemsize + k * np.dtype(vtype).itemsize
                lengths.append((pname + "#n", k))
        dtype = np.dtype(dtype_fields)
        if count == 0 or pos + dtype.itemsize * count <= len(data):
            arr = np.frombuffer(data, dtype=dtype, count=count, offset=pos)
            if all(np.all(arr[field] == k) for field, k in lengths):
                return [arr[p[0]] for p in props], pos + dtype.itemsize * count
    except (ValueError, IndexError):
        pass
    for _ in range(count):
        for c, (pname, ltype, vtype) in enumerate(props):
            try:
                if ltype is None:
                    v = np.frombuffer(data, dtype=order + vtype, count=1, offset=pos)[0]
                    pos += np.dtype(vtype).itemsize
                else:
                    k = int(np.frombuffer(data, dtype=order + ltype, count=1, offset=pos)[0])
                    pos += np.dtype(ltype).itemsize
                    v = np.frombuffer(data, dtype=order + vtype, count=k, offset=pos)
                    pos += k * np.dtype(vtype).itemsize
            except ValueError:
                raise MeshError(f"{path}: PLY body ends before element {name!r} is complete") from None
            cols[c].append(v)
    return cols, pos


def _need_xyz(names, path):
    if not {"x", "y", "z"} <= set(names or ()):
        raise MeshError(f"{path}: PLY 'vertex' needs x, y, z properties; got {list(names or ())}")


def _face_column(props, path):
    for i, p in enumerate(props):
        if p[0] in ("vertex_indices", "vertex_index") and p[1] is not None:
            return i
    raise MeshError(f"{path}: PLY 'face' needs a list property vertex_indices; got {[p[0] for p in props]}")


def read_mesh(path) -> np.ndarray:
    """:func:`read_obj` or :func:`read_ply` by the file's suffix."""
    suffix = Path(path).suffix.lower()
    if suffix == ".obj":
        return read_obj(path)
    if suffix == ".ply":
        return read_ply(path)
    raise MeshError(f"{path}: mesh files must be .obj or .ply; got {suffix!r}")


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise MeshError(f"{path}: cannot read the mesh file ({exc.strerror or exc})") from None


def _read_text(path: Path) -> str:
    return _read_bytes(path).decode("utf-8", errors="replace")



# --------------------------------------------------------------------------
# a checkerboard texture as geometry

#: Most triangles one shape may be cut into by a checkerboard reflectance.
CHECKER_MAX_TRIANGLES = 200_000


def _split(poly, axis, c):
    """Cut a convex polygon (list of (position, g) pairs) by the line g[axis] = c: (below, above)."""
    below, above = [], []
    n = len(poly)
    for k in range(n):
        p, q = poly[k], poly[(k + 1) % n]
        sp, sq = p[1][axis] - c, q[1][axis] - c
        if sp <= 0:
            below.append(p)
        if sp >= 0:
            above.append(p)
        if (sp < 0 < sq) or (sq < 0 < sp):
            t = sp / (sp - sq)
            cut = (p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1]))
            below.append(cut)
            above.append(cut)
    return below, above


def split_by_checker(tris, g):
    """Cut triangles along the lines of a checkerboard so that every piece lies in one square.

    Parameters
    ----------
    tris : ndarray, shape (T, 3, 3)
        World positions.
    g : ndarray, shape (T, 3, 2)
        Each vertex's texture coordinates in units of one square (``2 (u', v')``
        for Mitsuba's checkerboard, whose squares are half a unit of ``u', v'``).
        They are interpolated linearly across each triangle, so cutting along
        ``g = integer`` and fan-triangulating the convex pieces is exact.

    Returns
    -------
    pieces : ndarray, shape (P, 3, 3)
        Triangles wound as the triangle they were cut from.
    square : ndarray of int, shape (P, 2)
        ``floor(g)`` of each piece: the square it lies in.
    """
    tris = np.asarray(tris, dtype=np.float64)
    g = np.asarray(g, dtype=np.float64)
    lo, hi = np.floor(g.min(axis=1)), np.ceil(g.max(axis=1))
    cells = np.prod(np.maximum(hi - lo, 1.0), axis=1)
    if 2.0 * cells.sum() > CHECKER_MAX_TRIANGLES:
        raise ValueError(f"the checkerboard would cut the shape into about {int(2 * cells.sum())} triangles "
                         f"(more than {CHECKER_MAX_TRIANGLES}): use fewer, larger squares")
    inside = np.all(hi - lo <= 1.0, axis=1)
    pieces = [tris[inside]]
    squares = [lo[inside].astype(np.int64)]
    for t in np.flatnonzero(~inside):
        polys = [[(tris[t, k], g[t, k]) for k in range(3)]]
        for axis in (0, 1):
            for c in range(int(lo[t, axis]) + 1, int(hi[t, axis])):
                cut = []
                for poly in polys:
                    below, above = _split(poly, axis, float(c))
                    cut += [p for p in (below, above) if len(p) >= 3]
                polys = cut
        for poly in polys:
            centre = np.mean([v[1] for v in poly], axis=0)
            for k in range(1, len(poly) - 1):
                pieces.append(np.array([[poly[0][0], poly[k][0], poly[k + 1][0]]]))
                squares.append(np.floor(centre)[None].astype(np.int64))
    out = np.concatenate(pieces)
    square = np.concatenate(squares)
    area2 = np.linalg.norm(np.cross(out[:, 1] - out[:, 0], out[:, 2] - out[:, 0]), axis=1)
    keep = area2 > 1e-14 * max(float(area2.max(initial=0.0)), 1e-300)
    return out[keep], square[keep]
