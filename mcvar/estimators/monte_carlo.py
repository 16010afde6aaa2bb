"""The Monte Carlo estimator with its error: ``Estimate``, ``estimate``,
``estimate_mean``, ``contribution`` (layer 3, module 1 of :mod:`mcvar.estimators`).

The lecture's 'The Monte Carlo Estimator' slide, ``(1/N) sum_j f(X_j) / p(X_j)``,
over any 2D sampler, with iid or randomized-replicate error bars and a
to-tolerance mode.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy import stats

from .._validation import (as_array, as_rng, check_choice, check_count, check_positive, check_probability,
                           settings_with)
from ..samplers import SAMPLERS, digital_shift, get_sampler

_METHODS = ("iid", "replicates")
_BATCH = 1 << 20          # rows evaluated at once: bounds memory, not results


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
    # a named iid sampler needs no replicates; a callable's points are not known to be iid
    iid = name is not None and SAMPLERS[name].iid
    if replicates is None:
        return 1 if iid else 16
    r = check_count(replicates, "replicates")
    if r == 1 and name is not None and not iid:
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


@dataclass(frozen=True)
class EstimateSettings:
    """How an estimator draws and stops: the keywords of :func:`estimate_mean` (see there),
    shared by :func:`estimate` and the MIS estimators. ``n`` has no default."""

    n: int | None = None
    sampler: object = "random"
    rng: object = None
    replicates: int | None = None
    atol: float | None = None
    rtol: float | None = None
    level: float = 0.99
    max_n: int = 1 << 28
    batch: int = _BATCH


def estimate_settings(settings, options: dict, where: str) -> EstimateSettings:
    """``settings`` with the keyword ``options`` (its fields) applied; ``n`` must be given."""
    s = settings_with(EstimateSettings, settings, options, where)
    if s.n is None:
        raise TypeError(f"{where}() needs n, the number of samples (keyword n= or EstimateSettings.n)")
    return s


def estimate_mean(g, settings: EstimateSettings | None = None, **options) -> Estimate:
    """Estimate ``E[g(U)]``, ``U`` uniform on the unit square, from any 2D sampler.

    The engine under :func:`estimate`: ``g`` maps unit-square points
    ``(n, 2)`` to per-sample contributions ``(n,)`` or ``(n, ...)`` (for a
    Monte Carlo integral, ``f(x) / p(x)`` with ``x`` the warped point), e.g.
    a method of :data:`mcvar.examples.PROBLEMS`.

    Parameters
    ----------
    g : callable
        ``g(u) -> contributions``; must return finite values.
    settings : EstimateSettings, optional
        The options below as one record; the keywords ``n``, ``sampler``,
        ``rng``, ``replicates``, ``atol``, ``rtol``, ``level``, ``max_n`` and
        ``batch`` replace its fields (any other keyword is a ``TypeError``).

    Other Parameters
    ----------------
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
    opts = estimate_settings(settings, options, "estimate_mean")
    rng, atol, rtol = opts.rng, opts.atol, opts.rtol
    n = check_count(opts.n, "n")
    max_n = check_count(opts.max_n, "max_n")
    batch = check_count(opts.batch, "batch")
    level = check_probability(opts.level, "level")
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1); got {level}")
    fn, name = _resolve_sampler(opts.sampler)
    r = _resolve_replicates(opts.replicates, name)
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


def estimate(f, *, sample=None, pdf=None, zero_pdf: Literal["raise", "drop"] = "raise",
             settings: EstimateSettings | None = None, **options) -> Estimate:
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
    zero_pdf : {'raise', 'drop'}, optional
        What a sampled point with ``pdf = 0`` and ``f != 0`` means; see Notes.

    Other Parameters
    ----------------
    settings, n, sampler, rng, replicates, atol, rtol, level, max_n, batch
        As in :func:`estimate_mean` (:class:`EstimateSettings` or its fields).

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
    settings = estimate_settings(settings, options, "estimate")
    return estimate_mean(contribution(f, sample=sample, pdf=pdf, zero_pdf=zero_pdf), settings)
