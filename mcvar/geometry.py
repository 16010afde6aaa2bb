"""Vectors, spherical coordinates and shading frames (layer 1).

The lecture's *surface-local space* ('Change of Syntax' slide): the normal is
``n = (0, 1, 0)`` and both ``wi`` and ``wo`` point away from the surface. A
direction's polar angle ``theta`` is measured from +y, its azimuth ``phi`` from
+x towards +z::

    v = (sin(theta) cos(phi), cos(theta), sin(theta) sin(phi))

Everything here works on arrays with coordinates on the last axis, shape
``(..., 3)``, in float64.
"""
from __future__ import annotations

import numpy as np

from ._validation import as_array, as_directions, check_count

__all__ = [
    "dot",
    "norm",
    "normalize",
    "cos_theta",
    "spherical_to_direction",
    "direction_to_spherical",
    "Frame",
    "polygon_pixel_coverage",
]


def dot(a, b) -> np.ndarray:
    """Dot product over the last axis: shape ``(...)``."""
    return np.einsum("...i,...i->...", np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))


def norm(v) -> np.ndarray:
    """Euclidean length over the last axis."""
    return np.sqrt(dot(v, v))


def normalize(v, *, name: str = "v") -> np.ndarray:
    """Unit vectors along ``v``; a zero vector is a ``ValueError`` naming ``name`` (never NaN)."""
    v = np.asarray(v, dtype=np.float64)
    length = norm(v)
    if np.any(~(length > 0)):
        raise ValueError(f"{name} must not contain zero-length (or NaN) vectors")
    return v / length[..., None]


def cos_theta(v) -> np.ndarray:
    """Cosine of the polar angle in local space: the y component."""
    return np.asarray(v, dtype=np.float64)[..., 1]


def spherical_to_direction(theta, phi) -> np.ndarray:
    """Unit direction from polar angle ``theta`` (from +y) and azimuth ``phi``."""
    theta = np.asarray(theta, dtype=np.float64)
    phi = np.asarray(phi, dtype=np.float64)
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), np.cos(theta), s * np.sin(phi)], axis=-1)


def direction_to_spherical(v, *, name: str = "v"):
    """Inverse of :func:`spherical_to_direction`.

    Returns ``(theta, phi)`` with ``theta`` in [0, pi] and ``phi`` in
    [0, 2 pi). The input need not be normalised; it must not be zero.
    """
    v = as_directions(v, name)
    length = norm(v)
    if np.any(~(length > 0)):
        raise ValueError(f"{name} must not contain zero-length vectors")
    y = np.clip(v[..., 1] / length, -1.0, 1.0)
    theta = np.arccos(y)
    phi = np.arctan2(v[..., 2], v[..., 0])
    phi = np.where(phi < 0.0, phi + 2.0 * np.pi, phi)
    # arctan2 can return exactly 2 pi after the shift for -0.0 inputs' neighbours
    phi = np.where(phi >= 2.0 * np.pi, 0.0, phi)
    return theta, phi


class Frame:
    """An orthonormal shading frame whose local +y axis is a given normal.

    Built with the branchless construction of Duff et al. [1]_, which stays
    orthonormal for every unit normal, including normals at or near +-y
    (where the classic ``cross(n, up)`` construction divides by ~0).

    Parameters
    ----------
    normal : array_like, shape (..., 3)
        Unit normals (normalised on entry).

    Notes
    -----
    Local coordinates ``(x, y, z)`` map to world ``x * s + y * n + z * t``,
    with ``(s, n, t)`` orthonormal and right-handed (``s x n = t``), so that
    ``to_world(to_local(v)) == v`` to rounding. For ``n = +y`` the frame is the
    identity.

    References
    ----------
    .. [1] T. Duff, J. Burgess, P. Christensen, C. Hery, A. Kensler, M. Liani,
       R. Villemin, "Building an Orthonormal Basis, Revisited", JCGT 6(1), 2017.
    """

    __slots__ = ("s", "n", "t")

    def __init__(self, normal):
        n = normalize(as_directions(normal, "normal"), name="normal")
        x, y, z = n[..., 0], n[..., 1], n[..., 2]
        # Duff et al.'s basis around an axis, applied to the cyclic permutation
        # (z, x, y) of the normal so that the normal plays local +y; cyclic
        # permutations keep cross products, so s x n = t holds.
        sign = np.copysign(1.0, y)
        a = -1.0 / (sign + y)
        b = z * x * a
        s = np.stack([sign + x * x * a, -x, b], axis=-1)
        t = np.stack([sign * b, -sign * z, 1.0 + sign * z * z * a], axis=-1)
        self.s = s
        self.n = n
        self.t = t

    def to_local(self, v) -> np.ndarray:
        """World direction(s) ``v`` expressed in this frame (normal = +y)."""
        v = np.asarray(v, dtype=np.float64)
        return np.stack([dot(v, self.s), dot(v, self.n), dot(v, self.t)], axis=-1)

    def to_world(self, v) -> np.ndarray:
        """Local direction(s) ``v`` (normal = +y) expressed in world space."""
        v = np.asarray(v, dtype=np.float64)
        return v[..., 0:1] * self.s + v[..., 1:2] * self.n + v[..., 2:3] * self.t


def _clip_halfplanes(poly: np.ndarray, h: np.ndarray, snap=None) -> np.ndarray:
    """Clip convex polygons ``poly`` (P, K, D) to ``h >= 0``, ``h`` (P, K) the
    signed distances of their vertices: Sutherland and Hodgman (1974), all
    polygons at once.

    Rows are cyclic vertex lists in which repeated vertices (zero-length
    edges) are allowed; the result has ``K + 1`` vertices per row (a convex
    polygon cut by a line or plane gains at most one), its unused slots repeating the
    last vertex kept. An empty result is all NaN.

    ``snap = (axis, bound)`` says the boundary is the line ``x[axis] = bound``
    (``bound`` broadcasting against ``h``): cut points get that coordinate
    exactly, not by interpolation (whose rounding is relative to the
    vertices' magnitude: a polygon with vertices at 1e300 would be cut
    1e284 off). The parameter is computed from halved distances, so that
    ``h - h_next`` does not overflow for vertices near the float limit.
    """
    nxt_poly = np.roll(poly, -1, axis=1)
    nxt_h = np.roll(h, -1, axis=1)
    inside = h >= 0.0
    cross = inside != (nxt_h >= 0.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        s = np.where(cross, (0.5 * h) / (0.5 * h - 0.5 * nxt_h), 0.0)
        cut = poly + s[..., None] * (nxt_poly - poly)
    if snap is not None:
        axis, bound = snap
        cut[..., axis] = np.where(cross, np.broadcast_to(bound, h.shape), cut[..., axis])
    p_count, k = h.shape
    cand = np.empty((p_count, 2 * k, poly.shape[2]))
    cand[:, 0::2] = poly
    cand[:, 1::2] = cut
    valid = np.empty((p_count, 2 * k), dtype=bool)
    valid[:, 0::2] = inside
    valid[:, 1::2] = cross
    # kept vertices first, in their cyclic order; the tail repeats the last one
    order = np.argsort(~valid, axis=1, kind="stable")[:, :k + 1]
    count = valid.sum(axis=1)
    last = np.maximum(count - 1, 0)
    order = np.where(np.arange(k + 1)[None, :] < count[:, None], order,
                     np.take_along_axis(order, last[:, None], axis=1))
    out = np.take_along_axis(cand, order[..., None], axis=1)
    out[count == 0] = np.nan
    return out


def polygon_pixel_coverage(vertices, width: int, height: int, *, chunk: int = 65536) -> np.ndarray:
    """Area of a convex polygon inside every pixel of a ``width x height`` raster.

    Parameters
    ----------
    vertices : array_like, shape (K, 2)
        The polygon's vertices in order (either orientation), in raster
        coordinates: pixel ``(i, j)`` (row ``i``, column ``j``) is the square
        ``[j, j + 1) x [i, i + 1)``, as in :meth:`mcvar.scene.Camera.project`.
    width, height : int
    chunk : int
        Pixels clipped at once (bounds the memory).

    Returns
    -------
    ndarray, shape (height, width), float64
        ``area(polygon ∩ pixel)`` in [0, 1]: the fraction of each pixel the
        polygon covers, i.e. the box-filtered image of its indicator
        function. Pixels outside the polygon's bounding box are 0; the sum is
        the polygon's area inside the raster.

    Notes
    -----
    Each pixel of the polygon's bounding box clips the polygon against its
    four sides (Sutherland and Hodgman [1]_, vectorized over pixels) and
    takes the shoelace area of what remains. Exact up to rounding.

    References
    ----------
    .. [1] I. E. Sutherland, G. W. Hodgman, "Reentrant Polygon Clipping",
       Communications of the ACM 17(1), 1974.
    """
    v = as_array(vertices, "vertices", ndim=2, last=2)
    width = check_count(width, "width")
    height = check_count(height, "height")
    chunk = check_count(chunk, "chunk")
    out = np.zeros((height, width))
    if v.shape[0] < 3:
        return out
    j0 = int(np.clip(np.floor(v[:, 0].min()), 0, width))
    j1 = int(np.clip(np.ceil(v[:, 0].max()), 0, width))
    i0 = int(np.clip(np.floor(v[:, 1].min()), 0, height))
    i1 = int(np.clip(np.ceil(v[:, 1].max()), 0, height))
    if j1 <= j0 or i1 <= i0:
        return out
    rows, cols = np.divmod(np.arange((i1 - i0) * (j1 - j0)), j1 - j0)
    rows += i0
    cols += j0
    for a in range(0, rows.size, chunk):
        r, c = rows[a:a + chunk, None].astype(np.float64), cols[a:a + chunk, None].astype(np.float64)
        poly = np.broadcast_to(v, (r.shape[0],) + v.shape)
        for axis, sign, bound in ((0, 1.0, c), (0, -1.0, c + 1.0), (1, 1.0, r), (1, -1.0, r + 1.0)):
            poly = _clip_halfplanes(poly, sign * (poly[..., axis] - bound), snap=(axis, bound))
        x, y = poly[..., 0], poly[..., 1]
        area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1))
        out[rows[a:a + chunk], cols[a:a + chunk]] = np.nan_to_num(area, nan=0.0)
    return out
