"""The chi-square goodness-of-fit machinery of :mod:`mcvar.testing` (layer 3).

Everything public here is re-exported by :mod:`mcvar.testing`: import it from
there. :func:`chi2_test` tests any (sampler, pdf) pair on the square, disk,
hemisphere or sphere, samplers that may fail included; :func:`bsdf_chi2_test`
adapts a BSDF with fixed ``wo`` to it.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
from scipy import stats

from .._validation import (as_directions, as_rng, as_unit_directions, check_choice, check_count, check_positive,
                           settings_with)
from ._domains import _DOMAIN_INFO, DOMAINS, Domain, _bounds, _expected_counts, _to_params

__all__ = ["DOMAINS", "Chi2Result", "Chi2Settings", "sidak_significance", "chi2_test", "bsdf_chi2_test"]


def sidak_significance(significance: float, test_count: int) -> float:
    """Per-test significance keeping the family-wise false-rejection rate at
    ``significance`` over ``test_count`` independent tests (Sidak):
    ``1 - (1 - significance)^(1 / test_count)``.

    Examples
    --------
    >>> round(sidak_significance(1e-3, 10), 8)
    0.00010005
    """
    a = check_positive(significance, "significance")
    if not a < 1.0:
        raise ValueError(f"significance must lie in (0, 1); got {a}")
    m = check_count(test_count, "test_count")
    return float(-np.expm1(np.log1p(-a) / m))


# --------------------------------------------------------------------------
# result
# --------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Chi2Result:
    """Outcome of :func:`chi2_test` and :func:`bsdf_chi2_test`.

    Attributes
    ----------
    statistic, dof, pvalue : float, int, float
        Pearson's statistic over the pooled cells, its degrees of freedom
        (cells - 1) and the upper-tail probability. ``statistic = inf`` and
        ``pvalue = 0`` when a sanity check failed (see ``message``).
    significance : float
        The significance each statistical test used: Sidak-corrected for
        ``test_count`` and, when the binomial check of the valid fraction
        runs too, for those two tests.
    passed : bool
        ``pvalue > significance`` and every sanity check passed.
    message : str
    observed, expected : ndarray, shape (bins[0], bins[1])
        Histograms over the parameter rectangle (before pooling), so that
        observed and expected can be plotted side by side.
    edges : tuple of two ndarray
        Bin edges along each parameter axis.
    coordinates : tuple of str
        Names of the parameter axes, e.g. ``('cos_theta', 'phi')``.
    domain : str
    n : int
    pdf_integral : float
        Integral of the pdf over ``bounds`` (numerical quadrature).
    integration_error : float
        Chi-square inflation the quadrature error of ``expected`` can cause,
        ``sum(delta^2 / E)`` over cells (small next to ``sqrt(2 dof)``).
    outside_bounds : int
        Samples inside the domain but outside ``bounds`` (one extra cell).
    failed : int
        Samples the sampler reported as failed (``valid`` False), or for
        :func:`bsdf_chi2_test` failed BSDF samples (pdf 0).
    valid_pvalue : float
        Two-sided binomial p-value of the number of valid samples against
        ``n * pdf_integral`` (NaN when the check did not run).
    delta : int
        :func:`bsdf_chi2_test` only: samples from a Dirac-delta lobe, left
        out of the histogram like failed samples.
    """

    statistic: float
    dof: int
    pvalue: float
    significance: float
    passed: bool
    message: str
    observed: np.ndarray = field(repr=False)
    expected: np.ndarray = field(repr=False)
    edges: tuple = field(repr=False)
    coordinates: tuple = ()
    domain: str = ""
    n: int = 0
    pdf_integral: float = float("nan")
    integration_error: float = 0.0
    outside_bounds: int = 0
    failed: int = 0
    valid_pvalue: float = float("nan")
    delta: int = 0



# --------------------------------------------------------------------------
# samples
# --------------------------------------------------------------------------

def _sample_points(sample, u, dim):
    """Points of ``sample(u)`` and its validity mask (None if not reported).

    ``sample(u)`` returns the points, or ``(points, valid)`` with ``valid`` a
    boolean array, or any other tuple whose first element is the points
    (e.g. a BSDF's ``(wi, weight, pdf)``).
    """
    out = sample(u)
    valid = None
    if isinstance(out, tuple):
        if len(out) == 2 and isinstance(out[1], np.ndarray) and out[1].dtype == np.bool_:
            valid = out[1]
            if valid.shape != (u.shape[0],):
                raise ValueError(f"the valid mask of sample(u) must have shape ({u.shape[0]},); "
                                 f"got shape {valid.shape}")
        out = out[0]
    x = np.asarray(out, dtype=np.float64)
    if x.shape != (u.shape[0], dim):
        raise ValueError(f"sample(u) must return shape ({u.shape[0]}, {dim}) for this domain; "
                         f"got shape {x.shape}")
    return x, valid


def _default_bins(n, domain):
    target = 100.0  # mean expected count per cell (fewer cells when n is small)
    if domain == "square":
        m = int(np.clip(round(np.sqrt(n / target)), 2, 80))
        return (m, m)
    m = int(np.clip(round(np.sqrt(n / (2 * target))), 1, 64))
    return (m, 2 * m)


def _fail(msg: str, fields: dict) -> Chi2Result:
    """A failed test: ``pvalue = 0`` with ``msg``; ``fields`` are :class:`Chi2Result` fields
    (``significance``, ``observed``, ``expected``, ``edges``, ``coordinates``, ``domain``,
    ``n`` and whichever of the counts are known)."""
    return Chi2Result(**{"statistic": float("inf"), "dof": 0, "pvalue": 0.0, "passed": False, "message": msg,
                         "pdf_integral": float("nan"), "outside_bounds": 0, "failed": 0,
                         "valid_pvalue": float("nan"), **fields})


@dataclass(frozen=True)
class Chi2Settings:
    """The options of :func:`chi2_test` and :func:`bsdf_chi2_test` (their keywords; see
    :func:`chi2_test` for each)."""

    n: int = 1_000_000
    rng: object = None
    bins: tuple | None = None
    bounds: tuple | None = None
    significance: float = 1e-3
    test_count: int = 1
    min_expected: float = 5.0
    normalization_atol: float = 1e-3
    batch_size: int = 1_000_000


def _valid_fraction_pvalue(valid, n, integral, int_err):
    """Two-sided binomial p-value of ``valid`` successes in ``n`` trials with
    success probability ``integral``, giving the quadrature error the benefit
    of the doubt (the probability nearest ``valid / n`` within ``int_err``)."""
    p = float(np.clip(valid / n, integral - int_err, integral + int_err))
    p = min(max(p, 0.0), 1.0)
    if p == 0.0 or p == 1.0:
        return 1.0 if valid == round(p * n) else 0.0
    return float(stats.binomtest(int(valid), int(n), p).pvalue)


def chi2_test(sample: Callable, pdf: Callable, domain: Domain, settings: Chi2Settings | None = None,
              **options) -> Chi2Result:
    """Chi-square goodness-of-fit test of a sampler against its pdf.

    Parameters
    ----------
    sample : callable
        ``sample(u)`` maps ``(m, 2)`` uniform points in [0, 1)^2 to ``(m, 2)``
        points (square, disk) or ``(m, 3)`` unit directions (hemisphere,
        sphere). A sampler whose samples may *fail* (a direction drawn below
        the horizon, a zero weight) returns ``(points, valid)`` instead, with
        ``valid`` a boolean ndarray of shape ``(m,)``: failed samples are left
        out of the histogram and their points are ignored (they may be NaN or
        outside the domain). Any other tuple is read as ``(points, ...)``
        (so a BSDF's ``lambda u: bsdf.sample(wo, u)`` works; see
        :func:`bsdf_chi2_test` for BSDFs with failures or delta lobes).
    pdf : callable
        ``pdf(x)`` gives the density of ``(m, d)`` points, shape ``(m,)``
        (a scalar or size-1 result, one constant for all, is broadcast):
        per unit area (square, disk) or per steradian (directions). For a
        sampler with failures it is the density of the *valid* samples, which
        integrates to the probability that a sample is valid (< 1).
    domain : {'square', 'disk', 'hemisphere', 'sphere'}
        'square' is [0, 1]^2, 'disk' the unit disk, 'hemisphere' the
        directions with ``y >= 0`` (normal +y) and 'sphere' all directions.
    settings : Chi2Settings, optional
        The options below (Other Parameters) as one record; those keywords
        replace its fields (any other keyword is a ``TypeError``).

    Other Parameters
    ----------------
    n : int
        Number of samples, failed ones included (drawn in batches of
        ``batch_size``).
    rng : None, int, SeedSequence or Generator
        Source of the uniform points.
    bins : (int, int), optional
        Histogram resolution over the parameter rectangle: ``(x, y)`` for the
        square, ``(r^2, phi)`` for the disk, ``(cos theta, phi)`` for
        directions, so that every cell has the same area or solid angle.
        Default: about 100 expected samples per cell.
    bounds : ((lo0, hi0), (lo1, hi1)), optional
        A sub-rectangle of the parameter rectangle to bin, e.g.
        ``((cos_theta_max, 1), (0, 2 pi))`` for a narrow cone so that its
        edge is a bin edge. Samples in the domain but outside ``bounds`` form
        one extra cell with expected count ``n (1 - integral over bounds)``.
    significance : float
        Family-wise significance (probability of rejecting a correct pair).
    test_count : int
        Number of tests in the family: the per-test significance is
        ``sidak_significance(significance, test_count)``.
    min_expected : float
        Cells with a smaller expected count are pooled (Mitsuba uses 5).
    normalization_atol : float
        With full bounds, the pdf must integrate to 1 within this tolerance;
        for a sampler reporting failures, to at most ``1 + normalization_atol``
        and to the valid fraction (binomial test). ``inf`` disables these
        sanity checks, leaving the statistic alone.

    Returns
    -------
    Chi2Result

    Notes
    -----
    Sanity checks come first and fail the test outright (``pvalue = 0``):
    non-finite valid samples, valid samples outside the domain, a pdf that
    is negative, NaN or infinite at a quadrature node, a pdf whose integral
    ``I`` is wrong, and samples in a cell where the pdf integrates to 0.
    ``I`` is wrong when it differs from 1 by more than
    ``normalization_atol`` (plus the quadrature's own error); for a sampler
    reporting failures (Mitsuba's semantics: failed samples are dropped, the
    pdf integrates to the probability of a valid sample) when it exceeds 1,
    or when the number of valid samples ``V`` is implausible under
    ``V ~ Binomial(n, I)`` (two-sided exact binomial test). That catches a
    pdf that ignores the failures (normalised to 1 over the valid region)
    and a sampler failing more or less often than its pdf allows. The
    binomial test and the chi-square test then run at ``1 - (1 - a)^(1/2)``
    each, so that ``a``, the Sidak-corrected significance, stays the
    probability of rejecting a correct sampler.

    The expected count of a cell is ``n`` times the integral of the pdf over
    it, computed with q-point Gauss-Legendre per axis (nodes interior to the
    cell, so a support boundary on a cell edge is exact and a pole or
    horizon singularity is never evaluated). ``q`` doubles from 4, in the
    cells still changing only, until the change in the expected counts,
    ``delta``, could move the statistic by less than a tenth of its standard
    deviation, ``sum(delta^2 / E) <= 0.1 sqrt(2 cells)``, and the integral by
    less than ``normalization_atol / 10`` (and a tenth of the binomial
    standard error of the valid fraction), or the node budget (4M) is spent
    (then a warning if the statistic could be affected). The normalisation
    checks allow for the remaining quadrature error ``sum |delta| / n``.

    Failed samples and samples outside ``bounds`` form one extra cell with
    expected count ``n (1 - I)`` (the multinomial has one more outcome), so
    that observed and expected totals agree. Cells with expected count below
    ``min_expected`` are merged, smallest first, into one pooled cell (grown
    until it reaches ``min_expected``); ``T = sum (O - E)^2 / E`` over the
    remaining cells is compared with a chi-square distribution with
    ``cells - 1`` degrees of freedom.

    References
    ----------
    .. [1] W. Jakob et al., Mitsuba 3 renderer, ``mitsuba/python/chi2.py``
       (the ChiSquareTest design: pooling, Sidak correction, sanity checks,
       invalid samples dropped from the histogram).
    .. [2] K. Pearson, "On the criterion that a given system of deviations
       from the probable ...", Philosophical Magazine 50(302), 1900.

    Examples
    --------
    >>> from mcvar import warps
    >>> r = chi2_test(warps.square_to_cosine_hemisphere,
    ...               warps.square_to_cosine_hemisphere_pdf, 'hemisphere',
    ...               n=100_000, rng=20240601)
    >>> r.passed
    True

    A sampler whose samples may fail: uniform directions on the sphere,
    those below the horizon failing; the valid ones have density
    ``1 / (4 pi)`` on the hemisphere, which integrates to 1/2.

    >>> def half(u):
    ...     d = warps.square_to_uniform_sphere(u)
    ...     return d, d[:, 1] >= 0.0
    >>> r = chi2_test(half, lambda d: np.full(len(d), 1 / (4 * np.pi)),
    ...               'hemisphere', n=100_000, rng=20240601)
    >>> r.passed, round(r.pdf_integral, 6)
    (True, 0.5)
    """
    if not callable(sample):
        raise TypeError(f"sample must be callable; got {type(sample).__name__}")
    if not callable(pdf):
        raise TypeError(f"pdf must be callable; got {type(pdf).__name__}")
    setup, info = _setup(domain, settings_with(Chi2Settings, settings, options, "chi2_test"))
    hist = _histogram(sample, setup)
    if isinstance(hist, str):
        return _fail(hist, info)
    observed, outside, failed, reports_valid = hist
    info.update(observed=observed, outside_bounds=outside, failed=failed)
    checked = _check_integral(pdf, setup, hist, info)
    if isinstance(checked, Chi2Result):
        return checked
    expected, _, integral, valid_p, _ = checked
    stat = _statistic(observed, expected, integral, outside + failed,
                      not setup.is_full or reports_valid, setup.min_expected, setup.bins)
    if isinstance(stat, str):
        return _fail(stat, {**info, "valid_pvalue": valid_p})
    return _verdict(stat, info, checked, hist, setup.n)


def _verdict(stat_dof: tuple, info: dict, checked: tuple, hist: tuple, n: int) -> Chi2Result:
    """The test's result from Pearson's statistic and its degrees of freedom."""
    stat, dof = stat_dof
    _, ierr, integral, valid_p, binomial = checked
    failed, reports_valid = hist[2], hist[3]
    pval = float(stats.chi2.sf(stat, dof))
    sig = info["significance"]
    passed = pval > sig
    msg = (f"chi-square {stat:.4g} on {dof} dof, p = {pval:.3g} {'>' if passed else '<='} significance "
           f"{sig:.3g}: {'accepted' if passed else 'rejected'}")
    if reports_valid:
        msg += (f"; {failed} of {n} samples failed, valid fraction {(n - failed) / n:.6g} vs "
                f"pdf integral {integral:.6g}" + (f" (binomial p = {valid_p:.3g})" if binomial else ""))
    return Chi2Result(statistic=stat, dof=dof, pvalue=pval, passed=passed, message=msg,
                      integration_error=ierr, valid_pvalue=valid_p, **info)


@dataclass(frozen=True)
class _Setup:
    """A chi-square test's checked settings and histogram geometry."""

    domain: str
    n: int
    batch_size: int
    gen: np.random.Generator
    min_expected: float
    atol: float
    full_bounds: tuple
    is_full: bool
    bins: tuple
    dim: int
    edges: tuple


def _setup(domain, opts: Chi2Settings):
    """Every setting checked before any work: ``(_Setup, the result's known fields)``."""
    domain = check_choice(domain, "domain", DOMAINS)
    n = check_count(opts.n, "n")
    batch_size = check_count(opts.batch_size, "batch_size")
    sig = sidak_significance(opts.significance, opts.test_count)
    min_expected = check_positive(opts.min_expected, "min_expected")
    atol = check_positive(opts.normalization_atol, "normalization_atol", allow_inf=True)
    full_bounds, is_full = _bounds(domain, opts.bounds)
    bins = _default_bins(n, domain) if opts.bins is None else opts.bins
    if np.ndim(bins) != 1 or len(bins) != 2:
        raise ValueError(f"bins must be a pair of ints; got {bins!r}")
    bins = (check_count(bins[0], "bins[0]"), check_count(bins[1], "bins[1]"))
    _, coords, _, dim = _DOMAIN_INFO[domain]
    edges = tuple(np.linspace(full_bounds[k][0], full_bounds[k][1], bins[k] + 1) for k in range(2))
    empty = np.zeros(bins)
    info = dict(significance=sig, observed=empty, expected=empty, edges=edges, coordinates=coords,
                domain=domain, n=n)
    return _Setup(domain, n, batch_size, as_rng(opts.rng), min_expected, atol, full_bounds, is_full, bins, dim,
                  edges), info


def _histogram(sample, setup: _Setup):
    """Histogram of ``n`` samples over the parameter rectangle: ``(observed, outside, failed,
    reports_valid)``, or a message saying why the samples fail the test outright."""
    domain, dim, n, batch_size, gen, bins = setup.domain, setup.dim, setup.n, setup.batch_size, setup.gen, setup.bins
    observed = np.zeros(bins[0] * bins[1], dtype=np.int64)
    outside = failed = 0
    reports_valid = False
    (lo0, hi0), (lo1, hi1) = setup.full_bounds
    for start in range(0, n, batch_size):
        m = min(batch_size, n - start)
        x, valid = _sample_points(sample, gen.random((m, 2)), dim)
        if valid is not None:
            reports_valid = True
            x = x[valid]
            failed += m - x.shape[0]
        finite = np.all(np.isfinite(x), axis=1)
        if not np.all(finite):
            return (f"{int((~finite).sum())} of {m} samples are NaN or Inf"
                    + (" (and marked valid)" if valid is not None else ""))
        c0, c1, ok = _to_params(x, domain)
        if not np.all(ok):
            hint = ("" if valid is not None else
                    "; a sampler whose samples may fail returns (points, valid)")
            return f"{int((~ok).sum())} of {m} samples lie outside the {domain} domain{hint}"
        inb = (c0 >= lo0) & (c0 <= hi0) & (c1 >= lo1) & (c1 <= hi1)
        outside += int((~inb).sum())
        i0 = np.minimum(((c0[inb] - lo0) / (hi0 - lo0) * bins[0]).astype(np.int64), bins[0] - 1)
        i1 = np.minimum(((c1[inb] - lo1) / (hi1 - lo1) * bins[1]).astype(np.int64), bins[1] - 1)
        observed += np.bincount(i0 * bins[1] + i1, minlength=bins[0] * bins[1])
    return observed.reshape(bins).astype(np.float64), outside, failed, reports_valid


def _check_integral(pdf, setup: _Setup, hist: tuple, info: dict):
    """Expected counts and the normalisation checks: ``(expected, integration error, integral,
    valid-fraction p-value, binomial test run?)`` or a failed :class:`Chi2Result`. Updates
    ``info`` (expected counts, integral, the significance after the binomial test's share)."""
    domain, edges, n, is_full, atol, sig = (setup.domain, setup.edges, setup.n, setup.is_full, setup.atol,
                                            info["significance"])
    _, _, failed, reports_valid = hist
    n_valid = n - failed
    int_tol = 0.1 * atol if np.isfinite(atol) else np.inf
    binomial = reports_valid and is_full and np.isfinite(atol)
    if binomial:  # resolve the integral well below the valid fraction's standard error
        f = n_valid / n
        int_tol = min(int_tol, 0.1 * np.sqrt(max(f * (1.0 - f), 1.0 / n) / n))
    expected, ierr, int_err, problem = _expected_counts(pdf, domain, edges, n, int_tol)
    if problem is not None:
        return _fail(problem, info)
    integral = float(expected.sum() / n)
    info.update(expected=expected, pdf_integral=integral)
    slack = atol + int_err
    if is_full and not reports_valid and not abs(integral - 1.0) <= slack:
        return _fail(f"pdf integrates to {integral:.6g} over the {domain}, not 1 "
                     f"(tolerance {atol:g} + quadrature error {int_err:.2g})", info)
    if not integral <= 1.0 + slack:
        where = f"over the {domain}" if is_full else "over bounds alone"
        return _fail(f"pdf integrates to {integral:.6g} > 1 {where}", info)
    valid_p = float("nan")
    if binomial:
        sig = sidak_significance(sig, 2)
        info["significance"] = sig
        valid_p = _valid_fraction_pvalue(n_valid, n, integral, int_err)
        if not valid_p > sig:
            return _fail(f"{n_valid} of {n} samples are valid (fraction {n_valid / n:.6g}) but the "
                         f"pdf integrates to {integral:.6g}: binomial p = {valid_p:.3g} <= {sig:.3g}; "
                         "the pdf must integrate to the probability of a valid sample",
                         {**info, "valid_pvalue": valid_p})
    return expected, ierr, integral, valid_p, binomial


def _statistic(observed, expected, integral, rest, extra_cell, min_expected, bins):
    """Pearson's statistic after pooling: ``(T, dof)``, or a message when samples fell where
    the pdf integrates to 0."""
    obs = observed.ravel()
    exp = expected.ravel()
    n = observed.sum() + rest
    if extra_cell:
        obs = np.append(obs, rest)
        # 1 - I within rounding of 0 leaves nothing for failures or the outside
        exp = np.append(exp, n * (1.0 - integral) if 1.0 - integral > 1e-12 else 0.0)
    zero = exp <= 0.0
    if np.any(obs[zero] > 0):
        k = int(obs[zero].sum())
        what = ("samples failed or fell outside bounds although the pdf integrates to 1"
                if zero[-1] and obs[-1] > 0 and exp.size > observed.size
                else "samples fell in cells where the pdf integrates to 0")
        return f"{k} {what}"
    obs, exp = obs[~zero], exp[~zero]
    order = np.argsort(exp, kind="stable")
    obs, exp = obs[order], exp[order]
    cum = np.cumsum(exp)
    small = int(np.searchsorted(exp, min_expected, side="left"))  # cells with E < min_expected
    if small > 0:
        # grow the pool to at least min_expected
        k = max(small, int(np.searchsorted(cum, min_expected, side="left")) + 1)
        k = min(k, exp.size)
        obs = np.append(obs[k:], obs[:k].sum())
        exp = np.append(exp[k:], exp[:k].sum())
    dof = int(exp.size - 1)
    if dof < 1:
        raise ValueError(f"n = {int(n)} is too small for {bins} bins: fewer than 2 cells reach the "
                         f"expected count {min_expected}")
    return float(np.sum((obs - exp) ** 2 / exp)), dof


# --------------------------------------------------------------------------
# BSDF adapter
# --------------------------------------------------------------------------

def bsdf_chi2_test(bsdf, wo, settings: Chi2Settings | None = None, **options) -> Chi2Result:
    """Chi-square test of a BSDF's ``sample`` against its ``pdf`` at a fixed ``wo``.

    Parameters
    ----------
    bsdf : object with ``sample(wo, u)`` and ``pdf(wo, wi)``
        The BSDF protocol of :class:`mcvar.testing.BSDFLike` (e.g. any
        :mod:`mcvar.bsdf` model). A mixed model (``has_delta`` true,
        ``is_delta`` false) must accept ``sample(..., return_delta=True)``.
    wo : array_like, shape (3,)
        The outgoing unit direction, local space (normal +y). For a
        reflection model it must lie above the horizon (``wo[1] > 0``).

    Other Parameters
    ----------------
    settings, n, rng, bins, significance, test_count, min_expected, normalization_atol, batch_size
        As in :func:`chi2_test` (``bounds`` excepted); ``n`` counts every
        sample, failed and delta ones included.

    Returns
    -------
    Chi2Result
        ``failed`` counts failed samples and ``delta`` delta-lobe samples;
        ``pdf_integral`` is the non-delta pdf's integral, which must match
        the fraction of samples that are neither.

    Raises
    ------
    ValueError
        For a purely delta BSDF (``is_delta``: its pdf is discrete, there is
        no density to test), a ``wo`` that is not a unit vector, or a
        reflection model's ``wo`` at or below the horizon (every sample
        fails there).

    Notes
    -----
    The domain is the sphere for a transmissive BSDF (attribute
    ``transmissive``) and the upper hemisphere otherwise. A sample is left
    out of the histogram when it failed, i.e. ``sample`` reported pdf 0
    (:mod:`mcvar.bsdf`'s contract) or weight 0 for a direction below the
    horizon of a reflection model (docs/conventions.md: a zero weight means
    a failed sample), and when it came from a Dirac-delta lobe (the
    ``return_delta`` mask: its pdf is a discrete probability, not a
    density). The non-delta ``pdf`` then integrates to
    ``1 - P(delta) - P(failure)``, which :func:`chi2_test` checks against
    the observed fraction of valid samples (binomial test), next to the
    chi-square statistic of the valid samples' histogram. So a smooth
    :class:`mcvar.bsdf.Plastic` is tested on its diffuse part, and a delta
    lobe chosen with the wrong probability shows up as a valid fraction
    the pdf does not account for.

    A non-finite or negative pdf reported by ``sample`` for a non-delta
    sample fails the test outright.

    Examples
    --------
    >>> from mcvar.bsdf import Microfacet
    >>> wo = np.array([0.6, 0.8, 0.0])
    >>> r = bsdf_chi2_test(Microfacet(0.3), wo, n=100_000, rng=20240601)
    >>> r.passed, r.failed > 0
    (True, True)
    """
    opts = settings_with(Chi2Settings, settings, options, "bsdf_chi2_test")
    if opts.bounds is not None:
        raise TypeError("bsdf_chi2_test() takes no bounds: it bins the whole hemisphere or sphere")
    for meth in ("pdf", "sample"):
        if not callable(getattr(bsdf, meth, None)):
            raise TypeError(f"bsdf must have a callable {meth}(...); got {type(bsdf).__name__}")
    if bool(getattr(bsdf, "is_delta", False)):
        raise ValueError(f"bsdf must have a non-delta part: {type(bsdf).__name__} is a Dirac delta "
                         "(is_delta), its pdf is a discrete probability with no density to test")
    wo = as_directions(wo, "wo")
    if wo.shape != (3,):
        raise ValueError(f"wo must be one direction, shape (3,); got shape {wo.shape}")
    wo = as_unit_directions(wo, "wo")  # the one rule for directions (docs/conventions.md)
    transmissive = bool(getattr(bsdf, "transmissive", False))
    if not transmissive and not wo[1] > 0.0:
        raise ValueError(f"wo must lie above the horizon (wo[1] > 0) for a reflection BSDF, where "
                         f"every sample fails otherwise; got wo[1] = {wo[1]:.6g}")
    mixed = bool(getattr(bsdf, "has_delta", False))
    domain = "sphere" if transmissive else "hemisphere"
    tally = {"delta": 0, "failed": 0, "problem": None}

    def sample(u):
        wo_b = np.broadcast_to(wo, (u.shape[0], 3))
        out = bsdf.sample(wo_b, u, return_delta=True) if mixed else bsdf.sample(wo_b, u)
        wi = np.array(out[0], dtype=np.float64)
        weight = np.asarray(out[1], dtype=np.float64).reshape(u.shape[0], -1)
        p = np.asarray(out[2], dtype=np.float64).reshape(u.shape[0])
        delta = np.asarray(out[3], dtype=bool).reshape(u.shape[0]) if mixed else np.zeros(u.shape[0], bool)
        bad = ~delta & ~(np.isfinite(p) & (p >= 0.0))
        if np.any(bad) and tally["problem"] is None:
            tally["problem"] = (f"sample() reported a NaN, Inf or negative pdf for {int(bad.sum())} "
                                f"of {u.shape[0]} non-delta samples")
            wi[bad] = np.nan          # makes chi2_test stop at once
        failed = ~delta & ~bad & ((p <= 0.0) | (~np.any(weight > 0.0, axis=1)
                                                & (wi[:, 1] < 0.0) & (not transmissive)))
        tally["delta"] += int(delta.sum())
        tally["failed"] += int(failed.sum())
        return wi, ~(delta | failed)

    def pdf(x):
        return bsdf.pdf(np.broadcast_to(wo, x.shape), x)

    r = chi2_test(sample, pdf, domain, opts)
    n = opts.n
    msg = r.message
    if tally["problem"] is not None:
        msg = tally["problem"]
    elif tally["delta"]:
        msg += (f" ({tally['delta']} of these, {tally['delta'] / n:.4g}, are delta-lobe samples, "
                "excluded by design)")
    return replace(r, message=msg, failed=tally["failed"], delta=tally["delta"])
