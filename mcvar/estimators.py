"""Monte Carlo estimators that report their error (layer 3).

The lecture's 'Monte Carlo Estimator' slide, ``(1/N) sum_j f(X_j) / p(X_j)``,
with everything needed to trust the number it returns: a standard error and an
interval beside every mean (:class:`Estimate`), exact merging of batches,
honest error bars for QMC and stratified points (randomized replicates),
sampling to a tolerance, importance sampling, and multiple importance sampling
with the balance and power heuristics ('Multiple Importance Sampling' slide).
"""
from __future__ import annotations

import numpy as np

from ._validation import as_array, check_positive

__all__ = [
    "balance_heuristic",
    "power_heuristic",
]


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
