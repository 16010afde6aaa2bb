"""Optics of one smooth interface (layer 2): pure functions of directions and indices.

The lecture's 'Reflective Material', 'Refractive Material', 'Total Internal
Reflection' and 'Fresnel Coefficient' slides as vectorised functions:
mirror reflection, Snell refraction with its total-internal-reflection mask,
the critical and Brewster angles, exact dielectric Fresnel (``R_s``, ``R_p``
and their mean), Schlick's approximation, conductor Fresnel with a complex
index, and the complex indices of copper and gold (:data:`COPPER`,
:data:`GOLD`). The materials of :mod:`mcvar.bsdf` are built on them, and
``mcvar.bsdf`` re-exports every name here (``from mcvar.bsdf import
fresnel_dielectric`` is the same function).

Conventions (docs/conventions.md)
---------------------------------
* Surface-local space: the normal is **+y**; directions ``(..., 3)`` float64 unit vectors
  point **away** from the surface on the side they lie on.
* The medium of index ``eta_i`` lies on the +y side, ``eta_t`` on the -y
  side. A direction with ``y < 0``, or a negative ``cos_i``, means the light
  arrives from the ``eta_t`` side, and the two indices swap roles: every
  function is correct from either side of the interface.
* Nothing here draws random numbers or holds state.
"""
from __future__ import annotations

from typing import Literal

import numpy as np

from ._validation import as_array, as_unit_directions, check_choice, check_positive
from .geometry import dot

__all__ = [
    "reflect",
    "refract",
    "critical_angle",
    "brewster_angle",
    "fresnel_dielectric",
    "fresnel_schlick",
    "fresnel_conductor",
    "COPPER",
    "GOLD",
]

#: ``(x, y, z) -> (-x, y, -z)``: mirror reflection about the normal +y
_FLIP_XZ = np.array([-1.0, 1.0, -1.0])

#: Complex refractive indices ``(n, k)`` of copper and gold at the photon
#: energies 1.88, 2.26 and 2.75 eV (659.5, 548.6 and 450.9 nm: red, green,
#: blue) from Table I of Johnson & Christy (1972), "Optical constants of the
#: noble metals", Phys. Rev. B 6, 4370.
COPPER = {"eta": (0.22, 1.02, 1.24), "k": (3.747, 2.577, 2.397)}
GOLD = {"eta": (0.14, 0.43, 1.38), "k": (3.697, 2.455, 1.914)}


def _cosines(cos_i, name: str = "cos_i") -> np.ndarray:
    """``cos_i`` as a float array, checked to lie in [-1, 1] (up to rounding) and clipped to it."""
    c = as_array(cos_i, name)
    if c.size and not np.all(np.abs(c) <= 1.0 + 1e-12):
        raise ValueError(f"{name} must lie in [-1, 1]; got values in [{c.min()}, {c.max()}]")
    return np.clip(c, -1.0, 1.0)


def reflect(w, normal=None) -> np.ndarray:
    """Mirror direction of ``w`` about the normal (+y unless ``normal`` is given).

    Parameters
    ----------
    w : array_like, shape (..., 3)
        Unit directions pointing away from the surface.
    normal : array_like, shape (..., 3), optional
        Unit normals (e.g. microfacet half vectors); default +y.

    Returns
    -------
    ndarray, shape (..., 3)
        ``-w + 2 (w . n) n``, the lecture's 'Reflective Material' formula;
        for ``n = +y`` simply ``(-x, y, -z)``.
    """
    w = as_unit_directions(w, "w")
    if normal is None:
        return w * _FLIP_XZ
    n = as_unit_directions(normal, "normal")
    return 2.0 * dot(w, n)[..., None] * n - w


def refract(w, eta_i: float, eta_t: float):
    """Refract ``w`` through a smooth interface with normal +y (Snell's law).

    The medium of index ``eta_i`` lies on the +y side, ``eta_t`` on the -y
    side. ``w`` points away from the surface on the side it lies on: if
    ``w.y >= 0`` it is in ``eta_i`` and the result points into the -y side;
    if ``w.y < 0`` the light comes from the ``eta_t`` side and the roles swap.

    Returns
    -------
    wt : ndarray, shape (..., 3)
        Unit refracted directions (pointing away from the surface, on the
        other side). Where total internal reflection occurs, the mirror
        direction ``reflect(w)`` instead (the lecture's edge case), never NaN.
    tir : ndarray of bool, shape (...)
        True where ``(eta_1 / eta_2)^2 (1 - cos^2 theta_1) > 1``.

    Notes
    -----
    With ``r = eta_1 / eta_2``, ``c = |w.y|`` and ``s = sign(w.y)``:
    ``cos theta_t = sqrt(1 - r^2 (1 - c^2))`` (lecture, 'Refractive Material')
    and ``wt = -r w + (r c - cos theta_t) s y``.
    """
    w = as_unit_directions(w, "w")
    eta_i = check_positive(eta_i, "eta_i")
    eta_t = check_positive(eta_t, "eta_t")
    s = np.where(w[..., 1] >= 0.0, 1.0, -1.0)
    c = np.abs(w[..., 1])
    r = np.where(s > 0, eta_i / eta_t, eta_t / eta_i)
    sin2_t = r * r * np.maximum(0.0, 1.0 - c * c)
    tir = sin2_t > 1.0
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin2_t))
    wt = -r[..., None] * w
    wt[..., 1] += (r * c - cos_t) * s
    length = np.sqrt(np.maximum(dot(wt, wt), 1e-300))
    wt = wt / length[..., None]
    wt = np.where(tir[..., None], w * _FLIP_XZ, wt)
    return wt, tir


def critical_angle(eta_i: float, eta_t: float) -> float:
    """Angle of incidence (radians) beyond which total internal reflection occurs.

    Solves ``1 - (eta_i / eta_t)^2 (1 - cos^2 theta) = 0`` (lecture, 'Total
    Internal Reflection'): ``theta_c = arcsin(eta_t / eta_i)``, 41.81 degrees
    for glass (1.5) to air. Only defined for ``eta_i >= eta_t``; otherwise a
    ``ValueError`` (light entering a denser medium is never totally reflected).
    """
    eta_i = check_positive(eta_i, "eta_i")
    eta_t = check_positive(eta_t, "eta_t")
    if not eta_i >= eta_t:
        raise ValueError(
            f"critical_angle needs eta_i >= eta_t (total internal reflection only happens "
            f"going into a less dense medium); got eta_i={eta_i}, eta_t={eta_t}")
    return float(np.arcsin(eta_t / eta_i))


def brewster_angle(eta_i: float, eta_t: float) -> float:
    """Brewster's angle ``arctan(eta_t / eta_i)`` (radians), where ``R_p = 0``."""
    eta_i = check_positive(eta_i, "eta_i")
    eta_t = check_positive(eta_t, "eta_t")
    return float(np.arctan2(eta_t, eta_i))


def _oriented(cos_i, eta_i, eta_t):
    c = _cosines(cos_i)
    eta_i = check_positive(eta_i, "eta_i")
    eta_t = check_positive(eta_t, "eta_t")
    back = c < 0.0
    e1 = np.where(back, eta_t, eta_i)
    e2 = np.where(back, eta_i, eta_t)
    return np.abs(c), e1, e2


def fresnel_dielectric(cos_i, eta_i: float, eta_t: float, *,
                       polarization: Literal["unpolarized", "s", "p"] = "unpolarized") -> np.ndarray:
    """Exact Fresnel reflectance of a smooth dielectric interface.

    Parameters
    ----------
    cos_i : array_like
        Cosine of the angle of incidence, measured on the side of ``eta_i``.
        A negative value means the light arrives from the other side, so the
        roles of ``eta_i`` and ``eta_t`` swap (the pbrt convention): the
        function is correct from either side of the interface.
    eta_i, eta_t : float
        Refractive indices of the incident and transmitting media.
    polarization : {'unpolarized', 's', 'p'}
        ``R_s``, ``R_p`` or their average (unpolarized light).

    Returns
    -------
    ndarray
        Reflectance in [0, 1]; 1 beyond the critical angle; 0 everywhere when
        ``eta_i == eta_t`` (no interface). ``T = 1 - R``.

    Notes
    -----
    The lecture's 'Fresnel Coefficient' slide with non-magnetic media::

        R_s = |(n1 cos_i - n2 cos_t) / (n1 cos_i + n2 cos_t)|^2
        R_p = |(n1 cos_t - n2 cos_i) / (n1 cos_t + n2 cos_i)|^2

    with ``cos_t`` from Snell's law. ``R_p = 0`` at Brewster's angle
    ``arctan(n2 / n1)``; at normal incidence ``R = ((n1 - n2)/(n1 + n2))^2``.

    References
    ----------
    .. [1] M. Born, E. Wolf, *Principles of Optics*, 7th ed., Cambridge
       University Press, 1999, section 1.5.

    Examples
    --------
    >>> round(float(fresnel_dielectric(1.0, 1.0, 1.5)), 12)   # glass at normal incidence
    0.04
    >>> float(fresnel_dielectric(np.cos(np.radians(50.0)), 1.5, 1.0))   # beyond 41.81 deg
    1.0
    """
    check_choice(polarization, "polarization", ("unpolarized", "s", "p"))
    c, e1, e2 = _oriented(cos_i, eta_i, eta_t)
    if eta_i == eta_t:
        return np.zeros_like(c)
    sin2_t = (e1 / e2) ** 2 * (1.0 - c * c)
    tir = sin2_t >= 1.0
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin2_t))
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = (e1 * c - e2 * cos_t) / (e1 * c + e2 * cos_t)
        rp = (e2 * c - e1 * cos_t) / (e2 * c + e1 * cos_t)
    rs = np.where(tir, 1.0, rs * rs)
    rp = np.where(tir, 1.0, rp * rp)
    if polarization == "s":
        return rs
    if polarization == "p":
        return rp
    return 0.5 * (rs + rp)


def fresnel_schlick(cos_i, eta_i: float, eta_t: float) -> np.ndarray:
    """Schlick's approximation ``R0 + (1 - R0)(1 - cos)^5`` (lecture slide).

    ``R0 = ((eta_i - eta_t) / (eta_i + eta_t))^2``. Same side convention as
    :func:`fresnel_dielectric`. Going into a less dense medium the cosine of
    the *transmitted* angle is used (and R = 1 under total internal
    reflection), without which Schlick's formula misses the critical angle
    entirely.

    References
    ----------
    .. [1] C. Schlick, "An Inexpensive BRDF Model for Physically-based
       Rendering", Computer Graphics Forum 13(3), 1994.
    """
    c, e1, e2 = _oriented(cos_i, eta_i, eta_t)
    r0 = ((e1 - e2) / (e1 + e2)) ** 2
    sin2_t = (e1 / e2) ** 2 * (1.0 - c * c)
    tir = sin2_t >= 1.0
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin2_t))
    x = np.where(e1 > e2, cos_t, c)
    r = r0 + (1.0 - r0) * (1.0 - x) ** 5
    return np.where(tir & (e1 > e2), 1.0, r)


def fresnel_conductor(cos_i, eta, k) -> np.ndarray:
    """Fresnel reflectance of a conductor with complex index ``eta + i k``.

    Parameters
    ----------
    cos_i : array_like
        Cosine of the angle of incidence (its absolute value is used: a
        conductor is opaque, so only one side is lit).
    eta, k : float or array_like, shape (c,)
        Real and imaginary parts of the conductor's index relative to the
        incident medium, per colour channel.

    Returns
    -------
    ndarray, shape ``cos_i.shape + eta.shape``
        Unpolarized reflectance in [0, 1].

    Notes
    -----
    The dielectric formulas with a complex index ``n2 = eta + i k`` and a
    complex ``cos_t = sqrt(1 - sin^2_i / n2^2)``; at normal incidence
    ``R = ((eta - 1)^2 + k^2) / ((eta + 1)^2 + k^2)``. With ``k = 0`` it is
    :func:`fresnel_dielectric` (total internal reflection included).

    References
    ----------
    .. [1] M. Born, E. Wolf, *Principles of Optics*, 7th ed., 1999, section 14.2.
    .. [2] M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*,
       4th ed., 2023, section 9.3.

    Examples
    --------
    >>> np.round(fresnel_conductor(1.0, **COPPER), 3).tolist()   # copper at normal incidence, RGB
    [0.943, 0.619, 0.539]
    """
    c = np.abs(_cosines(cos_i))
    eta = as_array(eta, "eta")
    k = as_array(k, "k")
    if eta.shape != k.shape or eta.ndim > 1:
        raise ValueError(f"eta and k must be scalars or 1-D arrays of the same shape; got {eta.shape} and {k.shape}")
    if not (np.all(eta > 0) and np.all(k >= 0)):
        raise ValueError(f"conductor index needs eta > 0 and k >= 0; got eta={eta.tolist()}, k={k.tolist()}")
    if eta.ndim == 1:
        c = c[..., None]
    n2 = eta + 1j * k
    cos_t = np.sqrt(1.0 - (1.0 - c * c) / (n2 * n2))
    with np.errstate(invalid="ignore", divide="ignore"):
        den_s = c + n2 * cos_t
        den_p = n2 * c + cos_t
        rs = np.where(den_s == 0, 0.0, np.abs((c - n2 * cos_t) / den_s) ** 2)
        rp = np.where(den_p == 0, 0.0, np.abs((n2 * c - cos_t) / den_p) ** 2)
    return np.clip(0.5 * (rs + rp), 0.0, 1.0)
