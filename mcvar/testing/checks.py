"""The deterministic and statistical checks of :mod:`mcvar.testing` (normalisation,
weight consistency, inverses, extremes, unbiasedness, power), re-exported there."""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable, Protocol, runtime_checkable

import numpy as np
from scipy import integrate, stats

from .._validation import as_array, as_directions, as_rng, check_count, check_choice, check_positive
from ._chi2 import _sample_points, sidak_significance
from ._domains import _DOMAIN_INFO, DOMAINS, Domain, _bounds, _eval_pdf, _from_params, _pdf_values, _to_params

__all__ = ["CheckResult", "PowerResult", "BSDFLike", "check_pdf_normalized", "check_weight_consistency",
           "check_inverse", "check_extremes", "check_unbiased", "measure_power"]


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
# normalisation
# --------------------------------------------------------------------------

def check_pdf_normalized(pdf: Callable, domain: Domain, *, bounds=None, atol: float = 1e-3,
                         rtol: float = 1e-6, max_subdivisions: int = 2000) -> CheckResult:
    """Check that a pdf integrates to 1 over its domain (adaptive cubature).

    Parameters
    ----------
    pdf : callable
        ``pdf(x)`` for ``(m, 2)`` points or ``(m, 3)`` directions, shape ``(m,)``
        (a scalar or size-1 result is broadcast to every point).
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
    """What :func:`check_weight_consistency` and :func:`bsdf_chi2_test` need
    (docs/conventions.md).

    ``eval(wo, wi) -> (n, 3)`` or ``(n,)``: f, the BSDF value;
    ``pdf(wo, wi) -> (n,)``: solid-angle density of ``sample``'s non-delta
    samples; ``sample(wo, u) -> (wi, weight, pdf)`` with
    ``weight = f |cos theta_i| / pdf`` (0 for a failed sample). Optional
    attributes: ``is_delta`` marks Dirac BSDFs, whose ``eval`` and ``pdf``
    are 0 for every direction pair; ``has_delta`` without ``is_delta`` a
    mixed model, whose ``sample(wo, u, return_delta=True)`` adds a mask of
    the delta-lobe samples; ``transmissive`` a BSDF that samples the whole
    sphere.
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
    p = _pdf_values(bsdf.pdf(wo_l, wi_l), m, "bsdf.pdf")
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
        cosine lobe). A sampler returning ``(points, valid)`` is judged on
        its valid points only.
    """
    domain = check_choice(domain, "domain", DOMAINS)
    u = _boundary_u() if u is None else as_array(u, "u", ndim=2, last=2)
    dim = _DOMAIN_INFO[domain][3]
    m = u.shape[0]
    try:
        x, valid = _sample_points(sample, u, dim)
    except (IndexError, ValueError, FloatingPointError, ZeroDivisionError) as exc:
        return CheckResult("extremes", False, float("inf"), 0.0,
                           f"sample raised {type(exc).__name__} on the boundary: {exc}", m)
    if valid is not None:  # failed samples are allowed anywhere (chi2_test's (points, valid))
        u, x = u[valid], x[valid]
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
        p = _pdf_values(pdf(x), x.shape[0])
    except (IndexError, ValueError, FloatingPointError, ZeroDivisionError) as exc:
        return CheckResult("extremes", False, float("inf"), 0.0,
                           f"pdf raised {type(exc).__name__} on boundary samples: {exc}", m)
    bad = ~(np.isfinite(p) & (p >= 0.0))
    if np.any(bad):
        first = u[np.nonzero(np.broadcast_to(bad, (x.shape[0],)))[0][0]]
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
