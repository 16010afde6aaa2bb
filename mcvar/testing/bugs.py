"""'Find the bug': small implementations that each ship one subtle bug (layer 3).

The course notebook ``notebooks/12_find_the_bug.ipynb`` hands a student each
class below as it stands. Each renders plausible pictures, each carries one
bug that renderers have really shipped, and each can be convicted by one of
the toolkit's own instruments (:func:`~mcvar.testing.bsdf_chi2_test`,
:func:`~mcvar.testing.chi2_test`, :func:`~mcvar.testing.check_pdf_normalized`,
:func:`~mcvar.testing.check_weight_consistency`,
:func:`~mcvar.testing.check_unbiased`). The student subclasses the class,
overrides the one method where the bug lives and hands the object to
``grade.exercise('12....', obj)``; the grader confirms the fix.

=========================  ===================  ==================================================
class                      method with the bug  instrument that sees it
=========================  ===================  ==================================================
:class:`FresnelGlass`      reflect_probability  the reflected share against the exact Fresnel
                                                reflectance (a binomial bias test per angle)
:class:`GGXReflection`     pdf                  ``bsdf_chi2_test`` (the weights stay
                                                consistent with the wrong pdf)
:class:`LatLongMap`        pdf                  ``chi2_test`` / ``check_pdf_normalized`` on
                                                the sphere
=========================  ===================  ==================================================

Where the bug is and how to fix it is *not* written here: the reference
fixes live with the course's solutions (``tests/solutions``), outside the
installed package. Everything else in each class is correct.

Conventions: the lecture's surface-local space (normal +y, ``wo`` and ``wi``
pointing away from the surface), a BSDF's ``sample(wo, u) -> (wi, weight,
pdf)`` with ``weight = f |cos| / pdf`` and a zero weight for a failed sample.
"""
from __future__ import annotations

import math

import numpy as np

from .. import warps
from .._validation import as_array, as_unit_square, check_positive
from ..optics import fresnel_dielectric, refract

__all__ = ["FresnelGlass", "GGXReflection", "LatLongMap", "BUG_MAP"]

_FLIP_XZ = np.array([-1.0, 1.0, -1.0])


def _wo_u(wo, u):
    wo = as_array(wo, "wo", last=3)
    u = as_unit_square(u)
    wo = np.broadcast_to(wo.reshape(-1, 3), (u.shape[0], 3)) if wo.size == 3 else wo.reshape(-1, 3)
    if wo.shape[0] != u.shape[0]:
        raise ValueError(f"wo must be one direction or {u.shape[0]} (one per u); got {wo.shape[0]}")
    return np.array(wo, dtype=np.float64), u


class FresnelGlass:
    """Smooth glass as the lecture's 'Glass' slide writes it: refract; under
    total internal reflection reflect; otherwise reflect with probability
    ``F`` and refract with ``1 - F``.

    Choosing each lobe with the probability of its share of the energy makes
    every weight 1; ``sample`` reports the discrete lobe probability as its
    pdf (``F`` or ``1 - F``; a delta BSDF: ``is_delta``). Radiance's ``eta^2``
    scaling on refraction is left out, as on the slide.

    Parameters
    ----------
    eta : float
        Index of the inside (-y side) relative to the outside (+y side).

    Notes
    -----
    Exercise ``12.glass``: one of the two methods computes something other
    than what its docstring promises.
    """

    is_delta = True
    has_delta = True
    transmissive = True

    def __init__(self, eta: float = 1.5):
        self.eta = check_positive(eta, "eta")

    def reflect_probability(self, wo, wt):
        """Fresnel reflectance ``F`` for light leaving along ``wo`` (outside
        if ``wo.y > 0``, inside if ``< 0``); ``wt`` is the refracted direction
        on the other side. Total internal reflection is handled by
        :meth:`sample` (it sets ``F = 1``)."""
        return fresnel_dielectric(np.abs(wt[:, 1]), 1.0, self.eta)

    def sample(self, wo, u):
        """``(wi, weight, pdf)`` for outgoing ``wo`` (one or ``(n, 3)``) and ``u`` (n, 2)."""
        wo, u = _wo_u(wo, u)
        wt, tir = refract(wo, 1.0, self.eta)
        f = np.where(tir, 1.0, np.asarray(self.reflect_probability(wo, wt), dtype=np.float64))
        chosen = (u[:, 0] < f) | tir
        wi = np.where(chosen[:, None], wo * _FLIP_XZ, wt)
        pdf = np.where(chosen, f, 1.0 - f)
        return wi, np.ones(u.shape[0]), pdf

    def eval(self, wo, wi):
        """0 for every pair of directions (a delta BSDF has no density)."""
        return np.zeros(np.shape(wi)[0])

    def pdf(self, wo, wi):
        """0 for every pair of directions (a delta BSDF has no density)."""
        return np.zeros(np.shape(wi)[0])

    def __repr__(self):
        return f"FresnelGlass(eta={self.eta:g})"


def _smith_g1(w, alpha):
    c2 = np.clip(w[:, 1] ** 2, 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t2 = np.where(c2 > 0, (1.0 - c2) / np.where(c2 > 0, c2, 1.0), np.inf)
    return np.where(w[:, 1] > 0, 2.0 / (1.0 + np.sqrt(1.0 + alpha * alpha * t2)), 0.0)


class GGXReflection:
    """A white rough mirror: the GGX microfacet reflection of Walter et al.
    (2007), ``f = D(h) G(wo, wi) / (4 cos_o cos_i)``, ``F = 1``.

    ``sample`` draws a microfacet normal ``h`` with density ``D(h) cos(theta_h)``
    (:func:`mcvar.warps.square_to_ggx`), reflects ``wo`` about it, and returns
    ``weight = eval cos_i / pdf`` with the pdf from :meth:`pdf`. A reflected
    direction below the horizon is a failed sample (weight 0).

    Parameters
    ----------
    alpha : float
        GGX roughness.

    Notes
    -----
    Exercise ``12.ggx_pdf``: one method is wrong.
    """

    is_delta = False
    has_delta = False
    transmissive = False

    def __init__(self, alpha: float = 0.3):
        self.alpha = check_positive(alpha, "alpha")

    def eval(self, wo, wi):
        """``D(h) G(wo, wi) / (4 cos_o cos_i)`` above the surface, else 0; shape (n,)."""
        wo, wi = np.asarray(wo, dtype=np.float64), np.asarray(wi, dtype=np.float64)
        wo = np.broadcast_to(wo, wi.shape)
        h = wo + wi
        h = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-300)
        up = (wo[:, 1] > 0) & (wi[:, 1] > 0)
        d = warps.square_to_ggx_pdf(h, self.alpha) / np.maximum(h[:, 1], 1e-300)
        g = _smith_g1(wo, self.alpha) * _smith_g1(wi, self.alpha)
        den = np.where(up, 4.0 * wo[:, 1] * wi[:, 1], 1.0)
        return np.where(up, d * g / den, 0.0)

    def pdf(self, wo, wi):
        """Density per steradian of the directions ``sample`` draws; shape (n,)."""
        wo, wi = np.asarray(wo, dtype=np.float64), np.asarray(wi, dtype=np.float64)
        wo = np.broadcast_to(wo, wi.shape)
        h = wo + wi
        h = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-300)
        up = (wo[:, 1] > 0) & (wi[:, 1] > 0)
        return np.where(up, warps.square_to_ggx_pdf(h, self.alpha), 0.0)

    def sample(self, wo, u):
        """``(wi, weight, pdf)``; ``weight = eval cos_i / pdf``, 0 for a failed sample."""
        wo, u = _wo_u(wo, u)
        h = warps.square_to_ggx(u, self.alpha)
        wi = 2.0 * np.sum(wo * h, axis=1, keepdims=True) * h - wo
        p = np.asarray(self.pdf(wo, wi), dtype=np.float64)
        ok = (wi[:, 1] > 0) & (p > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            weight = np.where(ok, self.eval(wo, wi) * wi[:, 1] / np.where(ok, p, 1.0), 0.0)
        return wi, weight, np.where(ok, p, 0.0)

    def __repr__(self):
        return f"GGXReflection(alpha={self.alpha:g})"


class LatLongMap:
    """Importance sampling of a lat-long environment map, the lecture's way.

    Each pixel ``(i, j)`` (row ``i`` from the top, ``theta`` from the +y
    pole) is chosen with probability ``P_ij ~ L_ij sin(theta_i)`` ('Creating
    A PDF': luminance times the row centre's sine) by inverting the CDF of
    the flattened image ('Inversion Sampling'); the direction is then
    uniform in ``(theta, phi)`` inside the pixel. ``pdf(w)`` is the density
    of those directions **per steradian**, as a light's pdf must be to be
    combined with a BSDF's.

    Parameters
    ----------
    image : array_like, shape (H, W)
        Non-negative luminance.

    Notes
    -----
    Exercise ``12.envmap_pdf``: one method is wrong.
    """

    def __init__(self, image):
        img = as_array(image, "image", ndim=2, nonnegative=True)
        self.image = img
        self.height, self.width = img.shape
        theta = (np.arange(self.height) + 0.5) * math.pi / self.height
        weights = (img * np.sin(theta)[:, None]).ravel()
        if not weights.sum() > 0:
            raise ValueError("image must have some positive luminance")
        self.probabilities = (weights / weights.sum()).reshape(img.shape)
        self._cdf = np.cumsum(self.probabilities.ravel())
        self._last = int(np.flatnonzero(weights > 0)[-1])

    def _pixel(self, w):
        w = np.asarray(w, dtype=np.float64)
        theta = np.arccos(np.clip(w[:, 1], -1.0, 1.0))
        phi = np.arctan2(w[:, 2], w[:, 0]) % (2.0 * math.pi)
        i = np.minimum((theta / math.pi * self.height).astype(int), self.height - 1)
        j = np.minimum((phi / (2.0 * math.pi) * self.width).astype(int), self.width - 1)
        return theta, i, j

    def sample(self, u):
        """Directions ``(n, 3)`` for ``u`` (n, 2): a pixel by ``u[:, 0]``, then a
        uniform ``(theta, phi)`` inside it (``u[:, 1]`` and ``u[:, 0]`` remapped)."""
        u = as_unit_square(u)
        k = np.minimum(np.searchsorted(self._cdf, u[:, 0], side="right"), self._last)
        p = self.probabilities.ravel()[k]
        lo = self._cdf[k] - p
        v = np.clip((u[:, 0] - lo) / np.where(p > 0, p, 1.0), 0.0, 1.0)
        i, j = np.divmod(k, self.width)
        theta = (i + u[:, 1]) * math.pi / self.height
        phi = (j + v) * 2.0 * math.pi / self.width
        s = np.sin(theta)
        return np.stack([s * np.cos(phi), np.cos(theta), s * np.sin(phi)], axis=1)

    def pdf(self, w):
        """Density per steradian of :meth:`sample`'s directions; shape (n,)."""
        theta, i, j = self._pixel(w)
        return self.probabilities[i, j] * self.height * self.width / (2.0 * math.pi ** 2)

    def __repr__(self):
        return f"LatLongMap({self.height} x {self.width})"


def _bug_map(h=16, w=32):
    """The map of exercise 12.envmap_pdf: a dim sky brightening towards the
    zenith, two small bright lights, a black ground band, a black top row
    (so that no sample lands on the pole itself)."""
    theta = (np.arange(h) + 0.5) * math.pi / h
    img = 0.2 + 0.8 * np.cos(theta)[:, None] ** 2 * np.ones(w)
    img[h - 3:] = 0.0
    img[0] = 0.0
    img[3, int(w * 0.3)] = 40.0
    img[2, int(w * 0.7)] = 15.0
    img[12, int(w * 0.5)] = 25.0
    return img


#: The luminance map of exercise ``12.envmap_pdf``.
BUG_MAP = _bug_map()
