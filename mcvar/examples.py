"""Integrands with known integrals and the lecture's estimator examples (layer 4).

Three things live here:

- :data:`INTEGRANDS`: a small library of functions on the unit square with
  exact integrals (step, diagonal, disk, aligned and rotated checkerboards,
  gaussian, ``exp(xy)``), modelled on pbrt-v4's ``function`` integrator:
  discontinuities of every orientation where QMC's advantage shrinks, and
  smooth functions where it shines.
- :data:`PROBLEMS`: the registry the convergence experiments sweep. Each
  :class:`Problem` has an exact value and ``methods``: functions from
  unit-square points (of *any* sampler) to per-sample contributions
  ``f(X) / p(X)`` whose mean is an unbiased estimate of ``exact``, with the
  analytic per-sample variance of each method where one exists.
- The lecture's examples: :func:`checkerboard` ('Variance Reduction
  Example'), :func:`fixed_grid_estimate` and :func:`single_sample_estimate`
  ('Consistent Or Unbiased?'), :func:`undivided_estimate` ('Biased vs.
  Unbiased Example') and :func:`running_sum` (why renderers accumulate in
  float64).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np
from scipy import integrate, special

from . import warps
from ._validation import as_array, as_points, as_rng, as_unit_square, check_count
from .estimators import Estimate, contribution, estimate, one_sample_mis_contribution

__all__ = [
    "checkerboard",
    "CHECKERBOARD_INTEGRAL",
    "CHECKERBOARD_MEAN",
    "CHECKERBOARD_VARIANCE",
    "Integrand",
    "INTEGRANDS",
    "Problem",
    "PROBLEMS",
    "hemisphere_problem",
    "fixed_grid_estimate",
    "single_sample_estimate",
    "undivided_estimate",
    "running_sum",
]


# --------------------------------------------------------------------------
# The lecture's checkerboard
# --------------------------------------------------------------------------

#: ``int_[0,2]^2 f`` for the lecture's board: two white unit cells.
CHECKERBOARD_INTEGRAL = 2.0
#: Mean of the integrand over [0, 2]^2 ('by inspection: 1/2').
CHECKERBOARD_MEAN = 0.5
#: Variance of the integrand over [0, 2]^2: ``(1/2)(1/4) + (1/2)(1/4)``.
CHECKERBOARD_VARIANCE = 0.25


def checkerboard(x) -> np.ndarray:
    """The lecture's checkerboard: 1 where ``floor(x) + floor(y)`` is even, else 0.

    Parameters
    ----------
    x : array_like, shape (n, 2)
        Points (any real coordinates; unit cells).

    Returns
    -------
    ndarray, shape (n,)

    Notes
    -----
    'Variance Reduction Example' slide: on ``Omega = [0, 2]^2`` the
    integrand has mean 1/2 and variance 1/4 and ``I = 2``. Uniform sampling
    (``p = 1/4``) gives contributions ``4 f`` in {0, 4}: per-sample variance
    ``16 * 1/4 = 4``, estimator variance ``4 / N``. 'You can't reduce the
    variance of an integrand, only of an estimator': importance sampling
    the white cells (``PROBLEMS['checkerboard'].methods['importance']``)
    makes it 0.

    Examples
    --------
    >>> checkerboard([[0.5, 0.5], [1.5, 0.5], [1.5, 1.5]]).tolist()
    [1.0, 0.0, 1.0]
    """
    p = as_points(x, "x", d=2)
    return (np.floor(p).sum(axis=1) % 2 == 0).astype(np.float64)


# --------------------------------------------------------------------------
# Integrand library on the unit square
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class Integrand:
    """A function on [0, 1]^2 with its exact integral.

    Attributes
    ----------
    name : str
    f : callable
        ``f(u) -> (n,)`` for points ``u`` of shape ``(n, 2)`` in [0, 1]^2.
    exact : float
        ``int_[0,1]^2 f``.
    variance : float
        ``int f^2 - exact^2``: the per-sample variance of uniform sampling.
    description : str
    """

    name: str
    f: Callable
    exact: float
    variance: float
    description: str


_DISK_R = 0.4
_GAUSS_SIGMA = 0.2
_ROT_K, _ROT_ANGLE = 8, math.pi / 6


def _step(u):
    return (as_unit_square(u)[:, 0] < 1.0 / 3.0).astype(np.float64)


def _diagonal(u):
    u = as_unit_square(u)
    return (u[:, 0] + u[:, 1] < 1.0).astype(np.float64)


def _disk(u):
    u = as_unit_square(u)
    return (((u[:, 0] - 0.5) ** 2 + (u[:, 1] - 0.5) ** 2) < _DISK_R ** 2).astype(np.float64)


def _board(k):
    def f(u):
        return checkerboard(k * as_unit_square(u))
    return f


def _rotated_board(u, k=_ROT_K, angle=_ROT_ANGLE):
    u = as_unit_square(u) - 0.5
    c, s = math.cos(angle), math.sin(angle)
    w = k * np.stack([c * u[:, 0] - s * u[:, 1], s * u[:, 0] + c * u[:, 1]], axis=1)
    return checkerboard(w + np.array([0.5, 0.0]))


def _gaussian(u):
    u = as_unit_square(u)
    return np.exp(-((u[:, 0] - 0.5) ** 2 + (u[:, 1] - 0.5) ** 2) / (2 * _GAUSS_SIGMA ** 2))


def _gauss_integral(sigma):
    # int_0^1 exp(-(x - 1/2)^2 / (2 sigma^2)) dx = sigma sqrt(2 pi) erf(1 / (2 sqrt(2) sigma)), squared
    return (sigma * math.sqrt(2 * math.pi) * math.erf(0.5 / (math.sqrt(2) * sigma))) ** 2


def _exp_xy(u):
    u = as_unit_square(u)
    return np.exp(u[:, 0] * u[:, 1])


def _exp_xy_integral(a):
    # int int exp(a x y) = int_0^1 (e^{a x} - 1) / (a x) dx = (Ei(a) - gamma - ln a) / a
    return (special.expi(a) - np.euler_gamma - math.log(a)) / a


def _indicator(name, f, area, description):
    return Integrand(name, f, area, area * (1.0 - area), description)


_G = _gauss_integral(_GAUSS_SIGMA)
_E = _exp_xy_integral(1.0)

#: The integrand library, all on [0, 1]^2 (pbrt-v4's ``function`` integrator
#: is the model). Indicators have variance ``I (1 - I)``.
INTEGRANDS: dict[str, Integrand] = {
    "step": _indicator("step", _step, 1.0 / 3.0,
                       "1 where x < 1/3: one axis-aligned edge, not on a dyadic line"),
    "diagonal": _indicator("diagonal", _diagonal, 0.5,
                           "1 where x + y < 1: an edge at 45 degrees, the worst case for grids"),
    "disk": _indicator("disk", _disk, math.pi * _DISK_R ** 2,
                       "1 inside the disk of radius 0.4 about (1/2, 1/2): a curved edge"),
    "checkerboard2": _indicator("checkerboard2", _board(2), 0.5,
                                "the lecture's 2 x 2 board scaled to the unit square: dyadic, so "
                                "Sobol and Hammersley integrate it exactly"),
    "checkerboard10": _indicator("checkerboard10", _board(10), 0.5,
                                 "a 10 x 10 board: 10 is not a power of two, so QMC is not exact"),
    "rotated_checkerboard": _indicator(
        "rotated_checkerboard", _rotated_board, 0.5,
        "an 8 x 8 board rotated by 30 degrees about the centre; exactly 1/2 because the point "
        "reflection through (1/2, 1/2) swaps the colours"),
    "gaussian": Integrand("gaussian", _gaussian, _G, _gauss_integral(_GAUSS_SIGMA / math.sqrt(2)) - _G ** 2,
                          "exp(-|u - c|^2 / (2 * 0.2^2)): smooth, peaked"),
    "exp_xy": Integrand("exp_xy", _exp_xy, _E, _exp_xy_integral(2.0) - _E ** 2,
                        "exp(x y): smooth; exact Ei(1) - gamma = 1.3179..."),
}


# --------------------------------------------------------------------------
# Problems: exact value + unbiased per-sample contributions
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class Problem:
    """An integral with its exact value and unbiased estimators of it.

    Attributes
    ----------
    name : str
    exact : float
    description : str
    methods : dict of str to callable
        Each maps unit-square points ``(n, 2)`` from any sampler to
        per-sample contributions ``(n,)``, ``f(X) / p(X)`` with ``X`` the
        warped point; their mean is an unbiased estimate of ``exact`` for
        uniform points (and for randomized stratified or QMC points).
    variances : dict of str to float
        Analytic per-sample variance of each method's contribution under
        uniform points, where known (the iid estimator's variance is this
        over ``N``).
    """

    name: str
    exact: float
    description: str
    methods: Mapping[str, Callable] = field(default_factory=dict)
    variances: Mapping[str, float] = field(default_factory=dict)


def _white_cells(u):
    """Warp to the two white cells of the [0, 2]^2 board (density 1/2 there)."""
    u = as_unit_square(u)
    hi = u[:, 0] >= 0.5
    x0 = np.minimum(2.0 * u[:, 0], np.nextafter(2.0, 0.0))   # [0,1) for cell (0,0), [1,2) for (1,1)
    return np.stack([x0, np.minimum(u[:, 1], np.nextafter(1.0, 0.0)) + hi], axis=1)


def _white_pdf(x):
    return 0.5 * checkerboard(x)


def _checkerboard_problem() -> Problem:
    uniform = contribution(checkerboard, sample=lambda u: 2.0 * as_unit_square(u),
                           pdf=lambda x: np.full(x.shape[0], 0.25))
    importance = contribution(checkerboard, sample=_white_cells, pdf=_white_pdf)
    return Problem(
        "checkerboard", CHECKERBOARD_INTEGRAL,
        "The lecture's 2 x 2 checkerboard on [0, 2]^2 (integral 2, integrand mean 1/2, variance 1/4). "
        "'uniform': 4 f(2u), variance 4. 'importance': samples only white cells, contribution "
        "always 2 (zero variance). Power-of-two aligned: Sobol/Hammersley are exact on it.",
        {"uniform": uniform, "importance": importance},
        {"uniform": 16.0 * CHECKERBOARD_VARIANCE, "importance": 0.0})


def hemisphere_problem(k: float = 1.0) -> Problem:
    """``int_H L_i cos(theta) dw`` with ``L_i = cos^k(theta)``: exact ``2 pi / (k + 2)``.

    Methods (all contributions of hemisphere directions warped from ``u``):

    - ``'uniform'``: ``p = 1/(2 pi)``, contribution ``2 pi cos^(k+1)``;
      variance ``4 pi^2 / (2k + 3) - I^2`` (``cos`` is uniform on [0, 1]).
    - ``'cosine'``: ``p = cos/pi``, contribution ``pi cos^k``; variance
      ``pi^2 / (k + 1) - I^2`` (``cos^2`` is uniform).
    - ``'mis'``: one-sample MIS of the two, balance heuristic, 1/2 each:
      contribution ``f / q``, ``q = (p_u + p_c)/2``; variance
      ``int f^2 / q - I^2 = 8 pi^2 int_0^1 c^(2k+2) / (1 + 2c) dc - I^2``.
    - ``'lobe'``: the Phong lobe ``cos^(k+1)``, proportional to the
      integrand: contribution ``2 pi / (k + 2)`` always, variance 0.

    For k >= 0 cosine sampling has the lower variance: the lecture's 'more
    radiance per sample'.
    """
    k = float(as_array(k, "k", ndim=0))
    if not k >= 0:
        raise ValueError(f"k must be >= 0; got {k}")
    exact = 2.0 * math.pi / (k + 2.0)

    def f(w):
        c = np.maximum(w[:, 1], 0.0)
        return c ** (k + 1.0)

    uni = (warps.square_to_uniform_hemisphere, warps.square_to_uniform_hemisphere_pdf)
    cos = (warps.square_to_cosine_hemisphere, warps.square_to_cosine_hemisphere_pdf)
    lobe = (lambda u: warps.square_to_phong_lobe(u, k + 1.0),
            lambda v: warps.square_to_phong_lobe_pdf(v, k + 1.0))
    mis_m2 = 8.0 * math.pi ** 2 * integrate.quad(lambda c: c ** (2 * k + 2) / (1 + 2 * c), 0, 1,
                                                 epsabs=1e-14, epsrel=1e-13)[0]
    return Problem(
        "hemisphere" if k == 1.0 else f"hemisphere_cos{k:g}",
        exact,
        f"int over the hemisphere of L_i cos(theta) with L_i = cos^{k:g}(theta): 2 pi/(k + 2) = {exact:.6g}. "
        "Uniform vs cosine-weighted sampling (lecture: 'Monte Carlo Uniform/Cosine Sampling'), "
        "their one-sample MIS, and the zero-variance cos^(k+1) lobe.",
        {"uniform": contribution(f, sample=uni[0], pdf=uni[1]),
         "cosine": contribution(f, sample=cos[0], pdf=cos[1]),
         "mis": one_sample_mis_contribution(f, [uni, cos]),
         "lobe": contribution(f, sample=lobe[0], pdf=lobe[1])},
        {"uniform": 4.0 * math.pi ** 2 / (2 * k + 3) - exact ** 2,
         "cosine": math.pi ** 2 / (k + 1) - exact ** 2,
         "mis": mis_m2 - exact ** 2,
         "lobe": 0.0})


def _integrand_problem(item: Integrand) -> Problem:
    return Problem(item.name, item.exact, item.description + " (on [0, 1]^2; 'uniform': f(u))",
                   {"uniform": contribution(item.f)}, {"uniform": item.variance})


#: The problems :mod:`mcvar.experiments` sweeps: ``'checkerboard'`` (the
#: lecture's board on [0, 2]^2), ``'hemisphere'`` (k = 1), ``'hemisphere_cos4'``,
#: and every :data:`INTEGRANDS` entry with its ``'uniform'`` method.
PROBLEMS: dict[str, Problem] = {
    "checkerboard": _checkerboard_problem(),
    "hemisphere": hemisphere_problem(1.0),
    "hemisphere_cos4": hemisphere_problem(4.0),
    **{name: _integrand_problem(item) for name, item in INTEGRANDS.items()},
}


# --------------------------------------------------------------------------
# 'Consistent Or Unbiased?' and 'Biased vs. Unbiased Example'
# --------------------------------------------------------------------------

def _box(lower, upper):
    lo = as_array(lower, "lower", ndim=1)
    hi = as_array(upper, "upper", ndim=1)
    if lo.shape != (2,) or hi.shape != (2,) or not np.all(hi > lo):
        raise ValueError(f"lower and upper must be 2-vectors with upper > lower; got {lo} and {hi}")
    return lo, hi


def fixed_grid_estimate(f, m: int, *, lower=(0.0, 0.0), upper=(1.0, 1.0)) -> float:
    """The m x m fixed-grid estimator: the mean of ``f`` at cell centres times the area.

    Parameters
    ----------
    f : callable
        ``f(x) -> (n,)`` for points ``(n, 2)``.
    m : int
        Grid resolution (``m^2`` samples).
    lower, upper : array_like, shape (2,)
        The box ``[lower, upper]`` (the lecture's image is ``[0, 2]^2`` for
        the checkerboard).

    Returns
    -------
    float

    Notes
    -----
    'Consistent Or Unbiased?', first estimator: deterministic, so its
    expectation is itself and its bias is its error. It is consistent for
    Riemann-integrable ``f`` (the error falls to 0 as ``m -> inf``) but
    biased at every finite ``m`` where ``f`` has edges off the grid. On the
    lecture's board the bias is exactly 0 for even ``m`` (no centre on a
    cell edge) and exactly ``2 / m^2`` for odd ``m`` (the middle row and
    column sit on the edges ``x = 1`` / ``y = 1``, where ``floor`` puts them
    in the upper cells: ``(m^2 + 1) / 2`` of the ``m^2`` centres are white).
    """
    m = check_count(m, "m")
    lo, hi = _box(lower, upper)
    c = (np.arange(m) + 0.5) / m
    gx, gy = np.meshgrid(lo[0] + (hi[0] - lo[0]) * c, lo[1] + (hi[1] - lo[1]) * c, indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    values = as_array(f(pts), "f(x)", ndim=1)
    if values.shape != (m * m,):
        raise ValueError(f"f must return shape ({m * m},); got {values.shape}")
    return float(values.mean() * np.prod(hi - lo))


def single_sample_estimate(f, *, lower=(0.0, 0.0), upper=(1.0, 1.0), rng=None) -> float:
    """One uniform sample of ``f`` times the area: unbiased, not consistent.

    'Consistent Or Unbiased?', second estimator: ``E[A f(X)] = int f``
    exactly, even for one sample, but the estimator never uses more than one
    sample, so its error does not fall however often it is 'iterated'
    (its variance stays ``A^2 Var f``, e.g. 4 on the lecture's board).
    Averaging R of them is a different, consistent estimator: plain Monte
    Carlo with R samples.
    """
    lo, hi = _box(lower, upper)
    x = lo + (hi - lo) * as_rng(rng).random((1, 2))
    value = as_array(f(x), "f(x)", ndim=1)
    if value.shape != (1,):
        raise ValueError(f"f must return shape (1,) for one point; got {value.shape}")
    return float(value[0] * np.prod(hi - lo))


def undivided_estimate(f, *, sample, n, sampler="random", rng=None, replicates=None) -> Estimate:
    """The lecture's biased estimator: average ``f(X)``, ``X ~ p``, without dividing by ``p``.

    Its expectation is ``int f p``, not ``int f``: samples are drawn
    'proportional to the PDF', over-representing where ``p`` is high
    ('Biased vs. Unbiased Example'). :func:`mcvar.estimators.estimate` with
    the same warp and its pdf divides by ``p`` and is unbiased. E.g.
    cosine sampling ``L_i cos`` with ``L_i = cos^k`` converges to
    ``2 / (k + 3)`` instead of ``2 pi / (k + 2)``.
    """
    if not callable(sample):
        raise TypeError(f"sample must be callable; got {type(sample).__name__}")
    return estimate(f, sample=sample, pdf=None, n=n, sampler=sampler, rng=rng, replicates=replicates)


# --------------------------------------------------------------------------
# Accumulation precision
# --------------------------------------------------------------------------

def running_sum(values, *, dtype=np.float32, initial: float = 0.0) -> np.ndarray:
    """The sequential running sum ``s_k = fl(s_(k-1) + x_k)`` in ``dtype``.

    A renderer's accumulation buffer: one add per sample, rounded to the
    buffer's precision. Returns every partial sum (``s_1 ... s_n``) so the
    running mean ``s_k / k`` can be plotted; ``initial`` continues a sum
    (process long streams in chunks).

    Notes
    -----
    Once ``s`` is large, its spacing ``ulp(s) = 2^(floor(log2 s) - 23)`` in
    float32 exceeds twice the increment and ``s + x`` rounds back to ``s``:
    the sum *stalls*. Adding 1.0 stalls at exactly ``2^24 = 16,777,216``
    (``2^24 + 1`` is a tie and rounds to the even ``2^24``); the lecture's
    checkerboard contributions {0, 4} stall at ``2^26``, i.e. after about
    ``3.4e7`` samples; values in [0, 1) at ``2^24``. ``numpy.sum`` hides
    this (pairwise summation, error ``O(eps log n)``), which is why this
    function uses ``numpy.cumsum``, a sequential loop. mcvar accumulates in
    float64 with pairwise sums per batch and Chan's update across batches
    (:meth:`mcvar.estimators.Estimate.merge`).

    References
    ----------
    N. J. Higham, "The accuracy of floating point summation", SIAM J. Sci.
    Comput. 14(4), 1993.
    """
    x = np.asarray(values)
    if x.ndim != 1:
        raise ValueError(f"values must be 1D; got shape {x.shape}")
    dt = np.dtype(dtype)
    if dt.kind != "f":
        raise TypeError(f"dtype must be a floating type; got {dt}")
    x = x.astype(dt, copy=False)
    if x.size and not np.all(np.isfinite(x)):
        raise ValueError("values must be finite")
    if initial != 0.0:
        x = np.concatenate([np.array([initial], dtype=dt), x])
        return np.cumsum(x, dtype=dt)[1:]
    return np.cumsum(x, dtype=dt)
