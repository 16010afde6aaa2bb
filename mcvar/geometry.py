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

from ._validation import as_directions

__all__ = [
    "dot",
    "norm",
    "normalize",
    "cos_theta",
    "spherical_to_direction",
    "direction_to_spherical",
    "Frame",
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
