"""Multiple importance sampling: heuristics, weights, multi- and one-sample MIS,
and the hemisphere estimator (layer 3, module 2 of :mod:`mcvar.estimators`).

Lecture slide 'Multiple Importance Sampling'; E. Veach, PhD thesis, 1997, ch. 9.
"""
from __future__ import annotations

import numbers
from typing import Literal

import numpy as np

from .._validation import as_array, check_choice, check_count, check_positive
from .. import warps
from .monte_carlo import (Estimate, _children, _divide, _eval_f, _iid, _mean_of, _Replicator,
                          _resolve_replicates, _resolve_sampler, EstimateSettings, contribution, estimate_mean,
                          estimate_settings)

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


def mis_estimate(f, strategies, *, heuristic: Literal["balance", "power"] = "balance", beta: float = 2.0,
                 zero_pdf: Literal["raise", "drop"] = "raise", settings: EstimateSettings | None = None,
                 **options) -> Estimate:
    """Multi-sample MIS: ``n_k`` samples from each strategy, weighted and summed.

    Parameters
    ----------
    f : callable
        Integrand ``f(x) -> (n,)`` or ``(n, ...)``.
    strategies : sequence of (sample, pdf)
        K strategies over the same domain and measure: warps
        ``sample(u) -> x`` with their densities ``pdf(x) -> (n,)``.
    heuristic : {'balance', 'power'}
        Weighting (:func:`mis_weights`); ``beta`` is the power's exponent.

    Other Parameters
    ----------------
    n : int or sequence of int
        Samples per strategy ``n_k`` (an int gives every strategy the same).
    settings, sampler, rng, replicates, zero_pdf, batch
        As in :func:`estimate` (:class:`EstimateSettings` or its fields; no
        tolerance: ``atol``/``rtol`` are a ``ValueError``); each strategy
        draws from its own stream.

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
    opts = estimate_settings(settings, options, "mis_estimate")
    if opts.atol is not None or opts.rtol is not None:
        raise ValueError("mis_estimate takes no tolerance (atol, rtol): give the samples per strategy, n")
    n, sampler, rng, replicates, batch = opts.n, opts.sampler, opts.rng, opts.replicates, opts.batch
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


def one_sample_mis(f, strategies, *, probabilities=None, heuristic: Literal["balance", "power"] = "balance",
                   beta: float = 2.0, zero_pdf: Literal["raise", "drop"] = "raise",
                   settings: EstimateSettings | None = None, **options) -> Estimate:
    """One-sample MIS: each sample picks one strategy at random, then is weighted.

    Strategy ``k`` is chosen with probability ``c_k`` from the first
    coordinate of the 2D point, which is then rescaled to [0, 1) and reused
    (so one 2D sampler, stratified or QMC, drives the choice and the warp).
    The contribution is ``w_k(X) f(X) / (c_k p_k(X))``.

    Parameters
    ----------
    f, strategies
        As in :func:`mis_estimate`.
    probabilities : array_like, shape (K,), optional
        Selection probabilities ``c_k`` (> 0, summing to 1); default uniform.
    heuristic, beta, zero_pdf
        As in :func:`mis_estimate`.

    Other Parameters
    ----------------
    n : int
        Total samples.
    settings, sampler, rng, replicates, atol, rtol, level, max_n, batch
        As in :func:`estimate` (:class:`EstimateSettings` or its fields).

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
    settings = estimate_settings(settings, options, "one_sample_mis")
    g = one_sample_mis_contribution(f, strategies, probabilities=probabilities, heuristic=heuristic,
                                    beta=beta, zero_pdf=zero_pdf)
    return estimate_mean(g, settings)


_HEMISPHERE = {
    "uniform": (warps.square_to_uniform_hemisphere, warps.square_to_uniform_hemisphere_pdf),
    "cosine": (warps.square_to_cosine_hemisphere, warps.square_to_cosine_hemisphere_pdf),
}


def hemisphere_estimate(radiance, *, method: Literal["uniform", "cosine", "mis"] = "cosine",
                        settings: EstimateSettings | None = None, **options) -> Estimate:
    """Estimate ``int_H L_i(w) cos(theta) dw`` over the hemisphere about +y.

    Parameters
    ----------
    radiance : callable
        ``L_i(w) -> (n,)`` or ``(n, 3)`` for local directions ``w`` (normal
        +y), finite and >= 0.
    method : {'uniform', 'cosine', 'mis'}
        ``'uniform'``: ``p = 1 / (2 pi)``, contribution ``2 pi L_i cos``;
        ``'cosine'``: ``p = cos / pi``, contribution ``pi L_i`` ('more
        radiance per sample'); ``'mis'``: one-sample MIS of the two with the
        balance heuristic (each picked with probability 1/2).

    Other Parameters
    ----------------
    n : int
        Samples.
    settings, sampler, rng, replicates, atol, rtol, level, max_n, batch
        As in :func:`estimate` (:class:`EstimateSettings` or its fields).

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
    settings = estimate_settings(settings, options, "hemisphere_estimate")
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
    return estimate_mean(g, settings)
