"""The course notebooks' exercises: how each is graded, a reference solution
and a planted wrong one (layer 3).

Every notebook ``notebooks/01`` ... ``06`` ends with exercises in which the
student writes the piece of code the lecture teaches into a stub, then runs
one cell::

    grade.exercise("01.jittered", jittered)

:data:`EXERCISES` maps each exercise name to an :class:`Exercise`: the
grader call with its fixed parameters (a seed, the exact value, the
domain), the names of the parts the student writes, a **reference**
solution, which must PASS, and a **wrong** solution carrying a classic
mistake, which must FAIL (``tests/test_grade.py`` runs both for every
exercise, so the graders themselves are tested). A course's own
autograder can import the same registry.

Reference and wrong solutions use NumPy and :mod:`mcvar.warps` only, as a
student would.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .. import warps
from .._validation import as_rng, check_choice
from .grade import (GradeResult, grade_bsdf, grade_consistent, grade_estimator, grade_pixel_sampler,
                    grade_sampler, grade_values, grade_warp)

__all__ = ["Exercise", "EXERCISES", "LambertianSolution", "exercise"]


@dataclass(frozen=True)
class Exercise:
    """One exercise of a course notebook.

    Attributes
    ----------
    name : str
        ``'NN.topic'``, NN the notebook number.
    title : str
    lecture : str
        The slide it exercises.
    parts : tuple of str
        What the student writes, in the order :meth:`grade` takes them.
    grade : callable
        ``grade(*parts, verbose=True) -> GradeResult``.
    reference : tuple
        A correct solution (PASS).
    wrong : tuple
        A solution with the classic mistake ``mistake`` (FAIL).
    mistake : str
    """

    name: str
    title: str
    lecture: str
    parts: tuple
    grade: Callable[..., GradeResult]
    reference: tuple
    wrong: tuple
    mistake: str

    @property
    def notebook(self) -> str:
        """The notebook number, e.g. ``'01'``."""
        return self.name.split(".")[0]


EXERCISES: dict[str, Exercise] = {}


def _register(ex: Exercise) -> Exercise:
    if ex.name in EXERCISES:
        raise ValueError(f"duplicate exercise {ex.name!r}")
    EXERCISES[ex.name] = ex
    return ex


# --------------------------------------------------------------------------
# 01 samplers

def _jittered(n, rng=None):
    k = math.isqrt(n)
    g = as_rng(rng)
    i, j = np.divmod(np.arange(n), k)
    return np.stack([(i + g.random(n)) / k, (j + g.random(n)) / k], axis=1)


def _jittered_wrong(n, rng=None):
    # a cell per sample, but the jitter is only half a cell: stratified, not uniform
    k = math.isqrt(n)
    g = as_rng(rng)
    i, j = np.divmod(np.arange(n), k)
    return np.stack([(i + 0.5 * g.random(n)) / k, (j + 0.5 * g.random(n)) / k], axis=1)


_register(Exercise(
    "01.jittered", "Jittered sampling", "Jittered Sampling",
    ("jittered",),
    lambda jittered, verbose=True: grade_sampler(jittered, 64, strata=(8, 8), replicates=400, rng=101,
                                                 name="01.jittered", verbose=verbose),
    (_jittered,), (_jittered_wrong,),
    "a random offset of half a cell: one point per stratum, but never in the upper half of any cell"))


def _radical_inverse2(i):
    i = np.asarray(i, dtype=np.uint64)
    out = np.zeros(i.shape)
    scale = 0.5
    while np.any(i):
        out += (i & np.uint64(1)) * scale
        i = i >> np.uint64(1)
        scale *= 0.5
    return out


def _hammersley(n, rng=None):
    i = np.arange(n)
    return np.stack([i / n, _radical_inverse2(i)], axis=1)


def _hammersley_wrong(n, rng=None):
    # the binary digits of i read in order instead of mirrored: y = i / n, every point on the diagonal
    i = np.arange(n)
    return np.stack([i / n, i / n], axis=1)


_register(Exercise(
    "01.hammersley", "Hammersley points", "Hammersley Sampling",
    ("hammersley",),
    lambda hammersley, verbose=True: grade_sampler(hammersley, 256, net=8, randomized=False, rng=102,
                                                   name="01.hammersley", verbose=verbose),
    (_hammersley,), (_hammersley_wrong,),
    "digits not mirrored about the point: Phi(i) = i / n puts every point on the diagonal"))


# --------------------------------------------------------------------------
# 02 estimators

def _board(x):
    return ((np.floor(x[:, 0]) + np.floor(x[:, 1])) % 2 == 0).astype(np.float64)


def _checkerboard(n, rng=None):
    x = 2.0 * as_rng(rng).random((n, 2))          # uniform on [0, 2]^2, p = 1/4
    return float(np.mean(_board(x) / 0.25))


def _checkerboard_wrong(n, rng=None):
    x = 2.0 * as_rng(rng).random((n, 2))
    return float(np.mean(_board(x)))             # the mean of f, not the integral: forgot 1/p


_register(Exercise(
    "02.checkerboard", "The checkerboard estimator", "Variance Reduction Example",
    ("estimate",),
    lambda estimate, verbose=True: grade_estimator(estimate, 2.0, n=1000, replicates=200, variance=4.0,
                                                   rng=201, name="02.checkerboard", verbose=verbose),
    (_checkerboard,), (_checkerboard_wrong,),
    "averages f without dividing by the pdf (estimates the mean 1/2, not the integral 2)"))


def _cos2(w):
    return np.maximum(w[:, 1], 0.0) ** 2


def _cosine_estimate(n, rng=None):
    w = warps.square_to_cosine_hemisphere(as_rng(rng).random((n, 2)))
    return float(np.mean(_cos2(w) / warps.square_to_cosine_hemisphere_pdf(w)))


def _cosine_estimate_wrong(n, rng=None):
    w = warps.square_to_cosine_hemisphere(as_rng(rng).random((n, 2)))
    return float(np.mean(_cos2(w) * 2.0 * math.pi))   # the uniform estimator's 2 pi with cosine samples


_register(Exercise(
    "02.cosine", "Cosine-weighted Monte Carlo", "Monte Carlo Cosine Sampling",
    ("estimate",),
    lambda estimate, verbose=True: grade_estimator(estimate, 2.0 * math.pi / 3.0, n=1000, replicates=100,
                                                   rng=202, name="02.cosine", verbose=verbose),
    (_cosine_estimate,), (_cosine_estimate_wrong,),
    "multiplies by the uniform 2 pi while drawing cosine-distributed directions"))


# --------------------------------------------------------------------------
# 03 BRDFs

class LambertianSolution:
    """Reference solution of exercise ``03.lambertian``: f = rho / pi, cosine sampling."""

    def __init__(self, albedo=0.8, *, pdf_without_cos=False):
        self.albedo = float(albedo)
        self._wrong = pdf_without_cos

    def eval(self, wo, wi):
        wi = np.asarray(wi, dtype=np.float64)
        up = (np.asarray(wo)[..., 1] > 0) & (wi[..., 1] > 0)
        return np.where(up, self.albedo / math.pi, 0.0)

    def pdf(self, wo, wi):
        wi = np.asarray(wi, dtype=np.float64)
        if self._wrong:   # the classic slip: uniform-hemisphere pdf for cosine samples
            return np.where(wi[..., 1] > 0, 1.0 / (2.0 * math.pi), 0.0)
        return np.where(wi[..., 1] > 0, wi[..., 1] / math.pi, 0.0)

    def sample(self, wo, u):
        wi = warps.square_to_cosine_hemisphere(u)
        p = self.pdf(wo, wi)
        with np.errstate(divide="ignore", invalid="ignore"):
            weight = np.where(p > 0, self.eval(wo, wi) * wi[:, 1] / np.where(p > 0, p, 1.0), 0.0)
        return wi, weight, p


_register(Exercise(
    "03.lambertian", "A Lambertian BSDF", "Lambertian Material",
    ("bsdf",),
    lambda bsdf, verbose=True: grade_bsdf(bsdf, n=100_000, rng=301, name="03.lambertian", verbose=verbose),
    (LambertianSolution(0.8),), (LambertianSolution(0.8, pdf_without_cos=True),),
    "reports the uniform pdf 1/(2 pi) for cosine-distributed samples"))

#: Schlick at air -> glass (R0 = 0.04) by hand: cos = 1, 0.8, 0.5, 0.2, 0.
_SCHLICK_COS = np.array([1.0, 0.8, 0.5, 0.2, 0.0])
_SCHLICK_VALUES = np.array([0.04, 0.04 + 0.96 * 0.2 ** 5, 0.04 + 0.96 / 32.0, 0.04 + 0.96 * 0.8 ** 5, 1.0])


def _schlick(cos_theta, n1, n2):
    r0 = ((n1 - n2) / (n1 + n2)) ** 2
    return r0 + (1.0 - r0) * (1.0 - cos_theta) ** 5


def _schlick_wrong(cos_theta, n1, n2):
    r0 = ((n1 - n2) / (n1 + n2)) ** 2
    return r0 + (1.0 - r0) * (1.0 - cos_theta) ** 4   # exponent 4: right at 0 and 90 degrees only


_register(Exercise(
    "03.schlick", "Schlick's approximation", "Schlick's Approximation",
    ("schlick",),
    lambda schlick, verbose=True: grade_values(schlick, (_SCHLICK_COS, 1.0, 1.5), _SCHLICK_VALUES,
                                               rtol=1e-9, name="03.schlick", verbose=verbose),
    (_schlick,), (_schlick_wrong,),
    "exponent 4 instead of 5 (agrees at normal and grazing incidence)"))


# --------------------------------------------------------------------------
# 04 environment lighting

def _sphere_flip(u):
    u = np.asarray(u, dtype=np.float64)
    flip = u[:, 0] >= 0.5
    u0 = np.where(flip, 2.0 * u[:, 0] - 1.0, 2.0 * u[:, 0])       # reuse the coin's bit
    w = warps.square_to_uniform_hemisphere(np.stack([np.minimum(u0, 1.0), u[:, 1]], axis=1))
    w[flip, 1] *= -1.0
    return w


def _sphere_flip_pdf(w):
    return np.full(np.shape(w)[0], 1.0 / (4.0 * math.pi))


def _sphere_flip_pdf_wrong(w):
    return np.full(np.shape(w)[0], 1.0 / (2.0 * math.pi))          # forgot 'double the options, half the pdf'


_register(Exercise(
    "04.sphere_flip", "Uniform sphere from a hemisphere and a coin", "Uniform Sampling (environment)",
    ("sample", "pdf"),
    lambda sample, pdf, verbose=True: grade_warp(sample, pdf, "sphere", n=200_000, rng=401,
                                                 name="04.sphere_flip", verbose=verbose),
    (_sphere_flip, _sphere_flip_pdf), (_sphere_flip, _sphere_flip_pdf_wrong),
    "keeps the hemisphere's pdf 1/(2 pi): the pdf integrates to 2"))


def _exercise_map(h=16, w=32):
    """A small lat-long luminance map: dim sky, a bright sun, a black ground band."""
    theta = (np.arange(h) + 0.5) * math.pi / h
    phi = (np.arange(w) + 0.5) * 2 * math.pi / w
    img = 0.2 + 0.8 * np.cos(theta)[:, None] ** 2 * np.ones(w)
    img[h - 3:] = 0.0
    img[3, int(w * 0.3)] = 40.0
    img[2, int(w * 0.7)] = 15.0
    return img + 0.0 * phi


EXERCISE_MAP = _exercise_map()


def _sample_pixels(image, r):
    h = image.shape[0]
    theta = (np.arange(h) + 0.5) * math.pi / h
    pdf = (image * np.sin(theta)[:, None]).ravel()
    cdf = np.cumsum(pdf / pdf.sum())
    idx = np.searchsorted(cdf, r, side="right")            # upper_bound
    last = np.flatnonzero(pdf > 0)[-1]                      # r -> 1 with rounding: last bright pixel
    return np.minimum(idx, last)


def _sample_pixels_wrong(image, r):
    cdf = np.cumsum(image.ravel() / image.sum())            # forgot sin(theta): the poles too likely
    return np.minimum(np.searchsorted(cdf, r, side="right"), image.size - 1)


_register(Exercise(
    "04.envmap_cdf", "Inversion sampling of an environment map", "Creating A PDF / Inversion Sampling",
    ("sample_pixels",),
    lambda sample_pixels, verbose=True: grade_pixel_sampler(sample_pixels, EXERCISE_MAP, n=200_000, rng=402,
                                                            name="04.envmap_cdf", verbose=verbose),
    (_sample_pixels,), (_sample_pixels_wrong,),
    "pixel probability proportional to L instead of L sin(theta)"))


# --------------------------------------------------------------------------
# 05 Cornell box: Russian roulette and MIS weights

#: The furnace walk of exercise 05.roulette: every bounce keeps ``RHO`` of the
#: throughput and adds emission 1, so the radiance is ``1 / (1 - RHO)``.
RHO = 0.7


def furnace_walk(roulette, n, rng=None, *, rho=RHO, start_depth=2):
    """Mean radiance of ``n`` furnace paths that use the student's Russian roulette.

    Parameters
    ----------
    roulette : callable
        ``roulette(beta, u) -> beta'``: the new throughput of each path (0 for
        a path that stops), given the throughputs ``beta`` (m,) and uniform
        numbers ``u`` (m,).
    n : int
    rng : seed
    rho : float
        Albedo: the throughput is multiplied by ``rho`` per bounce.
    start_depth : int
        Bounces before roulette starts.

    Returns
    -------
    float
        Estimate of ``1 / (1 - rho)``.
    """
    g = as_rng(rng)
    beta = np.ones(n)
    total = np.zeros(n)
    alive = np.arange(n)
    depth = 0
    while alive.size and depth < 10_000:
        total[alive] += beta[alive]           # emission 1 at every vertex
        beta[alive] *= rho
        depth += 1
        if depth >= start_depth:
            new = np.asarray(roulette(beta[alive].copy(), g.random(alive.size)), dtype=np.float64)
            if new.shape != (alive.size,):
                raise ValueError(f"roulette(beta, u) must return shape ({alive.size},); got {new.shape}")
            beta[alive] = new
            alive = alive[new > 0]
    return float(total.mean())


def _roulette(beta, u):
    q = np.minimum(0.95, beta)                # survival probability
    return np.where(u < q, beta / q, 0.0)


def _roulette_wrong(beta, u):
    q = np.minimum(0.95, beta)
    return np.where(u < q, beta, 0.0)         # survivors not re-weighted by 1/q


_register(Exercise(
    "05.roulette", "Russian roulette", "Number Of Ray Bounces",
    ("roulette",),
    lambda roulette, verbose=True: grade_estimator(lambda n, rng: furnace_walk(roulette, n, rng), 1.0 / (1.0 - RHO),
                                                   n=2000, replicates=64, rng=501, name="05.roulette",
                                                   verbose=verbose),
    (_roulette,), (_roulette_wrong,),
    "survivors keep their throughput instead of dividing it by the survival probability"))

#: Phong exponent of the second strategy of exercise 05.mis_weight.
MIS_EXPONENT = 40.0


def mis_estimate(weight, n, rng=None):
    """Two-strategy MIS estimate of ``int cos(theta) (1 + 20 cos^40(theta)) d omega``.

    Half of ``n`` samples come from the uniform hemisphere (pdf ``1/2pi``),
    half from a Phong lobe ``cos^40``; each contribution is
    ``weight(p_own, p_other) f / p_own`` with the student's MIS ``weight``.
    The exact value is ``pi + 40 pi / 42``.
    """
    g = as_rng(rng)
    m = max(n // 2, 1)
    k = MIS_EXPONENT

    def f(w):
        c = np.maximum(w[:, 1], 0.0)
        return c * (1.0 + 20.0 * c ** k)

    strategies = ((warps.square_to_uniform_hemisphere, warps.square_to_uniform_hemisphere_pdf),
                  (lambda u: warps.square_to_phong_lobe(u, k), lambda v: warps.square_to_phong_lobe_pdf(v, k)))
    total = 0.0
    for a, (sample, pdf) in enumerate(strategies):
        w = sample(g.random((m, 2)))
        p_own = pdf(w)
        p_other = strategies[1 - a][1](w)
        wt = np.asarray(weight(p_own, p_other), dtype=np.float64)
        if wt.shape != p_own.shape:
            raise ValueError(f"weight(p_own, p_other) must return shape {p_own.shape}; got {wt.shape}")
        total += np.mean(np.where(p_own > 0, wt * f(w) / np.where(p_own > 0, p_own, 1.0), 0.0))
    return float(total)


MIS_EXACT = math.pi + 20.0 * 2.0 * math.pi / (MIS_EXPONENT + 2.0)


def _power_heuristic(p_own, p_other):
    a, b = p_own ** 2, p_other ** 2
    return np.where(a + b > 0, a / np.where(a + b > 0, a + b, 1.0), 0.0)


def _power_heuristic_wrong(p_own, p_other):
    s = p_own + p_other                       # squares the balance weight: weights no longer sum to 1
    return np.where(s > 0, (p_own / np.where(s > 0, s, 1.0)) ** 2, 0.0)


_register(Exercise(
    "05.mis_weight", "The power heuristic", "Multiple Importance Sampling",
    ("weight",),
    lambda weight, verbose=True: grade_estimator(lambda n, rng: mis_estimate(weight, n, rng), MIS_EXACT,
                                                 n=4000, replicates=64, rng=502, name="05.mis_weight",
                                                 verbose=verbose),
    (_power_heuristic,), (_power_heuristic_wrong,),
    "(p_own / (p_own + p_other))^2: the weights of a sample do not sum to 1"))


# --------------------------------------------------------------------------
# 06 bias and consistency

def _sample_variance(n, rng=None):
    x = as_rng(rng).random(n)
    return float(np.var(x, ddof=1))


def _sample_variance_wrong(n, rng=None):
    x = as_rng(rng).random(n)
    return float(np.var(x))                   # ddof = 0: biased by (n - 1) / n, consistent


_register(Exercise(
    "06.sample_variance", "An unbiased variance estimator", "Variance / Bias & Consistency",
    ("estimate",),
    lambda estimate, verbose=True: grade_estimator(estimate, 1.0 / 12.0, n=4, replicates=4000, rng=601,
                                                   name="06.sample_variance", verbose=verbose),
    (_sample_variance,), (_sample_variance_wrong,),
    "divides by n instead of n - 1 (biased by a factor 3/4 at n = 4, consistent)"))


def _quarter_disk(x):
    return (x[:, 0] ** 2 + x[:, 1] ** 2 < 1.0).astype(np.float64)


def _grid_estimate(n, rng=None):
    m = max(1, math.isqrt(n))
    c = (np.arange(m) + 0.5) / m
    x, y = np.meshgrid(c, c)
    return float(np.mean(_quarter_disk(np.stack([x.ravel(), y.ravel()], axis=1))))


def _grid_estimate_wrong(n, rng=None):
    return float(_quarter_disk(as_rng(rng).random((1, 2)))[0])   # one random sample, whatever n


_register(Exercise(
    "06.grid_consistent", "The fixed grid is consistent", "Consistent Or Unbiased?",
    ("estimate",),
    lambda estimate, verbose=True: grade_consistent(estimate, math.pi / 4.0, [16, 256, 4096, 65536],
                                                    replicates=32, rng=602, name="06.grid_consistent",
                                                    verbose=verbose),
    (_grid_estimate,), (_grid_estimate_wrong,),
    "a single random sample whatever n: unbiased, but its error never falls"))


def exercise(name: str, *solution, verbose: bool = True) -> GradeResult:
    """Grade the course notebooks' exercise ``name`` (see :mod:`mcvar.testing.exercises`).

    Parameters
    ----------
    name : str
        A key of :data:`EXERCISES`, e.g. ``'01.jittered'``.
    *solution
        The student's function(s) or object, in the order the exercise names them.
    verbose : bool

    Returns
    -------
    GradeResult
    """
    key = check_choice(name, "name", tuple(EXERCISES))
    ex = EXERCISES[key]
    if len(solution) != len(ex.parts):
        raise TypeError(f"exercise {key!r} takes {len(ex.parts)} argument(s) ({', '.join(ex.parts)}); "
                        f"got {len(solution)}")
    return ex.grade(*solution, verbose=verbose)
