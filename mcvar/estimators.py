"""Monte Carlo estimators that report their error (layer 3).

The lecture's 'Monte Carlo Estimator' slide, ``(1/N) sum_j f(X_j) / p(X_j)``,
with what is needed to trust the number it returns:

- :class:`Estimate`: a mean with its per-sample variance, standard error and
  interval, and the error model used (``'iid'`` or randomized
  ``'replicates'``); independent runs merge exactly (Chan et al.), so 10^9
  samples taken in batches equal one pass, to rounding.
- :func:`estimate`: ``f``, a warp ``sample`` and its ``pdf`` over *any* 2D
  sampler of :mod:`mcvar.samplers` (importance sampling when the warp is not
  uniform, stratified or QMC estimation when the sampler is), with honest
  error bars for stratified and QMC points and a to-tolerance mode;
  :func:`estimate_mean` does the same for a ready-made per-sample
  contribution ``g(u)`` (e.g. :data:`mcvar.examples.PROBLEMS` methods).
- :func:`mis_estimate` (multi-sample MIS, ``n_k`` samples per strategy) and
  :func:`one_sample_mis`, weighted by :func:`balance_heuristic`,
  :func:`power_heuristic` or :func:`mis_weights`.
- :func:`replicate_study` and :func:`convergence_study`: R independent runs
  from ``SeedSequence(seed).spawn(R)``; empirical bias with its interval,
  variance, MSE, efficiency and the log-log error slope with its uncertainty.

Lecture slides: 'The Monte Carlo Estimator', 'Variance', 'Bias &
Consistency', 'Consistent Or Unbiased?', 'Multiple Importance Sampling'.
"""
from __future__ import annotations

import math
import numbers
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable, Literal, Sequence

import numpy as np
from scipy import stats

from ._validation import as_array, as_rng, check_choice, check_count, check_positive, check_probability
from .metrics import LogLogFit, loglog_fit
from .samplers import digital_shift, get_sampler
from . import warps

__all__ = [
    "Estimate",
    "estimate",
    "estimate_mean",
    "contribution",
    "one_sample_mis_contribution",
    "hemisphere_estimate",
    "mis_estimate",
    "one_sample_mis",
    "balance_heuristic",
    "power_heuristic",
    "mis_weights",
    "ReplicateStudy",
    "replicate_study",
    "ConvergenceStudy",
    "convergence_study",
]

_METHODS = ("iid", "replicates")
_BATCH = 1 << 20          # rows evaluated at once: bounds memory, not results
_IID_SAMPLERS = ("random",)


# --------------------------------------------------------------------------
# Estimate: a mean with its error, mergeable
# --------------------------------------------------------------------------

def _out(x):
    """A 0-d array as a Python float; arrays unchanged."""
    x = np.asarray(x, dtype=np.float64)
    return float(x) if x.ndim == 0 else x


@dataclass(frozen=True)
class Estimate:
    """A Monte Carlo estimate with its error: the result of every mcvar estimator.

    Parameters
    ----------
    mean : float or ndarray
        The estimate. An array (e.g. shape ``(3,)`` for RGB) estimates each
        component at once; ``variance`` then has the same shape.
    variance : float or ndarray
        Per-sample variance, ``>= 0``; ``inf`` when unknown (``n = 1``, or
        a multi-sample MIS estimate with a strategy of one sample), which
        gives an infinite interval rather than a false zero error.
        For ``method='iid'`` the unbiased sample variance of the
        contributions ``f(X)/p(X)``; for ``method='replicates'`` the
        per-sample variance implied by the scatter of the replicate means,
        ``m * s_R^2`` (``m`` samples per replicate), i.e. the variance an iid
        estimator would need to reach the same standard error. Either way
        ``stderr = sqrt(variance / n)``.
    n : int
        Number of samples (function evaluations) in the estimate, ``>= 1``.
    method : {'iid', 'replicates'}
        The error model: independent contributions, or the scatter of
        ``replicates`` independently randomized point sets (the only honest
        one for stratified and QMC points, whose samples are dependent).
    replicates : int
        R for ``method='replicates'`` (``>= 2``, dividing ``n``); 0 for iid.

    Attributes
    ----------
    stderr : float or ndarray
        Standard error of ``mean``: ``sqrt(variance / n)``.
    dof : int
        Degrees of freedom of the variance estimate: ``n - 1`` (iid) or
        ``R - 1`` (replicates); used for Student-t intervals.

    Notes
    -----
    Shape rules: ``mean`` and ``variance`` have the same shape (``()`` for a
    scalar integrand, ``(c,)`` for c channels, any shape in general);
    ``stderr`` and both ends of :meth:`ci` have it too. :meth:`merge` needs
    equal shapes.

    Merging two estimates of independent runs uses the parallel update of
    Chan, Golub and LeVeque [1]_: with ``M2 = (n - 1) s^2``,
    ``delta = mean_b - mean_a``, ``n = n_a + n_b``::

        mean = mean_a + delta * n_b / n
        M2   = M2_a + M2_b + delta^2 * n_a * n_b / n

    which equals the one-pass mean and variance of the pooled samples
    exactly (up to rounding), so estimates computed in batches of any size
    agree with one pass over all samples. For replicates the same update
    runs on the replicate means (both estimates must use the same number
    of samples per replicate).

    References
    ----------
    .. [1] T. F. Chan, G. H. Golub, R. J. LeVeque, "Updating formulae and a
       pairwise algorithm for computing sample variances", COMPSTAT 1982
       (Stanford report STAN-CS-79-773, 1979).

    Examples
    --------
    >>> e = Estimate.from_samples([1.0, 2.0, 3.0, 4.0])
    >>> e.mean, e.variance, e.n
    (2.5, 1.6666666666666667, 4)
    >>> e.merge(Estimate.from_samples([5.0])).mean
    3.0
    """

    mean: float | np.ndarray
    variance: float | np.ndarray
    n: int
    method: str = "iid"
    replicates: int = 0
    stderr: float | np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        n = check_count(self.n, "n")
        check_choice(self.method, "method", _METHODS)
        mean = as_array(self.mean, "mean")
        var = as_array(self.variance, "variance", finite=False)
        if mean.shape != var.shape:
            raise ValueError(f"variance must have the shape of mean {mean.shape}; got {var.shape}")
        if var.size and not np.all(var >= 0):
            raise ValueError("variance must be >= 0 (NaN not allowed)")
        if self.method == "iid":
            if self.replicates != 0:
                raise ValueError(f"replicates must be 0 for method='iid'; got {self.replicates}")
        else:
            r = check_count(self.replicates, "replicates")
            if r < 2 or n % r:
                raise ValueError(f"replicates must be >= 2 and divide n; got replicates={r}, n={n}")
            if var.size and not np.all(np.isfinite(var)):
                raise ValueError("variance must be finite for method='replicates'")
        object.__setattr__(self, "n", n)
        object.__setattr__(self, "mean", _out(mean))
        object.__setattr__(self, "variance", _out(var))
        object.__setattr__(self, "stderr", _out(np.sqrt(var / n)))

    # -- construction -------------------------------------------------------
    @classmethod
    def from_samples(cls, values) -> "Estimate":
        """The iid estimate from per-sample contributions, shape ``(n, ...)``.

        Mean by NumPy's pairwise summation and variance by the two-pass
        formula, both in float64 whatever the input dtype; one sample gives
        ``variance = inf`` (its error is unknown, not zero).
        """
        x = as_array(values, "values")
        if x.ndim == 0 or x.shape[0] == 0:
            raise ValueError(f"values must have shape (n, ...) with n >= 1; got shape {x.shape}")
        n = x.shape[0]
        mean = x.mean(axis=0)
        var = x.var(axis=0, ddof=1) if n > 1 else np.full(mean.shape, np.inf)
        return cls(mean, var, n)

    @classmethod
    def from_replicates(cls, means, m: int) -> "Estimate":
        """The estimate from ``R >= 2`` replicate means of ``m`` samples each.

        ``means`` has shape ``(R, ...)``; the result's mean is their average
        and its standard error their standard deviation over ``sqrt(R)``.
        """
        x = as_array(means, "means")
        m = check_count(m, "m")
        if x.ndim == 0 or x.shape[0] < 2:
            raise ValueError(f"means must have shape (R, ...) with R >= 2; got shape {x.shape}")
        r = x.shape[0]
        return cls(x.mean(axis=0), m * x.var(axis=0, ddof=1), r * m, "replicates", r)

    # -- derived --------------------------------------------------------------
    @property
    def dof(self) -> int:
        return self.n - 1 if self.method == "iid" else self.replicates - 1

    def half_width(self, level: float = 0.95):
        """Half-width of the two-sided ``level`` interval (Student t, ``dof``)."""
        level = check_probability(level, "level")
        if not 0.0 < level < 1.0:
            raise ValueError(f"level must lie in (0, 1); got {level}")
        if self.dof < 1:
            return _out(np.full(np.shape(self.mean), np.inf))
        return _out(stats.t.ppf(0.5 + level / 2.0, self.dof) * np.asarray(self.stderr))

    def ci(self, level: float = 0.95):
        """Two-sided confidence interval ``(low, high)`` for the true mean.

        ``mean -+ t_{dof}(1/2 + level/2) * stderr``: Student t with the
        estimate's degrees of freedom (it matters for few replicates; for
        large iid ``n`` it is the normal interval). Infinite for ``n = 1``.
        """
        h = np.asarray(self.half_width(level))
        m = np.asarray(self.mean)
        return _out(m - h), _out(m + h)

    # -- merging --------------------------------------------------------------
    def merge(self, other: "Estimate") -> "Estimate":
        """The estimate of both independent runs together (Chan et al. update)."""
        if not isinstance(other, Estimate):
            raise TypeError(f"other must be an Estimate; got {type(other).__name__}")
        if self.method != other.method:
            raise ValueError(f"cannot merge a {self.method!r} estimate with a {other.method!r} one")
        if np.shape(self.mean) != np.shape(other.mean):
            raise ValueError(f"cannot merge estimates of shapes {np.shape(self.mean)} "
                             f"and {np.shape(other.mean)}")
        if self.method == "iid":
            na, nb, scale = self.n, other.n, 1
        else:
            m = self.n // self.replicates
            if other.n // other.replicates != m:
                raise ValueError("replicate estimates merge only with the same samples per replicate; "
                                 f"got {m} and {other.n // other.replicates}")
            na, nb, scale = self.replicates, other.replicates, m
        ma, mb = np.asarray(self.mean), np.asarray(other.mean)
        # M2 of the units merged (samples, or replicate means); one unit has M2 = 0.
        m2a = 0.0 if na == 1 else np.asarray(self.variance) / scale * (na - 1)
        m2b = 0.0 if nb == 1 else np.asarray(other.variance) / scale * (nb - 1)
        n = na + nb
        delta = mb - ma
        mean = ma + delta * (nb / n)
        m2 = m2a + m2b + delta * delta * (na * nb / n)
        var = m2 / (n - 1) * scale
        if self.method == "iid":
            return Estimate(mean, var, n)
        return Estimate(mean, var, n * scale, "replicates", n)

    def __str__(self) -> str:
        def fmt(x, spec):
            x = np.asarray(x)
            return format(float(x), spec) if x.ndim == 0 else "[" + ", ".join(format(v, spec) for v in x.ravel()) + "]"
        lo, hi = self.ci(0.95)
        rep = f", R={self.replicates}" if self.method == "replicates" else ""
        return (f"{fmt(self.mean, '.7g')} +- {fmt(self.stderr, '.2g')} (95% CI [{fmt(lo, '.7g')}, "
                f"{fmt(hi, '.7g')}], n={self.n}, {self.method}{rep})")


# --------------------------------------------------------------------------
# Contributions f(X)/p(X), checked
# --------------------------------------------------------------------------

def _divide(fx, p, zero_pdf: str, where: str = "") -> np.ndarray:
    """``fx / p`` with the checks of :func:`estimate`; ``fx`` (n, ...), ``p`` (n,)."""
    n = fx.shape[0]
    if p.shape != (n,):
        raise ValueError(f"pdf must return shape ({n},) for {n} samples{where}; got {p.shape}")
    if not np.all(p >= 0):   # NaN fails too
        raise ValueError(f"pdf must be >= 0 (no NaN){where}; got {p[~(p >= 0)][0]}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"pdf must be finite{where}: a Dirac delta has no density to divide by")
    zero = p == 0.0
    pb = p.reshape((n,) + (1,) * (fx.ndim - 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(pb > 0, fx / np.where(pb > 0, pb, 1.0), 0.0)
    if zero.any() and zero_pdf == "raise":
        bad = zero.reshape((n,) + (1,) * (fx.ndim - 1)) & (fx != 0)
        if bad.any():
            raise ValueError(
                f"pdf is 0 at {int(bad.reshape(n, -1).any(axis=1).sum())} sampled point(s) where f != 0{where}: "
                "the sampler drew points its pdf says it cannot draw (a sampler/pdf mismatch), or f is "
                "nonzero on a measure-zero boundary such as the horizon; pass zero_pdf='drop' to count "
                "such samples as 0")
    if not np.all(np.isfinite(out)):
        raise ValueError(f"f(X)/p(X) overflowed to inf{where}: the pdf is too small where f is not")
    return out


def _eval_f(f, x, n: int, name: str = "f") -> np.ndarray:
    fx = as_array(f(x), f"{name}(x)", finite=False)
    if fx.ndim == 0 or fx.shape[0] != n:
        raise ValueError(f"{name} must return shape (n, ...) with n = {n} rows; got {fx.shape}")
    if not np.all(np.isfinite(fx)):
        raise ValueError(f"{name} returned NaN or Inf at {int((~np.isfinite(fx)).reshape(n, -1).any(axis=1).sum())} "
                         "sample(s)")
    return fx


def contribution(f, *, sample=None, pdf=None, zero_pdf: Literal["raise", "drop"] = "raise"):
    """The per-sample contribution ``g(u) = f(x) / p(x)``, ``x = sample(u)``.

    What :func:`estimate` averages, as a function of unit-square points
    ``(n, 2) -> (n,)`` (or ``(n, ...)``), to pass to :func:`estimate_mean`
    or to evaluate on points of one's own (``mcvar.examples.PROBLEMS``
    methods are built with it). ``sample=None`` is the identity warp and
    ``pdf=None`` the density 1; ``zero_pdf`` as in :func:`estimate`.
    """
    if not callable(f):
        raise TypeError(f"f must be callable; got {type(f).__name__}")
    for name, fn in (("sample", sample), ("pdf", pdf)):
        if fn is not None and not callable(fn):
            raise TypeError(f"{name} must be callable or None; got {type(fn).__name__}")
    check_choice(zero_pdf, "zero_pdf", ("raise", "drop"))

    def g(u):
        n = u.shape[0]
        x = u if sample is None else sample(u)
        fx = _eval_f(f, x, n)
        if pdf is None:
            return fx
        p = as_array(pdf(x), "pdf(x)", finite=False)
        return _divide(fx, p, zero_pdf)
    return g


def _points(sampler, m: int, rng) -> np.ndarray:
    u = sampler(m, rng=rng)
    u = np.asarray(u, dtype=np.float64)
    if u.shape != (m, 2):
        raise ValueError(f"sampler must return shape ({m}, 2); got {u.shape}")
    if not np.all((u >= 0.0) & (u <= 1.0)):   # NaN fails too
        raise ValueError(f"sampler must return points in [0, 1]^2 (no NaN); got {u[~((u >= 0) & (u <= 1))][0]}")
    return u


def _mean_of(g, u: np.ndarray, batch: int) -> Estimate:
    """iid Estimate of ``g`` over the rows of ``u``, evaluated in batches."""
    est = None
    for start in range(0, u.shape[0], batch):
        e = Estimate.from_samples(_checked_g(g, u[start:start + batch]))
        est = e if est is None else est.merge(e)
    return est


def _checked_g(g, u):
    y = as_array(g(u), "g(u)", finite=False)
    if y.ndim == 0 or y.shape[0] != u.shape[0]:
        raise ValueError(f"g must return shape (n, ...) with n = {u.shape[0]} rows; got {y.shape}")
    if not np.all(np.isfinite(y)):
        raise ValueError("g returned NaN or Inf: a contribution must be finite")
    return y


def _resolve_sampler(sampler):
    if callable(sampler):
        return sampler, None
    if isinstance(sampler, str):
        return get_sampler(sampler), sampler
    raise TypeError(f"sampler must be a sampler name or a callable (n, *, rng) -> (n, 2); "
                    f"got {type(sampler).__name__}")


def _resolve_replicates(replicates, name) -> int:
    if replicates is None:
        return 1 if name in _IID_SAMPLERS else 16
    r = check_count(replicates, "replicates")
    if r == 1 and name is not None and name not in _IID_SAMPLERS:
        raise ValueError(f"replicates must be >= 2 for sampler {name!r}: the iid standard error is wrong "
                         "for stratified and QMC points, whose samples are dependent; got 1")
    return r


class _Replicator:
    """Independent randomized point sets: one child stream per replicate.

    A deterministic sampler (plain grid, Hammersley, Halton) returns the same
    set for every stream; it is then randomized by a random digital shift
    (each point becomes uniform on the square, nets stay nets), so that the
    replicates are independent and each is unbiased.
    """

    def __init__(self, sampler, children):
        self.sampler = sampler
        self.children = children
        self.deterministic = None

    def points(self, m: int):
        sets = [_points(self.sampler, m, np.random.default_rng(c)) for c in self.children]
        if self.deterministic is None:
            self.deterministic = np.array_equal(sets[0], sets[1])
        if self.deterministic:
            # fresh streams for the shifts, independent of those that built the sets
            shifts = [np.random.default_rng(c).spawn(1)[0] for c in self.children]
            sets = [np.minimum(digital_shift(s, rng=r), np.nextafter(1.0, 0.0))
                    for s, r in zip(sets, shifts)]
        return sets


def _children(rng, k: int):
    """``k`` independent SeedSequences: ``SeedSequence(seed).spawn(k)`` for an int seed."""
    if isinstance(rng, np.random.SeedSequence):
        return rng.spawn(k)
    gen = as_rng(rng)
    return [g.bit_generator.seed_seq for g in gen.spawn(k)]


def _tolerance(atol, rtol):
    if atol is None and rtol is None:
        return None
    a = 0.0 if atol is None else check_positive(atol, "atol", allow_zero=True)
    r = 0.0 if rtol is None else check_positive(rtol, "rtol", allow_zero=True)
    if not (a > 0 or r > 0):
        raise ValueError(f"atol or rtol must be > 0 for a tolerance; got atol={atol}, rtol={rtol}")
    return a, r


def _target(est: Estimate, tol) -> np.ndarray:
    a, r = tol
    return np.maximum(a, r * np.abs(np.asarray(est.mean)))


def estimate_mean(g, *, n, sampler="random", rng=None, replicates=None, atol=None, rtol=None,
                  level: float = 0.99, max_n: int = 1 << 28, batch: int = _BATCH) -> Estimate:
    """Estimate ``E[g(U)]``, ``U`` uniform on the unit square, from any 2D sampler.

    The engine under :func:`estimate`: ``g`` maps unit-square points
    ``(n, 2)`` to per-sample contributions ``(n,)`` or ``(n, ...)`` (for a
    Monte Carlo integral, ``f(x) / p(x)`` with ``x`` the warped point), e.g.
    a method of :data:`mcvar.examples.PROBLEMS`.

    Parameters
    ----------
    g : callable
        ``g(u) -> contributions``; must return finite values.
    n : int
        Number of samples (``>= 1``). With ``replicates = R > 1`` each
        replicate gets ``n // R`` points (``n >= 2 R``) and the Estimate's
        ``n`` is ``R * (n // R)``. In tolerance mode ``n`` is the initial
        (pilot) size.
    sampler : str or callable, optional
        A name in :data:`mcvar.samplers.SAMPLERS` or a function
        ``(n, *, rng) -> (n, 2)`` points in [0, 1)^2. Default ``'random'``.
    rng : None, int, SeedSequence or Generator, optional
        Randomness; replicates use ``SeedSequence(seed).spawn(R)``.
    replicates : int, optional
        ``1`` for the iid error model (only valid for independent points);
        ``R >= 2`` for R independently randomized point sets. Default: 1
        for ``'random'``, 16 for every other sampler (including callables).
    atol, rtol : float, optional
        Tolerance mode: sample until the half-width of the ``level``
        interval is ``<= max(atol, rtol * |mean|)`` (componentwise).
    level : float, optional
        Confidence level of the tolerance criterion (0.99, as QMCPy's
        ``alpha = 0.01``).
    max_n : int, optional
        Budget in tolerance mode; when reached a ``RuntimeWarning`` says the
        tolerance was not met and the Estimate holds what was achieved.
    batch : int, optional
        Rows passed to ``g`` at once (memory only; results are unchanged).

    Returns
    -------
    Estimate
        ``method='iid'`` or ``'replicates'`` as used.

    Notes
    -----
    *Replicates.* The iid standard error ``s / sqrt(n)`` assumes independent
    samples; jittered, Latin, Sobol or Hammersley points are dependent by
    design (that is why they work), and ``s / sqrt(n)`` then overstates the
    error of a good point set and can understate it for a bad one. R
    independent randomizations (scrambles or shifts) give R independent,
    unbiased estimates whose scatter is the honest error [1]_ (ch. 17).

    *Tolerance, iid* (QMCPy's ``CubMCCLT``, [2]_): a pilot of ``n`` samples
    estimates ``sigma``; then ``N = ceil((z * 1.2 * sigma / tol)^2)`` fresh
    samples give the estimate (the pilot is not reused, which keeps the CLT
    interval valid; 1.2 inflates the pilot's sigma). If the interval is still
    too wide, a further stage adds samples from the updated variance.

    *Tolerance, replicates* (``CubQMCCLT``): R replicates of ``m`` points;
    ``m`` doubles (quadruples for samplers needing square counts) until the
    Student-t half-width over the replicate means meets the target. Earlier
    rounds are discarded, so the work is at most twice the final ``n``
    (four times for square-count samplers).

    References
    ----------
    .. [1] A. B. Owen, "Monte Carlo theory, methods and examples", 2013,
       ch. 17 (randomized QMC).
    .. [2] S.-C. T. Choi, F. J. Hickernell, R. Jagadeeswaran, M. J. McCourt,
       A. G. Sorokin, "Quasi-Monte Carlo Software", MCQMC 2020, Springer
       Proc. Math. Stat. 387, 2022.

    Examples
    --------
    >>> e = estimate_mean(lambda u: u[:, 0] * u[:, 1], n=4096, sampler="sobol", rng=7)
    >>> e.method, e.replicates, abs(e.mean - 0.25) < 5 * e.stderr
    ('replicates', 16, True)
    """
    if not callable(g):
        raise TypeError(f"g must be callable; got {type(g).__name__}")
    n = check_count(n, "n")
    max_n = check_count(max_n, "max_n")
    batch = check_count(batch, "batch")
    level = check_probability(level, "level")
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1); got {level}")
    fn, name = _resolve_sampler(sampler)
    r = _resolve_replicates(replicates, name)
    tol = _tolerance(atol, rtol)
    if r == 1:
        gen = as_rng(rng)
        if tol is None:
            return _iid(g, fn, n, gen, batch)
        return _iid_to_tolerance(g, fn, n, gen, batch, tol, level, max_n)
    m = n // r
    if m < 1:
        raise ValueError(f"n must be >= replicates ({r}) so every replicate has a point; got n={n}")
    rep = _Replicator(fn, _children(rng, r))
    if tol is None:
        return _replicate_once(g, rep, m, batch)
    return _replicates_to_tolerance(g, rep, m, batch, tol, level, max_n)


def _iid(g, fn, n, gen, batch) -> Estimate:
    est = None
    for start in range(0, n, batch):
        e = _mean_of(g, _points(fn, min(batch, n - start), gen), batch)
        est = e if est is None else est.merge(e)
    return est


def _iid_to_tolerance(g, fn, n0, gen, batch, tol, level, max_n) -> Estimate:
    z = stats.norm.ppf(0.5 + level / 2.0)
    pilot = _iid(g, fn, max(n0, 2), gen, batch)
    target = _target(pilot, tol)
    need = int(np.max(np.ceil((z * 1.2 * np.sqrt(np.asarray(pilot.variance)) / target) ** 2)))
    budget = max_n - pilot.n
    if budget < 2:
        warnings.warn(f"max_n={max_n} leaves no budget after the pilot; returning the pilot estimate",
                      RuntimeWarning, stacklevel=3)
        return pilot
    est = _iid(g, fn, min(max(need, 2), budget), gen, batch)
    while True:
        target = _target(est, tol)
        if np.all(np.asarray(est.half_width(level)) <= target):
            return est
        used = pilot.n + est.n
        if used >= max_n:
            warnings.warn(f"tolerance not met within max_n={max_n} samples: half-width "
                          f"{np.max(est.half_width(level)):.3g} > {np.min(target):.3g}",
                          RuntimeWarning, stacklevel=3)
            return est
        more = int(np.max(np.ceil((z * np.sqrt(np.asarray(est.variance)) / target) ** 2))) - est.n
        est = est.merge(_iid(g, fn, int(min(max(more, est.n // 10, 2), max_n - used)), gen, batch))


def _replicate_once(g, rep: _Replicator, m: int, batch: int) -> Estimate:
    means = [np.asarray(_mean_of(g, u, batch).mean) for u in rep.points(m)]
    return Estimate.from_replicates(np.stack(means), m)


def _replicates_to_tolerance(g, rep, m, batch, tol, level, max_n) -> Estimate:
    r = len(rep.children)
    est = _replicate_once(g, rep, m, batch)
    while True:
        target = _target(est, tol)
        if np.all(np.asarray(est.half_width(level)) <= target):
            return est
        grown = None
        for factor in (2, 4):
            if r * m * factor > max_n:
                break
            try:
                sets = rep.points(m * factor)
            except ValueError:      # e.g. jittered or grid need a square count
                continue
            grown = m * factor
            break
        if grown is None:
            warnings.warn(f"tolerance not met within max_n={max_n} samples: half-width "
                          f"{np.max(est.half_width(level)):.3g} > {np.min(target):.3g}",
                          RuntimeWarning, stacklevel=3)
            return est
        m = grown
        est = Estimate.from_replicates(np.stack([np.asarray(_mean_of(g, u, batch).mean) for u in sets]), m)


def estimate(f, *, sample=None, pdf=None, n, sampler="random", rng=None, atol=None, rtol=None,
             replicates=None, level: float = 0.99, max_n: int = 1 << 28,
             zero_pdf: Literal["raise", "drop"] = "raise", batch: int = _BATCH) -> Estimate:
    """The Monte Carlo estimator ``(1/N) sum_j f(X_j) / p(X_j)``, with its error.

    ``X_j = sample(U_j)`` for unit-square points ``U_j`` from ``sampler``: a
    uniform warp is plain Monte Carlo, a warp that follows the integrand is
    importance sampling, a stratified or QMC sampler gives stratified or
    quasi-Monte Carlo estimation, all with the same code.

    Parameters
    ----------
    f : callable
        The integrand on the warp's domain: ``f(x) -> (n,)`` or ``(n, ...)``
        (e.g. RGB), finite.
    sample : callable, optional
        The warp ``sample(u) -> x`` from ``(n, 2)`` unit-square points to the
        domain (e.g. :func:`mcvar.warps.square_to_cosine_hemisphere`).
        Default: the identity (integrate over the unit square).
    pdf : callable, optional
        The warp's density ``pdf(x) -> (n,)`` in the measure of the integral
        (solid angle for directions). Default: 1 (uniform on the square).
    n, sampler, rng, replicates, atol, rtol, level, max_n, batch
        As in :func:`estimate_mean`.
    zero_pdf : {'raise', 'drop'}, optional
        What a sampled point with ``pdf = 0`` and ``f != 0`` means; see Notes.

    Returns
    -------
    Estimate

    Notes
    -----
    The lecture's 'The Monte Carlo Estimator' slide: dividing by the pdf
    makes the estimator unbiased for ``int f`` whenever ``p > 0`` wherever
    ``f != 0``; because ``p`` integrates to 1 the domain's size is already
    accounted for ('Monte Carlo Uniform Sampling': ``p = 1 / 2 pi`` gives the
    factor ``2 pi``; 'Monte Carlo Cosine Sampling': ``p = cos / pi`` cancels
    the cosine).

    Samples with ``p(X) = 0`` contribute 0 (never NaN: such a sample failed,
    like a zero BSDF weight). If ``f(X) != 0`` at such a point the sampler
    drew where its own pdf says it cannot: either sampler and pdf disagree
    (a bug this check catches; the default raises ``ValueError``) or the
    point lies on a measure-zero boundary (e.g. the horizon for cosine
    sampling, reached by u exactly on the square's edge). ``zero_pdf='drop'``
    counts these as 0, which is exact on a measure-zero set and otherwise
    biases the estimate by ``-int_{p=0} f``: the same bias as an integrand
    that is nonzero where the pdf is 0, which no sampled-based check can see.

    Examples
    --------
    The lecture's checkerboard on [0, 2]^2 (integral 2), uniform sampling:

    >>> import numpy as np
    >>> board = lambda x: (np.floor(x).sum(axis=1) % 2 == 0).astype(float)
    >>> e = estimate(board, sample=lambda u: 2 * u, pdf=lambda x: np.full(len(x), 0.25),
    ...              n=100_000, rng=2024)
    >>> abs(e.mean - 2) < 5 * e.stderr, round(e.variance, 1)
    (True, 4.0)
    """
    return estimate_mean(contribution(f, sample=sample, pdf=pdf, zero_pdf=zero_pdf), n=n, sampler=sampler, rng=rng,
                         replicates=replicates, atol=atol, rtol=rtol, level=level, max_n=max_n,
                         batch=batch)


# --------------------------------------------------------------------------
# MIS weights
# --------------------------------------------------------------------------

def _heuristic_pdfs(pdf_f, pdf_g):
    f = as_array(pdf_f, "pdf_f", finite=False)
    g = as_array(pdf_g, "pdf_g", finite=False)
    for name, a in (("pdf_f", f), ("pdf_g", g)):
        if a.size and not np.all(a >= 0):  # NaN fails too
            bad = a[~(a >= 0)].ravel()[0]
            raise ValueError(f"{name} must be >= 0 (NaN not allowed); got {bad}")
    try:
        f, g = np.broadcast_arrays(f, g)
    except ValueError as exc:
        raise ValueError(f"pdf_f and pdf_g must broadcast together; got shapes "
                         f"{np.shape(pdf_f)} and {np.shape(pdf_g)}") from exc
    return f, g


def power_heuristic(pdf_f, pdf_g, n_f=1, n_g=1, beta=2.0):
    """Veach's power heuristic: the MIS weight of strategy f against g.

    Parameters
    ----------
    pdf_f, pdf_g : array_like
        Densities of the sample under strategy f (the one that drew it) and
        under the other strategy g, in the same measure; broadcast together.
        ``inf`` stands for a Dirac delta (a specular lobe).
    n_f, n_g : float, optional
        Sample counts (or fractions ``c_k``) of the two strategies, >= 0.
    beta : float, optional
        Exponent, > 0. ``beta = 1`` is the balance heuristic; ``beta = inf``
        is the maximum heuristic (weight 1 for the larger ``n p``, ties 1/2).

    Returns
    -------
    ndarray or float
        ``(n_f p_f)^beta / ((n_f p_f)^beta + (n_g p_g)^beta)`` in [0, 1], with
        the shape of the broadcast inputs (a float for scalar inputs).

    Notes
    -----
    Computed as ``1 / (1 + (n_g p_g / (n_f p_f))^beta)`` so that large pdfs
    never overflow to ``inf / inf``. Where both ``n p`` are 0 the sample cannot
    have been drawn by either strategy and the weight is 0 (not NaN); where
    ``p_f = inf`` (a delta) the weight is exactly 1, as in pbrt-v4's
    ``PowerHeuristic``; where ``p_g = inf`` and ``p_f`` is finite it is 0.
    Weights of f and g sum to 1 wherever either pdf is positive, the
    condition for an unbiased multi-sample MIS estimator [1]_ (eq. 9.2).

    References
    ----------
    .. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
       Simulation", PhD thesis, Stanford University, 1997, ch. 9.
    .. [2] E. Veach, L. J. Guibas, "Optimally Combining Sampling Techniques for
       Monte Carlo Rendering", SIGGRAPH 1995.

    Examples
    --------
    >>> float(power_heuristic(1.0, 1.0))
    0.5
    >>> float(power_heuristic(2.0, 1.0))
    0.8
    """
    n_f = check_positive(n_f, "n_f", allow_zero=True)
    n_g = check_positive(n_g, "n_g", allow_zero=True)
    beta = check_positive(beta, "beta", allow_inf=True)
    f, g = _heuristic_pdfs(pdf_f, pdf_g)
    a = n_f * f
    b = n_g * g
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ratio = b / a                       # >= 0, inf where a == 0 < b
        w = 1.0 / (1.0 + ratio ** beta)
    w = np.where(a > 0, w, 0.0)             # neither (or only g) can draw it
    w = np.where(np.isinf(a), 1.0, w)        # a delta in f always wins
    w = np.where(np.isinf(b) & ~np.isinf(a), 0.0, w)
    return w[()] if w.ndim == 0 else w


def balance_heuristic(pdf_f, pdf_g, n_f=1, n_g=1):
    """Veach's balance heuristic: ``n_f p_f / (n_f p_f + n_g p_g)``.

    The weight that turns the lecture's MIS estimator
    ``(1/N) sum_i sum_j f(x_ij) / sum_k c_k p_k(x_ij)`` into a sum of
    per-strategy estimators: ``w_f(x) f(x) / (n_f p_f(x))`` summed over f's
    samples. Same conventions as :func:`power_heuristic` with ``beta = 1``:
    0 where both pdfs are 0, exactly 1 where ``p_f = inf`` (a delta).

    Parameters
    ----------
    pdf_f, pdf_g : array_like
        Densities of the sample under the strategy that drew it (f) and the
        other (g); ``inf`` marks a delta.
    n_f, n_g : float, optional
        Sample counts or fractions, >= 0.

    Returns
    -------
    ndarray or float
        Weights in [0, 1], broadcast shape of the pdfs.

    Notes
    -----
    Veach proves the balance heuristic's variance is within
    ``(1/min_k n_k - 1/N) mu^2`` of any other weighting's [1]_ (theorem 9.2).

    References
    ----------
    .. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
       Simulation", PhD thesis, Stanford University, 1997, ch. 9.

    Examples
    --------
    >>> float(balance_heuristic(3.0, 1.0))
    0.75
    >>> float(balance_heuristic(0.0, 0.0))
    0.0
    """
    return power_heuristic(pdf_f, pdf_g, n_f, n_g, beta=1.0)


def mis_weights(pdfs, counts=None, *, heuristic: Literal["balance", "power"] = "balance",
                beta: float = 2.0) -> np.ndarray:
    """MIS weights of K strategies: ``w_k(x) = (n_k p_k)^b / sum_l (n_l p_l)^b``.

    Parameters
    ----------
    pdfs : array_like, shape (K, n)
        ``pdfs[l, j]``: density of sample ``j`` under strategy ``l``, >= 0;
        ``inf`` marks a delta.
    counts : array_like, shape (K,), optional
        Sample counts or fractions ``n_k`` (>= 0); default all 1.
    heuristic : {'balance', 'power'}
        ``b = 1`` or ``b = beta``.
    beta : float
        Exponent of the power heuristic (> 0; ``inf`` is the maximum
        heuristic).

    Returns
    -------
    ndarray, shape (K, n)
        ``w[k, j]``: the weight sample ``j`` gets if strategy ``k`` drew it.
        Columns sum to 1 where any ``n_l p_l > 0`` and are 0 where all are.
        Where some ``n_l p_l`` are infinite the weight is shared equally
        among them (1 for a single delta), as in :func:`power_heuristic`.

    Notes
    -----
    Veach's heuristics generalised to K strategies [1]_ (eqs. 9.4 and 9.5);
    with K = 2, ``w[0] == power_heuristic(pdfs[0], pdfs[1], n_0, n_1, b)``.
    Computed after dividing each column by its maximum, so no power
    overflows.

    References
    ----------
    .. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
       Simulation", PhD thesis, Stanford University, 1997, ch. 9.
    """
    check_choice(heuristic, "heuristic", ("balance", "power"))
    b = 1.0 if heuristic == "balance" else check_positive(beta, "beta", allow_inf=True)
    p = as_array(pdfs, "pdfs", ndim=2, finite=False)
    if p.size and not np.all(p >= 0):
        raise ValueError("pdfs must be >= 0 (NaN not allowed)")
    k = p.shape[0]
    c = np.ones(k) if counts is None else as_array(counts, "counts", ndim=1, nonnegative=True)
    if c.shape != (k,):
        raise ValueError(f"counts must have shape ({k},), one per strategy; got {c.shape}")
    a = c[:, None] * p
    inf = np.isinf(a)
    top = np.max(np.where(inf, 0.0, a), axis=0, initial=0.0)
    with np.errstate(divide="ignore", invalid="ignore", under="ignore"):
        s = np.where(top > 0, a / np.where(top > 0, top, 1.0), 0.0) ** b
        total = s.sum(axis=0)
        w = np.where(total > 0, s / np.where(total > 0, total, 1.0), 0.0)
    n_inf = inf.sum(axis=0)
    return np.where(n_inf > 0, inf / np.maximum(n_inf, 1), w)


def _strategies(strategies):
    try:
        pairs = [tuple(s) for s in strategies]
    except TypeError as exc:
        raise TypeError("strategies must be a sequence of (sample, pdf) pairs") from exc
    if len(pairs) < 1 or any(len(p) != 2 or not all(callable(q) for q in p) for p in pairs):
        raise TypeError("strategies must be a non-empty sequence of (sample, pdf) pairs of callables")
    return pairs


def _pdf_matrix(pairs, x, n):
    rows = []
    for l, (_, pdf) in enumerate(pairs):
        p = as_array(pdf(x), f"pdf of strategy {l}", finite=False)
        if p.shape != (n,):
            raise ValueError(f"pdf of strategy {l} must return shape ({n},); got {p.shape}")
        if not np.all(p >= 0):
            raise ValueError(f"pdf of strategy {l} must be >= 0 (no NaN)")
        if not np.all(np.isfinite(p)):
            raise ValueError(f"pdf of strategy {l} must be finite: a delta has no density to divide by")
        rows.append(p)
    return np.stack(rows)


def _mis_contribution(f, pairs, k, counts, heuristic, beta, zero_pdf):
    """Per-sample ``w_k f / p_k`` for samples of strategy k (multi-sample MIS)."""
    def g(u):
        n = u.shape[0]
        x = pairs[k][0](u)
        fx = _eval_f(f, x, n)
        p = _pdf_matrix(pairs, x, n)
        w = mis_weights(p, counts, heuristic=heuristic, beta=beta)[k]
        return _divide(fx * w.reshape((n,) + (1,) * (fx.ndim - 1)), p[k], zero_pdf,
                       f" (strategy {k})")
    return g


def mis_estimate(f, strategies, *, n, heuristic: Literal["balance", "power"] = "balance",
                 beta: float = 2.0, sampler="random", rng=None, replicates=None,
                 zero_pdf: Literal["raise", "drop"] = "raise", batch: int = _BATCH) -> Estimate:
    """Multi-sample MIS: ``n_k`` samples from each strategy, weighted and summed.

    Parameters
    ----------
    f : callable
        Integrand ``f(x) -> (n,)`` or ``(n, ...)``.
    strategies : sequence of (sample, pdf)
        K strategies over the same domain and measure: warps
        ``sample(u) -> x`` with their densities ``pdf(x) -> (n,)``.
    n : int or sequence of int
        Samples per strategy ``n_k`` (an int gives every strategy the same).
    heuristic : {'balance', 'power'}
        Weighting (:func:`mis_weights`); ``beta`` is the power's exponent.
    sampler, rng, replicates, zero_pdf, batch
        As in :func:`estimate`; each strategy draws from its own stream.

    Returns
    -------
    Estimate
        ``n = sum n_k``. iid: ``stderr^2 = sum_k s_k^2 / n_k`` (the strategies'
        sample means are independent) and ``variance = n * stderr^2``
        (``inf``, i.e. unknown, if some ``n_k = 1``: one sample has no
        sample variance);
        replicates: each replicate runs the whole estimator with
        ``n_k // R`` samples per strategy.

    Notes
    -----
    The estimator ``F = sum_k (1/n_k) sum_j w_k(X_kj) f(X_kj) / p_k(X_kj)``
    is unbiased when the weights sum to 1 wherever ``f != 0`` [1]_ (eq. 9.2).
    With the balance heuristic ``w_k = n_k p_k / sum_l n_l p_l`` it is the
    lecture's 'Multiple Importance Sampling' slide,
    ``(1/N) sum_i sum_j f(x_ij) / sum_k c_k p_k(x_ij)`` with
    ``c_k = n_k / N``: every sample is divided by the mixture density.

    References
    ----------
    .. [1] E. Veach, L. J. Guibas, "Optimally Combining Sampling Techniques
       for Monte Carlo Rendering", SIGGRAPH 1995; E. Veach, PhD thesis,
       Stanford University, 1997, ch. 9.
    """
    if not callable(f):
        raise TypeError(f"f must be callable; got {type(f).__name__}")
    pairs = _strategies(strategies)
    k = len(pairs)
    counts = [n] * k if isinstance(n, numbers.Integral) and not isinstance(n, bool) else list(n)
    if len(counts) != k:
        raise ValueError(f"n must give one count per strategy ({k}); got {len(counts)}")
    counts = [check_count(c, f"n[{i}]") for i, c in enumerate(counts)]
    check_choice(zero_pdf, "zero_pdf", ("raise", "drop"))
    check_choice(heuristic, "heuristic", ("balance", "power"))
    batch = check_count(batch, "batch")
    fn, name = _resolve_sampler(sampler)
    r = _resolve_replicates(replicates, name)
    cvec = np.asarray(counts, dtype=np.float64)
    gs = [_mis_contribution(f, pairs, i, cvec, heuristic, beta, zero_pdf) for i in range(k)]
    streams = _children(rng, k)
    if r == 1:
        parts = [_iid(gs[i], fn, counts[i], np.random.default_rng(streams[i]), batch) for i in range(k)]
        mean = sum(np.asarray(p.mean) for p in parts)
        se2 = sum(np.asarray(p.variance) / p.n if p.n > 1 else np.inf for p in parts)
        total = sum(counts)
        return Estimate(mean, total * se2, total)
    per = [c // r for c in counts]
    if min(per) < 1:
        raise ValueError(f"every n_k must be >= replicates ({r}); got {counts}")
    reps = [_Replicator(fn, s.spawn(r)) for s in streams]
    sets = [rep.points(m) for rep, m in zip(reps, per)]
    means = [sum(np.asarray(_mean_of(gs[i], sets[i][j], batch).mean) for i in range(k)) for j in range(r)]
    return Estimate.from_replicates(np.stack(means), sum(per))


def one_sample_mis_contribution(f, strategies, *, probabilities=None,
                                heuristic: Literal["balance", "power"] = "balance", beta: float = 2.0,
                                zero_pdf: Literal["raise", "drop"] = "raise"):
    """The per-sample contribution of :func:`one_sample_mis`, ``u (n, 2) -> (n, ...)``.

    Strategy ``k`` is chosen with probability ``c_k`` from ``u[:, 0]``, which
    is then rescaled to [0, 1) and reused by the strategy's warp; the
    contribution is ``w_k(X) f(X) / (c_k p_k(X))``. Arguments as in
    :func:`one_sample_mis`.
    """
    if not callable(f):
        raise TypeError(f"f must be callable; got {type(f).__name__}")
    pairs = _strategies(strategies)
    k = len(pairs)
    check_choice(zero_pdf, "zero_pdf", ("raise", "drop"))
    check_choice(heuristic, "heuristic", ("balance", "power"))
    if heuristic == "power":
        check_positive(beta, "beta", allow_inf=True)
    if probabilities is None:
        c = np.full(k, 1.0 / k)
    else:
        c = as_array(probabilities, "probabilities", ndim=1)
        if c.shape != (k,) or not np.all(c > 0) or abs(c.sum() - 1.0) > 1e-12:
            raise ValueError(f"probabilities must be {k} positive numbers summing to 1; got {c.tolist()}")
    edges = np.concatenate([[0.0], np.cumsum(c)[:-1]])

    def g(u):
        m = u.shape[0]
        pick = np.clip(np.searchsorted(edges, u[:, 0], side="right") - 1, 0, k - 1)
        v = np.array(u, dtype=np.float64)
        v[:, 0] = np.clip((u[:, 0] - edges[pick]) / c[pick], 0.0, np.nextafter(1.0, 0.0))
        x = None
        for i in range(k):
            sel = pick == i
            if sel.any():
                xi = np.asarray(pairs[i][0](v[sel]), dtype=np.float64)
                if x is None:
                    x = np.empty((m,) + xi.shape[1:])
                x[sel] = xi
        if x is None:                       # m == 0
            x = np.asarray(pairs[0][0](v), dtype=np.float64)
        fx = _eval_f(f, x, m)
        p = _pdf_matrix(pairs, x, m)
        rows = np.arange(m)
        w = mis_weights(p, c, heuristic=heuristic, beta=beta)[pick, rows]
        return _divide(fx * w.reshape((m,) + (1,) * (fx.ndim - 1)), c[pick] * p[pick, rows], zero_pdf)
    return g


def one_sample_mis(f, strategies, *, n, probabilities=None,
                   heuristic: Literal["balance", "power"] = "balance", beta: float = 2.0,
                   sampler="random", rng=None, replicates=None,
                   zero_pdf: Literal["raise", "drop"] = "raise", atol=None, rtol=None,
                   level: float = 0.99, max_n: int = 1 << 28, batch: int = _BATCH) -> Estimate:
    """One-sample MIS: each sample picks one strategy at random, then is weighted.

    Strategy ``k`` is chosen with probability ``c_k`` from the first
    coordinate of the 2D point, which is then rescaled to [0, 1) and reused
    (so one 2D sampler, stratified or QMC, drives the choice and the warp).
    The contribution is ``w_k(X) f(X) / (c_k p_k(X))``.

    Parameters
    ----------
    f, strategies
        As in :func:`mis_estimate`.
    n : int
        Total samples.
    probabilities : array_like, shape (K,), optional
        Selection probabilities ``c_k`` (> 0, summing to 1); default uniform.
    heuristic, beta, sampler, rng, replicates, zero_pdf, atol, rtol, level, max_n, batch
        As in :func:`mis_estimate` and :func:`estimate`.

    Returns
    -------
    Estimate

    Notes
    -----
    Unbiased for weights that sum to 1 [1]_ (section 9.2.4). With the balance
    heuristic the contribution is ``f / sum_l c_l p_l``: sampling the
    mixture density, which Veach shows is the optimal one-sample weighting.

    References
    ----------
    .. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
       Simulation", PhD thesis, Stanford University, 1997, ch. 9.
    """
    g = one_sample_mis_contribution(f, strategies, probabilities=probabilities, heuristic=heuristic,
                                    beta=beta, zero_pdf=zero_pdf)
    return estimate_mean(g, n=n, sampler=sampler, rng=rng, replicates=replicates, atol=atol,
                         rtol=rtol, level=level, max_n=max_n, batch=batch)


_HEMISPHERE = {
    "uniform": (warps.square_to_uniform_hemisphere, warps.square_to_uniform_hemisphere_pdf),
    "cosine": (warps.square_to_cosine_hemisphere, warps.square_to_cosine_hemisphere_pdf),
}


def hemisphere_estimate(radiance, *, n, method: Literal["uniform", "cosine", "mis"] = "cosine",
                        sampler="random", rng=None, replicates=None, atol=None, rtol=None,
                        level: float = 0.99, max_n: int = 1 << 28) -> Estimate:
    """Estimate ``int_H L_i(w) cos(theta) dw`` over the hemisphere about +y.

    Parameters
    ----------
    radiance : callable
        ``L_i(w) -> (n,)`` or ``(n, 3)`` for local directions ``w`` (normal
        +y), finite and >= 0.
    n : int
        Samples.
    method : {'uniform', 'cosine', 'mis'}
        ``'uniform'``: ``p = 1 / (2 pi)``, contribution ``2 pi L_i cos``;
        ``'cosine'``: ``p = cos / pi``, contribution ``pi L_i`` ('more
        radiance per sample'); ``'mis'``: one-sample MIS of the two with the
        balance heuristic (each picked with probability 1/2).
    sampler, rng, replicates, atol, rtol, level, max_n
        As in :func:`estimate`.

    Returns
    -------
    Estimate

    Notes
    -----
    The lecture's slides 'Monte Carlo Uniform Sampling' and 'Monte Carlo
    Cosine Sampling'. Cosine sampling reaches the horizon (``p = 0``) only on
    the edge of the unit square; there ``L_i cos = 0`` so nothing is lost.
    """
    check_choice(method, "method", ("uniform", "cosine", "mis"))
    if not callable(radiance):
        raise TypeError(f"radiance must be callable; got {type(radiance).__name__}")

    def f(w):
        li = _eval_f(radiance, w, w.shape[0], "radiance")
        if not np.all(li >= 0):
            raise ValueError("radiance must be >= 0")
        cos = w[:, 1]
        return li * np.maximum(cos, 0.0).reshape((-1,) + (1,) * (li.ndim - 1))

    if method == "mis":
        g = one_sample_mis_contribution(f, [_HEMISPHERE["uniform"], _HEMISPHERE["cosine"]])
    else:
        sample, pdf = _HEMISPHERE[method]
        g = contribution(f, sample=sample, pdf=pdf)
    return estimate_mean(g, n=n, sampler=sampler, rng=rng, replicates=replicates, atol=atol,
                         rtol=rtol, level=level, max_n=max_n)


# --------------------------------------------------------------------------
# Replicates: bias, variance, MSE, efficiency, consistency
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class ReplicateStudy:
    """R independent runs of one estimator at one sample count.

    Attributes
    ----------
    values : ndarray, shape (R,)
        The R estimates.
    n : int
        Samples per run.
    exact : float or None
        The true value, if known (needed for bias and MSE).
    seconds : ndarray, shape (R,)
        Wall-clock time of each run.

    Notes
    -----
    With ``V = values``: ``bias = mean(V) - exact`` with standard error
    ``s_V / sqrt(R)`` and a Student-t interval ('Bias & Consistency':
    an estimator is unbiased if ``E[I - I_n] = 0``, even for one sample);
    ``variance = s_V^2`` (ddof 1) with the chi-square interval of a normal
    sample; ``mse = mean((V - exact)^2) = bias^2 + variance`` (up to
    ``(R-1)/R``); ``efficiency = 1 / (variance * time)``, time per run
    (Veach's efficiency, thesis section 2.4).
    """

    values: np.ndarray
    n: int
    exact: float | None
    seconds: np.ndarray

    @property
    def replicates(self) -> int:
        return int(self.values.size)

    @property
    def mean(self) -> float:
        return float(self.values.mean())

    @property
    def variance(self) -> float:
        return float(self.values.var(ddof=1))

    def _exact(self) -> float:
        if self.exact is None:
            raise ValueError("exact is None: bias and MSE need the true value")
        return float(self.exact)

    @property
    def bias(self) -> float:
        return self.mean - self._exact()

    @property
    def bias_stderr(self) -> float:
        return math.sqrt(self.variance / self.replicates)

    def bias_ci(self, level: float = 0.95) -> tuple[float, float]:
        """Student-t interval for the bias (R - 1 degrees of freedom)."""
        level = _open_level(level)
        h = stats.t.ppf(0.5 + level / 2, self.replicates - 1) * self.bias_stderr
        return float(self.bias - h), float(self.bias + h)

    def variance_ci(self, level: float = 0.95) -> tuple[float, float]:
        """Chi-square interval for the variance (exact for normal estimates)."""
        level = _open_level(level)
        dof = self.replicates - 1
        s = dof * self.variance
        return float(s / stats.chi2.ppf(0.5 + level / 2, dof)), float(s / stats.chi2.ppf(0.5 - level / 2, dof))

    @property
    def mse(self) -> float:
        return float(np.mean((self.values - self._exact()) ** 2))

    @property
    def rmse(self) -> float:
        return math.sqrt(self.mse)

    @property
    def time(self) -> float:
        """Mean seconds per run."""
        return float(self.seconds.mean())

    @property
    def efficiency(self) -> float:
        """``1 / (variance * time)``; ``inf`` for a zero-variance estimator."""
        d = self.variance * self.time
        return math.inf if d == 0 else 1.0 / d


def _open_level(level) -> float:
    level = check_probability(level, "level")
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1); got {level}")
    return level


def _scalar_run(estimator, n, gen):
    out = estimator(n, gen)
    value = out.mean if isinstance(out, Estimate) else out
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 0 or not np.isfinite(arr):
        raise ValueError(f"estimator must return a finite scalar (or an Estimate of one); got {value!r}")
    return float(arr)


def replicate_study(estimator: Callable, n, *, replicates: int = 32, exact=None,
                    rng=None) -> ReplicateStudy:
    """Run ``estimator(n, rng)`` R times on independent streams.

    Parameters
    ----------
    estimator : callable
        ``estimator(n, rng) -> float`` or an :class:`Estimate` with a scalar
        mean; ``rng`` is a ``numpy.random.Generator``.
    n : int
        Samples per run (passed through).
    replicates : int
        R >= 2.
    exact : float, optional
        True value, for bias and MSE.
    rng : None, int, SeedSequence or Generator
        Run ``i`` uses child ``i`` of ``SeedSequence(seed).spawn(R)``.

    Returns
    -------
    ReplicateStudy

    Examples
    --------
    >>> import numpy as np
    >>> one = lambda n, rng: 4.0 * float(np.floor(2 * rng.random(2)).sum() % 2 == 0)
    >>> s = replicate_study(one, 1, replicates=400, exact=2.0, rng=5)
    >>> s.bias_ci(0.999)[0] < 0 < s.bias_ci(0.999)[1]
    True
    """
    if not callable(estimator):
        raise TypeError(f"estimator must be callable; got {type(estimator).__name__}")
    r = check_count(replicates, "replicates")
    if r < 2:
        raise ValueError(f"replicates must be >= 2 to measure a variance; got {r}")
    n = check_count(n, "n")
    if exact is not None:
        exact = float(as_array(exact, "exact", ndim=0))
    values = np.empty(r)
    seconds = np.empty(r)
    for i, child in enumerate(_children(rng, r)):
        t0 = time.perf_counter()
        values[i] = _scalar_run(estimator, n, np.random.default_rng(child))
        seconds[i] = time.perf_counter() - t0
    return ReplicateStudy(values, n, exact, seconds)


@dataclass(frozen=True)
class ConvergenceStudy:
    """Replicate studies of one estimator at increasing sample counts.

    Attributes
    ----------
    ns : ndarray of int
        Sample counts.
    studies : tuple of ReplicateStudy
        One per count.
    """

    ns: np.ndarray
    studies: tuple

    def values(self, quantity: str) -> np.ndarray:
        """``'variance'``, ``'mse'``, ``'rmse'``, ``'bias'``, ``'abs_bias'``,
        ``'time'`` or ``'efficiency'`` at each ``n``."""
        check_choice(quantity, "quantity", ("variance", "mse", "rmse", "bias", "abs_bias", "time",
                                            "efficiency"))
        if quantity == "abs_bias":
            return np.array([abs(s.bias) for s in self.studies])
        return np.array([getattr(s, quantity) for s in self.studies], dtype=np.float64)

    def fit(self, quantity: Literal["variance", "mse", "rmse", "abs_bias"] = "rmse") -> LogLogFit:
        """Log-log slope of ``quantity`` against ``n`` with its standard error.

        ``'rmse'`` is the consistency slope: -1/2 for plain Monte Carlo,
        steeper for stratified and QMC points on smooth integrands, 0 for an
        estimator whose error does not fall (not consistent). For
        ``'variance'`` the fit is weighted by the known spread of a log
        sample variance, ``sd(log s^2) ~ sqrt(2 / (R - 1))`` (normal
        replicates), so its slope error does not rest on few residuals.
        """
        check_choice(quantity, "quantity", ("variance", "mse", "rmse", "abs_bias"))
        y = self.values(quantity)
        if quantity == "variance":
            r = np.array([s.replicates for s in self.studies])
            return loglog_fit(self.ns, y, sigma_log=np.sqrt(2.0 / (r - 1)))
        return loglog_fit(self.ns, y)


def convergence_study(estimator: Callable, ns: Sequence[int], *, replicates: int = 32, exact=None,
                      rng=None) -> ConvergenceStudy:
    """:func:`replicate_study` at each ``n`` in ``ns`` (independent streams per ``n``).

    Examples
    --------
    >>> import numpy as np
    >>> mc = lambda n, rng: float(np.mean(rng.random(n)))
    >>> c = convergence_study(mc, [64, 256, 1024, 4096], replicates=64, exact=0.5, rng=11)
    >>> fit = c.fit("variance")
    >>> abs(fit.slope + 1) < 5 * fit.slope_stderr
    True
    """
    counts = [check_count(v, "ns[i]") for v in ns]
    if len(counts) < 1:
        raise ValueError("ns must hold at least one sample count")
    children = _children(rng, len(counts))
    studies = tuple(replicate_study(estimator, m, replicates=replicates, exact=exact, rng=c)
                    for m, c in zip(counts, children))
    return ConvergenceStudy(np.asarray(counts), studies)
