"""Replicate and convergence studies: bias, variance, MSE, efficiency and the
log-log error slope of any estimator (layer 3, module 3 of :mod:`mcvar.estimators`).

Lecture slides 'Variance', 'Bias & Consistency', 'Consistent Or Unbiased?'.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable, Literal, Sequence

import numpy as np
from scipy import stats

from .._validation import as_array, check_choice, check_count, check_probability
from ..metrics import LogLogFit, loglog_fit
from .monte_carlo import Estimate, _children

# --------------------------------------------------------------------------
# Replicates: bias, variance, MSE, efficiency, consistency
# --------------------------------------------------------------------------

def replicate_moments(values, exact=None, exact_variance=0.0) -> tuple:
    """Variance, squared bias and MSE of R independent replicates of an estimate.

    The one implementation of replicate statistics in mcvar: used by
    :class:`ReplicateStudy` (scalar estimates) and by
    :func:`mcvar.experiments.sweep` (images, averaged over pixels).

    Parameters
    ----------
    values : array_like, shape (R, ...)
        R >= 2 independent estimates (each a scalar or an array, e.g. an image).
    exact : array_like, optional
        The true value, broadcast to ``values.shape[1:]``. None: only the
        variance is returned (bias and MSE need the truth).
    exact_variance : array_like
        Variance of ``exact`` itself per element (a rendered reference's own
        noise); 0 for an exact value.

    Returns
    -------
    variance, bias2, mse : float
        Averages over elements of ``s^2`` (the sample variance across
        replicates, ddof = 1), of ``b^2 - s^2 / R - v`` with
        ``b = mean_r X_r - exact`` and ``v = exact_variance``, and of their sum
        (computed as ``mean (X_r - exact)^2 - v``, so equal to
        ``variance + bias2`` up to rounding).
        ``bias2`` and ``mse`` are None when ``exact`` is None.

    Notes
    -----
    ``E[b^2] = beta^2 + Var(X) / R + v``, so ``bias2`` is unbiased for the
    squared bias ``beta^2`` (and can be slightly negative when it is 0);
    ``mse = (R - 1) / R s^2 + b^2 - v``, which for ``v = 0`` equals the plain
    ``mean_r (X_r - exact)^2`` ('Variance' and 'Bias & Consistency' slides).
    """
    x = np.asarray(values, dtype=np.float64)
    r = x.shape[0] if x.ndim else 0
    if r < 2:
        raise ValueError(f"values must hold >= 2 replicates along axis 0; got shape {x.shape}")
    x = x.reshape(r, -1)
    s2 = x.var(axis=0, ddof=1)
    variance = float(s2.mean())
    if exact is None:
        return variance, None, None
    ref = np.broadcast_to(np.asarray(exact, dtype=np.float64).reshape(-1), (x.shape[1],)) \
        if np.size(exact) in (1, x.shape[1]) else None
    if ref is None:
        raise ValueError(f"exact must be a scalar or hold one value per element of an estimate "
                         f"({x.shape[1]}); got shape {np.shape(exact)}")
    v = np.reshape(np.asarray(exact_variance, dtype=np.float64), -1)
    b = x.mean(axis=0) - ref
    bias2 = float(np.mean(b * b - s2 / r - v))
    mse = float(np.mean((x - ref) ** 2) - np.mean(v))  # = variance + bias2, without cancellation
    return variance, bias2, mse


def efficiency(mse, seconds) -> float:
    """Efficiency ``1 / (MSE x seconds)``, the one definition used in mcvar.

    Veach defines the efficiency of an *unbiased* estimator as
    ``1 / (variance x time)``, where time is the cost of one estimate;
    for a biased estimator the variance is replaced by the mean squared error
    ``MSE = variance + bias^2``, which equals the variance when the bias is
    0. mcvar always uses the MSE (from :func:`replicate_moments`), so biased
    and unbiased methods are compared on one scale; it therefore needs the
    true value (or a reference).

    Parameters
    ----------
    mse : float
        Mean squared error of one estimate (may be slightly negative when
        measured with a bias correction).
    seconds : float
        Mean wall time of one estimate, >= 0.

    Returns
    -------
    float
        ``1 / (mse * seconds)``; ``inf`` when ``mse * seconds <= 0`` (an
        estimator with no measurable error, or no measurable time).

    References
    ----------
    .. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
       Simulation", PhD thesis, Stanford University, 1997, sec. 2.4.3.
    """
    mse = float(mse)
    seconds = float(seconds)
    if not np.isfinite(mse):
        raise ValueError(f"mse must be finite; got {mse}")
    if not (np.isfinite(seconds) and seconds >= 0):
        raise ValueError(f"seconds must be finite and >= 0; got {seconds}")
    d = mse * seconds
    return math.inf if d <= 0 else 1.0 / d


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
    ``(R-1)/R``); ``efficiency = 1 / (mse * time)``, time per run
    (:func:`efficiency`: Veach's efficiency, thesis section 2.4.3, with the
    MSE in place of the variance so that biased estimators are measured on
    the same scale; it needs ``exact``). Variance, bias and MSE come from
    :func:`replicate_moments`.
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
        return replicate_moments(self.values)[0]

    def _exact(self) -> float:
        if self.exact is None:
            raise ValueError("exact is None: bias, MSE and efficiency need the true value")
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
        return replicate_moments(self.values, self._exact())[2]

    @property
    def rmse(self) -> float:
        return math.sqrt(self.mse)

    @property
    def time(self) -> float:
        """Mean seconds per run."""
        return float(self.seconds.mean())

    @property
    def efficiency(self) -> float:
        """``1 / (mse * time)`` (:func:`efficiency`); ``inf`` for an exact
        estimator. Needs ``exact``."""
        return efficiency(self.mse, self.time)


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
