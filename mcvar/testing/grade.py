"""Graders for exercises: one call, a clear PASS or FAIL with the reason (layer 3).

A course's notebook (or its own autograder) hands a student's function to one
of these graders; the grader runs the statistical checks of
:mod:`mcvar.testing` on it and returns a :class:`GradeResult`, printing one
line such as::

    PASS  disk warp: chi-square p = 0.41 over 200000 samples; u = 0 and 1 handled

Nothing new is measured here: every grader is a thin, documented composition
of the existing checks (:func:`~mcvar.testing.chi2_test`,
:func:`~mcvar.testing.bsdf_chi2_test`, :func:`~mcvar.testing.check_extremes`,
:func:`~mcvar.testing.check_weight_consistency`,
:func:`~mcvar.testing.check_unbiased`), with fixed seeds so that a grade is
reproducible.

==============================  ==========================================================
grader                          question
==============================  ==========================================================
:func:`grade_warp`              does ``sample`` draw from the density ``pdf`` claims (and
                                survive ``u`` = 0 and 1)?
:func:`grade_sampler`           is a point set in the unit square, stratified as claimed
                                (or a (0, m, 2)-net), and uniform over randomizations?
:func:`grade_bsdf`              are a BSDF's weights ``f cos / pdf``, and does ``sample``
                                draw from ``pdf``, at several ``wo``?
:func:`grade_estimator`         is an estimator unbiased (and of the claimed variance)?
:func:`grade_consistent`        does an estimator's error fall as ``n`` grows?
:func:`grade_pixel_sampler`     does an environment-map sampler pick pixels with
                                probability proportional to ``L sin(theta)`` (the
                                lecture's 'Creating A PDF')?
:func:`grade_values`            does a function return known closed-form values?
:func:`grade_dielectric`        does a glass pick mirror / Snell directions, weight 1,
                                reflecting in the proportion of the exact Fresnel term?
:func:`grade_chain`             does a Markov chain step leave its target invariant?
:func:`grade_coverage`          do a standard error's intervals cover at their level?
:func:`exercise`                the course notebooks' exercises by name
                                (:mod:`mcvar.testing.exercises`)
==============================  ==========================================================

A student's code that raises :class:`NotImplementedError` (the stub left
as is) is graded **NOT ATTEMPTED**; any other exception it raises is a
**FAIL** naming the exception. Bad arguments given to a grader itself raise
``ValueError`` / ``TypeError`` as everywhere in mcvar.
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import stats

from .._validation import (as_array, as_rng, as_unit_directions, check_bool, check_choice, check_count,
                           check_positive)
from ..discrepancy import is_net
from ..geometry import spherical_to_direction
from ..optics import fresnel_dielectric, refract
from ._domains import DOMAINS
from .checks import CheckResult, check_extremes, check_unbiased, check_weight_consistency
from ._chi2 import bsdf_chi2_test, chi2_test, sidak_significance

__all__ = [
    "GradeResult",
    "grade_warp",
    "grade_sampler",
    "grade_bsdf",
    "grade_estimator",
    "grade_consistent",
    "grade_pixel_sampler",
    "grade_values",
    "grade_dielectric",
    "grade_chain",
    "grade_coverage",
    "NOT_ATTEMPTED",
]

#: Status of a stub that still raises NotImplementedError.
NOT_ATTEMPTED = "NOT ATTEMPTED"


@dataclass(frozen=True)
class GradeResult:
    """The outcome of one grader call.

    Attributes
    ----------
    name : str
        What was graded (e.g. ``'disk warp'``).
    passed : bool
        True only for status ``'PASS'``.
    status : {'PASS', 'FAIL', 'NOT ATTEMPTED'}
    reason : str
        One sentence: the evidence for a pass, the first failed check for a
        fail.
    checks : tuple
        The :class:`~mcvar.testing.CheckResult` / :class:`~mcvar.testing.Chi2Result`
        objects the verdict rests on (empty when the student's code raised).
    seconds : float
        Wall time of the grading.
    """

    name: str
    passed: bool
    status: str
    reason: str
    checks: tuple = ()
    seconds: float = 0.0

    def __repr__(self) -> str:
        return f"{self.status}  {self.name}: {self.reason}"

    __str__ = __repr__


# --------------------------------------------------------------------------
# running student code

class _StudentError(Exception):
    """An exception raised inside the student's code (kept in ``.exc``)."""

    def __init__(self, exc: BaseException):
        super().__init__(str(exc))
        self.exc = exc


def _guard(fn: Callable) -> Callable:
    """Wrap a student's callable so that its exceptions are told apart from the checks'."""
    if not callable(fn):
        raise TypeError(f"expected a callable (your function); got {type(fn).__name__}")

    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except _StudentError:
            raise
        except Exception as exc:  # noqa: BLE001 - every student exception is reported
            raise _StudentError(exc) from exc

    return wrapped


class _GuardedBSDF:
    """A student's BSDF object with guarded ``eval``, ``pdf`` and ``sample``."""

    def __init__(self, bsdf):
        for meth in ("eval", "pdf", "sample"):
            if not callable(getattr(bsdf, meth, None)):
                raise TypeError(f"bsdf must have a callable {meth}(...); got {type(bsdf).__name__}")
        self._bsdf = bsdf
        self.eval = _guard(bsdf.eval)
        self.pdf = _guard(bsdf.pdf)
        self.sample = _guard(bsdf.sample)

    def __getattr__(self, key):  # is_delta, has_delta, transmissive ...
        return getattr(self._bsdf, key)


def _run(name: str, body: Callable, verbose: bool) -> GradeResult:
    """Run ``body() -> (passed, reason, checks)`` and turn the outcome into a GradeResult."""
    start = time.perf_counter()
    checks: tuple = ()
    try:
        passed, reason, checks = body()
        status = "PASS" if passed else "FAIL"
    except _StudentError as err:
        passed = False
        if isinstance(err.exc, NotImplementedError):
            status = NOT_ATTEMPTED
            reason = "the stub still raises NotImplementedError: replace it with your solution and run again"
        else:
            status = "FAIL"
            reason = f"your code raised {type(err.exc).__name__}: {err.exc}"
    except (ValueError, TypeError) as exc:  # a check could not use what the student returned
        passed, status = False, "FAIL"
        reason = f"the checks could not use your result: {exc}"
    result = GradeResult(name, bool(passed), status, reason, tuple(checks),
                         time.perf_counter() - start)
    if verbose:
        print(result)
    return result


def _teacher_args(name, verbose, significance=None, rng=None):
    """The grader's own arguments, checked before any student code runs: a bad
    one is the teacher's error (a ``ValueError`` or ``TypeError`` naming it),
    never a FAIL of the student's code. Returns ``(significance, rng)``."""
    if not isinstance(name, str):
        raise TypeError(f"name must be a string; got {type(name).__name__}")
    check_bool(verbose, "verbose")
    if significance is not None:
        significance = check_positive(significance, "significance")
        if not significance < 1.0:
            raise ValueError(f"significance must lie in (0, 1) (a test's false-alarm rate); got {significance}")
    return significance, as_rng(rng)


def _exact_value(exact) -> np.ndarray:
    """``exact`` of an estimator grader: finite real numbers (a ValueError naming it)."""
    return as_array(exact, "exact")


def _first_failure(checks) -> str | None:
    for c in checks:
        if not c.passed:
            return c.message
    return None


# --------------------------------------------------------------------------
# graders

def grade_warp(sample: Callable, pdf: Callable, domain: str, *, n: int = 200_000, rng=None,
               bins=None, significance: float = 1e-3, name: str = "warp",
               verbose: bool = True) -> GradeResult:
    """Grade a warp and its pdf: boundary values, then a chi-square test.

    Parameters
    ----------
    sample, pdf : callable
        ``sample(u)`` maps ``(m, 2)`` uniform points to points of ``domain``;
        ``pdf(x)`` is their density (as in :func:`mcvar.testing.chi2_test`).
    domain : {'square', 'disk', 'hemisphere', 'sphere'}
    n : int
        Samples of the chi-square test.
    rng : None, int, SeedSequence or Generator
        Fix it for a reproducible grade.
    bins, significance
        As in :func:`mcvar.testing.chi2_test` (which also checks that the pdf
        integrates to 1).
    name : str
        Shown in the result.
    verbose : bool
        Print the result line.

    Returns
    -------
    GradeResult
        PASS when :func:`~mcvar.testing.check_extremes` and
        :func:`~mcvar.testing.chi2_test` both pass.
    """
    significance, rng = _teacher_args(name, verbose, significance, rng)
    domain = check_choice(domain, "domain", DOMAINS)
    n = check_count(n, "n")
    s, p = _guard(sample), _guard(pdf)

    def body():
        ext = check_extremes(s, p, domain)
        if not ext.passed:
            return False, f"at u = 0 or 1: {ext.message}", (ext,)
        chi = chi2_test(s, p, domain, n=n, rng=rng, bins=bins, significance=significance)
        if not chi.passed:
            return False, chi.message, (ext, chi)
        return True, (f"chi-square p = {chi.pvalue:.3g} over {n} samples (pdf integrates to "
                      f"{chi.pdf_integral:.6f}); u = 0 and 1 handled"), (ext, chi)

    return _run(name, body, verbose)


def grade_sampler(sampler: Callable, n: int, *, strata=None, net: int | None = None,
                  randomized: bool = True, replicates: int = 200, rng=None,
                  significance: float = 1e-3, name: str = "sampler",
                  verbose: bool = True) -> GradeResult:
    """Grade a 2D point-set sampler ``sampler(n, rng=...) -> (n, 2)`` in [0, 1)^2.

    Parameters
    ----------
    sampler : callable
        Called as ``sampler(n, rng=generator)``.
    n : int
        Points per set.
    strata : (int, int), optional
        Claimed stratification: every cell of a ``strata[0] x strata[1]`` grid
        holds exactly ``n / (strata[0] strata[1])`` points (jittered: ``(k, k)``
        with ``n = k^2``; n-rooks: ``(n, 1)`` and ``(1, n)`` both).
    net : int, optional
        Claimed (0, m, 2)-net in base 2 with ``n = 2^m``
        (:func:`mcvar.discrepancy.is_net`).
    randomized : bool
        True: the union of ``replicates`` independent sets must be uniform
        (chi-square against the constant density; stratified sets are
        *under*-dispersed, which the upper-tail test accepts). False: a
        deterministic pattern, checked once, without the uniformity test.
    replicates : int
    rng : seed
    significance : float
        Of the uniformity test.
    name, verbose
        As in :func:`grade_warp`.

    Returns
    -------
    GradeResult
    """
    significance, rng = _teacher_args(name, verbose, significance, rng)
    check_bool(randomized, "randomized")
    n = check_count(n, "n")
    replicates = check_count(replicates, "replicates") if randomized else 1
    if strata is not None:
        strata = tuple(check_count(k, "strata[i]") for k in strata)
        if len(strata) != 2 or n % (strata[0] * strata[1]):
            raise ValueError(f"strata must be two counts whose product divides n = {n}; got {strata}")
    if net is not None and 2 ** check_count(net, "net", allow_zero=True) != n:
        raise ValueError(f"net = m requires n = 2**m; got n = {n}, m = {net}")
    s = _guard(sampler)
    streams = as_rng(rng).spawn(replicates)

    def body():
        sets = []
        for g in streams:
            pts = np.asarray(s(n, rng=g), dtype=np.float64)
            if pts.shape != (n, 2):
                return False, f"sampler({n}) returned shape {pts.shape}, expected ({n}, 2)", ()
            if not np.all(np.isfinite(pts)) or np.any(pts < 0.0) or np.any(pts >= 1.0):
                return False, "points must be finite and lie in [0, 1)^2", ()
            sets.append(pts)
        checks = []
        if strata is not None:
            kx, ky = strata
            per = n // (kx * ky)
            for pts in sets:
                cell = np.floor(pts[:, 0] * kx).astype(int) * ky + np.floor(pts[:, 1] * ky).astype(int)
                counts = np.bincount(cell, minlength=kx * ky)
                if np.any(counts != per):
                    bad = int(np.sum(counts != per))
                    msg = (f"not stratified on the {kx} x {ky} grid: {bad} cells do not hold exactly "
                           f"{per} point(s) (counts from {counts.min()} to {counts.max()})")
                    return False, msg, (CheckResult("strata", False, float(bad), 0.0, msg, n),)
            checks.append(CheckResult("strata", True, 0.0, 0.0,
                                      f"{per} point(s) in every cell of the {kx} x {ky} grid", n))
        if net is not None:
            bad = sum(not is_net(pts, net) for pts in sets)
            msg = f"{len(sets) - bad} of {len(sets)} sets are (0, {net}, 2)-nets"
            checks.append(CheckResult("net", bad == 0, float(bad), 0.0, msg, n))
            if bad:
                return False, msg + ": some elementary interval of area 2^-m does not hold exactly one point", tuple(checks)
        if randomized:
            allp = np.concatenate(sets)
            chi = chi2_test(lambda u: allp[:u.shape[0]], lambda x: np.ones(x.shape[0]), "square",
                            n=allp.shape[0], batch_size=allp.shape[0], rng=0, significance=significance)
            checks.append(chi)
            if not chi.passed:
                return False, (f"the union of {replicates} sets is not uniform on the square: "
                               f"{chi.message}"), tuple(checks)
        parts = [c.message for c in checks if isinstance(c, CheckResult)]
        if randomized:
            parts.append(f"union of {replicates} sets uniform (chi-square p = {checks[-1].pvalue:.3g})")
        return True, "; ".join(parts) or "points in [0, 1)^2", tuple(checks)

    return _run(name, body, verbose)


def _default_wo():
    theta = np.radians([10.0, 45.0, 80.0])
    return spherical_to_direction(theta, np.array([0.3, 1.7, 4.0]))


def grade_bsdf(bsdf, *, wo=None, n: int = 100_000, rng=None, significance: float = 1e-3,
               name: str = "BSDF", verbose: bool = True) -> GradeResult:
    """Grade a BSDF object (``eval``, ``pdf``, ``sample``: :class:`mcvar.testing.BSDFLike`).

    At each outgoing direction, :func:`~mcvar.testing.check_weight_consistency`
    (``weight == eval |cos| / pdf`` and ``sample``'s pdf == ``pdf()``) and
    :func:`~mcvar.testing.bsdf_chi2_test` (``sample`` draws from ``pdf``, which
    integrates to the fraction of valid samples), Sidak-corrected over the
    directions.

    Parameters
    ----------
    bsdf : object
    wo : array_like, shape (k, 3), optional
        Unit outgoing directions (local space, normal +y); default three, at
        10, 45 and 80 degrees from the normal.
    n : int
        Samples per chi-square test.
    rng, significance, name, verbose
        As in :func:`grade_warp`.

    Returns
    -------
    GradeResult
    """
    significance, rng = _teacher_args(name, verbose, significance, rng)
    wos = _default_wo() if wo is None else as_unit_directions(wo, "wo").reshape(-1, 3)
    if wos.shape[0] == 0:
        raise ValueError("wo must hold at least one direction; got none")
    n = check_count(n, "n")
    b = _GuardedBSDF(bsdf)
    streams = as_rng(rng).spawn(2 * wos.shape[0])

    def body():
        checks = []
        for k, w in enumerate(wos):
            deg = np.degrees(np.arccos(np.clip(w[1], -1, 1)))
            wc = check_weight_consistency(b, w, n=10_000, rng=streams[2 * k])
            checks.append(wc)
            if not wc.passed:
                return False, f"at wo {deg:.0f} deg from the normal: {wc.message}", tuple(checks)
            chi = bsdf_chi2_test(b, w, n=n, rng=streams[2 * k + 1], significance=significance,
                                 test_count=wos.shape[0])
            checks.append(chi)
            if not chi.passed:
                return False, f"at wo {deg:.0f} deg from the normal: {chi.message}", tuple(checks)
        ps = ", ".join(f"{c.pvalue:.2g}" for c in checks[1::2])
        return True, (f"weights = f cos / pdf and sample() matches pdf() at {wos.shape[0]} directions "
                      f"(chi-square p = {ps})"), tuple(checks)

    return _run(name, body, verbose)


def _at_least_two(replicates):
    replicates = check_count(replicates, "replicates")
    if replicates < 2:
        raise ValueError(f"replicates must be >= 2 (a standard error needs two); got {replicates}")
    return replicates


def _replicate(est, n, streams):
    vals = [np.asarray(est(n, rng=g), dtype=np.float64) for g in streams]
    shapes = {v.shape for v in vals}
    if len(shapes) != 1:
        raise ValueError(f"the estimator returned values of different shapes {sorted(shapes)}")
    v = np.stack(vals)
    if not np.all(np.isfinite(v)):
        raise ValueError(f"the estimator returned NaN or Inf in {int(np.sum(~np.isfinite(v)))} replicates")
    return v


def grade_estimator(estimator: Callable, exact, *, n: int, replicates: int = 64, variance=None,
                    rng=None, significance: float = 1e-3, name: str = "estimator",
                    verbose: bool = True) -> GradeResult:
    """Grade an estimator: unbiased, and (optionally) of the claimed variance.

    Parameters
    ----------
    estimator : callable
        ``estimator(n, rng=generator)`` returns one estimate (a number or an
        array, e.g. RGB) from ``n`` samples.
    exact : float or array_like
        The value it must be unbiased for.
    n : int
        Samples per estimate (unbiased means: at this ``n`` too, even 1).
    replicates : int
        Independent estimates (streams spawned from ``rng``); the test uses
        their mean and standard error.
    variance : float, optional
        Claimed variance of *one sample's* contribution, so that the
        estimate's variance is ``variance / n``. Tested with the chi-square
        interval of the replicates' sample variance (valid when the estimates
        are near normal, i.e. ``n`` not tiny). ``0`` claims a zero-variance
        estimator: every replicate must then be equal to rounding.
    rng, significance, name, verbose
        As in :func:`grade_warp`.

    Returns
    -------
    GradeResult

    Notes
    -----
    The bias test is :func:`mcvar.testing.check_unbiased` with the
    half-width ``t_{R-1}`` quantile (the standard error comes from ``R``
    replicates), at ``significance`` split Sidak-wise between the bias and
    the variance tests.
    """
    significance, rng = _teacher_args(name, verbose, significance, rng)
    exact = _exact_value(exact)
    n = check_count(n, "n")
    replicates = _at_least_two(replicates)
    if variance is not None:
        variance = float(as_array(variance, "variance", nonnegative=True))
    est = _guard(estimator)
    streams = as_rng(rng).spawn(replicates)
    tests = 2 if variance is not None else 1
    sig = sidak_significance(significance, tests)

    def body():
        v = _replicate(est, n, streams)
        mean = v.mean(axis=0)
        se = v.std(axis=0, ddof=1) / np.sqrt(replicates)
        comps = max(1, mean.size)
        z = float(stats.t.isf(sidak_significance(sig, comps) / 2.0, replicates - 1))
        ub = check_unbiased(mean, exact, stderr=se, z=z)
        checks = [ub]
        fmt = lambda a: np.array2string(np.asarray(a), precision=5) if np.ndim(a) else f"{float(a):.6g}"
        if not ub.passed:
            return False, (f"biased: mean of {replicates} estimates {fmt(mean)} +- {fmt(se)} vs exact "
                           f"{fmt(exact)} ({ub.value:.1f} standard errors)"), tuple(checks)
        reason = (f"unbiased: mean of {replicates} estimates {fmt(mean)} +- {fmt(se)}, exact {fmt(exact)} "
                  f"({ub.value:.2f} standard errors)")
        if variance is not None:
            s2 = v.reshape(replicates, -1).var(axis=0, ddof=1) * n     # per-sample variance, each component
            if variance == 0.0:
                spread = float(np.max(np.ptp(v.reshape(replicates, -1), axis=0)))
                ok = spread <= 64 * np.finfo(float).eps * max(1.0, float(np.max(np.abs(v))))
                msg = f"claimed zero variance; the estimates spread over {spread:.3g}"
                checks.append(CheckResult("variance", bool(ok), spread, 0.0, msg, replicates))
                if not ok:
                    return False, msg, tuple(checks)
                return True, reason + "; zero variance: every estimate equal", tuple(checks)
            dof = replicates - 1
            a = sidak_significance(sig, s2.size)
            lo = variance * stats.chi2.ppf(a / 2, dof) / dof
            hi = variance * stats.chi2.isf(a / 2, dof) / dof
            ok = bool(np.all((s2 >= lo) & (s2 <= hi)))
            msg = (f"n x Var = {fmt(s2 if s2.size > 1 else s2[0])} vs claimed {variance:.6g} "
                   f"(accepted [{lo:.4g}, {hi:.4g}])")
            checks.append(CheckResult("variance", ok, float(np.max(s2)), variance, msg, replicates))
            if not ok:
                return False, "variance: " + msg, tuple(checks)
            reason += "; " + msg
        return True, reason, tuple(checks)

    return _run(name, body, verbose)


def grade_consistent(estimator: Callable, exact, ns, *, replicates: int = 32, rng=None,
                     significance: float = 1e-3, name: str = "consistency",
                     verbose: bool = True) -> GradeResult:
    """Grade consistency: does the error fall as the sample count grows?

    Parameters
    ----------
    estimator : callable
        ``estimator(n, rng=generator)``, as in :func:`grade_estimator`.
    exact : float or array_like
    ns : sequence of int
        Increasing sample counts (at least two; span a factor of 100 or more).
    replicates : int
        Estimates per ``n``.
    rng, significance, name, verbose
        As in :func:`grade_warp`.

    Returns
    -------
    GradeResult
        PASS when the squared errors at the largest ``n`` are smaller than
        those at the smallest (one-sided Mann-Whitney U test at
        ``significance``; it handles deterministic estimators, whose
        replicates are all equal), or when both are exactly 0.

    Notes
    -----
    A consistent estimator's error tends to 0 in probability; over a finite
    range of ``n`` the evidence is that it *falls*. A biased-but-consistent
    estimator (the lecture's fixed grid) passes; an unbiased but inconsistent
    one (a single sample, whatever ``n``) fails.
    """
    significance, rng = _teacher_args(name, verbose, significance, rng)
    exact = _exact_value(exact)
    if isinstance(ns, (str, bytes)) or not hasattr(ns, "__iter__"):
        raise TypeError(f"ns must be a sequence of increasing counts; got {type(ns).__name__}")
    ns = [check_count(v, f"ns[{i}]") for i, v in enumerate(ns)]
    if len(ns) < 2 or any(b <= a for a, b in zip(ns, ns[1:])):
        raise ValueError(f"ns must be at least two increasing counts; got {ns}")
    replicates = _at_least_two(replicates)
    est = _guard(estimator)
    streams = as_rng(rng).spawn(len(ns))
    ex = np.asarray(exact, dtype=np.float64)

    def body():
        sq = []
        for n, g in zip(ns, streams):
            v = _replicate(est, n, g.spawn(replicates))
            sq.append(np.sum((v - ex).reshape(replicates, -1) ** 2, axis=1))
        rmse = [float(np.sqrt(s.mean())) for s in sq]
        table = ", ".join(f"n={n}: {r:.3g}" for n, r in zip(ns, rmse))
        first, last = sq[0], sq[-1]
        if np.all(first == 0) and np.all(last == 0):
            return True, f"exact at every n (RMSE {table})", ()
        p = float(stats.mannwhitneyu(last, first, alternative="less").pvalue)
        ok = p < significance
        chk = CheckResult("consistent", ok, p, significance,
                          f"squared errors at n={ns[-1]} below those at n={ns[0]}: p = {p:.3g}", replicates)
        if not ok:
            return False, (f"the error does not fall with n (RMSE {table}; Mann-Whitney p = {p:.3g}): "
                           "does your estimator use all n samples?"), (chk,)
        return True, f"the error falls with n (RMSE {table}; Mann-Whitney p = {p:.2g})", (chk,)

    return _run(name, body, verbose)


def _lat_long_probabilities(image):
    img = as_array(image, "image", nonnegative=True)
    if img.ndim == 3 and img.shape[-1] == 3:
        img = img @ np.array([0.2126, 0.7152, 0.0722])
    if img.ndim != 2:
        raise ValueError(f"image must have shape (H, W) or (H, W, 3); got {img.shape}")
    h = img.shape[0]
    theta = (np.arange(h) + 0.5) * np.pi / h
    w = img * np.sin(theta)[:, None]
    total = w.sum()
    if not total > 0:
        raise ValueError("image must have some positive luminance")
    return w / total


def grade_pixel_sampler(sample_pixels: Callable, image, *, n: int = 200_000, rng=None,
                        significance: float = 1e-3, name: str = "environment-map sampler",
                        verbose: bool = True) -> GradeResult:
    """Grade an environment-map pixel sampler against the lecture's pdf.

    Parameters
    ----------
    sample_pixels : callable
        ``sample_pixels(image, r)`` maps uniform numbers ``r``, shape ``(m,)``
        in [0, 1), to flat pixel indices ``i W + j`` (shape ``(m,)``), each
        pixel chosen with probability proportional to ``L sin(theta_i)``
        (luminance times the sine of the row centre's polar angle, the
        lecture's 'Creating A PDF' slide) by inverting a CDF.
    image : array_like, shape (H, W) or (H, W, 3)
        A lat-long map; RGB is reduced to Rec. 709 luminance.
    n, rng, significance, name, verbose
        As in :func:`grade_warp`.

    Returns
    -------
    GradeResult
        PASS when ``r = 0`` and ``r -> 1`` give valid indices and a
        chi-square test (:func:`mcvar.testing.chi2_test`, one cell per pixel)
        accepts the pixel counts.
    """
    significance, rng = _teacher_args(name, verbose, significance, rng)
    prob = _lat_long_probabilities(image)
    h, w = prob.shape
    img = np.array(image, dtype=np.float64)
    sp = _guard(sample_pixels)
    n = check_count(n, "n")

    def indices(r):
        idx = np.asarray(sp(img, r))
        if idx.shape != r.shape:
            raise ValueError(f"sample_pixels(image, r) must return shape {r.shape}; got {idx.shape}")
        if not np.issubdtype(idx.dtype, np.integer):
            raise ValueError(f"pixel indices must be integers; got dtype {idx.dtype}")
        return idx

    def body():
        edge = indices(np.array([0.0, 0.5, np.nextafter(1.0, 0.0)]))
        if np.any(edge < 0) or np.any(edge >= h * w):
            msg = f"r = 0, 0.5, 1 - 2^-53 gave indices {edge.tolist()}, outside [0, {h * w})"
            return False, msg, (CheckResult("extremes", False, float("inf"), 0.0, msg, 3),)

        def sample(u):
            idx = indices(u[:, 0])
            if np.any(idx < 0) or np.any(idx >= h * w):
                return np.full((u.shape[0], 2), np.nan)  # chi2_test reports non-finite samples
            i, j = np.divmod(idx, w)
            return np.stack([(j + u[:, 1]) / w, (i + 0.5) / h], axis=1)

        def pdf(x):
            j = np.clip((x[:, 0] * w).astype(int), 0, w - 1)
            i = np.clip((x[:, 1] * h).astype(int), 0, h - 1)
            return prob[i, j] * h * w

        chi = chi2_test(sample, pdf, "square", n=n, rng=rng, bins=(w, h), significance=significance)
        if not chi.passed:
            return False, ("pixel counts do not follow P ~ L sin(theta): " + chi.message
                           + " (pixel indices are i W + j, row i from the top)"), (chi,)
        return True, (f"pixels chosen with probability L sin(theta) / sum: chi-square p = {chi.pvalue:.3g} "
                      f"over {n} samples, {h} x {w} pixels; r = 0 and r -> 1 stay in range"), (chi,)

    return _run(name, body, verbose)


def grade_values(function: Callable, inputs, expected, *, rtol: float = 1e-6, atol: float = 1e-12,
                 name: str = "function", verbose: bool = True) -> GradeResult:
    """Grade a function against known values.

    Parameters
    ----------
    function : callable
        Called once as ``function(*inputs)`` (vectorised arguments).
    inputs : tuple
        Positional arguments (arrays broadcast as the function does).
    expected : array_like
        Closed-form values the result must match within ``atol + rtol |expected|``.
    rtol, atol : float
    name, verbose
        As in :func:`grade_warp`.

    Returns
    -------
    GradeResult
    """
    _teacher_args(name, verbose)
    rtol = check_positive(rtol, "rtol", allow_zero=True)
    atol = check_positive(atol, "atol", allow_zero=True)
    exp = as_array(expected, "expected")
    fn = _guard(function)
    inputs = tuple(inputs)

    def body():
        got = np.asarray(fn(*inputs), dtype=np.float64)
        if got.shape != exp.shape:
            return False, f"returned shape {got.shape}, expected {exp.shape}", ()
        err = np.abs(got - exp)
        bad = ~(err <= atol + rtol * np.abs(exp))
        if np.any(bad):
            k = int(np.argmax(bad.ravel()))
            try:
                where = "at (" + ", ".join(f"{np.ravel(np.broadcast_to(a, exp.shape))[k]:.6g}"
                                           for a in inputs) + ")" if inputs else f"at entry {k}"
            except ValueError:      # inputs that do not broadcast to the result (a table per value)
                where = f"at entry {k}"
            msg = (f"{int(bad.sum())} of {exp.size} values wrong; {where} you return "
                   f"{got.ravel()[k]:.8g}, expected {exp.ravel()[k]:.8g}")
            return False, msg, (CheckResult("values", False, float(err.max()), rtol, msg, exp.size),)
        msg = f"all {exp.size} values match (largest error {float(err.max()):.2g})"
        return True, msg, (CheckResult("values", True, float(err.max()), rtol, msg, exp.size),)

    return _run(name, body, verbose)


def grade_dielectric(glass, eta: float, *, n: int = 20_000, degrees=(0.0, 30.0, 60.0, 80.0, 89.0),
                     inside_degrees=(20.0, 40.0, 45.0, 70.0), rng=None, significance: float = 1e-3,
                     name: str = "glass", verbose: bool = True) -> GradeResult:
    """Grade a smooth dielectric (the lecture's 'Glass'): Snell, total internal
    reflection, and a Fresnel-weighted choice of lobe.

    At each outgoing angle (from outside, ``wo.y > 0``, and from inside the
    glass, ``wo.y < 0``) ``glass.sample(wo, u)`` is called with ``n`` uniform
    points and must return, for every sample,

    1. either the mirror direction or Snell's refracted direction
       (:func:`mcvar.optics.refract`), to ``1e-9``;
    2. weight 1 (choosing a lobe with its share of the energy: the glass
       neither creates nor absorbs light, the furnace test of a delta BSDF);
    3. reflections in the proportion of the exact Fresnel reflectance
       :func:`mcvar.optics.fresnel_dielectric`: the count of reflected samples
       is Binomial(n, F), tested two-sided with Sidak's correction over the
       angles; beyond the critical angle (``F = 1``) every sample reflects.

    Parameters
    ----------
    glass : object
        With ``sample(wo, u) -> (wi, weight, pdf)`` (``wo`` of shape (n, 3), all
        rows equal, ``u`` of shape (n, 2)), e.g. :class:`mcvar.bsdf.Glass`.
    eta : float
        Inside index relative to outside.
    n : int
        Samples per angle.
    degrees, inside_degrees : sequence of float
        Angles from the normal of ``wo`` outside and inside, in [0, 90).
    rng, significance, name, verbose
        As in :func:`grade_warp`.

    Returns
    -------
    GradeResult
    """
    sample = getattr(glass, "sample", None)
    if not callable(sample):
        raise TypeError(f"glass must have a callable sample(wo, u); got {type(glass).__name__}")
    eta = check_positive(eta, "eta")
    n = check_count(n, "n")
    significance = check_positive(significance, "significance")
    angles = [(float(a), 1.0) for a in degrees] + [(float(a), -1.0) for a in inside_degrees]
    if not angles or any(not 0.0 <= a < 90.0 for a, _ in angles):
        raise ValueError(f"degrees and inside_degrees must be angles in [0, 90); got {degrees}, {inside_degrees}")
    s = _guard(sample)
    streams = as_rng(rng).spawn(len(angles))
    sig = sidak_significance(significance, len(angles))

    def body():
        checks, zs = [], []
        for (deg, side), g in zip(angles, streams):
            t = np.radians(deg)
            wo = np.array([np.sin(t), side * np.cos(t), 0.0])
            where = f"wo {deg:g} deg from the normal {'outside' if side > 0 else 'inside the glass'}"
            u = g.random((n, 2))
            out = s(np.tile(wo, (n, 1)), u)
            if not isinstance(out, tuple) or len(out) < 3:
                return False, f"sample(wo, u) must return (wi, weight, pdf); got {type(out).__name__}", tuple(checks)
            wi = np.asarray(out[0], dtype=np.float64).reshape(n, 3)
            weight = np.asarray(out[1], dtype=np.float64).reshape(n, -1)
            mirror = wo * np.array([-1.0, 1.0, -1.0])
            wt, tir = refract(wo[None], 1.0, eta)
            is_r = np.all(np.abs(wi - mirror) < 1e-9, axis=1)
            is_t = np.all(np.abs(wi - wt[0]) < 1e-9, axis=1) & ~bool(tir[0])
            if not np.all(is_r | is_t):
                k = int(np.argmax(~(is_r | is_t)))
                msg = (f"at {where}: {int(np.sum(~(is_r | is_t)))} of {n} directions are neither the mirror nor "
                       f"Snell's refraction (e.g. {np.round(wi[k], 6).tolist()})")
                return False, msg, tuple(checks)
            if not np.all(np.abs(weight - 1.0) < 1e-9):
                msg = (f"at {where}: weights must be 1 (a lobe chosen with its share of the energy); "
                       f"they range over [{weight.min():.4g}, {weight.max():.4g}], mean {weight.mean():.4g}")
                return False, msg, tuple(checks)
            f = float(fresnel_dielectric(np.array([wo[1]]), 1.0, eta)[0]) if not tir[0] else 1.0
            k = int(np.sum(is_r))
            if f >= 1.0 or f <= 0.0:
                ok = k == (n if f >= 1.0 else 0)
                z = 0.0 if ok else float("inf")
                msg = f"at {where}: {k} of {n} reflected, F = {f:g}"
            else:
                z = (k - n * f) / np.sqrt(n * f * (1.0 - f))
                p = float(2.0 * stats.norm.sf(abs(z)))
                ok = p >= sig
                msg = f"at {where}: {k / n:.4f} of the samples reflected, exact Fresnel F = {f:.4f} (z = {z:+.1f})"
            checks.append(CheckResult("fresnel", bool(ok), float(z), f, msg, n))
            zs.append(abs(z))
            if not ok:
                return False, msg, tuple(checks)
        return True, (f"mirror or Snell directions, weights 1, reflected shares match the exact Fresnel "
                      f"reflectance at {len(angles)} angles (largest |z| = {max(zs):.2f}; total internal "
                      "reflection beyond the critical angle)"), tuple(checks)

    return _run(name, body, verbose)


def grade_chain(step: Callable, sample_target: Callable, pdf: Callable, *, steps: int = 20,
                n: int = 100_000, rng=None, significance: float = 1e-3, name: str = "Markov chain",
                verbose: bool = True) -> GradeResult:
    """Grade a Markov chain step: does it leave the target density invariant?

    ``n`` chains start from exact samples of the target on the unit square
    (``sample_target(u)``), each takes ``steps`` steps of ``step(x, rng)``; if
    the step satisfies detailed balance for the target, the chains are still
    distributed as the target (a stationary distribution stays put), which a
    chi-square test of the ``n`` final states against ``pdf`` checks
    (:func:`mcvar.testing.chi2_test`). A step that favours some states (an
    acceptance missing a proposal density ratio) drifts away from it.

    Parameters
    ----------
    step : callable
        ``step(x, rng) -> x'`` for states ``x`` (n, 2) in [0, 1)^2,
        vectorised over chains.
    sample_target : callable
        ``sample_target(u) -> x``: exact samples of the target from uniform ``u``.
    pdf : callable
        The target's normalised density on the square.
    steps, n : int
    rng, significance, name, verbose
        As in :func:`grade_warp`.

    Returns
    -------
    GradeResult
    """
    for fn, what in ((step, "step"), (sample_target, "sample_target"), (pdf, "pdf")):
        if not callable(fn):
            raise TypeError(f"{what} must be callable; got {type(fn).__name__}")
    steps = check_count(steps, "steps")
    n = check_count(n, "n")
    significance = check_positive(significance, "significance")
    st = _guard(step)
    g_start, g_walk = as_rng(rng).spawn(2)

    def body():
        x = np.asarray(sample_target(g_start.random((n, 2))), dtype=np.float64)
        moved = 0
        for _ in range(steps):
            y = np.asarray(st(x.copy(), g_walk), dtype=np.float64)
            if y.shape != x.shape:
                return False, f"step(x, rng) returned shape {y.shape}, expected {x.shape}", ()
            if not np.all(np.isfinite(y)) or np.any(y < 0.0) or np.any(y >= 1.0):
                return False, "step(x, rng) must return finite states in [0, 1)^2", ()
            moved += int(np.sum(np.any(y != x, axis=1)))
            x = y
        rate = moved / (n * steps)
        if rate == 0.0:
            return False, "no chain ever moved: every proposal was rejected", ()
        chi = chi2_test(lambda u: x[:u.shape[0]], pdf, "square", n=n, batch_size=n, rng=0,
                        significance=significance)
        if not chi.passed:
            return False, (f"after {steps} steps the chains no longer follow the target (they started "
                           f"exactly on it): {chi.message}; acceptance rate {rate:.2f}"), (chi,)
        return True, (f"the target stays invariant: {n} chains after {steps} steps still follow it "
                      f"(chi-square p = {chi.pvalue:.3g}); acceptance rate {rate:.2f}"), (chi,)

    return _run(name, body, verbose)


def grade_coverage(stderr: Callable, series, truth: float, *, level: float = 0.95,
                   significance: float = 1e-3, name: str = "error bars",
                   verbose: bool = True) -> GradeResult:
    """Grade a standard-error estimator by the coverage of its intervals.

    For each of ``R`` independent series (rows of ``series``, e.g. Markov
    chains), the interval ``mean +- z_{(1+level)/2} stderr(row)`` must cover
    ``truth`` in a fraction ``level`` of the rows: the number that do is
    Binomial(R, level), tested two-sided at ``significance``. Error bars too
    narrow (the iid ``s / sqrt(N)`` of a correlated chain) cover too rarely;
    too wide ones cover too often.

    Parameters
    ----------
    stderr : callable
        ``stderr(h) -> float`` for one series ``h`` (N,).
    series : array_like, shape (R, N)
    truth : float
        The expectation every series' mean estimates.
    level : float
        Nominal coverage, in (0, 1).
    significance, name, verbose
        As in :func:`grade_warp`.

    Returns
    -------
    GradeResult
    """
    h = as_array(series, "series", ndim=2)
    if h.shape[0] < 20 or h.shape[1] < 2:
        raise ValueError(f"series must hold at least 20 series of 2 or more values; got shape {h.shape}")
    truth = float(as_array(truth, "truth"))
    level = float(level)
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must lie in (0, 1); got {level}")
    significance = check_positive(significance, "significance")
    se_fn = _guard(stderr)
    z = float(stats.norm.isf((1.0 - level) / 2.0))

    def body():
        se = np.array([float(np.asarray(se_fn(row.copy()), dtype=np.float64)) for row in h])
        if not np.all(np.isfinite(se)) or np.any(se < 0):
            return False, "stderr(h) must return a finite, non-negative number", ()
        covered = int(np.sum(np.abs(h.mean(axis=1) - truth) <= z * se))
        r = h.shape[0]
        p = float(stats.binomtest(covered, r, level).pvalue)
        ok = p >= significance
        msg = (f"{level:.0%} intervals cover the truth in {covered} of {r} series ({covered / r:.1%}; "
               f"binomial p = {p:.3g})")
        chk = CheckResult("coverage", ok, covered / r, level, msg, r)
        if not ok:
            hint = "too narrow: does it account for the correlation?" if covered / r < level else "too wide"
            return False, f"{msg}: the error bars are {hint}", (chk,)
        return True, msg, (chk,)

    return _run(name, body, verbose)
