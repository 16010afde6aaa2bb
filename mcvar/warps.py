"""Warps from the unit square to sampling domains, each beside its pdf (layer 2).

Every family is three functions, named as in Mitsuba and Nori:

* ``square_to_X(u)``: maps an ``(n, 2)`` array of points ``u`` in [0, 1]^2
  (1.0 included) to the domain, as a pure function of ``u`` (no random number
  generator inside: one warp serves iid, stratified and QMC points);
* ``square_to_X_pdf(v)``: the density of the warped points, **per unit solid
  angle** for directions and **per unit area** for points on the disk,
  triangle or parallelogram; exactly 0 outside the support, never NaN;
* ``X_to_square(v)``: the inverse map, where one exists.

Directions are ``(n, 3)`` unit vectors in the lecture's surface-local space
('Change of Syntax' slide): the normal is **+y**, polar angle ``theta`` from
+y and azimuth ``phi`` from +x towards +z (``docs/conventions.md``). Every
pdf and inverse that takes directions requires unit vectors (length within
``mcvar._validation.UNIT_TOLERANCE`` of 1) and raises a ``ValueError`` naming
the argument otherwise: nothing is normalised silently. To sample
about another axis, warp in local space and move the result with
:class:`mcvar.geometry.Frame`.

The lecture's slides implemented here: 'Uniform Sampling' (the sphere with pdf
``1 / (4 pi)``, and its 'flip a coin, flip the sign' construction from the
hemisphere), 'Monte Carlo Uniform Sampling' (hemisphere, ``1 / (2 pi)``) and
'Monte Carlo Cosine Sampling' (``cos(theta) / pi``).
"""
from __future__ import annotations

import numpy as np

from ._validation import as_array, as_directions, as_unit_directions, as_unit_square, check_positive
from .geometry import Frame, normalize

__all__ = [
    "square_to_uniform_disk_concentric",
    "square_to_uniform_disk_concentric_pdf",
    "uniform_disk_concentric_to_square",
    "square_to_uniform_hemisphere",
    "square_to_uniform_hemisphere_pdf",
    "uniform_hemisphere_to_square",
    "square_to_cosine_hemisphere",
    "square_to_cosine_hemisphere_pdf",
    "cosine_hemisphere_to_square",
    "square_to_uniform_sphere",
    "square_to_uniform_sphere_pdf",
    "uniform_sphere_to_square",
    "square_to_uniform_sphere_flip",
    "square_to_uniform_sphere_flip_pdf",
    "uniform_sphere_flip_to_square",
    "square_to_uniform_cone",
    "square_to_uniform_cone_pdf",
    "uniform_cone_to_square",
    "square_to_sphere_from_point",
    "square_to_sphere_from_point_pdf",
    "sphere_from_point_to_square",
    "square_to_phong_lobe",
    "square_to_phong_lobe_pdf",
    "phong_lobe_to_square",
    "square_to_beckmann",
    "square_to_beckmann_pdf",
    "beckmann_to_square",
    "square_to_ggx",
    "square_to_ggx_pdf",
    "ggx_to_square",
    "square_to_ggx_visible",
    "square_to_ggx_visible_pdf",
    "square_to_uniform_triangle",
    "square_to_uniform_triangle_pdf",
    "uniform_triangle_to_square",
    "square_to_world_triangle",
    "square_to_world_triangle_pdf",
    "world_triangle_to_square",
    "square_to_uniform_parallelogram",
    "square_to_uniform_parallelogram_pdf",
    "uniform_parallelogram_to_square",
    "area_to_solid_angle_pdf",
    "square_to_spherical_rectangle",
    "square_to_spherical_rectangle_pdf",
    "spherical_rectangle_to_square",
]

_TWO_PI = 2.0 * np.pi
_INV_PI = 1.0 / np.pi
_INV_TWO_PI = 1.0 / (2.0 * np.pi)
_INV_FOUR_PI = 1.0 / (4.0 * np.pi)

#: Support tolerance of the flat-domain pdfs (disk, triangle, parallelogram):
#: a point produced by a warp may land a few ulps outside the exact boundary
#: (``cos^2 + sin^2`` rounds above 1); it must still get its density.
_SUPPORT_TOL = 1e-12

#: Smallest roughness accepted by the microfacet warps. ``1 / alpha^2`` must
#: stay finite with headroom (float64 overflows near alpha = 1e-154); anything
#: this smooth is a mirror in practice and belongs to a delta BSDF.
ALPHA_MIN = 1e-100


# --------------------------------------------------------------------------
# shared helpers
# --------------------------------------------------------------------------

def _direction(cos_t, sin_t, phi) -> np.ndarray:
    """Direction with polar cosine/sine about +y and azimuth ``phi``."""
    return np.stack([sin_t * np.cos(phi), cos_t, sin_t * np.sin(phi)], axis=-1)


def _sin_from_cos(cos_t) -> np.ndarray:
    return np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))


def _azimuth_to_u(x, z) -> np.ndarray:
    """``phi / (2 pi)`` in [0, 1) for the azimuth of ``(x, z)``."""
    u = np.arctan2(z, x) * _INV_TWO_PI
    u = np.where(u < 0.0, u + 1.0, u)
    return np.where(u >= 1.0, 0.0, u)


def _stack_u(u0, u1) -> np.ndarray:
    return np.stack([np.clip(u0, 0.0, 1.0), np.clip(u1, 0.0, 1.0)], axis=-1)


def _dirs(v, name="v", ndim=None) -> np.ndarray:
    """Directions at which a pdf or an inverse is evaluated: unit vectors
    (docs/conventions.md, 'Directions and frames'), else a ValueError naming ``name``."""
    return as_unit_directions(v, name, ndim=ndim)


def _points2(p, name="p") -> np.ndarray:
    return as_array(p, name, last=2)


def _alpha(alpha, name) -> float:
    a = check_positive(alpha, name)
    if not a >= ALPHA_MIN:
        raise ValueError(f"{name} must be >= {ALPHA_MIN} (use a delta BSDF for a perfect mirror); got {a}")
    return a


def _alphas(alpha_x, alpha_y):
    ax = _alpha(alpha_x, "alpha_x")
    ay = ax if alpha_y is None else _alpha(alpha_y, "alpha_y")
    return ax, ay


# --------------------------------------------------------------------------
# disk
# --------------------------------------------------------------------------

def square_to_uniform_disk_concentric(u) -> np.ndarray:
    """Uniform point on the unit disk by Shirley and Chiu's concentric map.

    Parameters
    ----------
    u : array_like, shape (n, 2)
        Points in [0, 1]^2.

    Returns
    -------
    ndarray, shape (n, 2)
        Points ``(x, y)`` with ``x^2 + y^2 <= 1``. In the cosine-hemisphere warp
        the disk's ``(x, y)`` become the local ``(x, z)``.

    Notes
    -----
    ``u`` is mapped to ``(a, b) = 2 u - 1`` in [-1, 1]^2; concentric squares
    go to concentric circles: for ``|a| > |b|``, ``r = a`` and
    ``phi = (pi / 4) (b / a)``, otherwise ``r = b`` and
    ``phi = pi / 2 - (pi / 4) (a / b)``. The map preserves fractional area, so
    the density is the constant ``1 / pi``, and it keeps strata compact (low
    distortion), which is why stratified and QMC points survive it.

    References
    ----------
    .. [1] P. Shirley, K. Chiu, "A Low Distortion Map Between Disk and Square",
       Journal of Graphics Tools 2(3), 1997.

    Examples
    --------
    >>> square_to_uniform_disk_concentric([[1.0, 0.5]])
    array([[1., 0.]])
    """
    u = as_unit_square(u)
    x, y = _concentric_disk_unchecked(u[:, 0], u[:, 1])
    return np.stack([x, y], axis=-1)


def _concentric_disk_unchecked(u0, u1, trig=np.float64):
    """The concentric map on already-checked 1-D coordinates ``u0, u1`` in
    [0, 1]: returns ``(x, y)``. The one implementation of the map, shared by
    :func:`square_to_uniform_disk_concentric` (after validation) and the
    integrators' wavefront loop (on arrays it built itself).

    ``trig=np.float32`` evaluates ``cos phi`` and ``sin phi`` in single
    precision (NumPy's SIMD float32 trigonometry: about 20x faster than
    float64 here; error ~1e-7 in x and y, far below a renderer's noise); the
    public functions keep float64."""
    a = 2.0 * u0
    a -= 1.0
    b = 2.0 * u1
    b -= 1.0
    first = np.abs(a) > np.abs(b)
    r = np.where(first, a, b)
    num = np.where(first, b, a)
    # r = 0 only when a = b = 0, where num = 0 too: phi = pi / 2, r = 0
    q = np.divide(num, r, out=np.zeros_like(num), where=r != 0.0)
    q *= np.pi / 4.0
    phi = np.where(first, q, np.pi / 2.0 - q)
    if trig is not np.float64:
        phi = phi.astype(trig)
    return r * np.cos(phi), r * np.sin(phi)


def square_to_uniform_disk_concentric_pdf(p) -> np.ndarray:
    """Density of :func:`square_to_uniform_disk_concentric`: ``1 / pi`` per
    unit area on the unit disk, 0 outside (``x^2 + y^2 > 1 + 1e-12``).

    Parameters
    ----------
    p : array_like, shape (..., 2)
    """
    p = _points2(p)
    r2 = p[..., 0] ** 2 + p[..., 1] ** 2
    return np.where(r2 <= 1.0 + _SUPPORT_TOL, _INV_PI, 0.0)


def uniform_disk_concentric_to_square(p) -> np.ndarray:
    """Inverse of :func:`square_to_uniform_disk_concentric`.

    Parameters
    ----------
    p : array_like, shape (n, 2)
        Points on the unit disk.

    Returns
    -------
    ndarray, shape (n, 2)
        ``u`` in [0, 1]^2 with ``square_to_uniform_disk_concentric(u) == p``
        to rounding (the centre maps to ``(0.5, 0.5)``).
    """
    p = as_array(p, "p", ndim=2, last=2)
    x, y = p[:, 0], p[:, 1]
    r = np.hypot(x, y)
    phi = np.arctan2(y, x)
    phi = np.where(phi < -np.pi / 4.0, phi + _TWO_PI, phi)  # phi in [-pi/4, 7pi/4)
    q = np.pi / 4.0
    a = np.empty_like(r)
    b = np.empty_like(r)
    m1 = phi < q
    m2 = (phi >= q) & (phi < 3 * q)
    m3 = (phi >= 3 * q) & (phi < 5 * q)
    m4 = phi >= 5 * q
    a[m1] = r[m1]
    b[m1] = phi[m1] * r[m1] / q
    b[m2] = r[m2]
    a[m2] = (np.pi / 2.0 - phi[m2]) * r[m2] / q
    a[m3] = -r[m3]
    b[m3] = (phi[m3] - np.pi) * a[m3] / q
    b[m4] = -r[m4]
    a[m4] = (1.5 * np.pi - phi[m4]) * b[m4] / q
    return _stack_u(0.5 * (a + 1.0), 0.5 * (b + 1.0))


# --------------------------------------------------------------------------
# hemisphere and sphere
# --------------------------------------------------------------------------

def square_to_uniform_hemisphere(u) -> np.ndarray:
    """Uniform direction on the hemisphere about +y.

    Parameters
    ----------
    u : array_like, shape (n, 2)

    Returns
    -------
    ndarray, shape (n, 3)
        Unit directions with ``y >= 0``.

    Notes
    -----
    Archimedes' hat-box theorem: ``cos(theta)`` of a uniform direction is
    uniform, so ``cos(theta) = u0`` and ``phi = 2 pi u1``; the density is
    ``1 / (2 pi)`` per steradian (lecture, 'Monte Carlo Uniform Sampling').

    Examples
    --------
    >>> square_to_uniform_hemisphere([[1.0, 0.0]])
    array([[0., 1., 0.]])
    """
    u = as_unit_square(u)
    cos_t = u[:, 0]
    return _direction(cos_t, _sin_from_cos(cos_t), _TWO_PI * u[:, 1])


def square_to_uniform_hemisphere_pdf(v) -> np.ndarray:
    """``1 / (2 pi)`` per steradian for ``v[..., 1] >= 0`` (the horizon
    included), else 0."""
    v = _dirs(v)
    return np.where(v[..., 1] >= 0.0, _INV_TWO_PI, 0.0)


def uniform_hemisphere_to_square(v) -> np.ndarray:
    """Inverse of :func:`square_to_uniform_hemisphere`: ``u = (cos(theta), phi / (2 pi))``."""
    v = _dirs(v, ndim=2)
    return _stack_u(v[:, 1], _azimuth_to_u(v[:, 0], v[:, 2]))


def square_to_cosine_hemisphere(u) -> np.ndarray:
    """Cosine-weighted direction on the hemisphere about +y (Malley's method).

    Parameters
    ----------
    u : array_like, shape (n, 2)

    Returns
    -------
    ndarray, shape (n, 3)
        Unit directions with ``y >= 0``, density ``cos(theta) / pi``.

    Notes
    -----
    A uniform point ``(x, z)`` on the unit disk (here by the concentric map)
    lifted to the hemisphere, ``y = sqrt(1 - x^2 - z^2)``, has density
    ``cos(theta) / pi`` per steradian: the projection onto the disk has
    Jacobian ``cos(theta)`` (lecture, 'Monte Carlo Cosine Sampling': the pdf
    cancels the cosine, 'more radiance per sample').

    References
    ----------
    .. [1] M. Pharr, W. Jakob, G. Humphreys, "Physically Based Rendering",
       4th ed., section A.5.3 (Malley's method), 2023.
    """
    u = as_unit_square(u)
    return np.stack(_square_to_cosine_hemisphere_unchecked(u[:, 0], u[:, 1]), axis=-1)


def _square_to_cosine_hemisphere_unchecked(u0, u1, trig=np.float64):
    """Malley's method on already-checked 1-D coordinates: ``(x, y, z)``, 1-D
    each (structure of arrays). The one implementation behind
    :func:`square_to_cosine_hemisphere`, also called by the integrators on
    arrays they built themselves (no validation, no (n, 3) stacking);
    ``trig`` as in :func:`_concentric_disk_unchecked`."""
    x, z = _concentric_disk_unchecked(u0, u1, trig)
    y = x * x
    y += z * z
    np.subtract(1.0, y, out=y)
    np.maximum(y, 0.0, out=y)
    np.sqrt(y, out=y)
    return x, y, z


def _cosine_hemisphere_polar_unchecked(u0, u1):
    """Malley's method through the polar disk map, float32: ``r = sqrt(u0)``,
    ``phi = 2 pi u1``, so ``(x, y, z) = (r cos phi, sqrt(1 - u0), r sin phi)``.

    The same cosine-weighted density as :func:`square_to_cosine_hemisphere`
    (the polar map ``(sqrt(u0), 2 pi u1)`` is uniform on the disk: its
    Jacobian is ``pi``), about 3x cheaper than the concentric map (no branch,
    no division), but it stretches strata near the centre: the integrators
    use it only for iid numbers, whose stratification does not matter
    (pbrt-v4, sec. A.5.1 and A.5.3). ``u0, u1``: 1-D float32 in [0, 1]."""
    phi = u1 * np.float32(2.0 * np.pi)
    r = np.sqrt(u0)
    x = np.cos(phi)
    x *= r
    z = np.sin(phi)
    z *= r
    y = np.subtract(np.float32(1.0), u0)
    np.maximum(y, 0.0, out=y)
    np.sqrt(y, out=y)
    return x, y, z


def square_to_cosine_hemisphere_pdf(v) -> np.ndarray:
    """``cos(theta) / pi = v[..., 1] / pi`` per steradian for ``y >= 0``, else 0."""
    v = _dirs(v)
    y = v[..., 1]
    return np.where(y >= 0.0, y * _INV_PI, 0.0)


def cosine_hemisphere_to_square(v) -> np.ndarray:
    """Inverse of :func:`square_to_cosine_hemisphere`: project to the disk,
    then invert the concentric map."""
    v = _dirs(v, ndim=2)
    return uniform_disk_concentric_to_square(v[:, [0, 2]])


def square_to_uniform_sphere(u) -> np.ndarray:
    """Uniform direction on the unit sphere.

    Notes
    -----
    ``cos(theta) = 1 - 2 u0`` (uniform in [-1, 1] by the hat-box theorem) and
    ``phi = 2 pi u1``; the density is ``1 / (4 pi)`` per steradian, the
    surface area of the unit sphere being ``4 pi`` (lecture, 'Uniform
    Sampling').

    Examples
    --------
    >>> square_to_uniform_sphere([[0.0, 0.0], [1.0, 0.0]])
    array([[ 0.,  1.,  0.],
           [ 0., -1.,  0.]])
    """
    u = as_unit_square(u)
    cos_t = 1.0 - 2.0 * u[:, 0]
    return _direction(cos_t, _sin_from_cos(cos_t), _TWO_PI * u[:, 1])


def square_to_uniform_sphere_pdf(v) -> np.ndarray:
    """``1 / (4 pi)`` per steradian everywhere."""
    v = _dirs(v)
    return np.full(v.shape[:-1], _INV_FOUR_PI)


def uniform_sphere_to_square(v) -> np.ndarray:
    """Inverse of :func:`square_to_uniform_sphere`."""
    v = _dirs(v, ndim=2)
    return _stack_u(0.5 * (1.0 - v[:, 1]), _azimuth_to_u(v[:, 0], v[:, 2]))


def square_to_uniform_sphere_flip(u) -> np.ndarray:
    """The lecture's sphere sampler: a hemisphere sample whose sign is flipped
    with probability 1/2.

    Parameters
    ----------
    u : array_like, shape (n, 2)

    Returns
    -------
    ndarray, shape (n, 3)
        Uniform directions on the sphere (the same distribution as
        :func:`square_to_uniform_sphere`).

    Notes
    -----
    The 'Uniform Sampling' slide: 'flip a coin, flip the sign' and 'double the
    options, half the pdf', ``(1 / (2 pi)) (1 / 2) = 1 / (4 pi)``. A warp may
    not draw its own coin (it is a pure function of ``u``), so the coin is
    taken from ``u0`` and ``u0`` is reused: ``u0 < 1/2`` keeps the hemisphere
    sample of ``(2 u0, u1)``, otherwise ``(2 u0 - 1, u1)`` is flipped to
    ``y < 0``. Conditioned on the coin, ``2 u0`` (or ``2 u0 - 1``) is again
    uniform, so both halves are uniform hemispheres.
    """
    u = as_unit_square(u)
    lower = u[:, 0] >= 0.5
    u0 = np.where(lower, 2.0 * u[:, 0] - 1.0, 2.0 * u[:, 0])
    v = square_to_uniform_hemisphere(np.stack([u0, u[:, 1]], axis=-1))
    v[:, 1] = np.where(lower, -v[:, 1], v[:, 1])
    return v


def square_to_uniform_sphere_flip_pdf(v) -> np.ndarray:
    """The slide's pdf: ``square_to_uniform_hemisphere_pdf(|v|) * 0.5 = 1 / (4 pi)``."""
    v = _dirs(v)
    folded = v.copy()
    folded[..., 1] = np.abs(folded[..., 1])
    return 0.5 * square_to_uniform_hemisphere_pdf(folded)


def uniform_sphere_flip_to_square(v) -> np.ndarray:
    """Inverse of :func:`square_to_uniform_sphere_flip`."""
    v = _dirs(v, ndim=2)
    folded = v.copy()
    folded[:, 1] = np.abs(v[:, 1])
    h = uniform_hemisphere_to_square(folded)
    u0 = np.where(v[:, 1] < 0.0, 0.5 * (h[:, 0] + 1.0), 0.5 * h[:, 0])
    return _stack_u(u0, h[:, 1])


# --------------------------------------------------------------------------
# cone and Phong lobe
# --------------------------------------------------------------------------

def _cos_max(cos_theta_max) -> float:
    if isinstance(cos_theta_max, (bool, np.bool_)):
        raise TypeError(f"cos_theta_max must be a real number; got {cos_theta_max!r}")
    try:
        c = float(cos_theta_max)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"cos_theta_max must be a real number; got {type(cos_theta_max).__name__}") from exc
    if not -1.0 <= c < 1.0:
        raise ValueError(f"cos_theta_max must lie in [-1, 1) (a cone of zero solid angle is a delta); got {c}")
    return c


def square_to_uniform_cone(u, cos_theta_max) -> np.ndarray:
    """Uniform direction in the cone ``cos(theta) >= cos_theta_max`` about +y.

    Parameters
    ----------
    u : array_like, shape (n, 2)
    cos_theta_max : float
        Cosine of the half-angle, in [-1, 1) (``0`` gives the hemisphere,
        ``-1`` the sphere).

    Notes
    -----
    ``cos(theta) = 1 - u0 (1 - cos_theta_max)``, ``phi = 2 pi u1``; density
    ``1 / (2 pi (1 - cos_theta_max))``, the inverse of the cone's solid angle.
    Used for spherical lights seen from outside (pbrt-v4,
    ``SampleUniformCone``).
    """
    u = as_unit_square(u)
    c = _cos_max(cos_theta_max)
    cos_t = np.clip(1.0 - u[:, 0] * (1.0 - c), c, 1.0)
    return _direction(cos_t, _sin_from_cos(cos_t), _TWO_PI * u[:, 1])


def square_to_uniform_cone_pdf(v, cos_theta_max) -> np.ndarray:
    """``1 / (2 pi (1 - cos_theta_max))`` inside the cone (boundary included), else 0."""
    v = _dirs(v)
    c = _cos_max(cos_theta_max)
    return np.where(v[..., 1] >= c, 1.0 / (_TWO_PI * (1.0 - c)), 0.0)


def uniform_cone_to_square(v, cos_theta_max) -> np.ndarray:
    """Inverse of :func:`square_to_uniform_cone`."""
    v = _dirs(v, ndim=2)
    c = _cos_max(cos_theta_max)
    return _stack_u((1.0 - v[:, 1]) / (1.0 - c), _azimuth_to_u(v[:, 0], v[:, 2]))


# --------------------------------------------------------------------------
# a sphere seen from a point: the cone it subtends (spherical area lights)
# --------------------------------------------------------------------------

def _sphere_view(ref, center, radius):
    """``(ref, axis, dc, sin2, one_minus_cos, inside)`` of spheres ``(center,
    radius)`` seen from points ``ref`` (n, 3): the unit axis towards the
    centre, the distance to it, ``sin^2 theta_max = r^2 / dc^2`` and
    ``1 - cos theta_max`` computed as ``sin^2 / (1 + cos)`` (no cancellation
    for a far, small sphere)."""
    ref = as_array(ref, "ref", ndim=2, last=3)
    n = ref.shape[0]
    c = np.broadcast_to(as_array(center, "center", finite=True), (n, 3))
    r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (n,))
    if not np.all(np.isfinite(r) & (r > 0.0)):
        raise ValueError("radius must be finite and > 0")
    v = c - ref
    dc = np.sqrt(np.einsum("ij,ij->i", v, v))
    inside = dc <= r
    axis = v / np.where(dc > 0.0, dc, 1.0)[:, None]
    sin2 = np.where(inside, 1.0, (r / np.where(inside, 1.0, dc)) ** 2)
    one_minus_cos = sin2 / (1.0 + np.sqrt(np.maximum(0.0, 1.0 - sin2)))
    return ref, c, r, axis, dc, sin2, one_minus_cos, inside


def square_to_sphere_from_point(u, ref, center, radius):
    """Directions from points ``ref`` towards a sphere, uniform in the cone it subtends.

    The next-event sampler of spherical area lights (pbrt-v4,
    ``Sphere::Sample(ctx, u)``; Shirley, Wang and Zimmerman 1996): seen from
    outside, the sphere covers the cone ``cos theta >= cos theta_max =
    sqrt(1 - r^2 / d_c^2)`` about the direction to its centre; a direction
    uniform in that cone (:func:`square_to_uniform_cone`'s map, per point)
    hits exactly the visible cap, with density ``1 / (2 pi (1 - cos
    theta_max))``, the inverse of the solid angle subtended (no ``r^2 /
    cos`` factor, no wasted samples on the back). From inside (or on) the
    sphere every direction hits it: a point uniform by area (``1 / (4 pi
    r^2)``) converted to solid angle, ``dist^2 / (4 pi r^2 |cos theta_l|)``.

    Parameters
    ----------
    u : array_like, shape (n, 2)
    ref : array_like, shape (n, 3)
        Shading points.
    center : array_like, shape (3,) or (n, 3)
    radius : float or array_like, shape (n,)

    Returns
    -------
    directions : ndarray, shape (n, 3)
        Unit directions from ``ref`` to the sampled points.
    distance : ndarray, shape (n,)
        Distance to the sampled point on the sphere.

    Notes
    -----
    The point is placed by the angle ``alpha`` at the centre (pbrt-v4):
    ``d_s = d_c cos theta - sqrt(r^2 - d_c^2 sin^2 theta)`` is the distance
    to the near intersection, ``cos alpha = (d_c^2 + r^2 - d_s^2) / (2 d_c
    r)``; the point is ``center + r (sin alpha cos phi s + cos alpha (-axis)
    + sin alpha sin phi t)``, so that it lies on the sphere to rounding even
    at the cone's rim, where the ray is tangent. Density:
    :func:`square_to_sphere_from_point_pdf`.
    """
    u = as_unit_square(u)
    ref, c, r, axis, dc, sin2, omc, inside = _sphere_view(ref, center, radius)
    if u.shape[0] != ref.shape[0]:
        raise ValueError(f"u and ref must have one row per sample; got {u.shape[0]} and {ref.shape[0]}")
    n = ref.shape[0]
    x = np.empty((n, 3))
    out = ~inside
    if np.any(out):
        cos_t = 1.0 - u[out, 0] * omc[out]
        sin2_t = u[out, 0] * omc[out] * (1.0 + cos_t)               # 1 - cos^2, without cancellation
        d, rr = dc[out], r[out]
        ds = d * cos_t - np.sqrt(np.maximum(0.0, rr * rr - d * d * sin2_t))
        cos_a = np.clip((d * d + rr * rr - ds * ds) / (2.0 * d * rr), -1.0, 1.0)
        local = _direction(cos_a, _sin_from_cos(cos_a), _TWO_PI * u[out, 1])
        fr = Frame(-axis[out])
        x[out] = c[out] + rr[:, None] * fr.to_world(local)
    if np.any(inside):
        x[inside] = c[inside] + r[inside, None] * square_to_uniform_sphere(u[inside])
    v = x - ref
    dist = np.sqrt(np.einsum("ij,ij->i", v, v))
    return v / np.where(dist > 0.0, dist, 1.0)[:, None], dist


def square_to_sphere_from_point_pdf(v, ref, center, radius) -> np.ndarray:
    """Solid-angle density of :func:`square_to_sphere_from_point` at unit directions ``v`` (n, 3).

    Outside the sphere: ``1 / (2 pi (1 - cos theta_max))`` for directions in
    the cone it subtends (its rim included), exactly 0 elsewhere. Inside:
    ``t^2 / (4 pi r^2 |cos theta_l|)`` at the point ``t`` along ``v`` where
    the ray leaves the sphere.
    """
    v = _dirs(v, ndim=2)
    ref, c, r, axis, dc, sin2, omc, inside = _sphere_view(ref, center, radius)
    if v.shape[0] != ref.shape[0]:
        raise ValueError(f"v and ref must have one row per direction; got {v.shape[0]} and {ref.shape[0]}")
    cos_axis = np.einsum("ij,ij->i", v, axis)
    # inside the cone: 1 - cos_axis <= 1 - cos_max, compared without cancellation
    in_cone = (cos_axis > 0.0) & (1.0 - cos_axis <= omc * (1.0 + 1e-9) + 4e-16)
    with np.errstate(divide="ignore"):
        pdf = np.where(in_cone & ~inside, 1.0 / (_TWO_PI * omc), 0.0)
    if np.any(inside):
        i = inside
        oc = ref[i] - c[i]
        b = np.einsum("ij,ij->i", oc, v[i])
        t = -b + np.sqrt(np.maximum(0.0, b * b - np.einsum("ij,ij->i", oc, oc) + r[i] ** 2))
        nrm = (oc + t[:, None] * v[i]) / r[i, None]
        cos_l = np.abs(np.einsum("ij,ij->i", nrm, v[i]))
        with np.errstate(divide="ignore", invalid="ignore"):
            pdf[i] = np.where(cos_l > 0.0, t * t / (4.0 * np.pi * r[i] ** 2 * cos_l), 0.0)
    return pdf


def sphere_from_point_to_square(v, ref, center, radius) -> np.ndarray:
    """Inverse of :func:`square_to_sphere_from_point` for directions ``v`` (n, 3)
    into the sphere (outside: the cone's ``(u0, u1)`` in the frame about the
    centre's direction; inside: the exit point's :func:`uniform_sphere_to_square`)."""
    v = _dirs(v, ndim=2)
    ref, c, r, axis, dc, sin2, omc, inside = _sphere_view(ref, center, radius)
    u = np.zeros((v.shape[0], 2))
    out = ~inside
    if np.any(out):
        # the sampled point's azimuth about -axis equals the direction's about +axis
        # (both frames share s and t up to the sign flip of the normal): use the point
        vo, ro, co, rr = v[out], ref[out], c[out], r[out]
        oc = ro - co
        b = np.einsum("ij,ij->i", oc, vo)
        t = -b - np.sqrt(np.maximum(0.0, b * b - np.einsum("ij,ij->i", oc, oc) + rr ** 2))
        local = Frame(-axis[out]).to_local((oc + t[:, None] * vo) / rr[:, None])
        cos_t = np.einsum("ij,ij->i", vo, axis[out])
        u[out] = _stack_u((1.0 - cos_t) / omc[out], _azimuth_to_u(local[:, 0], local[:, 2]))
    if np.any(inside):
        oc = ref[inside] - c[inside]
        b = np.einsum("ij,ij->i", oc, v[inside])
        t = -b + np.sqrt(np.maximum(0.0, b * b - np.einsum("ij,ij->i", oc, oc) + r[inside] ** 2))
        u[inside] = uniform_sphere_to_square((oc + t[:, None] * v[inside]) / r[inside, None])
    return u


def _exponent(exponent) -> float:
    return check_positive(exponent, "exponent", allow_zero=True)


def square_to_phong_lobe(u, exponent) -> np.ndarray:
    """Direction about +y with density proportional to ``cos(theta)^k``.

    Parameters
    ----------
    u : array_like, shape (n, 2)
    exponent : float
        ``k >= 0`` (``k = 0`` is the uniform hemisphere). Very large ``k``
        (a near-mirror lobe) is exact: ``sin(theta)`` is computed as
        ``sqrt(-expm1(2 log(u0) / (k + 1)))`` instead of from ``1 - cos^2``.

    Notes
    -----
    Density ``(k + 1) / (2 pi) cos(theta)^k`` per steradian on the hemisphere
    (normalised because ``int_0^1 c^k dc = 1 / (k + 1)``); its CDF in
    ``cos(theta)`` is ``cos^(k+1)``, so ``cos(theta) = u0^(1 / (k + 1))``.
    The lobe is about +y: the BSDF rotates it to the mirror direction with
    :class:`mcvar.geometry.Frame`.

    References
    ----------
    .. [1] E. Lafortune, Y. Willems, "Using the modified Phong reflectance
       model for physically based rendering", KU Leuven CW 197, 1994.
    """
    u = as_unit_square(u)
    k = _exponent(exponent)
    with np.errstate(divide="ignore"):
        log_c = np.log(u[:, 0]) / (k + 1.0)
    cos_t = np.exp(log_c)
    sin_t = np.sqrt(np.clip(-np.expm1(2.0 * log_c), 0.0, 1.0))
    return _direction(cos_t, sin_t, _TWO_PI * u[:, 1])


def square_to_phong_lobe_pdf(v, exponent) -> np.ndarray:
    """``(k + 1) / (2 pi) cos(theta)^k`` for ``y >= 0``, else 0."""
    v = _dirs(v)
    k = _exponent(exponent)
    y = v[..., 1]
    pos = y >= 0.0
    return np.where(pos, (k + 1.0) * _INV_TWO_PI * np.power(np.where(pos, y, 0.0), k), 0.0)


def phong_lobe_to_square(v, exponent) -> np.ndarray:
    """Inverse of :func:`square_to_phong_lobe`: ``u0 = cos(theta)^(k + 1)``."""
    v = _dirs(v, ndim=2)
    k = _exponent(exponent)
    return _stack_u(np.power(np.maximum(v[:, 1], 0.0), k + 1.0), _azimuth_to_u(v[:, 0], v[:, 2]))


# --------------------------------------------------------------------------
# microfacet normal distributions
# --------------------------------------------------------------------------

def square_to_beckmann(u, alpha) -> np.ndarray:
    """Microfacet normal from the Beckmann distribution, density ``D(h) cos(theta_h)``.

    Parameters
    ----------
    u : array_like, shape (n, 2)
    alpha : float
        RMS slope (roughness), ``>= ALPHA_MIN``.

    Returns
    -------
    ndarray, shape (n, 3)
        Unit half vectors with ``y >= 0`` (``u0 = 1`` gives the horizon).

    Notes
    -----
    ``D(h) = exp(-tan^2(theta) / alpha^2) / (pi alpha^2 cos^4(theta))``, so
    ``D(h) cos(theta)`` integrates to 1 over the hemisphere (the projected
    microfacet area equals the macro-surface area). Its slopes are Gaussian:
    ``tan^2(theta) = -alpha^2 log(1 - u0)``, ``phi = 2 pi u1`` [1]_. The normal
    is built as ``(tan cos(phi), 1, tan sin(phi)) / sqrt(1 + tan^2)`` so that
    tiny ``alpha`` keeps full precision and ``u0 = 1`` gives the horizon
    instead of ``inf / inf``.

    References
    ----------
    .. [1] B. Walter, S. Marschner, H. Li, K. Torrance, "Microfacet Models for
       Refraction through Rough Surfaces", EGSR 2007, eqs. (25), (28).
    """
    u = as_unit_square(u)
    a = _alpha(alpha, "alpha")
    with np.errstate(divide="ignore"):
        tan2 = -(a * a) * np.log1p(-u[:, 0])  # u0 = 1 -> inf: the horizon
    inf = np.isinf(tan2)
    tan2 = np.where(inf, 0.0, tan2)
    cos_t = np.where(inf, 0.0, 1.0 / np.sqrt(1.0 + tan2))
    sin_t = np.where(inf, 1.0, np.sqrt(tan2) * cos_t)
    return _direction(cos_t, sin_t, _TWO_PI * u[:, 1])


def square_to_beckmann_pdf(v, alpha) -> np.ndarray:
    """``D(h) cos(theta_h)`` per steradian for the Beckmann distribution, 0 for ``y <= 0``.

    Evaluated in log space, ``exp(-tan^2 / alpha^2 - log(pi alpha^2) - 3 log(cos))``,
    so it neither overflows nor forms ``0 / 0`` near the horizon or as
    ``alpha -> 0``.
    """
    v = _dirs(v)
    a = _alpha(alpha, "alpha")
    y = v[..., 1]
    pos = y > 0.0
    ys = np.where(pos, y, 1.0)
    with np.errstate(over="ignore", divide="ignore"):  # y^2 underflowing: tan^2 = inf, pdf 0
        tan2 = (v[..., 0] ** 2 + v[..., 2] ** 2) / (ys * ys)
        log_pdf = -tan2 / (a * a) - np.log(np.pi) - 2.0 * np.log(a) - 3.0 * np.log(ys)
    return np.where(pos, np.exp(log_pdf), 0.0)


def beckmann_to_square(v, alpha) -> np.ndarray:
    """Inverse of :func:`square_to_beckmann`: ``u0 = 1 - exp(-tan^2(theta) / alpha^2)``."""
    v = _dirs(v, ndim=2)
    a = _alpha(alpha, "alpha")
    y = np.maximum(v[:, 1], 0.0)
    s2 = v[:, 0] ** 2 + v[:, 2] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(y > 0.0, s2 / (y * y) / (a * a), np.inf)
    return _stack_u(-np.expm1(-t), _azimuth_to_u(v[:, 0], v[:, 2]))


def square_to_ggx(u, alpha_x, alpha_y=None) -> np.ndarray:
    """Microfacet normal from the (anisotropic) GGX / Trowbridge-Reitz distribution.

    Parameters
    ----------
    u : array_like, shape (n, 2)
    alpha_x : float
        Roughness along local x, ``>= ALPHA_MIN``.
    alpha_y : float, optional
        Roughness along local z (the second tangent; the name follows the
        literature, where the normal is z). Defaults to ``alpha_x``
        (isotropic).

    Returns
    -------
    ndarray, shape (n, 3)
        Unit half vectors, ``y >= 0``; density ``D(h) cos(theta_h)``.

    Notes
    -----
    With local normal +y,
    ``D(h) = 1 / (pi ax ay (hx^2/ax^2 + hz^2/ay^2 + hy^2)^2)``.
    In slope space the scaled slopes ``(hx / (ax hy), hz / (ay hy))`` have the
    isotropic density ``1 / (pi (1 + r^2)^2)``, whose radial CDF is
    ``r^2 / (1 + r^2)``: so ``r^2 = u0 / (1 - u0)`` and the azimuth of the
    scaled slope is ``2 pi u1``. Multiplying through by ``sqrt(1 - u0)``,
    ``h ~ (ax sqrt(u0) cos, sqrt(1 - u0), ay sqrt(u0) sin)``, which has no
    division and gives the horizon at ``u0 = 1``.

    References
    ----------
    .. [1] B. Walter, S. Marschner, H. Li, K. Torrance, "Microfacet Models for
       Refraction through Rough Surfaces", EGSR 2007, eqs. (33), (35).
    .. [2] E. Heitz, "Understanding the Masking-Shadowing Function in
       Microfacet-Based BRDFs", JCGT 3(2), 2014 (anisotropic form, slopes).
    """
    u = as_unit_square(u)
    ax, ay = _alphas(alpha_x, alpha_y)
    phi = _TWO_PI * u[:, 1]
    r = np.sqrt(u[:, 0])
    h = np.stack([ax * r * np.cos(phi), np.sqrt(1.0 - u[:, 0]), ay * r * np.sin(phi)], axis=-1)
    return normalize(h)


def _ggx_d(v, ax, ay):
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    with np.errstate(over="ignore"):
        q = (x / ax) ** 2 + (z / ay) ** 2 + y * y
        return 1.0 / (np.pi * ax * ay * q * q)


def square_to_ggx_pdf(v, alpha_x, alpha_y=None) -> np.ndarray:
    """``D(h) cos(theta_h)`` per steradian for GGX, 0 for ``y <= 0``."""
    v = _dirs(v)
    ax, ay = _alphas(alpha_x, alpha_y)
    y = v[..., 1]
    return np.where(y > 0.0, _ggx_d(v, ax, ay) * np.maximum(y, 0.0), 0.0)


def ggx_to_square(v, alpha_x, alpha_y=None) -> np.ndarray:
    """Inverse of :func:`square_to_ggx`: ``u0 = a / (a + hy^2)`` with
    ``a = hx^2/ax^2 + hz^2/ay^2``, ``u1`` the azimuth of the scaled slope."""
    v = _dirs(v, ndim=2)
    ax, ay = _alphas(alpha_x, alpha_y)
    sx, sz = v[:, 0] / ax, v[:, 2] / ay
    a = sx * sx + sz * sz
    b = np.maximum(v[:, 1], 0.0) ** 2
    with np.errstate(invalid="ignore"):
        u0 = np.where(a + b > 0.0, a / (a + b), 0.0)
    return _stack_u(u0, _azimuth_to_u(sx, sz))


def _wo_upper(wo, n):
    wo = as_directions(wo, "wo")
    if wo.ndim == 1:
        wo = np.broadcast_to(wo, (n, 3))
    elif wo.ndim != 2 or wo.shape[0] != n:
        raise ValueError(f"wo must have shape (3,) or ({n}, 3); got shape {wo.shape}")
    wo = _dirs(wo, "wo")
    if wo.size and not np.all(wo[:, 1] >= 0.0):
        raise ValueError("wo must lie in the upper hemisphere (wo[..., 1] >= 0); "
                         f"got min y {wo[:, 1].min()}")
    return wo


def square_to_ggx_visible(u, wo, alpha_x, alpha_y=None) -> np.ndarray:
    """Microfacet normal from GGX's distribution of *visible* normals (Heitz 2018).

    Parameters
    ----------
    u : array_like, shape (n, 2)
    wo : array_like, shape (3,) or (n, 3)
        Outgoing (viewing) unit direction, local space, ``wo[..., 1] >= 0``
        (the horizon included).
    alpha_x, alpha_y : float
        As in :func:`square_to_ggx`.

    Returns
    -------
    ndarray, shape (n, 3)
        Half vectors ``h`` with ``y >= 0`` and ``dot(wo, h) >= 0``, density
        :func:`square_to_ggx_visible_pdf`.

    Notes
    -----
    ``D_wo(h) = G1(wo) max(0, wo . h) D(h) / cos(theta_o)`` [1]_, eq. (1): only
    the normals ``wo`` can see, weighted by their projected area. Sampling it
    instead of ``D cos`` removes the back-facing and masked normals that
    produce zero-weight or high-weight BSDF samples, so the weight
    ``F G2 / G1`` stays <= 1. Algorithm ([2]_, listing 1, written with local
    normal +y): stretch ``wo`` to the alpha = 1 configuration, sample the
    projected hemisphere (a disk whose upper half is squashed by
    ``(1 + cos(theta_o)) / 2``), lift to the hemisphere and unstretch.

    References
    ----------
    .. [1] E. Heitz, E. d'Eon, "Importance Sampling Microfacet-Based BSDFs
       using the Distribution of Visible Normals", EGSR 2014.
    .. [2] E. Heitz, "Sampling the GGX Distribution of Visible Normals",
       JCGT 7(4), 2018.
    """
    u = as_unit_square(u)
    ax, ay = _alphas(alpha_x, alpha_y)
    wo = _wo_upper(wo, u.shape[0])
    # Heitz's coordinates (normal = z): X = our x, Y = our z, Z = our y.
    vh = normalize(np.stack([ax * wo[:, 0], ay * wo[:, 2], wo[:, 1]], axis=-1))
    lensq = vh[:, 0] ** 2 + vh[:, 1] ** 2
    has_t1 = lensq > 0.0
    inv = np.where(has_t1, 1.0 / np.sqrt(np.where(has_t1, lensq, 1.0)), 0.0)
    t1 = np.stack([np.where(has_t1, -vh[:, 1] * inv, 1.0),
                   np.where(has_t1, vh[:, 0] * inv, 0.0),
                   np.zeros_like(inv)], axis=-1)
    t2 = np.cross(vh, t1)
    r = np.sqrt(u[:, 0])
    phi = _TWO_PI * u[:, 1]
    p1 = r * np.cos(phi)
    p2 = r * np.sin(phi)
    s = 0.5 * (1.0 + vh[:, 2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(0.0, 1.0 - p1 * p1)) + s * p2
    p3 = np.sqrt(np.maximum(0.0, 1.0 - p1 * p1 - p2 * p2))
    nh = p1[:, None] * t1 + p2[:, None] * t2 + p3[:, None] * vh
    ne = np.stack([ax * nh[:, 0], np.maximum(0.0, nh[:, 2]), ay * nh[:, 1]], axis=-1)
    return normalize(ne)


def square_to_ggx_visible_pdf(h, wo, alpha_x, alpha_y=None) -> np.ndarray:
    """Density of :func:`square_to_ggx_visible` per steradian of ``h``.

    ``D_wo(h) = G1(wo) max(0, wo . h) D(h) / cos(theta_o)``, with Smith's
    ``G1(wo) / cos(theta_o) = 2 / (cos(theta_o) + sqrt(cos^2(theta_o) +
    ax^2 wo_x^2 + ay^2 wo_z^2))``, finite even at the grazing ``wo`` where
    ``G1`` and ``cos(theta_o)`` both vanish. 0 where ``h[..., 1] <= 0`` or
    ``dot(wo, h) <= 0``.

    Parameters
    ----------
    h : array_like, shape (n, 3)
    wo : array_like, shape (3,) or (n, 3)
    """
    h = _dirs(h, "h", ndim=2)
    ax, ay = _alphas(alpha_x, alpha_y)
    wo = _wo_upper(wo, h.shape[0])
    cos_o = wo[:, 1]
    g1_over_cos = 2.0 / (cos_o + np.sqrt(cos_o ** 2 + (ax * wo[:, 0]) ** 2 + (ay * wo[:, 2]) ** 2))
    woh = np.einsum("ij,ij->i", wo, h)
    ok = (woh > 0.0) & (h[:, 1] > 0.0)
    return np.where(ok, g1_over_cos * np.maximum(woh, 0.0) * _ggx_d(h, ax, ay), 0.0)


# --------------------------------------------------------------------------
# triangle and parallelogram
# --------------------------------------------------------------------------

def square_to_uniform_triangle(u) -> np.ndarray:
    """Uniform point in the reference triangle ``(0, 0), (1, 0), (0, 1)``.

    Returns
    -------
    ndarray, shape (n, 2)
        Barycentric coordinates ``(b1, b2)`` of the second and third vertex
        (``b0 = 1 - b1 - b2``): the point ``v0 + b1 (v1 - v0) + b2 (v2 - v0)``
        of any triangle.

    Notes
    -----
    Shirley's square-root map: ``r = sqrt(u0)``, ``(b1, b2) = (r (1 - u1), r u1)``;
    ``b1 + b2 = r`` has density ``2 r`` and the split along it is uniform, so
    the density is ``2`` per unit area of the reference triangle (area 1/2).

    References
    ----------
    .. [1] P. Shirley, "Nonuniform Random Point Sets via Warping", Graphics
       Gems III, 1992.
    """
    u = as_unit_square(u)
    r = np.sqrt(u[:, 0])
    return np.stack([r * (1.0 - u[:, 1]), r * u[:, 1]], axis=-1)


def square_to_uniform_triangle_pdf(b) -> np.ndarray:
    """2 per unit area inside the reference triangle (within 1e-12), else 0."""
    b = _points2(b, "b")
    b1, b2 = b[..., 0], b[..., 1]
    inside = (b1 >= -_SUPPORT_TOL) & (b2 >= -_SUPPORT_TOL) & (b1 + b2 <= 1.0 + _SUPPORT_TOL)
    return np.where(inside, 2.0, 0.0)


def uniform_triangle_to_square(b) -> np.ndarray:
    """Inverse of :func:`square_to_uniform_triangle`: ``u0 = (b1 + b2)^2``,
    ``u1 = b2 / (b1 + b2)`` (0 at the vertex ``v0``)."""
    b = as_array(b, "b", ndim=2, last=2)
    r = b[:, 0] + b[:, 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        u1 = np.where(r > 0.0, b[:, 1] / np.where(r > 0.0, r, 1.0), 0.0)
    return _stack_u(r * r, u1)


def _vertices(u_n, **named):
    out = []
    for name, v in named.items():
        arr = as_directions(v, name)
        if arr.ndim == 1:
            arr = np.broadcast_to(arr, (u_n, 3))
        elif arr.ndim != 2 or arr.shape[0] != u_n:
            raise ValueError(f"{name} must have shape (3,) or ({u_n}, 3); got shape {arr.shape}")
        out.append(arr)
    return out


def _cross_norm(e1, e2, what):
    area2 = np.linalg.norm(np.cross(e1, e2), axis=-1)
    if area2.size and not np.all(area2 > 0.0):
        raise ValueError(f"{what} must be non-degenerate (edges not parallel); got zero area")
    return area2


def _plane_coords(p, origin, e1, e2):
    """Coordinates ``(s, t)`` of ``p`` in the basis ``(e1, e2)`` and the
    distance of ``p`` from the plane, by the normal equations."""
    d = p - origin
    g11 = np.einsum("ij,ij->i", e1, e1)
    g12 = np.einsum("ij,ij->i", e1, e2)
    g22 = np.einsum("ij,ij->i", e2, e2)
    r1 = np.einsum("ij,ij->i", d, e1)
    r2 = np.einsum("ij,ij->i", d, e2)
    det = g11 * g22 - g12 * g12
    s = (g22 * r1 - g12 * r2) / det
    t = (g11 * r2 - g12 * r1) / det
    resid = np.linalg.norm(d - s[:, None] * e1 - t[:, None] * e2, axis=-1)
    scale = np.sqrt(g11) + np.sqrt(g22)
    return s, t, resid <= 1e-9 * scale


def square_to_world_triangle(u, v0, v1, v2) -> np.ndarray:
    """Uniform point on the triangle ``v0, v1, v2`` (an area light), shape (n, 3).

    Vertices are ``(3,)`` (one triangle) or ``(n, 3)`` (one triangle per
    sample, e.g. after choosing a triangle of a mesh light). The density is
    ``1 / area`` per unit area (:func:`square_to_world_triangle_pdf`); for a
    pdf per solid angle use :func:`area_to_solid_angle_pdf`.
    """
    u = as_unit_square(u)
    a, b, c = _vertices(u.shape[0], v0=v0, v1=v1, v2=v2)
    e1, e2 = b - a, c - a
    _cross_norm(e1, e2, "the triangle v0, v1, v2")
    bc = square_to_uniform_triangle(u)
    return a + bc[:, 0:1] * e1 + bc[:, 1:2] * e2


def square_to_world_triangle_pdf(points, v0, v1, v2) -> np.ndarray:
    """``1 / area`` per unit area for points on the triangle, else 0.

    A point counts as on the triangle when its barycentrics are within 1e-12
    of the closed triangle and its distance from the plane is at most 1e-9
    times the edge lengths (rounding of a ray hit or a warp).
    """
    p = as_array(points, "points", ndim=2, last=3)
    a, b, c = _vertices(p.shape[0], v0=v0, v1=v1, v2=v2)
    e1, e2 = b - a, c - a
    area = 0.5 * _cross_norm(e1, e2, "the triangle v0, v1, v2")
    s, t, in_plane = _plane_coords(p, a, e1, e2)
    inside = in_plane & (s >= -_SUPPORT_TOL) & (t >= -_SUPPORT_TOL) & (s + t <= 1.0 + _SUPPORT_TOL)
    return np.where(inside, 1.0 / area, 0.0)


def world_triangle_to_square(points, v0, v1, v2) -> np.ndarray:
    """Inverse of :func:`square_to_world_triangle` for points on the triangle."""
    p = as_array(points, "points", ndim=2, last=3)
    a, b, c = _vertices(p.shape[0], v0=v0, v1=v1, v2=v2)
    e1, e2 = b - a, c - a
    _cross_norm(e1, e2, "the triangle v0, v1, v2")
    s, t, _ = _plane_coords(p, a, e1, e2)
    return uniform_triangle_to_square(np.stack([np.maximum(s, 0.0), np.maximum(t, 0.0)], axis=-1))


def square_to_uniform_parallelogram(u, origin, edge1, edge2) -> np.ndarray:
    """Uniform point ``origin + u0 edge1 + u1 edge2`` on a parallelogram, shape (n, 3).

    The map is affine, so the density is the constant ``1 / |edge1 x edge2|``
    per unit area (:func:`square_to_uniform_parallelogram_pdf`): the
    rectangular area light of the Cornell box. ``origin``, ``edge1``,
    ``edge2`` are ``(3,)`` or ``(n, 3)``.
    """
    u = as_unit_square(u)
    o, e1, e2 = _vertices(u.shape[0], origin=origin, edge1=edge1, edge2=edge2)
    _cross_norm(e1, e2, "the parallelogram edge1, edge2")
    return o + u[:, 0:1] * e1 + u[:, 1:2] * e2


def square_to_uniform_parallelogram_pdf(points, origin, edge1, edge2) -> np.ndarray:
    """``1 / |edge1 x edge2|`` per unit area on the parallelogram, else 0
    (same tolerances as :func:`square_to_world_triangle_pdf`)."""
    p = as_array(points, "points", ndim=2, last=3)
    o, e1, e2 = _vertices(p.shape[0], origin=origin, edge1=edge1, edge2=edge2)
    area = _cross_norm(e1, e2, "the parallelogram edge1, edge2")
    s, t, in_plane = _plane_coords(p, o, e1, e2)
    lo, hi = -_SUPPORT_TOL, 1.0 + _SUPPORT_TOL
    inside = in_plane & (s >= lo) & (s <= hi) & (t >= lo) & (t <= hi)
    return np.where(inside, 1.0 / area, 0.0)


def uniform_parallelogram_to_square(points, origin, edge1, edge2) -> np.ndarray:
    """Inverse of :func:`square_to_uniform_parallelogram`."""
    p = as_array(points, "points", ndim=2, last=3)
    o, e1, e2 = _vertices(p.shape[0], origin=origin, edge1=edge1, edge2=edge2)
    _cross_norm(e1, e2, "the parallelogram edge1, edge2")
    s, t, _ = _plane_coords(p, o, e1, e2)
    return _stack_u(s, t)


def area_to_solid_angle_pdf(pdf_area, ref_points, light_points, light_normals) -> np.ndarray:
    """Convert a pdf per unit area on a light to a pdf per steradian at ``ref_points``.

    Parameters
    ----------
    pdf_area : float or array_like, shape (n,)
        Density per unit area of the light points, >= 0.
    ref_points, light_points : array_like, shape (n, 3) or (3,)
        The shading point and the sampled point on the light.
    light_normals : array_like, shape (n, 3) or (3,)
        Light surface normals (any non-zero length; either orientation).

    Returns
    -------
    ndarray, shape (n,)
        ``pdf_area * dist^2 / |cos(theta_light)|``, and exactly **0** where
        ``cos(theta_light) = 0`` (the light seen edge-on) or the two points
        coincide: such a sample carries no light, and 0 (never ``inf`` or
        NaN) lets an estimator drop it by its usual ``pdf > 0`` test.

    Notes
    -----
    A patch ``dA`` at distance ``r``, tilted by ``theta_light`` from the
    direction to the shading point, subtends ``dw = |cos(theta_light)| dA / r^2``
    (pbrt-v4, section 4.2.3), so ``p_w = p_A dA / dw``.
    """
    pa = as_array(pdf_area, "pdf_area", nonnegative=True)
    x = as_directions(ref_points, "ref_points")
    y = as_directions(light_points, "light_points")
    nl = as_directions(light_normals, "light_normals")
    try:
        pa, x, y, nl = np.broadcast_arrays(pa[..., None], x, y, nl)
    except ValueError as exc:
        raise ValueError("pdf_area (n,), ref_points, light_points and light_normals (n, 3) must "
                         f"broadcast together; got shapes {np.shape(pdf_area)}, {np.shape(ref_points)}, "
                         f"{np.shape(light_points)}, {np.shape(light_normals)}") from exc
    pa = pa[..., 0]
    d = y - x
    dist2 = np.einsum("...i,...i->...", d, d)
    nlen = np.sqrt(np.einsum("...i,...i->...", nl, nl))
    if nlen.size and not np.all(nlen > 0.0):
        raise ValueError("light_normals must be non-zero vectors")
    dn = np.abs(np.einsum("...i,...i->...", d, nl))
    ok = (dn > 0.0) & (dist2 > 0.0)
    # dist^2 / |cos| = dist^3 |n| / |d . n|
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        val = pa * dist2 * np.sqrt(dist2) * nlen / np.where(ok, dn, 1.0)
    if not np.all(np.isfinite(val[ok])):
        raise ValueError("the solid-angle pdf pdf_area * dist^2 / |cos| overflows float64 (ref_points "
                         f"and light_points up to {float(np.sqrt(np.max(dist2))):.3g} apart): "
                         "check the units of ref_points and light_points")
    return np.where(ok, val, 0.0)


# --------------------------------------------------------------------------
# rectangular lights by solid angle (Urena, Fajardo and King 2013)
# --------------------------------------------------------------------------

def _rectangle_frame(ref, origin, edge1, edge2):
    """Local coordinates of a rectangle seen from ``ref`` (Urena et al. 2013, sec. 3).

    Returns ``(x, y, z, x0, x1, y0, y1, z0)``: the unit edge directions and
    their normal (rows, ``(n, 3)``), and the rectangle's extent in that frame
    centred at ``ref``, with ``z`` oriented so that ``z0 <= 0``.
    """
    ref = as_array(ref, "ref_points", ndim=2, last=3)
    o, e1, e2 = _vertices(ref.shape[0], origin=origin, edge1=edge1, edge2=edge2)
    l1 = np.linalg.norm(e1, axis=-1)
    l2 = np.linalg.norm(e2, axis=-1)
    if l1.size and not (np.all(l1 > 0.0) and np.all(l2 > 0.0)):
        raise ValueError("edge1 and edge2 must be non-zero vectors")
    cos_12 = np.einsum("ij,ij->i", e1, e2) / (l1 * l2)
    if cos_12.size and np.max(np.abs(cos_12)) > 1e-9:
        raise ValueError("edge1 and edge2 must be orthogonal (a rectangle) for solid-angle sampling; "
                         f"got |cos| = {np.max(np.abs(cos_12)):.3g} (use square_to_uniform_parallelogram)")
    x = e1 / l1[:, None]
    y = e2 / l2[:, None]
    z = np.cross(x, y)
    d = o - ref
    x0 = np.einsum("ij,ij->i", d, x)
    y0 = np.einsum("ij,ij->i", d, y)
    z0 = np.einsum("ij,ij->i", d, z)
    flip = z0 > 0.0
    z = np.where(flip[:, None], -z, z)
    z0 = -np.abs(z0)
    return x, y, z, x0, x0 + l1, y0, y0 + l2, z0


def _rectangle_solid_angle(x0, x1, y0, y1, z0):
    """``(S, k, b0, b1)`` of the spherical rectangle ``[x0, x1] x [y0, y1]`` at
    height ``z0 < 0`` (Urena et al. 2013, eq. 4-6): its solid angle ``S`` and
    the constants of the sampler."""
    def unit(a, b, c):
        r = np.sqrt(a * a + b * b + c * c)
        return a / r, b / r, c / r

    zero = np.zeros_like(z0)
    n0 = unit(zero, z0, -y0)
    n1 = unit(-z0, zero, x1)
    n2 = unit(zero, -z0, y1)
    n3 = unit(z0, zero, -x0)

    def angle(a, b):
        return np.arccos(np.clip(-(a[0] * b[0] + a[1] * b[1] + a[2] * b[2]), -1.0, 1.0))

    g0, g1, g2, g3 = angle(n0, n1), angle(n1, n2), angle(n2, n3), angle(n3, n0)
    k = _TWO_PI - g2 - g3
    return g0 + g1 - k, k, n0[2], n2[2]


def _spherical_rectangle_unchecked(u0, u1, x0, x1, y0, y1, z0):
    """The sampler of :func:`square_to_spherical_rectangle` in the rectangle's
    local frame (Urena et al. 2013, sec. 4), on arrays of any matching shape:
    returns ``(xu, yv, S)``, the sample's coordinates ``x0 <= xu <= x1``,
    ``y0 <= yv <= y1`` in the plane ``z = z0 < 0`` and the solid angle ``S``.
    No checks: the integrators call it on structure-of-arrays rows."""
    s, k, b0, b1 = _rectangle_solid_angle(x0, x1, y0, y1, z0)
    phi = u0 * s + k
    with np.errstate(divide="ignore", invalid="ignore"):
        fu = (np.cos(phi) * b0 - b1) / np.sin(phi)
        cu = np.where(fu > 0.0, 1.0, -1.0) / np.sqrt(fu * fu + b0 * b0)
        cu = np.clip(np.where(np.isfinite(fu), cu, 0.0), -1.0, 1.0)
        xu = -(cu * z0) / np.maximum(np.sqrt(1.0 - cu * cu), 1e-300)
    xu = np.clip(xu, x0, x1)
    d2 = xu * xu + z0 * z0
    h0 = y0 / np.sqrt(d2 + y0 * y0)
    h1 = y1 / np.sqrt(d2 + y1 * y1)
    hv = h0 + u1 * (h1 - h0)
    hv2 = hv * hv
    with np.errstate(divide="ignore", invalid="ignore"):
        yv = np.where(hv2 < 1.0 - 1e-12, hv * np.sqrt(d2) / np.sqrt(np.maximum(1.0 - hv2, 1e-300)), y1)
    yv = np.clip(yv, y0, y1)
    return xu, yv, s


def _rectangle_soa_frame(edge1, edge2):
    """``(x, y, z, l1, l2)`` of a rectangle light for the SoA kernels below:
    unit edge directions and their cross product, each shape (3, 1), and the
    edge lengths. Raises ValueError if the edges are not orthogonal."""
    e1 = np.asarray(edge1, dtype=np.float64).reshape(3)
    e2 = np.asarray(edge2, dtype=np.float64).reshape(3)
    l1, l2 = float(np.linalg.norm(e1)), float(np.linalg.norm(e2))
    if l1 <= 0.0 or l2 <= 0.0 or abs(float(e1 @ e2)) > 1e-9 * l1 * l2:
        raise ValueError("solid-angle sampling needs a rectangle (non-zero, orthogonal edges); got edges "
                         f"{e1.tolist()} and {e2.tolist()}")
    x, y = e1 / l1, e2 / l2
    return x[:, None], y[:, None], np.cross(x, y)[:, None], l1, l2


def _rectangle_soa_local(p, origin, x, y, z):
    """The rectangle's corner ``origin`` in the frame ``(x, y, z)`` centred at the SoA points ``p`` (3, m)."""
    d = origin.reshape(3, 1) - p
    x0 = x[0] * d[0] + x[1] * d[1] + x[2] * d[2]
    y0 = y[0] * d[0] + y[1] * d[1] + y[2] * d[2]
    z0 = z[0] * d[0] + z[1] * d[1] + z[2] * d[2]
    return x0, y0, z0


def _spherical_rectangle_soa(u, p, origin, x, y, z, l1, l2):
    """:func:`square_to_spherical_rectangle` for structure-of-arrays shading points.

    ``p`` (3, m), ``u`` (2, m), the rectangle ``origin`` (3,) with the
    frame of :func:`_rectangle_soa_frame`. Returns ``(w, dist, S)``: unit
    directions (3, m) from ``p`` to the sampled points, their distances and
    the solid angle ``S`` of the rectangle seen from ``p`` (the density is
    ``1 / S``; 0 where the rectangle is seen edge-on)."""
    x0, y0, z0 = _rectangle_soa_local(p, origin, x, y, z)
    xu, yv, s = _spherical_rectangle_unchecked(u[0], u[1], x0, x0 + l1, y0, y0 + l2, -np.abs(z0))
    w = x * xu
    w += y * yv
    w += z * z0
    dist = np.sqrt(xu * xu + yv * yv + z0 * z0)
    w /= np.maximum(dist, 1e-300)
    return w, dist, s


def _rectangle_solid_angle_soa(p, origin, x, y, z, l1, l2):
    """Solid angle of the rectangle seen from the SoA points ``p`` (3, m)."""
    x0, y0, z0 = _rectangle_soa_local(p, origin, x, y, z)
    return _rectangle_solid_angle(x0, x0 + l1, y0, y0 + l2, -np.abs(z0))[0]


def square_to_spherical_rectangle(u, ref_points, origin, edge1, edge2) -> np.ndarray:
    """Point on a rectangle, uniform in the solid angle it subtends at ``ref_points``, shape (n, 3).

    The area-preserving map of Urena, Fajardo and King [1]_: ``u0`` picks the
    azimuthal slice so that the solid angle to its left is ``u0 S``, ``u1``
    the height within the slice uniformly in solid angle. The density is
    ``1 / S`` per steradian (:func:`square_to_spherical_rectangle_pdf`), so
    an area light sampled this way needs no ``r^2 / cos(theta_light)``
    factor: the variance that area sampling puts on points near the light
    (the Cornell box's ceiling and upper walls) is gone.

    Parameters
    ----------
    u : array_like, shape (n, 2)
        Points in [0, 1]^2.
    ref_points : array_like, shape (n, 3)
        The shading points (one per sample).
    origin, edge1, edge2 : array_like, shape (3,) or (n, 3)
        The rectangle ``origin + s edge1 + t edge2``, ``s, t`` in [0, 1];
        the edges must be orthogonal.

    Returns
    -------
    ndarray, shape (n, 3)
        Points on the rectangle (world space).

    References
    ----------
    .. [1] C. Urena, M. Fajardo, A. King, "An Area-Preserving Parametrization
       for Spherical Rectangles", Computer Graphics Forum 32(4) (EGSR 2013).
    """
    u = as_unit_square(u)
    ref = as_array(ref_points, "ref_points", ndim=2, last=3)
    if ref.shape[0] != u.shape[0]:
        raise ValueError(f"ref_points must have shape ({u.shape[0]}, 3) like u; got {ref.shape}")
    x, y, z, x0, x1, y0, y1, z0 = _rectangle_frame(ref, origin, edge1, edge2)
    xu, yv, _ = _spherical_rectangle_unchecked(u[:, 0], u[:, 1], x0, x1, y0, y1, z0)
    return ref + xu[:, None] * x + yv[:, None] * y + z0[:, None] * z


def square_to_spherical_rectangle_pdf(points, ref_points, origin, edge1, edge2) -> np.ndarray:
    """``1 / S`` per steradian (``S`` the solid angle of the rectangle seen
    from ``ref_points``) for points on the rectangle, else 0; 0 where the
    rectangle is seen edge-on (``S = 0``).

    The density is per unit solid angle at ``ref_points`` (unlike the
    per-area :func:`square_to_uniform_parallelogram_pdf`); a point counts as
    on the rectangle with the tolerances of the parallelogram's pdf.
    """
    p = as_array(points, "points", ndim=2, last=3)
    ref = as_array(ref_points, "ref_points", ndim=2, last=3)
    if ref.shape != p.shape:
        raise ValueError(f"ref_points must have shape {p.shape} like points; got {ref.shape}")
    on = square_to_uniform_parallelogram_pdf(p, origin, edge1, edge2) > 0.0
    x, y, z, x0, x1, y0, y1, z0 = _rectangle_frame(ref, origin, edge1, edge2)
    s = _rectangle_solid_angle(x0, x1, y0, y1, z0)[0]
    ok = on & (s > 0.0) & (z0 < 0.0)
    with np.errstate(divide="ignore"):
        return np.where(ok, 1.0 / np.where(ok, s, 1.0), 0.0)


def spherical_rectangle_to_square(points, ref_points, origin, edge1, edge2) -> np.ndarray:
    """Inverse of :func:`square_to_spherical_rectangle`: ``u0`` is the solid
    angle of the part of the rectangle left of the point over ``S`` (the map
    preserves solid angle), ``u1`` the height fraction ``(h - h0) / (h1 - h0)``."""
    p = as_array(points, "points", ndim=2, last=3)
    ref = as_array(ref_points, "ref_points", ndim=2, last=3)
    if ref.shape != p.shape:
        raise ValueError(f"ref_points must have shape {p.shape} like points; got {ref.shape}")
    x, y, z, x0, x1, y0, y1, z0 = _rectangle_frame(ref, origin, edge1, edge2)
    d = p - ref
    xu = np.clip(np.einsum("ij,ij->i", d, x), x0, x1)
    yv = np.clip(np.einsum("ij,ij->i", d, y), y0, y1)
    s = _rectangle_solid_angle(x0, x1, y0, y1, z0)[0]
    s_left = _rectangle_solid_angle(x0, xu, y0, y1, z0)[0]
    d2 = xu * xu + z0 * z0
    h0 = y0 / np.sqrt(d2 + y0 * y0)
    h1 = y1 / np.sqrt(d2 + y1 * y1)
    hv = yv / np.sqrt(d2 + yv * yv)
    with np.errstate(divide="ignore", invalid="ignore"):
        u0 = np.where(s > 0.0, s_left / np.where(s > 0.0, s, 1.0), 0.0)
        u1 = np.where(h1 > h0, (hv - h0) / np.where(h1 > h0, h1 - h0, 1.0), 0.0)
    return _stack_u(u0, u1)
