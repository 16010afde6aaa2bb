"""Convex shells: a closed convex polyhedron's triangles hit by half-spaces (layer 3, beside :mod:`mcvar.bvh`).

A room or a box whose triangles bound a convex polyhedron (open faces such as
the Cornell room's front or a block's bottom allowed) is intersected without
testing its triangles: the polyhedron is the intersection of its faces'
half-spaces ``n_p . x <= c_p``, so a ray ``o + t d`` is inside it exactly for
``t`` in ``[t_near, t_far]``, the largest entering and the smallest leaving
plane distance (the slab method of Kay and Kajiya 1986, for any convex
polyhedron: Haines 1991, 'Fast ray-convex polyhedron intersection', Graphics
Gems II). One small matrix product gives every plane's distance for a chunk
of rays, two reductions give ``t_near`` and ``t_far``, and the face is the
plane that attains them; a face of two triangles (a quad) is resolved by the
side of its diagonal. Shells of one kind are stacked (:class:`ShellStack`) so
that one product serves all of them. On the Cornell box (the room, 7 planes
with its open front; the two blocks, 6 each with their open bottoms) this
made `render_adaptive` 9-17 % faster than the triangle groups with their boxes in interleaved renders (1-8 % per path in the suite)
(docs/performance.md, 'Convex shells'); shadow rays keep the groups' boxes,
which most of them miss.

:func:`find_shell` accepts a set of triangles only when this is exact: the
triangles are convex (every vertex on the inner side of every triangle's
plane), each plane holds one triangle or two sharing an edge, the open edges
form planar holes, and the polyhedron of all these planes
(``scipy.spatial.HalfspaceIntersection``) has exactly the triangles' vertices
and, on every plane, a face whose area the plane's triangles (or its hole)
cover. A point of the polyhedron's boundary then lies on a triangle unless it
lies in a hole, so the first boundary crossing beyond ``epsilon`` that is not
in a hole is the closest triangle hit of the whole set.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ConvexShell", "ShellStack", "find_shell", "shell_hits", "MAX_PLANES", "SHELL_SLICE"]

#: Largest number of planes (faces and holes) a shell may have: the test costs
#: O(planes) per ray, so a finely tessellated convex object stays with the BVH.
MAX_PLANES = 24
_TINY = np.float32(1e-30)
_INF = np.float32(np.inf)
#: Rays per slice of :meth:`mcvar.tracer.Tracer`'s closest-hit loop over shells:
#: measured on a 128 x 128 render's own rays (best of 6, ns a ray): 2048 rays
#: 164, 4096 142, 8192 133, 16384 180 (the slice's temporaries leave the cache).
SHELL_SLICE = 8192


@dataclass(frozen=True, eq=False)
class ConvexShell:
    """The planes of one convex polyhedron, as row tables for the ray kernels.

    Attributes
    ----------
    w_rows : ndarray, shape (P, 4)
        ``[-n_p, c_p]``: ``w_rows @ [o; 1] = c_p - n_p . o``, positive inside.
    n_rows : ndarray, shape (P, 3)
        Outward unit normals ``n_p``.
    code : ndarray of uint8, shape (P, 1)
        1 + the plane's index in the tracer's face tables for a face, 0 for a hole.
    prims : ndarray of int64, shape (P, 2)
        The face's triangles (``-1`` in the second column for a one-triangle face).
    diagonal : ndarray, shape (P, 4)
        ``[m, -m . a]`` of the face's diagonal ``a b``: ``m . x - m . a >= 0`` on
        the side of ``prims[p, 0]`` (zero rows for one-triangle faces).
    tol : float
        Slack of the inside test at the entry point (float32 rounding of the
        plane distances).
    """

    w_rows: np.ndarray
    n_rows: np.ndarray
    code: np.ndarray
    prims: np.ndarray
    diagonal: np.ndarray
    tol: float

    @property
    def n_planes(self) -> int:
        return self.w_rows.shape[0]


def _plane_of(points, tol):
    """Unit normal and offset of the best plane through ``points``, or None if not planar."""
    mean = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - mean)
    n = vt[2]
    c = float(n @ mean)
    if np.abs(points @ n - c).max() > tol:
        return None
    return n, c


def _polygon_area(points, n):
    """Area of the convex hull of coplanar ``points`` with normal ``n``."""
    from scipy.spatial import ConvexHull
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    uv = np.stack([points @ u, points @ v], axis=1)
    if uv.shape[0] < 3:
        return 0.0
    try:
        return float(ConvexHull(uv).volume)
    except Exception:            # collinear (qhull raises its own error type)
        return 0.0


def find_shell(triangles, idx, *, first_code: int = 1, dtype=np.float32) -> ConvexShell | None:
    """The convex shell of the triangles ``triangles[idx]``, or None where the shell test would not be exact.

    Parameters
    ----------
    triangles : ndarray, shape (T, 3, 3)
        All of the scene's triangles.
    idx : array_like of int
        The candidate set (a connected group of triangles).
    first_code : int
        Code of the shell's first face in the tracer's face tables (1-based).
    dtype : numpy dtype
        Precision of the ray kernels.

    Returns
    -------
    ConvexShell or None
        None unless every condition of the module's description holds, or
        when the shell would have more than :data:`MAX_PLANES` planes or
        ``first_code`` + its faces would not fit a uint8 code.
    """
    from scipy.spatial import HalfspaceIntersection
    idx = np.asarray(idx, dtype=np.int64)
    tri = np.asarray(triangles, dtype=np.float64)[idx]
    if idx.size < 4:
        return None
    verts = tri.reshape(-1, 3)
    scale = max(1.0, float(np.abs(verts).max()))
    tol = 1e-9 * scale
    centre = verts.mean(axis=0)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    c = np.einsum("ij,ij->i", n, tri[:, 0])
    flip = n @ centre - c > 0
    n[flip] *= -1.0
    c[flip] *= -1.0
    if np.any(verts @ n.T - c > tol):
        return None                                  # not convex
    # faces: coplanar triangles
    faces = []                                       # [normal, offset, local triangle indices]
    for i in range(idx.size):
        for f in faces:
            if abs(n[i] @ f[0] - 1.0) < 1e-12 and abs(c[i] - f[1]) < tol:
                f[2].append(i)
                break
        else:
            faces.append([n[i], c[i], [i]])
    if any(len(f[2]) > 2 for f in faces):
        return None
    # edges by vertex keys: interior edges are shared by exactly two triangles
    keys = np.round(verts / tol).astype(np.int64).reshape(-1, 3, 3)
    edges = {}
    for i in range(idx.size):
        for a, b in ((0, 1), (1, 2), (2, 0)):
            e = tuple(sorted((tuple(keys[i, a]), tuple(keys[i, b]))))
            edges.setdefault(e, []).append((i, a, b))
    if any(len(v) > 2 for v in edges.values()):
        return None
    # holes: loops of open edges, each planar
    open_edges = [(v[0][0], v[0][1], v[0][2]) for v in edges.values() if len(v) == 1]
    holes = []
    if open_edges:
        ends = {}
        for k, (i, a, b) in enumerate(open_edges):
            for v in (a, b):
                ends.setdefault(tuple(keys[i, v]), []).append(k)
        seen = np.zeros(len(open_edges), dtype=bool)
        for k0 in range(len(open_edges)):
            if seen[k0]:
                continue
            loop, stack = [], [k0]
            while stack:                              # the open edges connected to k0
                k = stack.pop()
                if seen[k]:
                    continue
                seen[k] = True
                i, a, b = open_edges[k]
                loop += [tri[i, a], tri[i, b]]
                for v in (a, b):
                    stack += ends[tuple(keys[i, v])]
            pts = np.array(loop)
            plane = _plane_of(pts, tol)
            if plane is None:
                return None
            hn, hc = plane
            if hn @ centre - hc > 0:
                hn, hc = -hn, -hc
            holes.append([hn, hc, []])
    planes = faces + holes
    for h in holes:
        if any(abs(h[0] @ f[0] - 1.0) < 1e-12 and abs(h[1] - f[1]) < tol for f in faces):
            return None                              # a hole in the plane of a face
    if len(planes) > MAX_PLANES or first_code + len(faces) > 255:
        return None
    normals = np.array([p[0] for p in planes])
    offsets = np.array([p[1] for p in planes])
    try:
        hs = HalfspaceIntersection(np.concatenate([normals, -offsets[:, None]], axis=1), centre)
    except Exception:            # unbounded or no interior (qhull's own error type)
        return None
    hull = hs.intersections
    d = np.linalg.norm(hull[:, None] - verts[None], axis=2)
    if d.min(axis=1).max() > 1e3 * tol or d.min(axis=0).max() > 1e3 * tol:
        return None                                  # the polyhedron has other corners
    for p in planes:
        on = hull[np.abs(hull @ p[0] - p[1]) < 1e3 * tol]
        face_area = _polygon_area(on, p[0])
        if p[2]:
            covered = sum(0.5 * np.linalg.norm(np.cross(tri[i, 1] - tri[i, 0], tri[i, 2] - tri[i, 0])) for i in p[2])
            if abs(covered - face_area) > 1e-9 * max(face_area, 1.0) * 10:
                return None                          # a face with an uncovered part
    prims = np.full((len(planes), 2), -1, dtype=np.int64)
    diagonal = np.zeros((len(planes), 4))
    code = np.zeros((len(planes), 1), dtype=np.uint8)
    for k, p in enumerate(planes):
        if not p[2]:
            continue
        code[k, 0] = first_code + k
        prims[k, :len(p[2])] = idx[p[2]]
        if len(p[2]) == 2:
            i, j = p[2]
            shared = [v for v in range(3) if any((keys[i, v] == keys[j, w]).all() for w in range(3))]
            if len(shared) != 2:
                return None                          # two triangles of a plane not sharing an edge
            a, b = tri[i, shared[0]], tri[i, shared[1]]
            third = tri[i, 3 - shared[0] - shared[1]]
            m = np.cross(p[0], b - a)
            m /= np.linalg.norm(m)
            if m @ (third - a) < 0:
                m = -m
            diagonal[k] = [m[0], m[1], m[2], -m @ a]
    w_rows = np.concatenate([-normals, offsets[:, None]], axis=1)
    # float32 plane distances of points within `scale`: a few roundings of scale
    eps32 = float(np.finfo(dtype).eps)
    return ConvexShell(np.ascontiguousarray(w_rows, dtype=dtype), np.ascontiguousarray(normals, dtype=dtype),
                       code, prims, diagonal, 16.0 * eps32 * scale)


@dataclass(frozen=True, eq=False)
class ShellStack:
    """Shells of one kind stacked for one matrix product: ``B`` shells of ``P`` planes.

    Shells with fewer planes repeat their last plane (a repeated half-space
    changes no bound). ``rows`` planes in all; ``code`` is (B, P, 1).
    """

    w_rows: np.ndarray
    n_rows: np.ndarray
    code: np.ndarray
    tol: float
    shape: tuple

    @classmethod
    def of(cls, shells):
        p = max(sh.n_planes for sh in shells)
        pad = lambda a: np.concatenate([a, np.repeat(a[-1:], p - a.shape[0], axis=0)])
        return cls(np.ascontiguousarray(np.concatenate([pad(sh.w_rows) for sh in shells])),
                   np.ascontiguousarray(np.concatenate([pad(sh.n_rows) for sh in shells])),
                   np.stack([pad(sh.code) for sh in shells]),
                   max(sh.tol for sh in shells), (len(shells), p))


def _argmax_code(values, best, code):
    """The ``code`` of the plane attaining ``best`` per shell and ray (the largest code on a tie).

    ``values`` (B, P, m), ``best`` (B, m), ``code`` (B, P, 1): (B, m) uint8.
    (Boolean times code and a maximum: NumPy's argmax over a short axis is
    several times slower.)"""
    eq = values == best[:, None, :]
    eq = eq.view(np.uint8)
    eq *= code
    return eq.max(axis=1)


def _leave(stack: ShellStack, w, s, eps, t0=None):
    """Where rays whose origin (or entry point, at ``t0``) is inside leave: ``(t, code)``, (B, m).

    ``t0 + min over s_p > 0 of w_p / s_p`` is ``t0 + 1 / max_p (s_p / w_p)``:
    one division, one reduction, no masks (entering planes give s / w < 0)."""
    r = s / np.maximum(w, _TINY)
    rmax = r.max(axis=1)
    code = _argmax_code(r, rmax, stack.code)
    with np.errstate(divide="ignore"):
        t = 1 / rmax
    if t0 is not None:
        t += t0
    ok = code > 0
    ok &= rmax > 0
    ok &= t > eps
    return np.where(ok, t, _INF if t.dtype == np.float32 else np.inf), code * ok


def _enter(stack: ShellStack, w, s, eps):
    """First face crossing of rays whose origin is outside: ``(t, code)``, (B, m); overwrites ``w``."""
    # entering planes (s < 0) bound t from below by w / s; the others give
    # -huge where w > 0 (no bound) and +huge where w < 0 (outside and not
    # coming in: no t inside, so the entry point below is outside)
    t_lo = w / np.minimum(s, -_TINY)
    tn = t_lo.max(axis=1)
    w -= tn[:, None, :] * s                          # distances from the entry point
    inside = w.min(axis=1) >= -stack.tol            # the line meets the polyhedron
    ahead = inside & (tn > eps)
    code = _argmax_code(t_lo, tn, stack.code)
    code *= ahead
    hit = code > 0
    t = np.where(hit, tn, _INF if tn.dtype == np.float32 else np.inf)
    rest = inside & ~hit                            # in through a hole, or at the origin
    if rest.any():
        t2, c2 = _leave(stack, w, s, eps, np.maximum(tn, 0))
        np.copyto(t, t2, where=rest)
        np.copyto(code, c2, where=rest)
    return t, code


def shell_hits(stack: ShellStack, o4, d, eps):
    """First face of the stack's shells that each ray crosses beyond ``eps``.

    Parameters
    ----------
    stack : ShellStack
    o4 : ndarray, shape (4, m)
        Homogeneous origins in the stack's dtype.
    d : ndarray, shape (3, m)
        Unit directions.
    eps : float
        Crossings at ``t <= eps`` are ignored (self-intersection).

    Returns
    -------
    t : ndarray, shape (m,)
        inf where no face is crossed.
    code : ndarray of uint8, shape (m,)
        The face's code, 0 for none; among shells crossed at the same
        distance, the largest code.
    """
    b, p = stack.shape
    m = o4.shape[1]
    w = (stack.w_rows @ o4).reshape(b, p, m)
    s = (stack.n_rows @ d).reshape(b, p, m)
    out = w.min(axis=1) < 0                         # origin outside some plane: (B, m)
    n_out = int(np.count_nonzero(out))
    if n_out == 0:
        t, code = _leave(stack, w, s, eps)
    elif n_out == out.size:
        t, code = _enter(stack, w, s, eps)
    else:                                           # both kernels, each where it applies
        t, code = _leave(stack, w, s, eps)
        t_in, c_in = _enter(stack, w, s, eps)
        np.copyto(t, t_in, where=out)
        np.copyto(code, c_in, where=out)
    if b == 1:
        return t[0], code[0]
    best = t.min(axis=0)
    code *= t == best
    return best, code.max(axis=0)
