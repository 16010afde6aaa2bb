"""Reflectance functions and materials (layer 3).

The lecture's 'BRDFs' and 'Materials' sections as code: the materials, each
with ``eval``, ``pdf`` and ``sample``, and what they do to light
(:func:`directional_albedo`, :func:`exitant_radiance`). They are built on the
optics of a single interface (reflection, Snell refraction, the critical
angle, exact and Schlick Fresnel, conductor Fresnel with a complex index),
which live in :mod:`mcvar.optics` and are re-exported here, so
``mcvar.bsdf.fresnel_dielectric is mcvar.optics.fresnel_dielectric``.

Conventions (docs/conventions.md, the lecture's 'Change of Syntax' slide)
-------------------------------------------------------------------------
* Surface-local space: the normal is **+y**; ``wo`` and ``wi`` are unit
  vectors that both point **away** from the surface; arrays ``(n, 3)`` float64.
* ``eval(wo, wi) -> (n, 3)`` is the BSDF ``f`` in RGB (per steradian), without
  the cosine; Dirac-delta lobes are not part of ``eval`` (0 there).
* ``pdf(wo, wi) -> (n,)`` is the density of ``sample`` per unit solid angle of
  ``wi`` for the non-delta part, including the probability of choosing that
  part; 0 for delta BSDFs.
* ``sample(wo, u) -> BSDFSample(wi, weight, pdf)`` with ``u`` in [0, 1]^2.
  For a non-delta sample ``weight = eval * |cos theta_i| / pdf`` and ``pdf`` is
  per solid angle. For a delta lobe ``pdf`` is the *discrete* probability of
  choosing that lobe and ``weight`` the lobe's throughput divided by it (glass
  chooses reflection with probability ``F`` and returns weight 1 for it). A
  failed sample (``wo`` below the horizon of a reflection model, a direction
  drawn under the horizon) has ``weight = 0`` and ``pdf = 0``; never NaN.
  ``sample(..., return_delta=True)`` also returns a per-sample mask telling
  which samples came from a delta lobe (needed for mixed models such as
  :class:`Plastic` by next-event estimation and MIS).
* ``is_delta`` is True when every lobe is a Dirac delta; ``has_delta`` is True
  when at least one is (so ``has_delta and not is_delta`` marks a mixed model
  whose ``eval``/``pdf`` cover only the non-delta part).
* Multi-lobe models choose a lobe with ``u[:, 0]``: lobe ``j`` is chosen when
  ``u0`` falls in its interval ``[c_j, c_j + p_j)`` and ``u0`` is then rescaled
  to ``(u0 - c_j) / p_j`` to sample that lobe, so stratification survives.
* Reflection models are one-sided in local space: they reflect light arriving
  on the +y side only (``wo.y > 0`` and ``wi.y > 0``); anything else gives 0.
  Two-sided surfaces (the Cornell box walls) are handled by the caller, who
  flips the shading normal towards ``wo``. Transmissive models
  (:class:`Refractive`, :class:`Glass`; attribute ``transmissive``) must
  *not* be flipped: ``wo.y < 0`` tells them the ray is inside the medium of
  index ``eta``.

The transmitted radiance is not scaled by ``(eta_i / eta_t)^2``: like the
lecture's glass code we transport the quantity that is conserved along paths
entering and leaving a closed dielectric (the factors cancel for a camera and
lights outside the glass).
"""
from __future__ import annotations

import numbers
from typing import Callable, Literal, NamedTuple

import numpy as np
from scipy.special import erf

from ._validation import (
    as_array,
    as_rgb,
    as_rng,
    as_unit_square,
    check_choice,
    check_count,
    check_positive,
)
from .geometry import Frame, dot
# The optics of one interface live in mcvar.optics and are re-exported here
# (issue 4 names them as mcvar.bsdf's): one definition, two addresses.
from .optics import (
    COPPER,
    GOLD,
    _FLIP_XZ,
    _cosines,
    brewster_angle,
    critical_angle,
    fresnel_conductor,
    fresnel_dielectric,
    fresnel_schlick,
    reflect,
    refract,
)
from .samplers import SAMPLERS, pixel_samples
from .warps import (
    square_to_beckmann,
    square_to_beckmann_pdf,
    square_to_cosine_hemisphere,
    square_to_cosine_hemisphere_pdf,
    square_to_ggx_pdf,
    square_to_ggx_visible,
    square_to_ggx_visible_pdf,
    square_to_phong_lobe,
    square_to_phong_lobe_pdf,
)

__all__ = [
    "reflect",
    "refract",
    "critical_angle",
    "brewster_angle",
    "fresnel_dielectric",
    "fresnel_schlick",
    "fresnel_conductor",
    "BSDFSample",
    "BSDF",
    "Lambertian",
    "Mirror",
    "Refractive",
    "Glass",
    "Microfacet",
    "Conductor",
    "Plastic",
    "COPPER",
    "GOLD",
    "Retroreflective",
    "directional_albedo",
    "AlbedoEstimate",
    "hemisphere_directions",
    "hemisphere_lookup",
    "exitant_radiance",
]

_UNIT_TOL = 1e-6
_PRESETS = {"copper": COPPER, "gold": GOLD}


# --------------------------------------------------------------------------
# argument checks
# --------------------------------------------------------------------------

def _directions(v, name: str) -> np.ndarray:
    arr = as_array(v, name, ndim=2, last=3)
    if arr.shape[0]:
        length = np.sqrt(np.einsum("ij,ij->i", arr, arr))
        bad = ~(np.abs(length - 1.0) <= _UNIT_TOL)
        if np.any(bad):
            raise ValueError(
                f"{name} must hold unit vectors (|length - 1| <= {_UNIT_TOL}); "
                f"row {int(np.argmax(bad))} has length {length[bad][0]!r}")
    return arr


def _pair(wo, wi):
    wo = _directions(wo, "wo")
    wi = _directions(wi, "wi")
    if wo.shape != wi.shape:
        raise ValueError(f"wo and wi must have the same shape (n, 3); got {wo.shape} and {wi.shape}")
    return wo, wi


#: Why a reflectance / transmittance channel must be <= 1 (the message of ``as_rgb``).
_ENERGY = "energy conservation"


def _alpha(a, name: str) -> float:
    a = check_positive(a, name)
    if not a <= 1.0:
        raise ValueError(f"{name} (microfacet roughness) must lie in (0, 1]; got {a}")
    return a


# --------------------------------------------------------------------------
# BSDF objects
# --------------------------------------------------------------------------

class BSDFSample(NamedTuple):
    """Result of :meth:`BSDF.sample`.

    Attributes
    ----------
    wi : ndarray, shape (n, 3)
        Sampled unit directions (pointing away from the surface).
    weight : ndarray, shape (n, 3)
        ``f |cos theta_i| / pdf`` (non-delta) or the chosen delta lobe's
        throughput divided by its probability; 0 for a failed sample.
    pdf : ndarray, shape (n,)
        Per solid angle for non-delta samples; the discrete lobe probability
        for delta samples; 0 for a failed sample.
    """

    wi: np.ndarray
    weight: np.ndarray
    pdf: np.ndarray


class BSDF:
    """Base class: argument checks around the three methods of the contract.

    Subclasses implement ``_eval``, ``_pdf`` and ``_sample`` on checked
    arrays; ``_sample`` returns ``(wi, weight, pdf, delta_mask)``. See the
    module docstring for the conventions (normal +y, both directions pointing
    away, measures of ``pdf``, delta lobes, lobe selection with ``u[:, 0]``).
    """

    #: every lobe is a Dirac delta (``eval`` and ``pdf`` are 0 everywhere)
    is_delta: bool = False
    #: at least one lobe is a Dirac delta (``eval``/``pdf`` omit it)
    has_delta: bool = False
    #: light may cross the surface (``wo.y < 0`` means inside): never flip the normal
    transmissive: bool = False

    def eval(self, wo, wi) -> np.ndarray:
        """BSDF value ``f(wo, wi)``, shape (n, 3) RGB, delta lobes excluded."""
        wo, wi = _pair(wo, wi)
        return self._eval(wo, wi)

    def pdf(self, wo, wi) -> np.ndarray:
        """Solid-angle density of ``sample`` for the non-delta part, shape (n,)."""
        wo, wi = _pair(wo, wi)
        return self._pdf(wo, wi)

    def sample(self, wo, u, *, return_delta: bool = False):
        """Draw ``wi`` given ``wo`` from uniform points ``u`` in [0, 1]^2.

        Parameters
        ----------
        wo : array_like, shape (n, 3)
            Unit outgoing directions in local space.
        u : array_like, shape (n, 2)
            Points in [0, 1]^2 (1.0 included): iid, stratified or QMC.
        return_delta : bool
            Also return a bool mask, shape (n,), True where the sample came
            from a Dirac-delta lobe.

        Returns
        -------
        BSDFSample
            ``(wi, weight, pdf)``, plus the delta mask when asked for.
        """
        wo = _directions(wo, "wo")
        u = as_unit_square(u, "u")
        if u.shape[0] != wo.shape[0]:
            raise ValueError(f"u must have one row per direction: wo has {wo.shape[0]} rows, u has {u.shape[0]}")
        wi, weight, pdf, delta = self._sample(wo, u)
        result = BSDFSample(wi, weight, pdf)
        return (*result, delta) if return_delta else result

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={_fmt(v)}" for k, v in self._params().items())
        return f"{type(self).__name__}({params})"

    def _params(self) -> dict:
        return {}


def _fmt(v):
    if isinstance(v, np.ndarray):
        return "(" + ", ".join(f"{x:g}" for x in v.tolist()) + ")"
    if isinstance(v, float):
        return f"{v:g}"
    return repr(v)


class Lambertian(BSDF):
    """Ideal diffuse reflection ``f = albedo / pi`` (lecture, 'Lambertian Material').

    Parameters
    ----------
    albedo : float or array_like, shape (3,)
        Reflectance ``rho`` per channel, in [0, 1].

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(7)
    >>> wo = np.tile([0.0, 1.0, 0.0], (4, 1))
    >>> wi, weight, pdf = Lambertian((0.8, 0.5, 0.2)).sample(wo, rng.random((4, 2)))
    >>> weight[0].tolist()                               # f cos / pdf = albedo exactly
    [0.8, 0.5, 0.2]

    Notes
    -----
    Sampled with the cosine-weighted hemisphere (``pdf = cos theta_i / pi``),
    so ``weight = f cos / pdf = albedo`` exactly: a zero-variance estimator of
    the directional albedo, which is ``albedo`` for every ``wo``. One-sided:
    0 unless ``wo.y > 0`` and ``wi.y > 0``.
    """

    def __init__(self, albedo=0.8):
        self.albedo = as_rgb(albedo, "albedo", upper=1.0, why=_ENERGY)

    def _params(self):
        return {"albedo": self.albedo}

    def _eval(self, wo, wi):
        ok = (wo[:, 1] > 0.0) & (wi[:, 1] > 0.0)
        return np.where(ok[:, None], self.albedo / np.pi, 0.0)

    def _pdf(self, wo, wi):
        ok = (wo[:, 1] > 0.0) & (wi[:, 1] > 0.0)
        return np.where(ok, square_to_cosine_hemisphere_pdf(wi), 0.0)

    def _sample(self, wo, u):
        wi = square_to_cosine_hemisphere(u)
        pdf = np.where(wo[:, 1] > 0.0, square_to_cosine_hemisphere_pdf(wi), 0.0)
        ok = (pdf > 0.0) & (wi[:, 1] > 0.0)
        pdf = np.where(ok, pdf, 0.0)
        weight = np.where(ok[:, None], self.albedo, 0.0)
        return wi, weight, pdf, np.zeros(len(wo), dtype=bool)


class Mirror(BSDF):
    """Ideal specular reflection, a Dirac delta (lecture, 'Reflective Material').

    ``wi = reflect(wo) = -wo + 2 (wo . n) n``; ``weight = reflectance`` and
    ``pdf = 1`` (the only lobe). ``eval`` and ``pdf`` are 0 for every pair.

    Parameters
    ----------
    reflectance : float or array_like, shape (3,)
        Fraction reflected per channel, in [0, 1] (1: the lecture's ideal
        mirror, nothing absorbed).
    """

    is_delta = True
    has_delta = True

    def __init__(self, reflectance=1.0):
        self.reflectance = as_rgb(reflectance, "reflectance", upper=1.0, why=_ENERGY)

    def _params(self):
        return {"reflectance": self.reflectance}

    def _eval(self, wo, wi):
        return np.zeros((len(wo), 3))

    def _pdf(self, wo, wi):
        return np.zeros(len(wo))

    def _sample(self, wo, u):
        ok = wo[:, 1] > 0.0
        wi = wo * _FLIP_XZ
        weight = np.where(ok[:, None], self.reflectance, 0.0)
        return wi, weight, ok.astype(float), ok.copy()


class Refractive(BSDF):
    """Ideal refraction by Snell's law, a Dirac delta (lecture, 'Refractive Material').

    The +y side is the outside (index 1), the -y side the inside (index
    ``eta``); ``wo.y < 0`` means the ray is inside. Every sample refracts,
    except under total internal reflection, where it reflects (the lecture's
    edge case). No Fresnel reflection: see :class:`Glass` for that.

    Parameters
    ----------
    eta : float
        Index of the inside relative to the outside, > 0.
    transmittance : float or array_like, shape (3,)
        Tint of refracted light, in [0, 1]; total internal reflection is
        lossless (weight 1).
    """

    is_delta = True
    has_delta = True
    transmissive = True

    def __init__(self, eta=1.5, transmittance=1.0):
        self.eta = check_positive(eta, "eta")
        self.transmittance = as_rgb(transmittance, "transmittance", upper=1.0, why=_ENERGY)

    def _params(self):
        return {"eta": self.eta, "transmittance": self.transmittance}

    def _eval(self, wo, wi):
        return np.zeros((len(wo), 3))

    def _pdf(self, wo, wi):
        return np.zeros(len(wo))

    def _sample(self, wo, u):
        wi, tir = refract(wo, 1.0, self.eta)
        weight = np.where(tir[:, None], 1.0, self.transmittance)
        n = len(wo)
        return wi, weight, np.ones(n), np.ones(n, dtype=bool)


_FRESNEL_MODES = ("exact", "schlick")


class Glass(BSDF):
    """Smooth glass: Fresnel-weighted choice of reflection or refraction (lecture, 'Glass').

    The lecture's code: refract; under total internal reflection reflect;
    otherwise reflect with probability ``F`` and refract with ``1 - F``.
    Choosing a lobe with the probability equal to its share of the energy
    makes every weight 1 (times the lobe's tint): ``pdf`` is ``F`` or
    ``1 - F`` (discrete lobe probabilities).

    Parameters
    ----------
    eta : float
        Index of the inside (-y side) relative to the outside (+y side).
    fresnel : {'exact', 'schlick'} or float
        How ``F`` is computed: :func:`fresnel_dielectric`,
        :func:`fresnel_schlick`, or a constant in [0, 1] (the lecture's
        'without Fresnel: constant reflection' picture; total internal
        reflection still reflects everything).
    reflectance, transmittance : float or array_like, shape (3,)
        Tints of the two lobes, in [0, 1].

    Notes
    -----
    The lobe is chosen by ``u[:, 0] < F`` (``F = 1`` always reflects, so
    ``u0 = 1.0`` is safe); ``u[:, 1]`` is unused.
    """

    is_delta = True
    has_delta = True
    transmissive = True

    def __init__(self, eta=1.5, fresnel="exact", reflectance=1.0, transmittance=1.0):
        self.eta = check_positive(eta, "eta")
        if isinstance(fresnel, str):
            check_choice(fresnel, "fresnel", _FRESNEL_MODES)
        elif isinstance(fresnel, numbers.Real) and not isinstance(fresnel, (bool, np.bool_)):
            fresnel = float(fresnel)
            if not 0.0 <= fresnel <= 1.0:
                raise ValueError(f"fresnel as a constant must lie in [0, 1]; got {fresnel}")
        else:
            raise TypeError(f"fresnel must be 'exact', 'schlick' or a number in [0, 1]; got {type(fresnel).__name__}")
        self.fresnel = fresnel
        self.reflectance = as_rgb(reflectance, "reflectance", upper=1.0, why=_ENERGY)
        self.transmittance = as_rgb(transmittance, "transmittance", upper=1.0, why=_ENERGY)

    def _params(self):
        return {"eta": self.eta, "fresnel": self.fresnel}

    def reflectance_probability(self, cos_o) -> np.ndarray:
        """``F`` for outgoing cosines ``cos_o`` (negative: inside the glass)."""
        cos_o = _cosines(cos_o, "cos_o")
        if self.fresnel == "exact":
            f = fresnel_dielectric(cos_o, 1.0, self.eta)
        elif self.fresnel == "schlick":
            f = fresnel_schlick(cos_o, 1.0, self.eta)
        else:
            f = np.full(cos_o.shape, self.fresnel)
        c = np.abs(cos_o)
        r = np.where(cos_o >= 0.0, 1.0 / self.eta, self.eta)
        tir = r * r * (1.0 - c * c) > 1.0
        return np.where(tir, 1.0, f)

    def _eval(self, wo, wi):
        return np.zeros((len(wo), 3))

    def _pdf(self, wo, wi):
        return np.zeros(len(wo))

    def _sample(self, wo, u):
        f = self.reflectance_probability(wo[:, 1])
        wt, _ = refract(wo, 1.0, self.eta)
        choose_r = (u[:, 0] < f) | (f >= 1.0)
        wi = np.where(choose_r[:, None], wo * _FLIP_XZ, wt)
        weight = np.where(choose_r[:, None], self.reflectance, self.transmittance)
        pdf = np.where(choose_r, f, 1.0 - f)
        return wi, weight, pdf, np.ones(len(wo), dtype=bool)


# --------------------------------------------------------------------------
# microfacet reflection (Walter et al. 2007; Heitz 2014)
# --------------------------------------------------------------------------

_DISTRIBUTIONS = ("ggx", "beckmann")


def _smith_lambda(w, ax, ay, distribution):
    """Smith's Lambda for direction(s) ``w`` above the surface (Heitz 2014, eqs. 72, 86)."""
    cos2 = w[:, 1] ** 2
    # alpha^2 tan^2(theta) for the alpha projected on w's azimuth
    a2t2 = np.divide((ax * w[:, 0]) ** 2 + (ay * w[:, 2]) ** 2, cos2,
                     out=np.full(len(w), np.inf), where=cos2 > 0.0)
    if distribution == "ggx":
        return 0.5 * (np.sqrt(1.0 + a2t2) - 1.0)         # inf at grazing
    lam = np.where(np.isinf(a2t2), np.inf, 0.0)          # 0 at normal incidence
    pos = np.isfinite(a2t2) & (a2t2 > 0.0)
    a = 1.0 / np.sqrt(a2t2[pos])
    lam[pos] = 0.5 * (erf(a) - 1.0) + np.exp(-a * a) / (2.0 * a * np.sqrt(np.pi))
    return lam


class Microfacet(BSDF):
    """Glossy microfacet reflection (Cook-Torrance with GGX or Beckmann normals).

    ``f = F(wo . h) D(h) G2(wo, wi) / (4 cos_o cos_i)`` with ``h`` the half
    vector, ``D`` the normal distribution (Trowbridge-Reitz/GGX or Beckmann)
    with roughness ``alpha_x`` along local x and ``alpha_y`` along local z,
    ``G2 = 1 / (1 + Lambda(wo) + Lambda(wi))`` the height-correlated Smith
    shadowing-masking, and Schlick's Fresnel with normal-incidence colour
    ``reflectance``. ``alpha_y != alpha_x`` is anisotropic: rotating both
    directions about the normal changes ``f``.

    Parameters
    ----------
    alpha_x : float
        Roughness (the NDF's ``alpha``, not squared) in (0, 1]; ``alpha -> 0``
        approaches a mirror.
    alpha_y : float, optional
        Roughness along local z; default ``alpha_x`` (isotropic).
    distribution : {'ggx', 'beckmann'}
    reflectance : float or array_like, shape (3,)
        Fresnel reflectance at normal incidence ``F0`` per channel, in [0, 1].

    Notes
    -----
    Sampling draws a half vector ``h`` and reflects ``wo`` about it, so
    ``pdf(wi) = p_h(h) / (4 |wo . h|)`` (Walter et al. 2007, eq. 14). GGX
    draws ``h`` from the distribution of visible normals ``D_wo(h) = G1(wo)
    |wo . h| D(h) / cos_o`` (Heitz 2018), giving ``weight = F G2 / G1(wo) <=
    F``; Beckmann (isotropic only in ``mcvar.warps``) draws ``D(h) cos
    theta_h``, giving ``weight = F G2 |wo . h| / (cos_o cos theta_h)``.
    Samples reflected under the horizon fail (weight 0).

    References
    ----------
    .. [1] B. Walter, S. Marschner, H. Li, K. Torrance, "Microfacet Models for
       Refraction through Rough Surfaces", EGSR 2007.
    .. [2] E. Heitz, "Understanding the Masking-Shadowing Function in
       Microfacet-Based BRDFs", JCGT 3(2), 2014.
    .. [3] R. Cook, K. Torrance, "A Reflectance Model for Computer Graphics",
       ACM TOG 1(1), 1982.
    .. [4] E. Heitz, "Sampling the GGX Distribution of Visible Normals",
       JCGT 7(4), 2018.
    """

    def __init__(self, alpha_x=0.2, alpha_y=None, *,
                 distribution: Literal["ggx", "beckmann"] = "ggx", reflectance=1.0):
        self.alpha_x = _alpha(alpha_x, "alpha_x")
        self.alpha_y = self.alpha_x if alpha_y is None else _alpha(alpha_y, "alpha_y")
        self.distribution = check_choice(distribution, "distribution", _DISTRIBUTIONS)
        if self.distribution == "beckmann" and self.alpha_x != self.alpha_y:
            raise ValueError("anisotropic roughness (alpha_y != alpha_x) needs distribution='ggx'; "
                             f"got beckmann with alpha_x={self.alpha_x}, alpha_y={self.alpha_y}")
        self.reflectance = as_rgb(reflectance, "reflectance", upper=1.0, why=_ENERGY)

    @property
    def anisotropic(self) -> bool:
        """True when ``alpha_x != alpha_y``."""
        return self.alpha_x != self.alpha_y

    def _params(self):
        return {"alpha_x": self.alpha_x, "alpha_y": self.alpha_y,
                "distribution": self.distribution, "reflectance": self.reflectance}

    def fresnel(self, cos_h) -> np.ndarray:
        """Fresnel term at microfacet cosines ``cos_h``, shape ``(n, 3)``."""
        c = np.clip(np.asarray(cos_h, dtype=np.float64), 0.0, 1.0)[:, None]
        return self.reflectance + (1.0 - self.reflectance) * (1.0 - c) ** 5

    # the normal distribution and its sampling (mcvar.warps) ----------------------
    def _ndf(self, h):
        """``D(h)``, from the warps' ``D(h) cos(theta_h)``."""
        if self.distribution == "ggx":
            dcos = square_to_ggx_pdf(h, self.alpha_x, self.alpha_y)
        else:
            dcos = square_to_beckmann_pdf(h, self.alpha_x)
        return np.divide(dcos, h[:, 1], out=np.zeros(len(h)), where=h[:, 1] > 0.0)

    def _h_pdf(self, h, wo_up):
        """Density of the sampled half vector: visible normals (GGX) or ``D cos`` (Beckmann)."""
        if self.distribution == "ggx":
            return square_to_ggx_visible_pdf(h, wo_up, self.alpha_x, self.alpha_y)
        return square_to_beckmann_pdf(h, self.alpha_x)

    def _sample_h(self, u, wo_up):
        if self.distribution == "ggx":
            return square_to_ggx_visible(u, wo_up, self.alpha_x, self.alpha_y)
        return square_to_beckmann(u, self.alpha_x)

    def _lambda(self, w):
        return _smith_lambda(w, self.alpha_x, self.alpha_y, self.distribution)

    @staticmethod
    def _upper(wo):
        """``wo`` with rows below the horizon replaced by +y (they fail anyway)."""
        return np.where((wo[:, 1] >= 0.0)[:, None], wo, np.array([0.0, 1.0, 0.0]))

    @staticmethod
    def _half(wo, wi):
        h = wo + wi
        length = np.sqrt(np.einsum("ij,ij->i", h, h))
        return h / np.maximum(length, 1e-300)[:, None]

    def _eval(self, wo, wi):
        co, ci = wo[:, 1], wi[:, 1]
        ok = (co > 0.0) & (ci > 0.0)
        h = self._half(wo, wi)
        g = 1.0 / (1.0 + self._lambda(wo) + self._lambda(wi))
        value = np.divide(self._ndf(h) * g, 4.0 * co * ci, out=np.zeros(len(wo)), where=ok)
        return self.fresnel(dot(wo, h)) * value[:, None]

    def _pdf(self, wo, wi):
        co, ci = wo[:, 1], wi[:, 1]
        h = self._half(wo, wi)
        oh = dot(wo, h)
        ok = (co > 0.0) & (ci > 0.0) & (oh > 0.0)
        return np.divide(self._h_pdf(h, self._upper(wo)), 4.0 * oh, out=np.zeros(len(wo)), where=ok)

    def _sample(self, wo, u):
        wo_up = self._upper(wo)
        h = self._sample_h(u, wo_up)
        oh = dot(wo, h)
        wi = 2.0 * oh[:, None] * h - wo
        wi /= np.sqrt(np.einsum("ij,ij->i", wi, wi))[:, None]
        co, ci = wo[:, 1], wi[:, 1]
        pdf = np.divide(self._h_pdf(h, wo_up), 4.0 * oh, out=np.zeros(len(wo)), where=oh > 0.0)
        ok = (co > 0.0) & (ci > 0.0) & (oh > 0.0) & (pdf > 0.0)
        lam_o = self._lambda(wo)
        g2 = 1.0 / (1.0 + lam_o + self._lambda(wi))
        if self.distribution == "ggx":      # f cos / pdf = F G2 / G1(wo)
            scale = np.where(ok, g2 * (1.0 + np.where(ok, lam_o, 0.0)), 0.0)
        else:                               # f cos / pdf = F G2 |wo.h| / (cos_o cos_h)
            scale = np.divide(g2 * oh, co * h[:, 1], out=np.zeros(len(wo)), where=ok)
        weight = np.where(ok[:, None], self.fresnel(oh) * np.where(ok, scale, 0.0)[:, None], 0.0)
        return wi, weight, np.where(ok, pdf, 0.0), np.zeros(len(wo), dtype=bool)


class Conductor(Microfacet):
    """A metal: conductor Fresnel with a complex index, smooth or rough.

    ``alpha_x = 0`` (default) is a smooth metal, a Dirac delta like
    :class:`Mirror` with ``weight = F(cos_o)`` per channel; ``alpha_x > 0``
    is the :class:`Microfacet` model with :func:`fresnel_conductor` in place
    of Schlick's approximation (blurred *and* tinted reflections: the
    lecture's copper).

    Parameters
    ----------
    eta, k : float or array_like, shape (3,)
        Real and imaginary parts of the metal's index per RGB channel.
    alpha_x, alpha_y, distribution
        As in :class:`Microfacet`; ``alpha_x = 0`` means smooth.

    See Also
    --------
    Conductor.preset : copper and gold from Johnson & Christy (1972).
    """

    def __init__(self, eta, k, *, alpha_x=0.0, alpha_y=None,
                 distribution: Literal["ggx", "beckmann"] = "ggx"):
        self.eta = as_rgb(eta, "eta")
        self.k = as_rgb(k, "k")
        if not np.all(self.eta > 0.0):
            raise ValueError(f"eta must be > 0 in every channel; got {self.eta.tolist()}")
        smooth = isinstance(alpha_x, numbers.Real) and not isinstance(alpha_x, (bool, np.bool_)) \
            and float(alpha_x) == 0.0 and alpha_y in (None, 0, 0.0)
        if smooth:
            self.alpha_x = self.alpha_y = 0.0
            self.distribution = check_choice(distribution, "distribution", _DISTRIBUTIONS)
            self.is_delta = self.has_delta = True
        else:
            super().__init__(alpha_x, alpha_y, distribution=distribution)
        self.reflectance = self.fresnel(np.ones(1))[0]

    @classmethod
    def preset(cls, name: Literal["copper", "gold"], *, alpha_x=0.0, alpha_y=None,
               distribution: Literal["ggx", "beckmann"] = "ggx") -> "Conductor":
        """Copper or gold with Johnson & Christy's (1972) indices at 659.5/548.6/450.9 nm.

        References
        ----------
        .. [1] P. B. Johnson, R. W. Christy, "Optical Constants of the Noble
           Metals", Physical Review B 6(12), 4370-4379, 1972, Table I.
        """
        check_choice(name, "name", tuple(_PRESETS))
        data = _PRESETS[name]
        return cls(data["eta"], data["k"], alpha_x=alpha_x, alpha_y=alpha_y, distribution=distribution)

    def _params(self):
        return {"eta": self.eta, "k": self.k, "alpha_x": self.alpha_x, "alpha_y": self.alpha_y,
                "distribution": self.distribution}

    def fresnel(self, cos_h) -> np.ndarray:
        return fresnel_conductor(np.clip(np.asarray(cos_h, dtype=np.float64), 0.0, 1.0), self.eta, self.k)

    def _eval(self, wo, wi):
        if self.is_delta:
            return np.zeros((len(wo), 3))
        return super()._eval(wo, wi)

    def _pdf(self, wo, wi):
        if self.is_delta:
            return np.zeros(len(wo))
        return super()._pdf(wo, wi)

    def _sample(self, wo, u):
        if not self.is_delta:
            return super()._sample(wo, u)
        ok = wo[:, 1] > 0.0
        weight = np.where(ok[:, None], self.fresnel(wo[:, 1]), 0.0)
        return wo * _FLIP_XZ, weight, ok.astype(float), ok.copy()


# --------------------------------------------------------------------------
# plastic: a diffuse base under a smooth dielectric coat
# --------------------------------------------------------------------------

def _diffuse_fresnel_reflectance(eta: float, order: int = 96) -> float:
    """Hemispherical average ``2 int_0^1 F(mu; 1 -> eta) mu dmu`` of the exact Fresnel term.

    Gauss-Legendre on [0, 1]; from the outside (``eta >= 1``) the integrand is
    smooth, so 96 nodes are exact to rounding.
    """
    x, w = np.polynomial.legendre.leggauss(order)
    mu = 0.5 * (x + 1.0)
    return float(np.sum(0.5 * w * 2.0 * mu * fresnel_dielectric(mu, 1.0, eta)))


class _DielectricCoat(Microfacet):
    """Isotropic GGX reflection off a rough dielectric (exact Fresnel, untinted)."""

    def __init__(self, alpha, eta):
        super().__init__(alpha, distribution="ggx")
        self.eta = eta

    def fresnel(self, cos_h):
        f = fresnel_dielectric(np.clip(np.asarray(cos_h, dtype=np.float64), 0.0, 1.0), 1.0, self.eta)
        return np.repeat(f[:, None], 3, axis=1)


#: cosines at which a rough coat's directional albedo E(mu) is tabulated
#: (denser towards grazing, where E changes fastest)
_E_MU = ((np.arange(48) + 0.5) / 48) ** 2


class Plastic(BSDF):
    """Plastic: a Lambertian base under a dielectric coat, smooth or rough.

    Light either reflects off the coat, or enters it, scatters in the base
    (albedo ``rho``), possibly bounces between base and coat, and leaves.

    *Smooth coat* (``alpha = 0``, default): the coat reflection is a Dirac
    delta with weight ``specular * F(cos_o)`` (exact Fresnel ``F``), and the
    diffuse part is::

        f_d = (1 - F(cos_o)) (1 - F(cos_i)) rho / (pi eta^2 (1 - rho F_dr,int))

    with ``F_dr,int`` the hemispherical-average reflectance of the coat seen
    from inside, ``1 - F_dr,int = (1 - F_dr,ext) / eta^2``. It is reciprocal,
    and the directional albedo is exactly ``specular F_o + (1 - F_o)
    rho_eff`` with ``rho_eff = rho (1 - F_dr,int) / (1 - rho F_dr,int)`` (the
    series of internal bounces summed), <= 1. The lecture's plastic: flipped
    (delta) and averaged (diffuse). ``is_delta`` False, ``has_delta`` True:
    ``eval``/``pdf`` are the diffuse part only.

    *Rough coat* (``alpha > 0``): the coat is isotropic GGX reflection with
    exact dielectric Fresnel (:class:`Microfacet` machinery), its directional
    albedo ``E(mu)`` is tabulated at construction (deterministic stratified
    sampling), and the base couples through it as in Kelemen &
    Szirmay-Kalos (2001)::

        f_d = rho_eff (1 - E(mu_o)) (1 - E(mu_i)) / (pi (1 - E_avg))

    which is reciprocal and keeps the albedo ``specular E_o + (1 - E_o)
    rho_eff <= 1``; for a smooth coat ``E = F`` and this is the formula above.
    The reflection is flipped *and blurred*. Both lobes are continuous:
    ``has_delta`` False, ``eval``/``pdf`` cover everything.

    Sampling chooses the coat with probability ``P = s E_o / (s E_o + (1 -
    E_o) mean(rho_eff))`` (``s`` the mean specular tint) from ``u[:, 0]``,
    rescaled to ``u0 / P`` or ``(u0 - P) / (1 - P)`` for the chosen lobe.
    Smooth: the delta sample has ``pdf = P`` (discrete), the diffuse one
    ``(1 - P) cos / pi``. Rough: ``pdf`` is the mixture ``P p_coat + (1 - P)
    cos / pi`` whichever lobe drew ``wi``, and ``weight = f cos / pdf``.

    Parameters
    ----------
    diffuse : float or array_like, shape (3,)
        Albedo ``rho`` of the base, in [0, 1].
    eta : float
        Index of the coat, >= 1.
    alpha : float
        GGX roughness of the coat in [0, 1]; 0 is smooth.
    specular : float or array_like, shape (3,)
        Tint of the coat reflection, in [0, 1] (1 for a physical dielectric).

    References
    ----------
    .. [1] A. Weidlich, A. Wilkie, "Arbitrarily Layered Micro-Facet Surfaces",
       GRAPHITE 2007.
    .. [2] C. Kelemen, L. Szirmay-Kalos, "A Microfacet Based Coupled
       Specular-Matte BRDF Model with Importance Sampling", Eurographics
       2001 short papers.
    .. [3] W. Jakob et al., Mitsuba renderer documentation, 'Smooth plastic
       material (plastic)'.
    """

    def __init__(self, diffuse=0.5, *, eta=1.5, alpha=0.0, specular=1.0):
        self.diffuse = as_rgb(diffuse, "diffuse", upper=1.0, why=_ENERGY)
        self.eta = check_positive(eta, "eta")
        if not self.eta >= 1.0:
            raise ValueError(f"eta of a plastic coat must be >= 1; got {self.eta}")
        alpha = check_positive(alpha, "alpha", allow_zero=True)
        self.alpha = 0.0 if alpha == 0.0 else _alpha(alpha, "alpha")
        self.specular = as_rgb(specular, "specular", upper=1.0, why=_ENERGY)
        self.fdr_ext = _diffuse_fresnel_reflectance(self.eta)
        #: hemispherical-average reflectance of the coat seen from inside,
        #: from 1 - F_dr,int = (1 - F_dr,ext) / eta^2 (energy balance).
        self.fdr_int = 1.0 - (1.0 - self.fdr_ext) / self.eta ** 2
        #: the base's albedo after all internal bounces
        self.effective_albedo = self.diffuse * (1.0 - self.fdr_int) / (1.0 - self.diffuse * self.fdr_int)
        self.has_delta = self.alpha == 0.0
        if self.has_delta:
            self._coat = None
            e_avg = self.fdr_ext
        else:
            self._coat = _DielectricCoat(self.alpha, self.eta)
            self._e_table = self._tabulate_coat_albedo()
            # E is piecewise linear in mu: Simpson on each piece is exact
            mu = np.concatenate([[0.0], _E_MU, [1.0]])
            mid = 0.5 * (mu[:-1] + mu[1:])
            g = 2.0 * mu * self._coat_albedo(mu)
            gm = 2.0 * mid * self._coat_albedo(mid)
            e_avg = float(np.sum(np.diff(mu) / 6.0 * (g[:-1] + 4.0 * gm + g[1:])))
        #: hemispherical average of the coat's albedo (F_dr,ext when smooth)
        self.coat_average = e_avg
        self._scale = self.effective_albedo / (np.pi * (1.0 - e_avg))

    def _tabulate_coat_albedo(self, k: int = 48) -> np.ndarray:
        g = (np.arange(k) + 0.5) / k
        u = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
        sin = np.sqrt(1.0 - _E_MU ** 2)
        wo = np.repeat(np.stack([sin, _E_MU, np.zeros_like(sin)], -1), len(u), axis=0)
        weight = self._coat._sample(wo, np.tile(u, (len(_E_MU), 1)))[1][:, 0]
        return weight.reshape(len(_E_MU), -1).mean(axis=1)

    def _coat_albedo(self, mu):
        """Directional albedo ``E(mu)`` of the coat alone (exact Fresnel when smooth)."""
        mu = np.clip(np.asarray(mu, dtype=np.float64), 0.0, 1.0)
        if self._coat is None:
            return fresnel_dielectric(mu, 1.0, self.eta)
        return np.interp(mu, _E_MU, self._e_table)

    def _params(self):
        return {"diffuse": self.diffuse, "eta": self.eta, "alpha": self.alpha, "specular": self.specular}

    def specular_probability(self, cos_o) -> np.ndarray:
        """Probability ``P`` of choosing the coat lobe for outgoing cosines ``cos_o``."""
        e = self._coat_albedo(cos_o)
        a = np.mean(self.specular) * e
        b = (1.0 - e) * np.mean(self.effective_albedo)
        return np.divide(a, a + b, out=np.zeros_like(e), where=(a + b) > 0.0)

    def _diffuse(self, co, ci):
        ok = (co > 0.0) & (ci > 0.0)
        t = (1.0 - self._coat_albedo(co)) * (1.0 - self._coat_albedo(ci))
        return np.where(ok[:, None], t[:, None] * self._scale, 0.0)

    def _eval(self, wo, wi):
        f = self._diffuse(wo[:, 1], wi[:, 1])
        if self._coat is not None:
            f = f + self.specular * self._coat._eval(wo, wi)
        return f

    def _pdf(self, wo, wi):
        co, ci = wo[:, 1], wi[:, 1]
        ok = (co > 0.0) & (ci > 0.0)
        p = self.specular_probability(co)
        pdf = (1.0 - p) * square_to_cosine_hemisphere_pdf(wi)
        if self._coat is not None:
            pdf = pdf + p * self._coat._pdf(wo, wi)
        return np.where(ok, pdf, 0.0)

    def _sample(self, wo, u):
        co = wo[:, 1]
        above = co > 0.0
        p = self.specular_probability(co)
        spec = u[:, 0] < p
        u_d = np.column_stack([np.clip(np.divide(u[:, 0] - p, 1.0 - p, out=np.zeros(len(p)), where=p < 1.0),
                                       0.0, 1.0), u[:, 1]])
        wd = square_to_cosine_hemisphere(u_d)
        if self._coat is None:
            return self._sample_smooth(wo, wd, p, spec, above)
        u_s = np.column_stack([np.clip(np.divide(u[:, 0], p, out=np.zeros(len(p)), where=p > 0.0), 0.0, 1.0),
                               u[:, 1]])
        ws = self._coat._sample(wo, u_s)[0]
        wi = np.where(spec[:, None], ws, wd)
        pdf = self._pdf(wo, wi)
        ok = above & (wi[:, 1] > 0.0) & (pdf > 0.0)
        f = self._eval(wo, wi)
        weight = np.where(ok[:, None], f * np.divide(wi[:, 1], pdf, out=np.zeros(len(p)), where=ok)[:, None], 0.0)
        return wi, weight, np.where(ok, pdf, 0.0), np.zeros(len(wo), dtype=bool)

    def _sample_smooth(self, wo, wd, p, spec, above):
        f_o = self._coat_albedo(wo[:, 1])
        ci = wd[:, 1]
        pdf_d = (1.0 - p) * square_to_cosine_hemisphere_pdf(wd)
        ok_d = above & ~spec & (ci > 0.0) & (pdf_d > 0.0)
        t = np.divide((1.0 - f_o) * (1.0 - self._coat_albedo(ci)), 1.0 - p, out=np.zeros(len(p)), where=ok_d)
        w_d = t[:, None] * self._scale * np.pi
        w_s = np.divide(f_o, p, out=np.zeros(len(p)), where=p > 0.0)[:, None] * self.specular
        ok_s = above & spec
        wi = np.where(spec[:, None], wo * _FLIP_XZ, wd)
        weight = np.where(ok_s[:, None], w_s, np.where(ok_d[:, None], w_d, 0.0))
        pdf = np.where(ok_s, p, np.where(ok_d, pdf_d, 0.0))
        return wi, weight, pdf, spec & above


# --------------------------------------------------------------------------
# retroreflection (Lafortune et al. 1997)
# --------------------------------------------------------------------------

class Retroreflective(BSDF):
    """A retroreflective lobe: light goes back towards where it came from.

    The generalised cosine lobe of Lafortune et al. (1997) with ``C_x = C_y =
    C_z = 1`` (their retro-reflection case ``C_x = C_z > 0``), normalised as
    the modified Phong lobe (Lafortune & Willems 1994)::

        f(wo, wi) = albedo (k + 2) / (2 pi) max(0, wo . wi)^k

    It peaks at ``wi = wo`` for every ``wo`` (a mirror peaks at
    ``reflect(wo)``), is symmetric in ``wo`` and ``wi`` (reciprocal), and its
    directional albedo is at most ``albedo``, reached at normal incidence
    (``int (k+2)/(2 pi) cos^(k+1) dw = 1``). Oren-Nayar's back-scattering is
    a broad rise towards the source; this lobe concentrates it like road
    signs and cat's eyes.

    Sampled by drawing a Phong lobe ``cos^k`` about ``wo`` (``pdf = (k + 1) /
    (2 pi) (wo . wi)^k``), so ``weight = albedo (k + 2) / (k + 1) cos theta_i``;
    directions under the horizon fail.

    Parameters
    ----------
    albedo : float or array_like, shape (3,)
        In [0, 1].
    exponent : float
        Lobe sharpness ``k >= 0``.

    References
    ----------
    .. [1] E. Lafortune, S.-C. Foo, K. Torrance, D. Greenberg, "Non-Linear
       Approximation of Reflectance Functions", SIGGRAPH 1997.
    .. [2] E. Lafortune, Y. Willems, "Using the Modified Phong Reflectance
       Model for Physically Based Rendering", KU Leuven CW 197, 1994.
    """

    def __init__(self, albedo=0.8, exponent=20.0):
        self.albedo = as_rgb(albedo, "albedo", upper=1.0, why=_ENERGY)
        self.exponent = check_positive(exponent, "exponent", allow_zero=True)

    def _params(self):
        return {"albedo": self.albedo, "exponent": self.exponent}

    def _eval(self, wo, wi):
        ok = (wo[:, 1] > 0.0) & (wi[:, 1] > 0.0)
        c = np.maximum(dot(wo, wi), 0.0)
        lobe = (self.exponent + 2.0) / (2.0 * np.pi) * np.power(c, self.exponent)
        return np.where(ok[:, None], lobe[:, None] * self.albedo, 0.0)

    def _pdf(self, wo, wi):
        ok = (wo[:, 1] > 0.0) & (wi[:, 1] > 0.0)
        c = np.maximum(dot(wo, wi), 0.0)
        return np.where(ok, (self.exponent + 1.0) / (2.0 * np.pi) * np.power(c, self.exponent), 0.0)

    def _sample(self, wo, u):
        local = square_to_phong_lobe(u, self.exponent)
        wi = Frame(wo).to_world(local)
        wi /= np.sqrt(np.einsum("ij,ij->i", wi, wi))[:, None]
        pdf = square_to_phong_lobe_pdf(local, self.exponent)
        ok = (wo[:, 1] > 0.0) & (wi[:, 1] > 0.0) & (pdf > 0.0)
        weight = ((self.exponent + 2.0) / (self.exponent + 1.0) * wi[:, 1])[:, None] * self.albedo
        return (wi, np.where(ok[:, None], weight, 0.0), np.where(ok, pdf, 0.0),
                np.zeros(len(wo), dtype=bool))


# --------------------------------------------------------------------------
# what a material does to light: albedo and exitant radiance
# --------------------------------------------------------------------------

class AlbedoEstimate(NamedTuple):
    """Monte Carlo directional albedo: ``mean`` and ``standard_error`` (m, 3), ``n`` per row."""

    mean: np.ndarray
    standard_error: np.ndarray
    n: int


_CHUNK = 1 << 18


def directional_albedo(bsdf: BSDF, wo, *, n: int = 4096, rng=None) -> AlbedoEstimate:
    """Directional albedo ``int f(wo, wi) |cos theta_i| dwi`` for each ``wo``, by sampling.

    The white-furnace quantity of the lecture's 'Integration of BRDF' slide
    (over the whole sphere, so transmission counts for glass): the mean of
    ``n`` sample weights of ``bsdf.sample`` per direction, delta lobes
    included, with its standard error. Energy conservation says it is <= 1.

    Parameters
    ----------
    bsdf : BSDF
    wo : array_like, shape (m, 3)
        Unit outgoing directions.
    n : int
        Samples per direction.
    rng : None, int, SeedSequence or Generator

    Returns
    -------
    AlbedoEstimate
    """
    if not isinstance(bsdf, BSDF):
        raise TypeError(f"bsdf must be an mcvar.bsdf.BSDF; got {type(bsdf).__name__}")
    wo = _directions(wo, "wo")
    n = check_count(n, "n")
    rng = as_rng(rng)
    m = len(wo)
    mean = np.zeros((m, 3))
    var = np.zeros((m, 3))
    rows = max(1, _CHUNK // n)
    for start in range(0, m, rows):          # every row's n samples lie in one block
        block = wo[start:start + rows]
        k = len(block)
        w = bsdf.sample(np.repeat(block, n, axis=0), rng.random((k * n, 2))).weight.reshape(k, n, 3)
        mean[start:start + k] = w.mean(axis=1)
        if n > 1:
            var[start:start + k] = w.var(axis=1, ddof=1)   # two-pass: no cancellation
    return AlbedoEstimate(mean, np.sqrt(var / n), n)


def hemisphere_directions(height: int, width: int | None = None):
    """Directions of the pixels of a hemisphere image (orthographic projection).

    The upper hemisphere is seen from above, projected orthographically onto
    the tangent plane: column ``j`` maps to ``x = 2 (j + 1/2) / width - 1``,
    row ``i`` (row 0 at the top) to ``z = 2 (i + 1/2) / height - 1``, and
    ``y = sqrt(1 - x^2 - z^2)``. Pixels outside the unit disk are not
    directions.

    Returns
    -------
    directions : ndarray, shape (height, width, 3)
        Unit vectors inside the disk, 0 outside.
    inside : ndarray of bool, shape (height, width)
    """
    height = check_count(height, "height")
    width = height if width is None else check_count(width, "width")
    x = 2.0 * (np.arange(width) + 0.5) / width - 1.0
    z = 2.0 * (np.arange(height) + 0.5) / height - 1.0
    xx, zz = np.meshgrid(x, z)
    r2 = xx * xx + zz * zz
    inside = r2 < 1.0
    y = np.sqrt(np.maximum(0.0, 1.0 - r2))
    d = np.stack([xx, y, zz], axis=-1)
    return np.where(inside[..., None], d, 0.0), inside


def hemisphere_lookup(image, directions) -> np.ndarray:
    """Radiance of a hemisphere image (see :func:`hemisphere_directions`) in given directions.

    Nearest pixel; 0 for directions with ``y <= 0`` (no light from below).

    Parameters
    ----------
    image : array_like, shape (H, W, 3)
        Non-negative radiance.
    directions : array_like, shape (n, 3)

    Returns
    -------
    ndarray, shape (n, 3)
    """
    image = as_array(image, "image", ndim=3, last=3, nonnegative=True)
    d = as_array(directions, "directions", ndim=2, last=3)
    h, w = image.shape[:2]
    j = np.clip(np.floor((d[:, 0] + 1.0) * 0.5 * w).astype(np.int64), 0, w - 1)
    i = np.clip(np.floor((d[:, 2] + 1.0) * 0.5 * h).astype(np.int64), 0, h - 1)
    return np.where((d[:, 1] > 0.0)[:, None], image[i, j], 0.0)


def exitant_radiance(bsdf: BSDF, incident, *, n: int = 64, size: int | None = None,
                     sampler: str = "random", rng=None) -> np.ndarray:
    """Exitant radiance of a material lit by an incident radiance field on the hemisphere.

    ``L_o(wo) = int f(wo, wi) L_i(wi) cos theta_i dwi`` for every pixel
    direction ``wo`` of a hemisphere image, estimated with ``n`` BSDF samples
    per pixel: ``mean(weight * L_i(wi))`` (delta lobes included). An image
    holds the upper hemisphere only (light from below is 0); a callable is
    asked about every sampled direction, so a transmissive material can see
    what lies below it. The lecture's exitant-radiance panels: diffuse
    averages everything to one colour, a mirror flips the image about the
    normal (a 180-degree rotation in this projection), plastic flips and
    averages, rough copper blurs and tints.

    Parameters
    ----------
    bsdf : BSDF
    incident : array_like, shape (H, W, 3), or callable
        A hemisphere image (:func:`hemisphere_directions` layout) or a
        function ``L(wi) -> (m, 3)`` of unit directions (any hemisphere).
    n : int
        Samples per pixel.
    size : int, optional
        Output size when ``incident`` is a callable (square image); default
        the image's own shape.
    sampler : str
        A key of :data:`mcvar.samplers.SAMPLERS` for each pixel's ``n`` points
        ('jittered' needs a square ``n``); stratified sets give smoother
        panels than 'random' for the same ``n``.
    rng : None, int, SeedSequence or Generator

    Returns
    -------
    ndarray, shape (H, W, 3)
        Exitant radiance, 0 outside the disk.
    """
    if not isinstance(bsdf, BSDF):
        raise TypeError(f"bsdf must be an mcvar.bsdf.BSDF; got {type(bsdf).__name__}")
    n = check_count(n, "n")
    check_choice(sampler, "sampler", tuple(SAMPLERS))
    rng = as_rng(rng)
    if callable(incident):
        if size is None:
            raise ValueError("size is required when incident is a callable")
        height = width = check_count(size, "size")
        radiance: Callable = incident
    else:
        image = as_array(incident, "incident", ndim=3, last=3, nonnegative=True)
        height, width = image.shape[:2]
        if size is not None and check_count(size, "size") != height:
            raise ValueError(f"size must match the incident image ({height}) or be None; got {size}")

        def radiance(d):
            return hemisphere_lookup(image, d)

    dirs, inside = hemisphere_directions(height, width)
    wo = dirs[inside]
    wo /= np.sqrt(np.einsum("ij,ij->i", wo, wo))[:, None]
    out = np.zeros((len(wo), 3))
    rows = max(1, _CHUNK // n)
    for start in range(0, len(wo), rows):
        k = len(wo[start:start + rows])
        block = np.repeat(wo[start:start + rows], n, axis=0)
        s = bsdf.sample(block, pixel_samples(sampler, k, n, rng=rng).reshape(-1, 2))
        live = np.any(s.weight > 0.0, axis=1)
        li = np.zeros((len(block), 3))
        if np.any(live):
            vals = as_array(radiance(s.wi[live]), "incident(wi)", nonnegative=True)
            if vals.shape != (int(live.sum()), 3):
                raise ValueError(f"incident(wi) must return shape (m, 3) for m directions; got {vals.shape}")
            li[live] = vals
        out[start:start + rows] = (s.weight * li).reshape(-1, n, 3).mean(axis=1)
    result = np.zeros((height, width, 3))
    result[inside] = out
    return result
