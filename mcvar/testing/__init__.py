"""Statistical and deterministic checks for samplers, pdfs and estimators (layer 3).

A kit that catches the bugs renderers actually ship:

* :func:`chi2_test`: does a sampler draw from the density its pdf claims?
  (Pearson's chi-square goodness of fit, after Mitsuba's ``chi2.py``);
* :func:`check_pdf_normalized`: does the pdf integrate to 1 (adaptive
  cubature, with its error estimate)?
* :func:`check_weight_consistency`: is a BSDF's sample weight
  ``eval * |cos| / pdf``, and does ``sample`` report the pdf ``pdf`` gives?
* :func:`check_inverse`: do a warp and its inverse round-trip?
* :func:`check_extremes`: does a warp survive ``u = 0`` and ``u = 1.0``
  exactly (no index past an array, no NaN pdf at the pole or horizon)?
* :func:`check_unbiased`: is an estimate within ``z`` standard errors of a
  known value?

Every check returns a frozen result with ``passed`` and a ``message``; none
raises on a failing sampler (bad *arguments* raise ``ValueError`` /
``TypeError``). :mod:`mcvar.testing.mutants` holds deliberately broken
samplers that the checks must reject, and :func:`measure_power` measures how
many samples each check needs to reject one.
"""
from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass, field
from typing import Callable, Literal, Protocol, runtime_checkable

import numpy as np
from scipy import integrate, stats

from .._validation import as_array, as_directions, as_rng, check_count, check_choice, check_positive

__all__ = [
    "DOMAINS",
    "Chi2Result",
    "CheckResult",
    "PowerResult",
    "BSDFLike",
    "sidak_significance",
    "chi2_test",
    "check_pdf_normalized",
    "check_weight_consistency",
    "check_inverse",
    "check_extremes",
    "check_unbiased",
    "measure_power",
]

Domain = Literal["square", "disk", "hemisphere", "sphere"]
DOMAINS = ("square", "disk", "hemisphere", "sphere")

_TWO_PI = 2.0 * np.pi
# Parameter rectangle, coordinate names, Jacobian of the parameterisation and
# dimension of the points of each domain. Directions are binned in
# (cos theta, phi): d(omega) = d(cos theta) d(phi), so equal parameter areas
# are equal solid angles; the disk in (r^2, phi): dA = (1/2) d(r^2) d(phi).
_DOMAIN_INFO = {
    "square": (((0.0, 1.0), (0.0, 1.0)), ("x", "y"), 1.0, 2),
    "disk": (((0.0, 1.0), (0.0, _TWO_PI)), ("r^2", "phi"), 0.5, 2),
    "hemisphere": (((0.0, 1.0), (0.0, _TWO_PI)), ("cos_theta", "phi"), 1.0, 3),
    "sphere": (((-1.0, 1.0), (0.0, _TWO_PI)), ("cos_theta", "phi"), 1.0, 3),
}


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
# results
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class CheckResult:
    """Outcome of a deterministic or statistical check.

    Attributes
    ----------
    check : str
        Which check ran.
    passed : bool
    value : float
        The measured quantity (an integral, a relative error, a z-score...).
    threshold : float
        What ``value`` was compared with.
    message : str
        A sentence saying what was found.
    n : int
        Number of samples or evaluations the verdict rests on.
    """

    check: str
    passed: bool
    value: float
    threshold: float
    message: str
    n: int = 0


@dataclass(frozen=True, eq=False)
class Chi2Result:
    """Outcome of :func:`chi2_test`.

    Attributes
    ----------
    statistic, dof, pvalue : float, int, float
        Pearson's statistic over the pooled cells, its degrees of freedom
        (cells - 1) and the upper-tail probability. ``statistic = inf`` and
        ``pvalue = 0`` when a sanity check failed (see ``message``).
    significance : float
        The per-test significance used (Sidak-corrected for ``test_count``).
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


@dataclass(frozen=True)
class PowerResult:
    """Rejection rate of a check against sample count (:func:`measure_power`).

    Attributes
    ----------
    n_values : tuple of int
    rejection_rate : tuple of float
        Fraction of replicates that rejected at each ``n``.
    n_reject : int or None
        Smallest ``n`` whose rejection rate reached ``target``; None if none did.
    target : float
    replicates : int
    """

    n_values: tuple
    rejection_rate: tuple
    n_reject: int | None
    target: float
    replicates: int


# --------------------------------------------------------------------------
# domains
# --------------------------------------------------------------------------

def _bounds(domain, bounds):
    full = _DOMAIN_INFO[domain][0]
    if bounds is None:
        return full, True
    b = as_array(bounds, "bounds")
    if b.shape != (2, 2):
        raise ValueError(f"bounds must be ((lo0, hi0), (lo1, hi1)); got shape {b.shape}")
    for k in range(2):
        lo, hi = b[k]
        flo, fhi = full[k]
        if not (flo <= lo < hi <= fhi):
            raise ValueError(f"bounds[{k}] must satisfy {flo} <= lo < hi <= {fhi} for domain "
                             f"{domain!r}; got ({lo}, {hi})")
    bb = ((float(b[0, 0]), float(b[0, 1])), (float(b[1, 0]), float(b[1, 1])))
    return bb, bb == full


def _to_params(x, domain):
    """Parameter coordinates of points ``x`` and a mask of points in the domain."""
    if domain == "square":
        c0, c1 = x[:, 0], x[:, 1]
        tol = 1e-12
        ok = (c0 >= -tol) & (c0 <= 1 + tol) & (c1 >= -tol) & (c1 <= 1 + tol)
        return np.clip(c0, 0, 1), np.clip(c1, 0, 1), ok
    phi_src = (x[:, 0], x[:, 1]) if domain == "disk" else (x[:, 0], x[:, 2])
    phi = np.arctan2(phi_src[1], phi_src[0])
    phi = np.where(phi < 0.0, phi + _TWO_PI, phi)
    phi = np.where(phi >= _TWO_PI, 0.0, phi)
    if domain == "disk":
        r2 = x[:, 0] ** 2 + x[:, 1] ** 2
        ok = r2 <= 1.0 + 1e-9
        return np.minimum(r2, 1.0), phi, ok
    norm = np.sqrt(np.einsum("ij,ij->i", x, x))
    ok = np.abs(norm - 1.0) <= 1e-6
    y = x[:, 1]
    if domain == "hemisphere":
        ok &= y >= -1e-9
        return np.clip(y, 0.0, 1.0), phi, ok
    return np.clip(y, -1.0, 1.0), phi, ok


def _from_params(c0, c1, domain):
    if domain == "square":
        return np.stack([c0, c1], axis=-1)
    if domain == "disk":
        r = np.sqrt(c0)
        return np.stack([r * np.cos(c1), r * np.sin(c1)], axis=-1)
    s = np.sqrt(np.maximum(0.0, 1.0 - c0 * c0))
    return np.stack([s * np.cos(c1), c0, s * np.sin(c1)], axis=-1)


def _eval_pdf(pdf, pts, name="pdf"):
    out = np.empty(pts.shape[0])
    step = 1 << 20
    for i in range(0, pts.shape[0], step):
        val = np.asarray(pdf(pts[i:i + step]), dtype=np.float64)
        if val.shape != (min(step, pts.shape[0] - i),):
            raise ValueError(f"{name}(x) must return shape (m,) for m points; got shape {val.shape}")
        out[i:i + step] = val
    return out


def _sample_points(sample, u, dim):
    x = sample(u)
    if isinstance(x, tuple):
        x = x[0]
    x = np.asarray(x, dtype=np.float64)
    if x.shape != (u.shape[0], dim):
        raise ValueError(f"sample(u) must return shape ({u.shape[0]}, {dim}) for this domain; "
                         f"got shape {x.shape}")
    return x


# --------------------------------------------------------------------------
# chi-square test
# --------------------------------------------------------------------------

@functools.lru_cache(maxsize=16)
def _gauss_legendre(q):
    nodes, weights = np.polynomial.legendre.leggauss(q)
    nodes.setflags(write=False)
    weights.setflags(write=False)
    return nodes, weights


def _cell_integrals(pdf, domain, lo0, hi0, lo1, hi1, q):
    """Integral of the pdf over the cells ``[lo0, hi0] x [lo1, hi1]`` (arrays
    of cell bounds in parameter space) by q-point Gauss-Legendre per axis.

    Returns the integrals and a message if the pdf is negative or not finite
    at some node (else None).
    """
    nodes, weights = _gauss_legendre(q)
    h0, h1 = 0.5 * (hi0 - lo0), 0.5 * (hi1 - lo1)
    m0, m1 = 0.5 * (hi0 + lo0), 0.5 * (hi1 + lo1)
    c0 = m0[:, None, None] + h0[:, None, None] * nodes[None, :, None]
    c1 = m1[:, None, None] + h1[:, None, None] * nodes[None, None, :]
    c0, c1 = np.broadcast_arrays(c0, c1)
    vals = _eval_pdf(pdf, _from_params(c0.ravel(), c1.ravel(), domain)).reshape(c0.shape)
    problem = None if np.all(np.isfinite(vals) & (vals >= 0.0)) else _pdf_problem(vals)
    jac = _DOMAIN_INFO[domain][2]
    integral = np.einsum("kij,i,j->k", vals, weights, weights) * h0 * h1 * jac
    return integral, problem


def _expected_counts(pdf, domain, edges, n, int_tol, q_max=512, budget=4_000_000):
    """Per-cell adaptive Gauss-Legendre: ``q`` doubles only in the cells whose
    expected count is still changing (a discontinuity of the pdf inside them).

    Refinement stops when the change of the last doubling, ``delta``, could
    move the statistic by less than a tenth of its standard deviation
    (``sum(delta^2 / E) <= 0.1 sqrt(2 cells)``) and the integral by less than
    ``int_tol`` (``sum |delta| / n``), or when the node budget is spent.

    Returns ``(expected, chi2_inflation, integral_error, problem)`` where
    ``problem`` is a message when the pdf is negative or not finite somewhere.
    """
    e0, e1 = edges
    b0, b1 = e0.size - 1, e1.size - 1
    i0, i1 = np.meshgrid(np.arange(b0), np.arange(b1), indexing="ij")
    lo0, hi0 = e0[i0.ravel()], e0[i0.ravel() + 1]
    lo1, hi1 = e1[i1.ravel()], e1[i1.ravel() + 1]
    cells = b0 * b1
    allowed = 0.1 * np.sqrt(2.0 * cells)  # a tenth of the statistic's standard deviation
    q = 4
    prev, problem = _cell_integrals(pdf, domain, lo0, hi0, lo1, hi1, q)
    if problem:
        return None, 0.0, 0.0, problem
    expected = n * prev
    err = np.full(cells, np.inf)
    dabs = np.full(cells, np.inf)
    active = np.arange(cells)
    while active.size:
        if 2 * q > q_max or active.size * 4 * q * q > budget:
            break
        q *= 2
        cur, problem = _cell_integrals(pdf, domain, lo0[active], hi0[active],
                                       lo1[active], hi1[active], q)
        if problem:
            return None, 0.0, 0.0, problem
        new = n * cur
        dabs[active] = np.abs(new - expected[active])
        err[active] = dabs[active] ** 2 / np.maximum(new, 1.0)
        expected[active] = new
        if np.sum(err) <= allowed and np.sum(dabs) <= int_tol * n:
            break
        keep = (err[active] > allowed / cells) | (dabs[active] > int_tol * n / cells)
        active = active[keep]
    total_err = float(np.sum(err))
    int_err = float(np.sum(dabs) / n)
    if total_err > allowed:
        warnings.warn(f"chi2_test: pdf quadrature not converged in {active.size} cells "
                      f"(q = {q} nodes per axis; chi-square inflation ~{total_err:.3g}); "
                      "align bin edges with the pdf's discontinuities (bounds=, bins=)",
                      RuntimeWarning, stacklevel=3)
    return expected.reshape(b0, b1), total_err, int_err, None


def _pdf_problem(vals):
    nonfinite = int((~np.isfinite(vals)).sum())
    if nonfinite:
        return f"pdf is NaN or Inf at {nonfinite} quadrature nodes"
    return f"pdf is negative at {int((vals < 0).sum())} quadrature nodes (minimum {np.min(vals):.3g})"


def _default_bins(n, domain):
    target = 100.0  # mean expected count per cell (fewer cells when n is small)
    if domain == "square":
        m = int(np.clip(round(np.sqrt(n / target)), 2, 80))
        return (m, m)
    m = int(np.clip(round(np.sqrt(n / (2 * target))), 1, 64))
    return (m, 2 * m)


def _fail(msg, *, sig, obs, exp, edges, coords, domain, n, integral=float("nan"), outside=0):
    return Chi2Result(statistic=float("inf"), dof=0, pvalue=0.0, significance=sig, passed=False,
                      message=msg, observed=obs, expected=exp, edges=edges, coordinates=coords,
                      domain=domain, n=n, pdf_integral=integral, outside_bounds=outside)


def chi2_test(sample: Callable, pdf: Callable, domain: Domain, *, n: int = 1_000_000,
              rng=None, bins=None, bounds=None, significance: float = 1e-3,
              test_count: int = 1, min_expected: float = 5.0,
              normalization_atol: float = 1e-3, batch_size: int = 1_000_000) -> Chi2Result:
    """Chi-square goodness-of-fit test of a sampler against its pdf.

    Parameters
    ----------
    sample : callable
        ``sample(u)`` maps ``(m, 2)`` uniform points in [0, 1)^2 to ``(m, 2)``
        points (square, disk) or ``(m, 3)`` unit directions (hemisphere,
        sphere). If it returns a tuple, the first element is used (so a BSDF's
        ``lambda u: bsdf.sample(wo, u)`` works).
    pdf : callable
        ``pdf(x)`` gives the density of ``(m, d)`` points, shape ``(m,)``:
        per unit area (square, disk) or per steradian (directions).
    domain : {'square', 'disk', 'hemisphere', 'sphere'}
        'square' is [0, 1]^2, 'disk' the unit disk, 'hemisphere' the
        directions with ``y >= 0`` (normal +y) and 'sphere' all directions.
    n : int
        Number of samples (drawn in batches of ``batch_size``).
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
        With full bounds, the pdf must integrate to 1 within this tolerance
        (``inf`` disables this sanity check, leaving the statistic alone).

    Returns
    -------
    Chi2Result

    Notes
    -----
    Sanity checks come first and fail the test outright (``pvalue = 0``):
    non-finite samples, samples outside the domain, a pdf that is negative,
    NaN or infinite at a quadrature node, a pdf not integrating to 1, and
    samples in a cell where the pdf integrates to 0.

    The expected count of a cell is ``n`` times the integral of the pdf over
    it, computed with q-point Gauss-Legendre per axis (nodes interior to the
    cell, so a support boundary on a cell edge is exact and a pole or
    horizon singularity is never evaluated). ``q`` doubles from 4, in the
    cells still changing only, until the change in the expected counts,
    ``delta``, could move the statistic by less than a tenth of its standard
    deviation, ``sum(delta^2 / E) <= 0.1 sqrt(2 cells)``, and the integral by
    less than ``normalization_atol / 10``, or the node budget (4M) is spent
    (then a warning if the statistic could be affected). The normalisation
    check allows for the remaining quadrature error ``sum |delta| / n``.

    Cells with expected count below ``min_expected`` are merged, smallest
    first, into one pooled cell (grown until it reaches ``min_expected``);
    ``T = sum (O - E)^2 / E`` over the remaining cells is compared with a
    chi-square distribution with ``cells - 1`` degrees of freedom.

    References
    ----------
    .. [1] W. Jakob et al., Mitsuba 3 renderer, ``mitsuba/python/chi2.py``
       (the ChiSquareTest design: pooling, Sidak correction, sanity checks).
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
    """
    if not callable(sample):
        raise TypeError(f"sample must be callable; got {type(sample).__name__}")
    if not callable(pdf):
        raise TypeError(f"pdf must be callable; got {type(pdf).__name__}")
    domain = check_choice(domain, "domain", DOMAINS)
    n = check_count(n, "n")
    batch_size = check_count(batch_size, "batch_size")
    sig = sidak_significance(significance, test_count)
    min_expected = check_positive(min_expected, "min_expected")
    normalization_atol = check_positive(normalization_atol, "normalization_atol", allow_inf=True)
    gen = as_rng(rng)
    full_bounds, is_full = _bounds(domain, bounds)
    if bins is None:
        bins = _default_bins(n, domain)
    if np.ndim(bins) != 1 or len(bins) != 2:
        raise ValueError(f"bins must be a pair of ints; got {bins!r}")
    bins = (check_count(bins[0], "bins[0]"), check_count(bins[1], "bins[1]"))
    _, coords, _, dim = _DOMAIN_INFO[domain]
    edges = tuple(np.linspace(full_bounds[k][0], full_bounds[k][1], bins[k] + 1) for k in range(2))
    empty = np.zeros(bins)

    # --- samples -----------------------------------------------------------
    observed = np.zeros(bins[0] * bins[1], dtype=np.int64)
    outside = 0
    for start in range(0, n, batch_size):
        m = min(batch_size, n - start)
        x = _sample_points(sample, gen.random((m, 2)), dim)
        finite = np.all(np.isfinite(x), axis=1)
        if not np.all(finite):
            return _fail(f"{int((~finite).sum())} of {m} samples are NaN or Inf", sig=sig, obs=empty,
                         exp=empty, edges=edges, coords=coords, domain=domain, n=n)
        c0, c1, ok = _to_params(x, domain)
        if not np.all(ok):
            return _fail(f"{int((~ok).sum())} of {m} samples lie outside the {domain} domain",
                         sig=sig, obs=empty, exp=empty, edges=edges, coords=coords, domain=domain, n=n)
        (lo0, hi0), (lo1, hi1) = full_bounds
        inb = (c0 >= lo0) & (c0 <= hi0) & (c1 >= lo1) & (c1 <= hi1)
        outside += int((~inb).sum())
        i0 = np.minimum(((c0[inb] - lo0) / (hi0 - lo0) * bins[0]).astype(np.int64), bins[0] - 1)
        i1 = np.minimum(((c1[inb] - lo1) / (hi1 - lo1) * bins[1]).astype(np.int64), bins[1] - 1)
        observed += np.bincount(i0 * bins[1] + i1, minlength=bins[0] * bins[1])
    observed = observed.reshape(bins).astype(np.float64)

    # --- expected counts -----------------------------------------------------
    int_tol = 0.1 * normalization_atol if np.isfinite(normalization_atol) else np.inf
    expected, ierr, int_err, problem = _expected_counts(pdf, domain, edges, n, int_tol)
    if problem is not None:
        return _fail(problem, sig=sig, obs=observed, exp=empty, edges=edges, coords=coords,
                     domain=domain, n=n, outside=outside)
    integral = float(expected.sum() / n)
    if is_full and not abs(integral - 1.0) <= normalization_atol + int_err:
        return _fail(f"pdf integrates to {integral:.6g} over the {domain}, not 1 "
                     f"(tolerance {normalization_atol:g} + quadrature error {int_err:.2g})", sig=sig, obs=observed, exp=expected,
                     edges=edges, coords=coords, domain=domain, n=n, integral=integral, outside=outside)
    if not is_full and not integral <= 1.0 + normalization_atol + int_err:
        return _fail(f"pdf integrates to {integral:.6g} > 1 over bounds alone", sig=sig, obs=observed,
                     exp=expected, edges=edges, coords=coords, domain=domain, n=n,
                     integral=integral, outside=outside)

    # --- pooling and statistic ---------------------------------------------
    obs = observed.ravel()
    exp = expected.ravel()
    if not is_full:
        obs = np.append(obs, outside)
        exp = np.append(exp, max(0.0, n * (1.0 - integral)))
    zero = exp <= 0.0
    if np.any(obs[zero] > 0):
        k = int(obs[zero].sum())
        return _fail(f"{k} samples fell in cells where the pdf integrates to 0", sig=sig,
                     obs=observed, exp=expected, edges=edges, coords=coords, domain=domain, n=n,
                     integral=integral, outside=outside)
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
        raise ValueError(f"n = {n} is too small for {bins} bins: fewer than 2 cells reach the "
                         f"expected count {min_expected}")
    stat = float(np.sum((obs - exp) ** 2 / exp))
    pval = float(stats.chi2.sf(stat, dof))
    passed = pval > sig
    msg = (f"chi-square {stat:.4g} on {dof} dof, p = {pval:.3g} "
           f"{'>' if passed else '<='} significance {sig:.3g}: "
           f"{'accepted' if passed else 'rejected'}")
    return Chi2Result(statistic=stat, dof=dof, pvalue=pval, significance=sig, passed=passed,
                      message=msg, observed=observed, expected=expected, edges=edges,
                      coordinates=coords, domain=domain, n=n, pdf_integral=integral,
                      integration_error=ierr, outside_bounds=outside)


# --------------------------------------------------------------------------
# normalisation
# --------------------------------------------------------------------------

def check_pdf_normalized(pdf: Callable, domain: Domain, *, bounds=None, atol: float = 1e-3,
                         rtol: float = 1e-6, max_subdivisions: int = 2000) -> CheckResult:
    """Check that a pdf integrates to 1 over its domain (adaptive cubature).

    Parameters
    ----------
    pdf : callable
        ``pdf(x)`` for ``(m, 2)`` points or ``(m, 3)`` directions, shape ``(m,)``.
    domain : {'square', 'disk', 'hemisphere', 'sphere'}
    bounds : optional
        Integrate over a sub-rectangle of the parameter rectangle only (as in
        :func:`chi2_test`); the pdf must then vanish outside it.
    atol : float
        Pass if ``|I - 1| + err <= atol``, where ``err`` is the cubature's own
        error estimate: a pass means the integral is within ``atol`` of 1
        even allowing for the quadrature error.
    rtol : float
        Relative tolerance requested from the cubature.

    Returns
    -------
    CheckResult
        ``value`` is the integral ``I``.

    Notes
    -----
    The integral is taken in the parameter coordinates of :func:`chi2_test`
    (``d omega = d(cos theta) d(phi)``, ``dA = (1/2) d(r^2) d(phi)``) with
    :func:`scipy.integrate.cubature` (a 21-point Gauss-Kronrod product rule
    with adaptive subdivision; its error estimate is the Gauss-Kronrod
    difference). Its nodes are interior, so the pole and the horizon are never
    evaluated.
    """
    if not callable(pdf):
        raise TypeError(f"pdf must be callable; got {type(pdf).__name__}")
    domain = check_choice(domain, "domain", DOMAINS)
    atol = check_positive(atol, "atol")
    rtol = check_positive(rtol, "rtol")
    max_subdivisions = check_count(max_subdivisions, "max_subdivisions")
    bb, _ = _bounds(domain, bounds)
    jac = _DOMAIN_INFO[domain][2]
    count = [0]

    def f(c):
        count[0] += c.shape[0]
        return jac * _eval_pdf(pdf, _from_params(c[:, 0], c[:, 1], domain))

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = integrate.cubature(f, [bb[0][0], bb[1][0]], [bb[0][1], bb[1][1]], rtol=rtol,
                                 atol=0.01 * atol, max_subdivisions=max_subdivisions)
    value, err = float(res.estimate), float(res.error)
    if not (np.isfinite(value) and np.isfinite(err)):
        return CheckResult("pdf_normalized", False, value, atol,
                           "pdf integral is not finite (NaN or Inf in the pdf)", count[0])
    dev = abs(value - 1.0)
    passed = dev + err <= atol
    msg = f"pdf integrates to {value:.8g} +- {err:.2g} over the {domain}"
    if not passed:
        msg += (f"; |I - 1| + error = {dev + err:.3g} > {atol:g}"
                + ("" if res.status == "converged" else " (cubature did not converge)"))
    return CheckResult("pdf_normalized", bool(passed), value, atol, msg, count[0])


# --------------------------------------------------------------------------
# BSDF weight consistency
# --------------------------------------------------------------------------

@runtime_checkable
class BSDFLike(Protocol):
    """What :func:`check_weight_consistency` needs (docs/conventions.md).

    ``eval(wo, wi) -> (n, 3)`` or ``(n,)``: f, the BSDF value;
    ``pdf(wo, wi) -> (n,)``: solid-angle density of ``sample``;
    ``sample(wo, u) -> (wi, weight, pdf)`` with ``weight = f |cos theta_i| / pdf``
    (0 for a failed sample). An optional ``is_delta`` attribute marks Dirac
    BSDFs, whose ``eval`` and ``pdf`` are 0 for every direction pair.
    """

    def eval(self, wo, wi): ...

    def pdf(self, wo, wi): ...

    def sample(self, wo, u): ...


def check_weight_consistency(bsdf: BSDFLike, wo, *, n: int = 10_000, rng=None,
                             rtol: float = 1e-6) -> CheckResult:
    """Check a BSDF's sample weights and pdfs against its ``eval`` and ``pdf``.

    Parameters
    ----------
    bsdf : BSDFLike
        Any object with ``eval``, ``pdf`` and ``sample`` (see :class:`BSDFLike`).
    wo : array_like, shape (3,) or (n, 3)
        Outgoing direction(s), local space (normal +y).
    n : int
        Number of samples.
    rtol : float
        Relative tolerance. Both sides are exact formulas of the same
        quantity, so they agree to rounding (~1e-15) unless one is wrong; 1e-6
        leaves room for algebraically simplified weights (e.g. ``F G2 / G1``).

    Returns
    -------
    CheckResult
        ``value`` is the largest relative disagreement found.

    Notes
    -----
    For every sample ``(wi, weight, p) = bsdf.sample(wo, u)``: weight, pdf and
    ``wi`` are finite, weight >= 0 and p >= 0; where ``p > 0``,
    ``weight == bsdf.eval(wo, wi) |wi_y| / p`` and, unless the sample failed
    (weight 0, which then requires ``eval = 0``), ``p == bsdf.pdf(wo, wi)``;
    where ``p = 0`` the weight is 0. For a delta BSDF (``is_delta``) only finiteness and signs
    are checked: its ``eval`` and ``pdf`` are 0 by convention. A mixed model
    (``has_delta`` true, ``is_delta`` false, e.g. a coated diffuse) is sampled
    with ``sample(wo, u, return_delta=True)``, whose fourth output marks the
    delta-lobe samples; those are checked like a delta BSDF's, the rest fully.
    """
    for meth in ("eval", "pdf", "sample"):
        if not callable(getattr(bsdf, meth, None)):
            raise TypeError(f"bsdf must have a callable {meth}(...); got {type(bsdf).__name__}")
    n = check_count(n, "n")
    rtol = check_positive(rtol, "rtol")
    gen = as_rng(rng)
    wo = as_directions(wo, "wo")
    if wo.ndim == 1:
        wo = np.broadcast_to(wo, (n, 3)).copy()
    elif wo.shape != (n, 3):
        raise ValueError(f"wo must have shape (3,) or ({n}, 3); got shape {wo.shape}")
    u = gen.random((n, 2))
    all_delta = bool(getattr(bsdf, "is_delta", False))
    mixed = bool(getattr(bsdf, "has_delta", False)) and not all_delta
    out = bsdf.sample(wo, u, return_delta=True) if mixed else bsdf.sample(wo, u)
    if not (isinstance(out, tuple) and len(out) == (4 if mixed else 3)):
        return CheckResult("weight_consistency", False, float("inf"), rtol,
                           "sample(wo, u) must return a tuple (wi, weight, pdf)"
                           + (" (+ delta mask with return_delta=True)" if mixed else ""), n)
    delta = np.asarray(out[3], dtype=bool).reshape(n) if mixed else np.full(n, all_delta)
    wi, weight, p_s = (np.asarray(a, dtype=np.float64) for a in out[:3])
    weight2 = weight.reshape(n, -1) if weight.size else weight.reshape(n, 0)
    problems = []
    if wi.shape != (n, 3):
        problems.append(f"wi has shape {wi.shape}, not ({n}, 3)")
    if p_s.shape != (n,):
        problems.append(f"pdf has shape {p_s.shape}, not ({n},)")
    if problems:
        return CheckResult("weight_consistency", False, float("inf"), rtol, "; ".join(problems), n)
    # a delta lobe may report pdf = inf (the MIS convention); NaN never
    p_ok = np.isfinite(p_s) | (delta & (p_s == np.inf))
    bad = ~(np.all(np.isfinite(wi), axis=1) & np.all(np.isfinite(weight2), axis=1) & p_ok)
    if np.any(bad):
        return CheckResult("weight_consistency", False, float("inf"), rtol,
                           f"{int(bad.sum())} of {n} samples have NaN or Inf in wi, weight or pdf", n)
    if not (np.all(weight2 >= 0.0) and np.all(p_s >= 0.0)):
        return CheckResult("weight_consistency", False, float("inf"), rtol,
                           "negative sample weight or pdf", n)
    if all_delta:
        return CheckResult("weight_consistency", True, 0.0, rtol,
                           "delta BSDF: weights finite and >= 0 (eval/pdf are 0 by convention)", n)
    zero_p = (p_s <= 0.0) & ~delta
    if np.any(weight2[zero_p] > 0.0):
        return CheckResult("weight_consistency", False, float("inf"), rtol,
                           f"{int(np.any(weight2[zero_p] > 0, axis=1).sum())} samples have pdf 0 "
                           "but a non-zero weight", n)
    live = ~zero_p & ~delta
    m = int(live.sum())
    if m == 0:
        return CheckResult("weight_consistency", False, float("nan"), rtol,
                           "every sample failed (pdf 0): nothing to compare", n)
    wo_l, wi_l = wo[live], wi[live]
    f = np.asarray(bsdf.eval(wo_l, wi_l), dtype=np.float64).reshape(m, -1)
    p = np.asarray(bsdf.pdf(wo_l, wi_l), dtype=np.float64).reshape(m)
    ps = p_s[live]
    failed = ~np.any(weight2[live] > 0.0, axis=1)  # e.g. a lobe sample below the horizon
    rel_p = np.where(failed, 0.0, np.abs(ps - p) / ps)
    expected = f * np.abs(wi_l[:, 1])[:, None] / ps[:, None]
    got = weight2[live]
    scale = np.maximum(np.abs(expected), np.abs(got))
    with np.errstate(invalid="ignore", divide="ignore"):
        rel_w = np.where(scale > 0.0, np.abs(got - expected) / np.where(scale > 0, scale, 1.0), 0.0)
    worst_p, worst_w = float(np.max(rel_p)), float(np.max(rel_w))
    worst = max(worst_p, worst_w)
    passed = worst <= rtol
    if passed:
        msg = f"{m} samples: weight = eval |cos| / pdf and sample pdf = pdf() within {worst:.2g}"
    elif worst_p > rtol:
        k = int((rel_p > rtol).sum())
        msg = (f"{k} of {m} samples: the pdf returned by sample() differs from pdf(wo, wi) "
               f"(relative error up to {worst_p:.3g})")
    else:
        k = int(np.any(rel_w > rtol, axis=1).sum())
        msg = (f"{k} of {m} samples: weight != eval |cos| / pdf "
               f"(relative error up to {worst_w:.3g})")
    return CheckResult("weight_consistency", bool(passed), worst, rtol, msg, m)


# --------------------------------------------------------------------------
# inverse, extremes, unbiasedness
# --------------------------------------------------------------------------

def check_inverse(forward: Callable, inverse: Callable, *, n: int = 10_000, rng=None,
                  atol: float = 1e-9, periodic=(False, False), u=None) -> CheckResult:
    """Check that ``inverse(forward(u)) == u`` (a warp's round trip).

    Parameters
    ----------
    forward, inverse : callable
        ``forward(u)`` maps ``(m, 2)`` points of the square to the domain and
        ``inverse`` maps them back.
    n : int
        Number of uniform points (ignored when ``u`` is given).
    atol : float
        Largest absolute error accepted in ``u``; float64 warps round-trip to
        ~1e-15, so 1e-9 only fails a wrong inverse.
    periodic : (bool, bool)
        Coordinates compared modulo 1 (an azimuth ``u1 = 2 pi phi``: 0 and 1
        are the same direction).
    u : array_like, shape (m, 2), optional
        Points to test instead of random ones (avoid points where the map is
        not injective, e.g. the pole, where the azimuth is undefined).

    Returns
    -------
    CheckResult
        ``value`` is the largest error.
    """
    if not (callable(forward) and callable(inverse)):
        raise TypeError("forward and inverse must be callable")
    atol = check_positive(atol, "atol")
    if u is None:
        n = check_count(n, "n")
        u = as_rng(rng).random((n, 2))
    else:
        u = as_array(u, "u", ndim=2, last=2)
    x = forward(u)
    if isinstance(x, tuple):
        x = x[0]
    back = np.asarray(inverse(x), dtype=np.float64)
    if back.shape != u.shape:
        return CheckResult("inverse", False, float("inf"), atol,
                           f"inverse returned shape {back.shape}, expected {u.shape}", u.shape[0])
    err = np.abs(back - u)
    for k in range(2):
        if periodic[k]:
            err[:, k] = np.minimum(err[:, k], 1.0 - err[:, k])
    if not np.all(np.isfinite(err)):
        return CheckResult("inverse", False, float("inf"), atol,
                           "round trip produced NaN or Inf", u.shape[0])
    worst = float(err.max()) if err.size else 0.0
    passed = worst <= atol
    k = int(np.any(err > atol, axis=1).sum())
    msg = (f"round trip error <= {worst:.2g}" if passed
           else f"{k} of {u.shape[0]} points do not round-trip (error up to {worst:.3g})")
    return CheckResult("inverse", bool(passed), worst, atol, msg, u.shape[0])


def _boundary_u(k=257):
    t = np.linspace(0.0, 1.0, k)
    t = np.concatenate([t, [np.nextafter(0.0, 1.0), np.nextafter(1.0, 0.0), 0.5]])
    zeros, ones = np.zeros_like(t), np.ones_like(t)
    return np.concatenate([np.stack(p, axis=-1) for p in
                           ((t, zeros), (t, ones), (zeros, t), (ones, t))], axis=0)


def check_extremes(sample: Callable, pdf: Callable, domain: Domain, *, u=None) -> CheckResult:
    """Run a warp on the square's boundary: ``u`` exactly 0 and 1.0.

    The classic shipped bugs live there: ``u = 1.0`` indexing one past the
    end of a table, ``sqrt(1 - r^2)`` of a radius that rounded above 1
    (NaN), a pdf computed as ``0 * inf`` at the pole or the horizon.

    Parameters
    ----------
    sample, pdf : callable
        As in :func:`chi2_test`.
    domain : {'square', 'disk', 'hemisphere', 'sphere'}
    u : array_like, shape (m, 2), optional
        Points to test; default: 257 points along each edge of the square,
        including the corners, ``nextafter(0, 1)`` and ``nextafter(1, 0)``.

    Returns
    -------
    CheckResult
        Passes when ``sample`` raises nothing and returns finite points in the
        domain, and ``pdf`` of them is finite and >= 0 (0 is allowed: the
        boundary may map to the edge of the support, e.g. the horizon of a
        cosine lobe).
    """
    domain = check_choice(domain, "domain", DOMAINS)
    u = _boundary_u() if u is None else as_array(u, "u", ndim=2, last=2)
    dim = _DOMAIN_INFO[domain][3]
    m = u.shape[0]
    try:
        x = _sample_points(sample, u, dim)
    except (IndexError, ValueError, FloatingPointError, ZeroDivisionError) as exc:
        return CheckResult("extremes", False, float("inf"), 0.0,
                           f"sample raised {type(exc).__name__} on the boundary: {exc}", m)
    finite = np.all(np.isfinite(x), axis=1)
    if not np.all(finite):
        bad = u[~finite][0]
        return CheckResult("extremes", False, float((~finite).sum()), 0.0,
                           f"{int((~finite).sum())} of {m} boundary samples are NaN/Inf "
                           f"(first at u = {bad.tolist()})", m)
    _, _, ok = _to_params(x, domain)
    if not np.all(ok):
        return CheckResult("extremes", False, float((~ok).sum()), 0.0,
                           f"{int((~ok).sum())} boundary samples lie outside the {domain}", m)
    try:
        p = np.asarray(pdf(x), dtype=np.float64)
    except (IndexError, ValueError, FloatingPointError, ZeroDivisionError) as exc:
        return CheckResult("extremes", False, float("inf"), 0.0,
                           f"pdf raised {type(exc).__name__} on boundary samples: {exc}", m)
    bad = ~(np.isfinite(p) & (p >= 0.0))
    if np.any(bad):
        first = u[np.nonzero(np.broadcast_to(bad, (m,)))[0][0]]
        return CheckResult("extremes", False, float(bad.sum()), 0.0,
                           f"pdf is NaN, Inf or negative at {int(bad.sum())} of {m} boundary samples "
                           f"(first at u = {first.tolist()})", m)
    return CheckResult("extremes", True, 0.0, 0.0,
                       f"{m} boundary points: finite samples in the {domain}, finite pdf >= 0", m)


def check_unbiased(estimate, exact, *, stderr=None, z: float | None = None,
                   significance: float = 1e-3, test_count: int = 1) -> CheckResult:
    """Check that an estimate agrees with a known value within ``z`` standard errors.

    Parameters
    ----------
    estimate : object with ``mean`` and ``stderr`` attributes, or number(s)
        E.g. a :class:`mcvar.estimators.Estimate`; or the mean itself (a float
        or array, e.g. RGB) with ``stderr=`` given.
    exact : float or array_like
        The true value (broadcast against the mean).
    stderr : float or array_like, optional
        Standard error, required when ``estimate`` is a number.
    z : float, optional
        Acceptance half-width in standard errors. Default: the two-sided
        normal quantile of the Sidak-corrected ``significance`` over
        ``test_count`` tests times the number of components of the mean
        (3.29 for one scalar at 1e-3).
    significance : float
    test_count : int

    Returns
    -------
    CheckResult
        ``value`` is the largest ``|mean - exact| / stderr`` over components.

    Notes
    -----
    By the central limit theorem ``(mean - exact) / stderr`` is
    approximately standard normal for an unbiased estimator, so a correct
    estimator fails with probability ``significance``. A zero standard error
    (a zero-variance estimator, e.g. a pdf proportional to the integrand)
    requires agreement to 64 ulps.
    """
    if hasattr(estimate, "mean") and hasattr(estimate, "stderr") and not isinstance(estimate, np.ndarray):
        mean, se = estimate.mean, estimate.stderr
        if stderr is not None:
            raise ValueError("stderr must not be given when estimate has a stderr attribute")
    else:
        if stderr is None:
            raise ValueError("stderr is required when estimate is a number (or pass an object "
                             "with mean and stderr attributes)")
        mean, se = estimate, stderr
    mean = as_array(mean, "estimate.mean")
    se = as_array(se, "stderr", nonnegative=True)
    ex = as_array(exact, "exact")
    try:
        mean, se, ex = np.broadcast_arrays(mean, se, ex)
    except ValueError as exc:
        raise ValueError(f"estimate, stderr and exact must broadcast; got shapes {mean.shape}, "
                         f"{se.shape}, {ex.shape}") from exc
    comps = max(1, mean.size)
    if z is None:
        sig = sidak_significance(significance, check_count(test_count, "test_count") * comps)
        z = float(stats.norm.isf(sig / 2.0))
    else:
        z = check_positive(z, "z")
    diff = np.abs(mean - ex)
    slack = 64.0 * np.finfo(np.float64).eps * np.maximum(np.abs(ex), np.abs(mean))
    ok = diff <= z * se + slack
    with np.errstate(divide="ignore", invalid="ignore"):
        zs = np.where(se > 0, diff / np.where(se > 0, se, 1.0), np.where(diff <= slack, 0.0, np.inf))
    worst = float(np.max(zs)) if zs.size else 0.0
    passed = bool(np.all(ok))
    msg = (f"|mean - exact| = {worst:.3g} standard errors "
           f"{'<=' if passed else '>'} z = {z:.3g}: {'consistent' if passed else 'biased'}")
    return CheckResult("unbiased", passed, worst, z, msg, int(comps))


# --------------------------------------------------------------------------
# power
# --------------------------------------------------------------------------

def measure_power(run: Callable, n_values, *, replicates: int = 10, target: float = 0.9,
                  rng=None, stop: bool = True) -> PowerResult:
    """Rejection rate of a check against the number of samples.

    Parameters
    ----------
    run : callable
        ``run(n, rng)`` runs a check with ``n`` samples and the ``Generator``
        ``rng`` and returns a result with a ``passed`` attribute.
    n_values : sequence of int
        Increasing sample counts to try.
    replicates : int
        Independent runs per ``n`` (streams from ``rng.spawn``).
    target : float
        Rejection rate that counts as 'rejected at this n' (default 0.9).
    stop : bool
        Stop at the first ``n`` reaching ``target``.

    Returns
    -------
    PowerResult
    """
    if not callable(run):
        raise TypeError(f"run must be callable; got {type(run).__name__}")
    ns = [check_count(v, "n_values[i]") for v in n_values]
    if not ns or any(b <= a for a, b in zip(ns, ns[1:])):
        raise ValueError(f"n_values must be a non-empty increasing sequence; got {ns}")
    replicates = check_count(replicates, "replicates")
    if not 0.0 < float(target) <= 1.0:
        raise ValueError(f"target must lie in (0, 1]; got {target}")
    gen = as_rng(rng)
    tried, rates, n_reject = [], [], None
    for n in ns:
        streams = gen.spawn(replicates)
        rejected = sum(not run(n, s).passed for s in streams)
        tried.append(n)
        rates.append(rejected / replicates)
        if rates[-1] >= target and n_reject is None:
            n_reject = n
            if stop:
                break
    return PowerResult(tuple(tried), tuple(rates), n_reject, float(target), replicates)
