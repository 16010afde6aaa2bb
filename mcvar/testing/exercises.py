"""The course notebooks' exercises: what each asks and how it is graded (layer 3).

Every course notebook ends with exercises in which the student writes the
piece of code the lecture teaches into a stub, then runs one cell::

    grade.exercise("01.jittered", jittered)

:data:`EXERCISES` maps each exercise name to an :class:`Exercise`: the
grader call with its fixed parameters (a seed, the exact value, the
domain), the names of the parts the student writes, and the untouched stub
(:meth:`Exercise.stubs`, graded NOT ATTEMPTED). The functions the graders
run a student's code in (:func:`furnace_walk`, :func:`mis_estimate`,
:func:`bdpt_estimate`, ...) are public, so that a student can call them on
their own code.

**No answers ship here.** The reference solutions (which must PASS) and the
planted wrong ones (a classic mistake each, which must FAIL) live with the
test suite, in ``tests/solutions`` (outside the installed package; a teacher
runs ``python -m solutions`` from ``tests/``), and ``tests/test_grade.py``
runs both for every exercise, so the graders themselves are tested. A
course's own autograder can import the same registry.

The 'find the bug' exercises (``12.*``) hand the student a class of
:mod:`mcvar.testing.bugs` with one subtle bug; the stub is that class with
the faulty method replaced by one raising ``NotImplementedError``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .. import warps
from .._validation import as_rng, check_choice
from . import bugs
from .grade import (GradeResult, grade_chain, grade_coverage, grade_dielectric, grade_bsdf,
                    grade_consistent, grade_estimator, grade_pixel_sampler, grade_sampler, grade_values,
                    grade_warp)

__all__ = ["Exercise", "EXERCISES", "exercise", "furnace_walk", "mis_estimate", "bdpt_estimate",
           "light_tracing_estimate", "large_step_chain", "correlated_series", "photon_estimate",
           "jacobi_solve", "bounce_furnace", "EXERCISE_MAP", "RHO", "MIS_EXPONENT", "MIS_EXACT", "LAB_EXACT"]


def _not_attempted(*args, **kwargs):
    raise NotImplementedError("the stub is untouched: write your solution here")


class _StubBSDF:
    """An untouched BSDF stub: every method raises NotImplementedError."""

    eval = pdf = sample = staticmethod(_not_attempted)


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
    stub : callable, optional
        ``stub() -> tuple``: the untouched stub of each part (graded NOT
        ATTEMPTED). Default: a function raising ``NotImplementedError`` per
        part (an object whose methods raise it for a part named ``'bsdf'``).
    """

    name: str
    title: str
    lecture: str
    parts: tuple
    grade: Callable[..., GradeResult]
    stub: Callable[[], tuple] | None = None

    @property
    def notebook(self) -> str:
        """The notebook number, e.g. ``'01'``."""
        return self.name.split(".")[0]

    def stubs(self) -> tuple:
        """The untouched stubs, one per part."""
        if self.stub is not None:
            return tuple(self.stub())
        return tuple(_StubBSDF() if part == "bsdf" else _not_attempted for part in self.parts)


EXERCISES: dict[str, Exercise] = {}


def _register(ex: Exercise) -> Exercise:
    if ex.name in EXERCISES:
        raise ValueError(f"duplicate exercise {ex.name!r}")
    EXERCISES[ex.name] = ex
    return ex


# --------------------------------------------------------------------------
# 01 samplers

_register(Exercise(
    "01.jittered", "Jittered sampling", "Jittered Sampling",
    ("jittered",),
    lambda jittered, verbose=True: grade_sampler(jittered, 64, strata=(8, 8), replicates=400, rng=101,
                                                 name="01.jittered", verbose=verbose)))

_register(Exercise(
    "01.hammersley", "Hammersley points", "Hammersley Sampling",
    ("hammersley",),
    lambda hammersley, verbose=True: grade_sampler(hammersley, 256, net=8, randomized=False, rng=102,
                                                   name="01.hammersley", verbose=verbose)))


# --------------------------------------------------------------------------
# 02 estimators

_register(Exercise(
    "02.checkerboard", "The checkerboard estimator", "Variance Reduction Example",
    ("estimate",),
    lambda estimate, verbose=True: grade_estimator(estimate, 2.0, n=1000, replicates=200, variance=4.0,
                                                   rng=201, name="02.checkerboard", verbose=verbose)))

_register(Exercise(
    "02.cosine", "Cosine-weighted Monte Carlo", "Monte Carlo Cosine Sampling",
    ("estimate",),
    lambda estimate, verbose=True: grade_estimator(estimate, 2.0 * math.pi / 3.0, n=1000, replicates=100,
                                                   rng=202, name="02.cosine", verbose=verbose)))


# --------------------------------------------------------------------------
# 03 BRDFs

_register(Exercise(
    "03.lambertian", "A Lambertian BSDF", "Lambertian Material",
    ("bsdf",),
    lambda bsdf, verbose=True: grade_bsdf(bsdf, n=100_000, rng=301, name="03.lambertian", verbose=verbose)))

#: Schlick at air -> glass (R0 = 0.04) by hand: cos = 1, 0.8, 0.5, 0.2, 0.
_SCHLICK_COS = np.array([1.0, 0.8, 0.5, 0.2, 0.0])
_SCHLICK_VALUES = np.array([0.04, 0.04 + 0.96 * 0.2 ** 5, 0.04 + 0.96 / 32.0, 0.04 + 0.96 * 0.8 ** 5, 1.0])

_register(Exercise(
    "03.schlick", "Schlick's approximation", "Schlick's Approximation",
    ("schlick",),
    lambda schlick, verbose=True: grade_values(schlick, (_SCHLICK_COS, 1.0, 1.5), _SCHLICK_VALUES,
                                               rtol=1e-9, name="03.schlick", verbose=verbose)))


# --------------------------------------------------------------------------
# 04 environment lighting

_register(Exercise(
    "04.sphere_flip", "Uniform sphere from a hemisphere and a coin", "Uniform Sampling (environment)",
    ("sample", "pdf"),
    lambda sample, pdf, verbose=True: grade_warp(sample, pdf, "sphere", n=200_000, rng=401,
                                                 name="04.sphere_flip", verbose=verbose)))


def _exercise_map(h=16, w=32):
    """A small lat-long luminance map: dim sky, a bright sun, a black ground band."""
    theta = (np.arange(h) + 0.5) * math.pi / h
    img = 0.2 + 0.8 * np.cos(theta)[:, None] ** 2 * np.ones(w)
    img[h - 3:] = 0.0
    img[3, int(w * 0.3)] = 40.0
    img[2, int(w * 0.7)] = 15.0
    return img


#: The luminance map of exercise ``04.envmap_cdf``.
EXERCISE_MAP = _exercise_map()

_register(Exercise(
    "04.envmap_cdf", "Inversion sampling of an environment map", "Creating A PDF / Inversion Sampling",
    ("sample_pixels",),
    lambda sample_pixels, verbose=True: grade_pixel_sampler(sample_pixels, EXERCISE_MAP, n=200_000, rng=402,
                                                            name="04.envmap_cdf", verbose=verbose)))


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


_register(Exercise(
    "05.roulette", "Russian roulette", "Number Of Ray Bounces",
    ("roulette",),
    lambda roulette, verbose=True: grade_estimator(lambda n, rng: furnace_walk(roulette, n, rng), 1.0 / (1.0 - RHO),
                                                   n=2000, replicates=64, rng=501, name="05.roulette",
                                                   verbose=verbose)))

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

_register(Exercise(
    "05.mis_weight", "The power heuristic", "Multiple Importance Sampling",
    ("weight",),
    lambda weight, verbose=True: grade_estimator(lambda n, rng: mis_estimate(weight, n, rng), MIS_EXACT,
                                                 n=4000, replicates=64, rng=502, name="05.mis_weight",
                                                 verbose=verbose)))


# --------------------------------------------------------------------------
# 06 bias and consistency

_register(Exercise(
    "06.sample_variance", "An unbiased variance estimator", "Variance / Bias & Consistency",
    ("estimate",),
    lambda estimate, verbose=True: grade_estimator(estimate, 1.0 / 12.0, n=4, replicates=4000, rng=601,
                                                   name="06.sample_variance", verbose=verbose)))

_register(Exercise(
    "06.grid_consistent", "The fixed grid is consistent", "Consistent Or Unbiased?",
    ("estimate",),
    lambda estimate, verbose=True: grade_consistent(estimate, math.pi / 4.0, [16, 256, 4096, 65536],
                                                    replicates=32, rng=602, name="06.grid_consistent",
                                                    verbose=verbose)))


# --------------------------------------------------------------------------
# 07 light transport: BDPT's MIS weight, light tracing's splat

def _both(name, first: GradeResult, second: Callable[[], GradeResult], verbose: bool) -> GradeResult:
    """Two graders in turn: the first's FAIL / NOT ATTEMPTED, else the second's verdict."""
    result = first if not first.passed else second()
    result = GradeResult(name, result.passed, result.status, result.reason,
                         first.checks + (result.checks if result is not first else ()),
                         first.seconds + (result.seconds if result is not first else 0.0))
    if verbose:
        print(result)
    return result


#: Strategy pdfs at the points of the 1D path space of exercise 07.bdpt_weight.
def _bdpt_pdfs(x):
    x = np.asarray(x, dtype=np.float64)
    return np.stack([np.ones_like(x), 2.0 * x, np.where(x < 0.5, 2.0, 0.0)], axis=-1)


_BDPT_SAMPLERS = (lambda u: u, lambda u: np.sqrt(u), lambda u: 0.5 * u)


def bdpt_estimate(weight, n, rng=None):
    """A one-dimensional stand-in for BDPT: three strategies sample the same
    'paths' ``x`` in [0, 1) and their contributions are combined with the
    student's MIS ``weight``.

    Strategy 0 samples ``x`` uniformly (pdf 1), strategy 1 with pdf ``2x``,
    strategy 2 uniformly on [0, 1/2) only (pdf 2 there, 0 beyond: like a
    connection strategy that cannot produce paths through a point light or
    a pinhole). Each draws ``n // 3`` samples; a sample ``x`` of strategy
    ``s`` contributes ``weight(pdfs, s) f(x) / p_s(x)`` with ``pdfs`` (m, 3)
    every strategy's pdf at ``x``. ``f(x) = 1 + x``: the integral is 1.5
    whatever the weights, as long as for every ``x`` the weights of the
    strategies that can sample it sum to 1.

    Parameters
    ----------
    weight : callable
        ``weight(pdfs, s) -> (m,)``: pdfs (m, k), s the strategy index (int).
    n : int
    rng : seed

    Returns
    -------
    float
    """
    g = as_rng(rng)
    m = max(n // 3, 1)
    total = 0.0
    for s, draw in enumerate(_BDPT_SAMPLERS):
        x = draw(g.random(m))
        pdfs = _bdpt_pdfs(x)
        w = np.asarray(weight(pdfs.copy(), s), dtype=np.float64)
        if w.shape != (m,):
            raise ValueError(f"weight(pdfs, s) must return shape ({m},); got {w.shape}")
        total += float(np.mean(w * (1.0 + x) / pdfs[:, s]))
    return total


#: Fixed pdf tuples of three strategies and which one sampled: the power heuristic by hand.
_BDPT_PDFS = np.array([[1.0, 2.0, 0.0], [1.0, 1.0, 1.0], [0.5, 1.5, 2.0], [1.0, 0.2, 0.0]])
_BDPT_S = np.array([0, 1, 2, 1])
_BDPT_POWER = np.array([1.0 / 5.0, 1.0 / 3.0, 4.0 / 6.5, 0.04 / 1.04])


def _bdpt_values(weight):
    return np.array([float(np.asarray(weight(_BDPT_PDFS[k:k + 1].copy(), int(_BDPT_S[k])),
                                      dtype=np.float64).reshape(-1)[0]) for k in range(len(_BDPT_S))])


_register(Exercise(
    "07.bdpt_weight", "The MIS weight of a BDPT strategy", "Bidirectional Path Tracing",
    ("weight",),
    lambda weight, verbose=True: _both(
        "07.bdpt_weight",
        grade_values(lambda: _bdpt_values(weight), (), _BDPT_POWER, rtol=1e-9, name="07.bdpt_weight",
                     verbose=False),
        lambda: grade_estimator(lambda n, rng: bdpt_estimate(weight, n, rng), 1.5, n=3000, replicates=64,
                                rng=701, name="07.bdpt_weight", verbose=False),
        verbose)))

#: Exercise 07.light_splat: a pinhole at the origin looking down -z, film at distance 1 of area 1
#: ([-1/2, 1/2]^2), an emitting square [-3/2, 3/2]^2 at z = -2 of radiance 1 towards the camera.
FILM_AREA = 1.0
_EMITTER_HALF, _EMITTER_Z = 1.5, 2.0


def light_tracing_estimate(splat, n, rng=None):
    """Light tracing's camera connection: the mean pixel value of the film.

    ``n`` points are drawn uniformly on an emitting square (radiance 1, pdf
    ``1 / area`` per unit area) facing a pinhole camera; each is connected to
    the pinhole and, if it projects into the film, splats
    ``L_e splat(cos_light, cos_camera, distance, FILM_AREA) / p_A`` (the
    student's ``splat`` is the geometry term times the camera's importance
    ``W_e``). The emitter fills the view, so every pixel sees radiance 1 and
    the film's mean pixel value is exactly 1.

    Parameters
    ----------
    splat : callable
        ``splat(cos_light, cos_camera, distance, film_area) -> (m,)``.
    n : int
    rng : seed

    Returns
    -------
    float
    """
    g = as_rng(rng)
    xy = (2.0 * g.random((n, 2)) - 1.0) * _EMITTER_HALF
    p_area = 1.0 / (2.0 * _EMITTER_HALF) ** 2
    dist = np.sqrt(np.sum(xy ** 2, axis=1) + _EMITTER_Z ** 2)
    cos = _EMITTER_Z / dist                      # the same angle at both ends (parallel planes)
    on_film = np.all(np.abs(xy / _EMITTER_Z) < 0.5 * math.sqrt(FILM_AREA), axis=1)
    value = np.asarray(splat(cos.copy(), cos.copy(), dist.copy(), FILM_AREA), dtype=np.float64)
    if value.shape != (n,):
        raise ValueError(f"splat(...) must return shape ({n},); got {value.shape}")
    return float(np.mean(np.where(on_film, 1.0 * value / p_area, 0.0)))


_register(Exercise(
    "07.light_splat", "Light tracing's splat to a pinhole camera", "Previous Methods (forward + connect to camera)",
    ("splat",),
    lambda splat, verbose=True: grade_estimator(lambda n, rng: light_tracing_estimate(splat, n, rng), 1.0,
                                                n=4000, replicates=64, rng=702, name="07.light_splat",
                                                verbose=verbose)))


# --------------------------------------------------------------------------
# 08 Metropolis: the large step's acceptance, error bars of a chain

def _target_pdf(x):
    return 4.0 * x[:, 0] * x[:, 1]                      # f(x) = 4 x0 x1 on [0, 1)^2


def _target_sample(u):
    return np.sqrt(u)


def _large_pdf(x):
    return 4.0 * (1.0 - x[:, 0]) * (1.0 - x[:, 1])       # q(x): the large step favours the corner 0


def _large_sample(u):
    return 1.0 - np.sqrt(1.0 - u)


#: Probability of a large step and width of a small one in exercise 08.large_step.
P_LARGE, SIGMA = 0.5, 0.05


def large_step_chain(acceptance):
    """A Metropolis step on ``f(x) = 4 x0 x1`` over [0, 1)^2 using the student's acceptance.

    With probability :data:`P_LARGE` the proposal is a *large step*: a fresh
    point drawn from ``q(x) = 4 (1 - x0)(1 - x1)`` (not uniform: an importance
    sampler that favours the wrong corner, as a path tracer's sampler can);
    otherwise a small Gaussian step of width :data:`SIGMA`, wrapped around the
    square (symmetric, so its ``q`` ratio is 1 and ``acceptance`` is called with
    ``q_x = q_y = 1``). The proposal ``y`` is accepted when ``u < acceptance(f(x),
    f(y), q(x), q(y))``.

    Returns
    -------
    callable
        ``step(x, rng) -> x'``, vectorised over chains.
    """
    def step(x, rng):
        g = as_rng(rng)
        m = x.shape[0]
        large = g.random(m) < P_LARGE
        y = np.where(large[:, None], _large_sample(g.random((m, 2))),
                     (x + SIGMA * g.standard_normal((m, 2))) % 1.0)
        y = np.minimum(y, np.nextafter(1.0, 0.0))
        qx = np.where(large, _large_pdf(x), 1.0)
        qy = np.where(large, _large_pdf(y), 1.0)
        a = np.asarray(acceptance(_target_pdf(x), _target_pdf(y), qx, qy), dtype=np.float64)
        if a.shape != (m,):
            raise ValueError(f"acceptance(...) must return shape ({m},); got {a.shape}")
        return np.where((g.random(m) < a)[:, None], y, x)
    return step


_register(Exercise(
    "08.large_step", "The acceptance of a large step", "Metropolis Hasting Algorithm",
    ("acceptance",),
    lambda acceptance, verbose=True: grade_chain(large_step_chain(acceptance), _target_sample, _target_pdf,
                                                 steps=10, n=100_000, rng=801, name="08.large_step",
                                                 verbose=verbose)))


def correlated_series(r=400, n=4000, *, phi=0.9, mean=0.5, rng=None):
    """``r`` independent AR(1) series of length ``n``: ``h_t = mean + phi (h_{t-1} - mean) + e_t``,
    started in equilibrium, unit stationary variance; the integrated
    autocorrelation time is ``(1 + phi) / (1 - phi)`` (19 for ``phi = 0.9``),
    as for a Metropolis chain's samples."""
    g = as_rng(rng)
    e = g.standard_normal((r, n)) * math.sqrt(1.0 - phi * phi)
    h = np.empty((r, n))
    h[:, 0] = g.standard_normal(r)
    for t in range(1, n):                    # a recursion in t, vectorised over the r series
        h[:, t] = phi * h[:, t - 1] + e[:, t]
    return h + mean


_SERIES = None


def _series():
    global _SERIES  # noqa: PLW0603 - built once, read-only: the grader's fixed data set
    if _SERIES is None:
        _SERIES = correlated_series(rng=802)
    return _SERIES


_register(Exercise(
    "08.chain_stderr", "Error bars of a Markov chain's mean", "Metropolis Hasting: Sampling An Image",
    ("stderr",),
    lambda stderr, verbose=True: grade_coverage(stderr, _series(), 0.5, level=0.95, name="08.chain_stderr",
                                                verbose=verbose)))


# --------------------------------------------------------------------------
# 09 photon mapping and radiosity

#: Exercise 09.photon_density: photons on the unit square, irradiance density linear in x.
PHOTON_POWER, PHOTON_QUERY, PHOTON_RADIUS, PHOTON_ALBEDO = 3.0, (0.3, 0.5), 0.2, 0.6
PHOTON_EXACT = PHOTON_ALBEDO / math.pi * PHOTON_POWER * (2.0 / 3.0) * (1.0 + PHOTON_QUERY[0])


def photon_estimate(radiance, n, rng=None):
    """Reflected radiance at one point from ``n`` photons, with the student's density estimate.

    Photons land uniformly on the unit square with powers proportional to
    ``1 + x`` (total :data:`PHOTON_POWER`): the irradiance is
    ``E(x) = PHOTON_POWER (2/3)(1 + x)``. The query point
    :data:`PHOTON_QUERY` on a Lambertian surface of albedo
    :data:`PHOTON_ALBEDO` gathers the photons within :data:`PHOTON_RADIUS`
    with ``radiance(dist2, power, radius, f)``. A disk average of a linear
    function is its centre value, so the right estimate is unbiased for
    ``f E(x_0)`` (:data:`PHOTON_EXACT`): here the blur of photon mapping is 0.
    """
    g = as_rng(rng)
    x = g.random((n, 2))
    power = PHOTON_POWER * (2.0 / 3.0) * (1.0 + x[:, 0]) / n
    dist2 = np.sum((x - np.asarray(PHOTON_QUERY)) ** 2, axis=1)
    return float(np.asarray(radiance(dist2, power, PHOTON_RADIUS, PHOTON_ALBEDO / math.pi), dtype=np.float64))


_register(Exercise(
    "09.photon_density", "A photon density estimate", "Photon Mapping",
    ("radiance",),
    lambda radiance, verbose=True: grade_estimator(lambda n, rng: photon_estimate(radiance, n, rng), PHOTON_EXACT,
                                                   n=4000, replicates=64, rng=901, name="09.photon_density",
                                                   verbose=verbose)))

#: Exercise 09.jacobi: three patches, their form factors (rows: from patch i), albedos, emission.
JACOBI_F = np.array([[0.0, 0.4, 0.3], [0.2, 0.0, 0.5], [0.3, 0.6, 0.0]])
JACOBI_RHO = np.array([0.8, 0.5, 0.3])
JACOBI_E = np.array([1.0, 0.0, 0.0])


def jacobi_solve(step, iterations=200):
    """Radiosities of the three-patch system by ``iterations`` of the student's
    ``step(B, E, rho, F) -> B'`` from ``B = E``."""
    b = JACOBI_E.copy()
    for _ in range(iterations):
        b = np.asarray(step(b.copy(), JACOBI_E.copy(), JACOBI_RHO.copy(), JACOBI_F.copy()), dtype=np.float64)
        if b.shape != JACOBI_E.shape:
            raise ValueError(f"step(B, E, rho, F) must return shape {JACOBI_E.shape}; got {b.shape}")
    return b


#: The exact radiosities, (I - diag(rho) F) B = E solved directly.
JACOBI_EXACT = np.linalg.solve(np.eye(3) - JACOBI_RHO[:, None] * JACOBI_F, JACOBI_E)

_register(Exercise(
    "09.jacobi", "A Jacobi step of radiosity", "Finite Element Radiosity",
    ("step",),
    lambda step, verbose=True: grade_values(lambda: jacobi_solve(step), (), JACOBI_EXACT, rtol=1e-9,
                                            name="09.jacobi", verbose=verbose)))


# --------------------------------------------------------------------------
# 11 the lab: a furnace, its exact radiance and a cosine-weighted bounce

#: The furnace of exercise 11.cosine_bounce: albedo, emission and the number of vertices of every path.
LAB_RHO, LAB_EMISSION, LAB_DEPTH = 0.5, 1.0, 8
LAB_EXACT = LAB_EMISSION * (1.0 - LAB_RHO ** LAB_DEPTH) / (1.0 - LAB_RHO)


def bounce_furnace(sample_bounce, n, rng=None):
    """Mean radiance of ``n`` furnace paths of :data:`LAB_DEPTH` vertices whose bounces
    the student samples.

    Inside a closed diffuse sphere of albedo :data:`LAB_RHO` emitting
    :data:`LAB_EMISSION` (notebook 11's furnace, one channel), each path adds
    the emission at each of its vertices and multiplies its throughput by
    ``f cos / pdf`` with ``f = rho / pi`` and ``(cos, pdf) = sample_bounce(u)``.
    No roulette: the exact value is ``L_e (1 - rho^D) / (1 - rho)``
    (:data:`LAB_EXACT`).
    """
    g = as_rng(rng)
    beta = np.ones(n)
    total = np.zeros(n)
    for _ in range(LAB_DEPTH):
        total += beta * LAB_EMISSION
        cos, pdf = sample_bounce(g.random(n))
        cos, pdf = np.asarray(cos, dtype=np.float64), np.asarray(pdf, dtype=np.float64)
        if cos.shape != (n,) or pdf.shape != (n,):
            raise ValueError(f"sample_bounce(u) must return cos and pdf of shape ({n},); got {cos.shape}, {pdf.shape}")
        beta = beta * np.where(pdf > 0, LAB_RHO / math.pi * cos / np.where(pdf > 0, pdf, 1.0), 0.0)
    return float(total.mean())


_register(Exercise(
    "11.cosine_bounce", "Cosine-weighted bounces in the furnace", "Lambertian Material / Monte Carlo Cosine Sampling",
    ("sample_bounce",),
    lambda sample_bounce, verbose=True: grade_estimator(lambda n, rng: bounce_furnace(sample_bounce, n, rng),
                                                        LAB_EXACT, n=256, replicates=32, variance=0.0, rng=1101,
                                                        name="11.cosine_bounce", verbose=verbose)))

#: Exercise 11.furnace_exact: emission, albedo and maximal number of path vertices (0: unlimited).
_FURNACE_LE = np.array([1.0, 0.5, 2.0, 1.0, 3.0])
_FURNACE_RHO = np.array([0.2, 0.5, 0.9, 0.0, 0.5])
_FURNACE_DEPTH = np.array([0, 0, 0, 4, 3])
#: By hand: L_e / (1 - rho) unlimited; L_e (1 + rho + ... + rho^(D-1)) for D vertices.
_FURNACE_VALUES = np.array([1.25, 1.0, 20.0, 1.0, 3.0 * 1.75])

_register(Exercise(
    "11.furnace_exact", "The furnace's exact radiance", "Review: The Rendering Equation / Bias & Consistency",
    ("furnace_radiance",),
    lambda furnace_radiance, verbose=True: grade_values(furnace_radiance, (_FURNACE_LE, _FURNACE_RHO, _FURNACE_DEPTH),
                                                        _FURNACE_VALUES, rtol=1e-12, name="11.furnace_exact",
                                                        verbose=verbose)))


# --------------------------------------------------------------------------
# 10 choosing a method

#: Exercise 10.efficiency: MSE (per pixel, against the reference) and wall seconds of three renders.
_EFF_MSE = np.array([1e-3, 4e-4, 2e-2, 5e-6])
_EFF_SECONDS = np.array([2.0, 5.0, 0.5, 8.0])
#: By hand: 1 / (MSE x time) (Veach 1997, sec. 2.4.3): the first two are equally efficient.
_EFF_VALUES = np.array([500.0, 500.0, 100.0, 25_000.0])

_register(Exercise(
    "10.efficiency", "Efficiency on one scale", "If there are so many good sampling methods, why not combine them?",
    ("efficiency",),
    lambda efficiency, verbose=True: grade_values(efficiency, (_EFF_MSE, _EFF_SECONDS), _EFF_VALUES, rtol=1e-12,
                                                  name="10.efficiency", verbose=verbose)))

#: Exercise 10.rounds: the image means (rounds, pixels) of the rounds an equal-time run
#: rendered, and each round's spp; the run's estimate weighs each round by its spp.
_ROUND_MEANS = np.array([[0.30, 1.0], [0.36, 2.0], [0.33, 4.0]])
_ROUND_SPP = np.array([4, 8, 4])
#: By hand: (4 * 0.30 + 8 * 0.36 + 4 * 0.33) / 16 and (4 + 16 + 16) / 16.
_ROUND_VALUES = np.array([0.3375, 2.25])

_register(Exercise(
    "10.rounds", "An equal-time run's estimate from its rounds", "Monte Carlo Estimator",
    ("combine_rounds",),
    lambda combine_rounds, verbose=True: grade_values(combine_rounds, (_ROUND_MEANS, _ROUND_SPP), _ROUND_VALUES,
                                                      rtol=1e-12, name="10.rounds", verbose=verbose)))


# --------------------------------------------------------------------------
# 12 find the bug

def _method(obj, name):
    fn = getattr(obj, name, None)
    if not callable(fn):
        raise TypeError(f"expected an object with a callable {name}(...); got {type(obj).__name__}")
    return fn


def _stub_subclass(base, method, *args):
    cls = type(f"My{base.__name__}", (base,), {method: lambda self, *a, **k: _not_attempted()})
    return (cls(*args),)


_register(Exercise(
    "12.glass", "Find the bug: glass with Fresnel and total internal reflection", "Glass / Fresnel Coefficient",
    ("glass",),
    lambda glass, verbose=True: grade_dielectric(glass, 1.5, n=20_000, rng=1201, name="12.glass",
                                                 verbose=verbose),
    stub=lambda: _stub_subclass(bugs.FresnelGlass, "reflect_probability", 1.5)))

_register(Exercise(
    "12.ggx_pdf", "Find the bug: a GGX lobe's pdf", "Glossy Specular / Importance Sampling",
    ("bsdf",),
    lambda bsdf, verbose=True: grade_bsdf(bsdf, n=100_000, rng=1202, name="12.ggx_pdf", verbose=verbose),
    stub=lambda: _stub_subclass(bugs.GGXReflection, "pdf", 0.3)))

_register(Exercise(
    "12.envmap_pdf", "Find the bug: the environment map's pdf", "Creating A PDF (solid angle)",
    ("envmap",),
    lambda envmap, verbose=True: grade_warp(_method(envmap, "sample"), _method(envmap, "pdf"), "sphere",
                                            n=200_000, rng=1203,
                                            name="12.envmap_pdf", verbose=verbose),
    stub=lambda: _stub_subclass(bugs.LatLongMap, "pdf", bugs.BUG_MAP)))


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
