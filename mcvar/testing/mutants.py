"""Deliberately broken samplers, pdfs, inverses and BSDFs (layer 3).

Each mutant reproduces a bug that physically based renderers have shipped:
a pdf that does not match its sampler, a forgotten ``sin(theta)``
Jacobian, a pdf off by a constant factor, an off-by-one exponent, ``u = 1.0``
indexing past a table, ``0 * inf`` at the horizon, a wrong inverse, a pdf
that ignores the samples its sampler fails (or a sampler failing where its
pdf says it should not), and BSDFs whose sample weights are not
``f cos / pdf``, whose pdf is off by a factor, or whose samples are drawn in
a mirrored frame. The checks of
:mod:`mcvar.testing` must reject every one of them; ``tests/test_testing.py``
proves it and measures how many samples each check needs (the table in
``docs/testing.md``).

A :class:`Mutant` names the checks that must catch it in ``caught_by``; the
checks not listed are not expected to (e.g. a sampler paired with the pdf of
another *normalised* distribution passes :func:`check_pdf_normalized`: only
the chi-square test can see it).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .. import warps
from .._validation import as_unit_square, check_positive
from ..geometry import Frame

__all__ = [
    "Mutant",
    "MUTANTS",
    "get",
    "weight_without_cos",
    "weight_not_divided_by_pdf",
    "sample_pdf_scaled",
    "pdf_scaled",
    "sample_tangent_flipped",
]

_PHONG_K = 20.0
_GGX_ALPHA = 0.3


@dataclass(frozen=True)
class Mutant:
    """A broken (sampler, pdf[, inverse]) triple and the correct one it breaks.

    Attributes
    ----------
    name, description : str
    domain : str
        Domain for :func:`mcvar.testing.chi2_test`.
    sample, pdf : callable
        The mutant's sampler ``sample(u)`` and pdf ``pdf(x)``.
    inverse : callable or None
        The mutant's inverse map, for :func:`mcvar.testing.check_inverse`.
    caught_by : tuple of str
        Checks that must reject it: ``'chi2'``, ``'pdf_normalized'``,
        ``'inverse'``, ``'extremes'``, ``'unbiased'``.
    correct_sample, correct_pdf : callable
        The pair it was derived from (passes every check).
    """

    name: str
    description: str
    domain: str
    sample: Callable
    pdf: Callable
    caught_by: tuple
    correct_sample: Callable
    correct_pdf: Callable
    inverse: Callable | None = None


# ---- broken samplers --------------------------------------------------------

def _hemisphere_uniform_theta(u):
    """theta uniform in [0, pi/2]: directions crowd the pole (no sin theta)."""
    u = as_unit_square(u)
    theta = 0.5 * np.pi * u[:, 0]
    phi = 2.0 * np.pi * u[:, 1]
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), np.cos(theta), s * np.sin(phi)], axis=-1)


def _pdf_theta_phi_as_solid_angle(v):
    """The (theta, phi) density of the theta-uniform sampler, 1 / (pi/2 * 2 pi)
    = 1 / pi^2, returned as if per solid angle: the 1 / sin(theta) forgotten
    (the correct solid-angle pdf is 1 / (pi^2 sin theta))."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v[:, 1] >= 0.0, 1.0 / np.pi ** 2, 0.0)


def _phong_off_by_one(u):
    """cos(theta) = u0^(1/k) instead of u0^(1/(k+1)): samples the k - 1 lobe."""
    return warps.square_to_phong_lobe(u, _PHONG_K - 1.0)


def _disk_linear_radius(u):
    """r = u0 instead of sqrt(u0): points crowd the centre."""
    u = as_unit_square(u)
    r = u[:, 0]
    phi = 2.0 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)


def _triangle_fold_free(u):
    """(b1, b2) = (u0, u1 (1 - u0)): inside the triangle but not uniform."""
    u = as_unit_square(u)
    return np.stack([u[:, 0], u[:, 1] * (1.0 - u[:, 0])], axis=-1)


_TABLE_N = 64
_TABLE_EDGES = np.linspace(0.0, 1.0, _TABLE_N + 1)


def _tabulated_hemisphere_unclamped(u):
    """Uniform hemisphere through a tabulated CDF in cos(theta), indexed with
    int(u0 * N) and no clamp: u0 = 1.0 reads one past the end."""
    u = np.asarray(u, dtype=np.float64)
    x = u[:, 0] * _TABLE_N
    i = x.astype(np.int64)
    frac = x - i
    cos_t = _TABLE_EDGES[i] + (_TABLE_EDGES[i + 1] - _TABLE_EDGES[i]) * frac
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t ** 2))
    phi = 2.0 * np.pi * u[:, 1]
    return np.stack([sin_t * np.cos(phi), cos_t, sin_t * np.sin(phi)], axis=-1)


def _cosine_unclamped_sqrt(u):
    """Malley's method with y = sqrt(1 - x^2 - z^2) unclamped: NaN where the
    concentric map's radius rounds above 1 on the square's boundary."""
    d = warps.square_to_uniform_disk_concentric(u)
    with np.errstate(invalid="ignore"):
        y = np.sqrt(1.0 - d[:, 0] ** 2 - d[:, 1] ** 2)
    return np.stack([d[:, 0], y, d[:, 1]], axis=-1)


def _ggx_pdf_textbook(v):
    """GGX D(h) cos(theta) from the tan^2 form: 0 * inf = NaN at the horizon."""
    v = np.asarray(v, dtype=np.float64)
    a2 = _GGX_ALPHA ** 2
    c = v[:, 1]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        tan2 = (1.0 - c * c) / (c * c)
        d = 1.0 / (np.pi * a2 * c ** 4 * (1.0 + tan2 / a2) ** 2)
        return np.where(c >= 0.0, d * c, 0.0)


def _ggx_pdf_without_cos(v):
    """D(h) alone, forgetting that the sampled density is D(h) cos(theta_h)."""
    v = np.asarray(v, dtype=np.float64)
    c = np.maximum(v[:, 1], 1e-300)
    return np.where(v[:, 1] > 0.0, warps.square_to_ggx_pdf(v, _GGX_ALPHA) / c, 0.0)


# A cosine lobe about a shading normal tilted by _TILT from the geometric
# normal +y (bump mapping): samples below the geometric horizon fail. Malley's
# method makes the failed set, in the lobe's projected disk, a half disk minus
# a half ellipse with semi-axes (cos tilt, 1): P(valid) = (1 + cos tilt) / 2.
_TILT = np.pi / 4
_SHADING_NORMAL = np.array([np.sin(_TILT), np.cos(_TILT), 0.0])
_P_VALID = 0.5 * (1.0 + np.cos(_TILT))
_EPSILON = 0.05


def _cos_shading(u):
    """Cosine lobe about the tilted shading normal; ``(points, valid)``."""
    d = Frame(_SHADING_NORMAL).to_world(warps.square_to_cosine_hemisphere(u))
    return d, d[:, 1] > 0.0


def _cos_shading_pdf(v):
    """Density of the valid samples: cos(theta_s) / pi above the geometric
    horizon, 0 below; it integrates to P(valid) = (1 + cos tilt) / 2."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v[:, 1] > 0.0, np.maximum(v @ _SHADING_NORMAL, 0.0) / np.pi, 0.0)


def _cos_shading_pdf_renormalised(v):
    """The failures ignored: the pdf renormalised to 1 over the valid region."""
    return _cos_shading_pdf(v) / _P_VALID


def _cos_shading_epsilon(u):
    """Also fails samples with y < epsilon (a grazing cut-off the pdf does not know)."""
    d, _ = _cos_shading(u)
    return d, d[:, 1] > _EPSILON


def _scaled(pdf, factor):
    return lambda v: factor * pdf(v)


_cos_s, _cos_p = warps.square_to_cosine_hemisphere, warps.square_to_cosine_hemisphere_pdf
_uni_s, _uni_p = warps.square_to_uniform_hemisphere, warps.square_to_uniform_hemisphere_pdf


def _phong_s(u):
    return warps.square_to_phong_lobe(u, _PHONG_K)


def _phong_p(v):
    return warps.square_to_phong_lobe_pdf(v, _PHONG_K)


def _ggx_s(u):
    return warps.square_to_ggx(u, _GGX_ALPHA)


def _ggx_p(v):
    return warps.square_to_ggx_pdf(v, _GGX_ALPHA)


def _flip_pdf_without_half(v):
    return warps.square_to_uniform_sphere_flip_pdf(v) * 2.0


MUTANTS: dict[str, Mutant] = {m.name: m for m in (
    Mutant("cosine_sampler_uniform_pdf",
           "cosine-weighted sampler reported with the uniform hemisphere pdf 1/(2 pi)",
           "hemisphere", _cos_s, _uni_p, ("chi2", "unbiased"), _cos_s, _cos_p),
    Mutant("pdf_times_2", "cosine sampler with pdf 2 cos / pi (off by a factor of 2)",
           "hemisphere", _cos_s, _scaled(_cos_p, 2.0), ("chi2", "pdf_normalized", "unbiased"),
           _cos_s, _cos_p),
    Mutant("pdf_times_1.05", "cosine sampler with pdf 1.05 cos / pi (5% too large)",
           "hemisphere", _cos_s, _scaled(_cos_p, 1.05), ("chi2", "pdf_normalized", "unbiased"),
           _cos_s, _cos_p),
    Mutant("pdf_missing_sin_theta",
           "theta-uniform hemisphere sampler with its (theta, phi) density 1/pi^2 used as a "
           "solid-angle pdf: the 1/sin(theta) Jacobian forgotten",
           "hemisphere", _hemisphere_uniform_theta, _pdf_theta_phi_as_solid_angle,
           ("chi2", "pdf_normalized"), _uni_s, _uni_p),
    Mutant("sampler_missing_sin_theta",
           "theta drawn uniformly (no sin(theta) in the sampler) but the uniform pdf 1/(2 pi) "
           "reported", "hemisphere", _hemisphere_uniform_theta, _uni_p, ("chi2",), _uni_s, _uni_p),
    Mutant("phong_exponent_off_by_one",
           f"Phong sampler with cos = u^(1/k) (exponent {_PHONG_K - 1:g}) against the pdf of "
           f"k = {_PHONG_K:g}", "hemisphere", _phong_off_by_one, _phong_p, ("chi2",),
           _phong_s, _phong_p),
    Mutant("sphere_flip_without_half",
           "the lecture's coin-flip sphere sampler with the hemisphere pdf 1/(2 pi) (forgot "
           "'half the pdf')", "sphere", warps.square_to_uniform_sphere_flip, _flip_pdf_without_half,
           ("chi2", "pdf_normalized"), warps.square_to_uniform_sphere_flip,
           warps.square_to_uniform_sphere_flip_pdf),
    Mutant("ggx_pdf_without_cos", f"GGX (alpha {_GGX_ALPHA}) sampler with pdf D(h), missing cos(theta_h)",
           "hemisphere", _ggx_s, _ggx_pdf_without_cos, ("chi2", "pdf_normalized"), _ggx_s, _ggx_p),
    Mutant("disk_linear_radius", "disk sampler with r = u0 instead of sqrt(u0), pdf 1/pi",
           "disk", _disk_linear_radius, warps.square_to_uniform_disk_concentric_pdf, ("chi2",),
           warps.square_to_uniform_disk_concentric, warps.square_to_uniform_disk_concentric_pdf),
    Mutant("triangle_non_uniform", "triangle sampler (u0, u1 (1 - u0)) with the uniform pdf 2",
           "square", _triangle_fold_free, warps.square_to_uniform_triangle_pdf, ("chi2",),
           warps.square_to_uniform_triangle, warps.square_to_uniform_triangle_pdf),
    Mutant("table_index_past_end",
           "tabulated hemisphere sampler indexing int(u0 * N) without clamping: u0 = 1.0 "
           "reads past the table", "hemisphere", _tabulated_hemisphere_unclamped, _uni_p,
           ("extremes",), _uni_s, _uni_p),
    Mutant("cosine_unclamped_sqrt",
           "cosine hemisphere with y = sqrt(1 - r^2) unclamped: NaN where r rounds above 1",
           "hemisphere", _cosine_unclamped_sqrt, _cos_p, ("extremes",), _cos_s, _cos_p),
    Mutant("ggx_pdf_nan_at_horizon",
           "GGX pdf from the textbook tan^2 form: 0 * inf = NaN for a normal on the horizon",
           "hemisphere", _ggx_s, _ggx_pdf_textbook, ("extremes",), _ggx_s, _ggx_p),
    Mutant("pdf_ignores_failures",
           "cosine lobe about a shading normal tilted 45 degrees, samples below the geometric "
           "horizon failing, with its pdf renormalised to 1 over the valid region (it must "
           f"integrate to P(valid) = {_P_VALID:.4f})", "hemisphere", _cos_shading,
           _cos_shading_pdf_renormalised, ("chi2", "unbiased"), _cos_shading, _cos_shading_pdf),
    Mutant("failure_cutoff_not_in_pdf",
           f"the same tilted cosine lobe failing every sample with y < {_EPSILON:g} (a grazing "
           "cut-off) while its pdf still counts them", "hemisphere", _cos_shading_epsilon,
           _cos_shading_pdf, ("chi2",), _cos_shading, _cos_shading_pdf),
    Mutant("cosine_wrong_inverse",
           "cosine hemisphere paired with the uniform hemisphere's inverse",
           "hemisphere", _cos_s, _cos_p, ("inverse",), _cos_s, _cos_p,
           inverse=warps.uniform_hemisphere_to_square),
)}


def get(name: str) -> Mutant:
    """The mutant called ``name`` (a ``ValueError`` lists the names)."""
    try:
        return MUTANTS[name]
    except KeyError:
        raise ValueError(f"name must be one of {tuple(MUTANTS)}; got {name!r}") from None


# ---- broken BSDFs: wrappers around any correct BSDF ------------------------

class _Wrapped:
    """A BSDF whose ``sample`` (and optionally ``pdf``) is altered; ``eval``
    passes through, as do ``is_delta``, ``has_delta``, ``transmissive`` and
    ``sample(..., return_delta=True)``."""

    def __init__(self, bsdf, alter, description, pdf_factor=1.0):
        for meth in ("eval", "pdf", "sample"):
            if not callable(getattr(bsdf, meth, None)):
                raise TypeError(f"bsdf must have a callable {meth}(...); got {type(bsdf).__name__}")
        self._bsdf = bsdf
        self._alter = alter
        self._pdf_factor = pdf_factor
        self.description = description
        self.is_delta = bool(getattr(bsdf, "is_delta", False))
        self.has_delta = bool(getattr(bsdf, "has_delta", self.is_delta))
        self.transmissive = bool(getattr(bsdf, "transmissive", False))

    def eval(self, wo, wi):
        return self._bsdf.eval(wo, wi)

    def pdf(self, wo, wi):
        return self._pdf_factor * np.asarray(self._bsdf.pdf(wo, wi), dtype=np.float64)

    def sample(self, wo, u, *, return_delta=False):
        out = self._bsdf.sample(wo, u, return_delta=True) if return_delta else self._bsdf.sample(wo, u)
        wi, weight, pdf = self._alter(np.array(out[0], dtype=np.float64),
                                      np.asarray(out[1], dtype=np.float64),
                                      np.asarray(out[2], dtype=np.float64))
        return (wi, weight, pdf, out[3]) if return_delta else (wi, weight, pdf)

    def __repr__(self):
        return f"<mutant BSDF: {self.description}>"


def _col(x, like):
    return x.reshape(x.shape + (1,) * (like.ndim - x.ndim))


def weight_without_cos(bsdf):
    """``bsdf`` whose sample weight is ``f / pdf``: the cosine forgotten."""
    def alter(wi, weight, pdf):
        c = np.abs(wi[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.where(_col(c, weight) > 0, weight / _col(np.where(c > 0, c, 1.0), weight), 0.0)
        return wi, w, pdf
    return _Wrapped(bsdf, alter, "weight = f / pdf (cos theta forgotten)")


def weight_not_divided_by_pdf(bsdf):
    """``bsdf`` whose sample weight is ``f cos``: not divided by the pdf
    (the lecture's 'biased' estimator)."""
    def alter(wi, weight, pdf):
        return wi, weight * _col(pdf, weight), pdf
    return _Wrapped(bsdf, alter, "weight = f cos (not divided by the pdf)")


def sample_pdf_scaled(bsdf, factor=1.05):
    """``bsdf`` whose ``sample`` reports ``factor`` times the pdf that
    ``pdf(wo, wi)`` gives (and a weight consistent with the wrong pdf)."""
    factor = check_positive(factor, "factor")

    def alter(wi, weight, pdf):
        return wi, weight / factor, pdf * factor
    return _Wrapped(bsdf, alter, f"sample() reports {factor:g} x pdf()")


def pdf_scaled(bsdf, factor=1.05):
    """``bsdf`` whose pdf is ``factor`` times too large, consistently: both
    ``pdf(wo, wi)`` and the pdf ``sample`` reports, with the weight divided
    accordingly (a constant dropped from the pdf formula). Weights stay
    ``eval |cos| / pdf``, so :func:`mcvar.testing.check_weight_consistency`
    cannot see it; :func:`mcvar.testing.bsdf_chi2_test` can (the pdf no
    longer integrates to the fraction of valid samples)."""
    factor = check_positive(factor, "factor")

    def alter(wi, weight, pdf):
        return wi, weight / factor, pdf * factor
    return _Wrapped(bsdf, alter, f"pdf() and sample() both {factor:g} x the true pdf",
                    pdf_factor=factor)


def sample_tangent_flipped(bsdf):
    """``bsdf`` whose sampled ``wi`` is mirrored across the plane of the
    normal and the bitangent (``x -> -x``: a shading frame with a flipped
    tangent), weight and pdf unchanged. Invisible for lobes symmetric under
    that mirror (a diffuse lobe, ``wo`` in the plane ``x = 0``); otherwise
    :func:`mcvar.testing.bsdf_chi2_test` sees the lobe in the wrong place."""
    def alter(wi, weight, pdf):
        wi[:, 0] = -wi[:, 0]
        return wi, weight, pdf
    return _Wrapped(bsdf, alter, "wi sampled in a frame with a flipped tangent")
