"""Markov chain Monte Carlo on the unit hypercube (layer 4).

The lecture's 'Metropolis Hasting Algorithm' and 'Metropolis Hasting: Sampling
An Image' slides: a random walk of *dependent* samples whose distribution
converges to ``f / b`` with ``b = integral of f``:

- :func:`metropolis`: Metropolis-Hastings on ``[0, 1)^dim`` with the
  mutations of Kelemen et al. [1]_ (a small symmetric Gaussian step wrapped
  on the torus, and with probability ``p_large`` an independent uniform
  'large step' that keeps the chain ergodic), acceptance
  ``a = min(1, f(y) / f(x))``, many chains at once, started from a bootstrap
  that also estimates ``b``.
- :class:`Chain`: the named result, with the statistics that correlated
  samples need: integrated autocorrelation time ``tau`` (Sokal's adaptive
  window [2]_) or batch means, effective sample size ``N / tau`` and an
  :class:`mcvar.estimators.Estimate` with an honest standard error.
- :func:`image_walk`: the lecture's demo, a walk whose visits reproduce an
  image; plain or expected-value splatting.
- :func:`integrated_time`, :func:`correlated_estimate`, :func:`tv_distance`:
  the statistics on their own arrays.

It sits in layer 4 because it reuses :class:`~mcvar.estimators.Estimate`
(layer 3) and the luminance weights of :mod:`mcvar.envmap` (layer 3).

References
----------
.. [1] C. Kelemen, L. Szirmay-Kalos, G. Antal, F. Csonka, "A Simple and
   Robust Mutation Strategy for the Metropolis Light Transport Algorithm",
   Computer Graphics Forum 21(3), 2002.
.. [2] A. D. Sokal, "Monte Carlo Methods in Statistical Mechanics:
   Foundations and New Algorithms", in Functional Integration (Cargese 1996),
   Plenum 1997, section 3 (the automatic windowing procedure).
.. [3] E. Veach, "Robust Monte Carlo Methods for Light Transport
   Simulation", PhD thesis, Stanford 1997, chapter 11.
.. [4] M. Pharr, W. Jakob, G. Humphreys, "Physically Based Rendering",
   4th ed., MIT Press 2023, section 13.4 (PSSMLT, bootstrap, splatting).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ._validation import (as_array, as_rng, check_budget, check_choice, check_count, check_positive,
                          check_probability, settings_with)
from .envmap import LUMINANCE_WEIGHTS
from .estimators import Estimate

__all__ = [
    "Chain",
    "WalkSettings",
    "IMAGE_WALK",
    "metropolis",
    "image_walk",
    "integrated_time",
    "batch_means_time",
    "correlated_estimate",
    "tv_distance",
    "MAX_STORED",
    "SOKAL_C",
    "BOOTSTRAP_CHUNK",
    "check_walk_budget",
]

#: Largest number of float64 numbers a :class:`Chain` stores for its
#: ``samples``, ``values`` and ``accepted`` (2**24: 128 MiB). Longer runs keep
#: every ``thin``-th step (``thin = ceil(n_steps * chains * (dim + 2) /
#: MAX_STORED)``); the acceptance rate still counts every step.
MAX_STORED = 1 << 24

#: Sokal's window constant: the window is the smallest ``M >= SOKAL_C * tau(M)``
#: (Sokal recommends 4-10; 5 as in emcee).
SOKAL_C = 5.0

#: Default number of bootstrap candidates (pbrt-v4's MLT uses 100 000).
N_BOOTSTRAP = 100_000
#: Bootstrap candidates evaluated per call of the target (bounds the memory of
#: what ``f`` or the path tracer allocates for them).
BOOTSTRAP_CHUNK = 1 << 16
#: Float64 numbers alive per chain and state dimension during a step (state,
#: proposal, the Gaussian step, the large-step points and ``np.where``'s copy),
#: rounded up.
WORDS_PER_CHAIN_DIM = 8


# ---------------------------------------------------------------------------
# Statistics of correlated series

def _series(x, name="x") -> np.ndarray:
    x = as_array(x, name)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2 or x.shape[0] < 2 or x.shape[1] < 1:
        raise ValueError(f"{name} must have shape (n_steps,) or (n_steps, chains) with n_steps >= 2; "
                         f"got shape {x.shape}")
    return x


def _autocorrelation(x: np.ndarray) -> np.ndarray:
    """Normalised autocorrelation ``rho(t)``, t = 0..n-1, averaged over chains.

    Autocovariances of each chain about its own mean, by FFT (zero-padded to
    avoid wrap-around), averaged over chains and divided by the lag-0 value.
    Returns None for a constant series.
    """
    n = x.shape[0]
    d = x - x.mean(axis=0)
    size = 1 << int(2 * n - 1).bit_length()
    spec = np.fft.rfft(d, n=size, axis=0)
    acov = np.fft.irfft(spec * np.conj(spec), n=size, axis=0)[:n].mean(axis=1)
    if not acov[0] > 0.0:
        return None
    return acov / acov[0]


def integrated_time(x, *, c: float = SOKAL_C):
    """Integrated autocorrelation time of a chain by Sokal's adaptive window.

    Parameters
    ----------
    x : array_like, shape (n_steps,) or (n_steps, chains)
        A scalar observable along one or several chains (columns).
    c : float
        Window constant (Sokal: 4-10).

    Returns
    -------
    tau : float
        ``tau = 1 + 2 sum_{t=1}^{M} rho(t)``, in steps, ``>= 1`` is not
        enforced (anti-correlated chains give ``tau < 1``); a constant series
        gives ``tau = n_steps`` (nothing can be said: one effective sample
        per chain).
    window : int
        ``M``, the smallest lag with ``M >= c * tau(M)``; ``n_steps - 1``
        when no lag qualifies (the chain is too short for its ``tau``: the
        value is then a lower bound).

    Notes
    -----
    The variance of the mean of ``N`` correlated samples is
    ``Var(x) tau / N``: ``N / tau`` is the effective sample size. Summing
    ``rho`` over all lags has a variance that does not shrink with ``N``;
    the window cuts the sum where the noise starts to dominate, with bias
    ``O(exp(-M / tau))`` (Sokal 1997, section 3).
    """
    x = _series(x)
    c = check_positive(c, "c")
    n = x.shape[0]
    rho = _autocorrelation(x)
    if rho is None:
        return float(n), 0
    taus = 2.0 * np.cumsum(rho) - 1.0          # taus[M] = 1 + 2 sum_{t=1}^{M} rho(t)
    ok = np.flatnonzero(np.arange(n) >= c * taus)
    m = int(ok[0]) if ok.size else n - 1
    return float(taus[m]), m


def batch_means_time(x, *, batches: int = 32) -> float:
    """Integrated autocorrelation time by batch means.

    Each chain is cut into ``batches`` batches of ``m = n_steps // batches``
    steps; ``tau = m Var(batch means) / Var(x)``, which tends to the
    integrated time when ``m >> tau``. A constant series gives ``n_steps``.
    """
    x = _series(x)
    batches = check_count(batches, "batches")
    n = x.shape[0]
    m = n // batches
    if m < 1:
        raise ValueError(f"batches must be <= n_steps ({n}); got {batches}")
    means = x[: m * batches].reshape(batches, m, -1).mean(axis=1)
    var = x.var(ddof=1)
    if not var > 0.0:
        return float(n)
    return float(m * means.var(ddof=1) / var)


def correlated_estimate(x, *, error: str = "sokal", batches: int = 32) -> Estimate:
    """The mean of a correlated series as an :class:`~mcvar.estimators.Estimate`.

    Parameters
    ----------
    x : array_like, shape (n_steps,) or (n_steps, chains)
        Values of the observable along the chains.
    error : {'sokal', 'batch', 'naive'}
        The error model:

        * ``'sokal'``: ``stderr = s / sqrt(ESS)``, ``ESS = N / tau`` with
          ``tau`` from :func:`integrated_time`. Returned as
          ``Estimate(mean, s^2 tau, N)`` whose ``variance`` is the
          per-sample variance an iid estimator would need for the same error
          (``method='iid'``, the only method :class:`Estimate` has for it;
          ``dof = N - 1`` is then optimistic for tiny ESS).
        * ``'batch'``: batch means; each chain cut into ``batches`` batches,
          the ``R = chains * batches`` batch means treated as replicates
          (:meth:`Estimate.from_replicates`, Student-t with ``R - 1`` dof).
        * ``'naive'``: :meth:`Estimate.from_samples` on all values as if
          they were independent; under-covers whenever ``tau > 1``. For
          comparison only.
    batches : int
        Batches per chain for ``'batch'``.
    """
    x = _series(x)
    check_choice(error, "error", ("sokal", "batch", "naive"))
    n = x.size
    if error == "naive":
        return Estimate.from_samples(x.ravel())
    if error == "batch":
        batches = check_count(batches, "batches")
        m = x.shape[0] // batches
        if m < 1:
            raise ValueError(f"batches must be <= n_steps ({x.shape[0]}); got {batches}")
        means = x[: m * batches].reshape(batches, m, -1).mean(axis=1).ravel()
        return Estimate.from_replicates(means, m)
    tau, _ = integrated_time(x)
    var = x.var(ddof=1) * max(tau, 0.0)
    return Estimate(float(x.mean()), float(var), n)


def tv_distance(p, q) -> float:
    """Total-variation distance ``(1/2) sum |p/sum p - q/sum q|`` of two histograms.

    ``p`` and ``q`` are non-negative arrays of the same shape (e.g. a visit
    histogram and an image), each normalised to sum 1 first. 0: identical
    distributions; 1: disjoint supports.
    """
    p = as_array(p, "p", nonnegative=True)
    q = as_array(q, "q", nonnegative=True)
    if p.shape != q.shape:
        raise ValueError(f"p and q must have the same shape; got {p.shape} and {q.shape}")
    sp, sq = p.sum(), q.sum()
    if not (sp > 0 and sq > 0):
        raise ValueError("p and q must each have a positive sum")
    return float(0.5 * np.abs(p / sp - q / sq).sum())


# ---------------------------------------------------------------------------
# The chain

@dataclass(frozen=True, eq=False)
class Chain:
    """The result of :func:`metropolis` or :func:`image_walk`.

    Attributes
    ----------
    samples : ndarray, shape (n_kept, chains, dim)
        The chain states after each kept step (``n_kept = ceil(n_steps /
        thin)``; step ``k * thin`` is kept), float64 in [0, 1).
    values : ndarray, shape (n_kept, chains)
        ``f`` at those states (> 0).
    accepted : ndarray of bool, shape (n_kept, chains)
        Whether the proposal of that step was accepted.
    acceptance_rate : float
        Accepted proposals over all ``n_steps * chains`` proposals (every
        step counted, thinned or not).
    b : Estimate
        The bootstrap estimate of ``b = integral of f`` over ``[0, 1)^dim``
        (mean of ``f`` at the iid uniform candidates) and its standard error.
    thin : int
        Stride between kept steps (1: all kept; see :data:`MAX_STORED`).
    n_steps : int
        Steps done per chain (fewer than asked if Ctrl-C stopped the walk:
        the finished steps are kept).
    histogram : ndarray or None
        :func:`image_walk` only: the splatted visit density, shape
        ``(H, W)``, summing to 1.
    splat : str or None
        :func:`image_walk` only: ``'plain'`` or ``'expected'``.
    tau : ndarray, shape (dim,)
        Integrated autocorrelation time of each coordinate (Sokal's window,
        :func:`integrated_time`), in kept steps.
    ess : float
        Effective sample size ``n_kept * chains / max(tau)``.

    Notes
    -----
    The chains start from the bootstrap (already distributed as ``f / b``
    up to the resampling of a finite candidate set), so no burn-in is
    discarded. Statistics pool the chains: autocovariances are averaged over
    chains, each about its own mean.
    """

    samples: np.ndarray
    values: np.ndarray
    accepted: np.ndarray
    acceptance_rate: float
    b: Estimate
    thin: int
    n_steps: int
    histogram: np.ndarray | None = None
    splat: str | None = None

    @property
    def chains(self) -> int:
        return self.samples.shape[1]

    @property
    def dim(self) -> int:
        return self.samples.shape[2]

    @property
    def tau(self) -> np.ndarray:
        return np.array([integrated_time(self.samples[:, :, k])[0] for k in range(self.dim)])

    @property
    def ess(self) -> float:
        return float(self.samples.shape[0] * self.chains / max(float(np.max(self.tau)), 1e-300))

    def integrated_time(self, h: Callable | None = None) -> float:
        """Sokal's integrated time of the observable ``h(samples)`` (default: ``f``)."""
        return integrated_time(self._observe(h))[0]

    def estimate(self, h: Callable | None = None, *, error: str = "sokal", batches: int = 32) -> Estimate:
        """The estimate of ``E_{f/b}[h]`` with a standard error for correlated samples.

        Parameters
        ----------
        h : callable, optional
            ``h(points (m, dim)) -> (m,)``; default: ``f`` itself (the values).
        error, batches
            As in :func:`correlated_estimate`.

        Notes
        -----
        An integral ``I = integral of g`` follows as ``b E_{f/b}[g / f]``
        (Veach 1997, eq. 11.3): pass ``h = g / f`` and multiply by ``b``.
        """
        return correlated_estimate(self._observe(h), error=error, batches=batches)

    def _observe(self, h):
        if h is None:
            return self.values
        flat = self.samples.reshape(-1, self.dim)
        v = as_array(h(flat), "h(samples)")
        if v.shape != (flat.shape[0],):
            raise ValueError(f"h must return shape ({flat.shape[0]},); got {v.shape}")
        return v.reshape(self.samples.shape[:2])

    def __repr__(self) -> str:
        return (f"Chain(n_steps={self.n_steps}, chains={self.chains}, dim={self.dim}, thin={self.thin}, "
                f"acceptance_rate={self.acceptance_rate:.3f}, b={self.b.mean:.6g} +- {self.b.stderr:.2g})")


# ---------------------------------------------------------------------------
# The sampler

def _evaluate(f, x: np.ndarray) -> np.ndarray:
    """``f(x)`` checked: real numbers, shape (m,), finite, >= 0."""
    out = f(x)
    try:
        v = np.asarray(out)
    except (TypeError, ValueError):     # ragged sequences
        v = np.asarray(out, dtype=object)
    if v.dtype.kind not in "biuf":
        raise TypeError(f"f must return real numbers (a non-negative density, shape ({x.shape[0]},)); "
                        f"got {type(out).__name__} of dtype {v.dtype}")
    v = v.astype(np.float64)
    if v.shape != (x.shape[0],):
        raise ValueError(f"f must return shape ({x.shape[0]},) for points of shape {x.shape}; got {v.shape}")
    if not np.all(np.isfinite(v) & (v >= 0.0)):
        bad = v[~(np.isfinite(v) & (v >= 0.0))][0]
        raise ValueError(f"f must return finite, non-negative values (a target density up to scale); got {bad}")
    return v


def _evaluate_chunked(evaluate, cand: np.ndarray, chunk: int | None = None):
    """``evaluate`` over the rows of ``cand`` ``chunk`` (default
    :data:`BOOTSTRAP_CHUNK`) at a time: the values (n,) and the payloads
    stacked (or None); one call when they fit."""
    chunk = BOOTSTRAP_CHUNK if chunk is None else chunk
    n = cand.shape[0]
    if n <= chunk:
        return evaluate(cand)
    fc = np.empty(n)
    payload = None
    for a in range(0, n, chunk):
        f, p = evaluate(cand[a:a + chunk])
        fc[a:a + chunk] = f
        if p is not None:
            if payload is None:
                payload = np.empty((n,) + np.shape(p)[1:], dtype=np.asarray(p).dtype)
            payload[a:a + chunk] = p
    return fc, payload


def check_walk_budget(dim: int, chains: int, n_bootstrap: int | None, n_steps: int = 0, thin: int = 1, *,
                      payload_words: int = 0, dim_name: str = "dim", dim_value=None) -> None:
    """The memory a chain run needs, checked against the budget before anything
    is drawn (:func:`mcvar._validation.check_budget`): the bootstrap's
    candidates (``n_bootstrap`` rows of ``dim`` numbers, their values and
    payloads, all kept for the resampling), a step's arrays
    (:data:`WORDS_PER_CHAIN_DIM` numbers per chain and dimension) and the
    kept states (every ``thin``-th of ``n_steps`` steps of ``chains`` states).
    One chain's state is checked first, blaming ``dim_name`` (``'dim'``, or
    PSSMLT's ``'state_depth'``); ``n_bootstrap=None`` skips the bootstrap."""
    per_chain = 8.0 * (WORDS_PER_CHAIN_DIM * dim + 4 + payload_words)
    check_budget(dim_name, dim if dim_value is None else dim_value, per_chain,
                 what=f"one chain's step in {dim} dimensions")
    if n_bootstrap is None:
        n_bootstrap = 0
    per_candidate = 8.0 * (dim + 1 + payload_words)
    check_budget("n_bootstrap", n_bootstrap, n_bootstrap * per_candidate, per_unit=per_candidate,
                 what=f"{n_bootstrap} bootstrap candidates of {dim} numbers, kept for resampling")
    dim_label = dim if dim_value is None else dim_value
    check_budget(f"chains={chains!r} with {dim_name}={dim_label!r}", None, chains * per_chain, per_unit=per_chain,
                 unit_name="chains", what=f"a step of {chains} chains in {dim} dimensions")
    n_kept = -(-n_steps // thin)
    check_budget("thin", thin, n_kept * 8.0 * chains * (dim + 2),
                 what=f"{n_kept} kept steps of {chains} chains in {dim} dimensions; a larger thin keeps fewer")


def _bootstrap(evaluate, dim: int, chains: int, n_bootstrap: int, rng):
    """Independent uniform candidates, ``b`` from their mean, chains resampled ``∝ f``."""
    cand = rng.random((n_bootstrap, dim))
    fc, payload = _evaluate_chunked(evaluate, cand)
    total = fc.sum()
    if not total > 0.0:
        raise ValueError(f"f is zero at all {n_bootstrap} bootstrap candidates: cannot start the chains "
                         "(raise n_bootstrap, or f has (almost) no support)")
    pick = rng.choice(n_bootstrap, size=chains, p=fc / total)
    return cand[pick], fc[pick], (None if payload is None else payload[pick]), Estimate.from_samples(fc)


def _check_walk(dim, n_steps, chains, sigma, p_large, n_bootstrap):
    dim = check_count(dim, "dim")
    n_steps = check_count(n_steps, "n_steps")
    chains = check_count(chains, "chains")
    sigma = check_positive(sigma, "sigma")
    p_large = check_probability(p_large, "p_large")
    n_bootstrap = check_count(n_bootstrap, "n_bootstrap")
    return dim, n_steps, chains, sigma, p_large, n_bootstrap


def _mutate(x: np.ndarray, sigma: float, p_large: float, rng) -> np.ndarray:
    """Kelemen's mutation: Gaussian step wrapped on the torus, or a uniform large step."""
    y = x + rng.normal(0.0, sigma, size=x.shape)
    y -= np.floor(y)
    if p_large > 0.0:
        large = rng.random(x.shape[0]) < p_large
        k = int(large.sum())
        if k:
            y[large] = rng.random((k, x.shape[1]))
    np.minimum(y, np.nextafter(1.0, 0.0), out=y)   # floor(y) may round 1 - 1e-17 up to 1
    return y


def _walk(evaluate, start, n_steps, mutation, rng, visit=None, thin=1):
    """The Metropolis loop shared by :func:`metropolis`, :func:`image_walk` and PSSMLT.

    ``start = (x, fx, payload)``: the chains' first states, their values and
    payloads (or None); ``mutation = (sigma, p_large)``: Kelemen's mutation.
    ``evaluate(points) -> (f, payload or None)``; ``visit(x, fx, px, y, fy,
    py, a, acc)`` is called at every step with the current state, the
    proposal, the acceptance probability and the accept flags (before the
    move), for splatting.
    Returns the kept states, values, acceptance flags, the acceptance count
    and the number of steps done (fewer than ``n_steps`` after Ctrl-C, which
    keeps the finished steps).
    """
    x, fx, payload = start
    sigma, p_large = mutation
    chains, dim = x.shape
    n_kept = -(-n_steps // thin)
    samples = np.empty((n_kept, chains, dim))
    values = np.empty((n_kept, chains))
    accepted = np.empty((n_kept, chains), dtype=bool)
    n_acc = 0
    done = 0
    try:
        for step in range(n_steps):
            y = _mutate(x, sigma, p_large, rng)
            fy, py = evaluate(y)
            a = np.minimum(1.0, fy / fx)               # fx > 0: chains only move to f > 0
            acc = rng.random(chains) < a
            if visit is not None:
                visit(x, fx, payload, y, fy, py, a, acc)
            x = np.where(acc[:, None], y, x)
            fx = np.where(acc, fy, fx)
            if payload is not None:
                payload = np.where(acc.reshape((-1,) + (1,) * (payload.ndim - 1)), py, payload)
            n_acc += int(acc.sum())
            if step % thin == 0:
                k = step // thin
                samples[k], values[k], accepted[k] = x, fx, acc
            done = step + 1
    except KeyboardInterrupt:
        if done == 0:
            raise
        # Ctrl-C keeps the finished steps (a splat in progress is at most one step off)
    kept = -(-done // thin)
    return samples[:kept], values[:kept], accepted[:kept], n_acc, done


def _stride(n_steps, chains, dim, thin):
    if thin is None:
        return max(1, math.ceil(n_steps * chains * (dim + 2) / MAX_STORED))
    return check_count(thin, "thin")


@dataclass(frozen=True)
class WalkSettings:
    """The chains of a Metropolis walk: how many, Kelemen's mutation (``sigma``, ``p_large``),
    the bootstrap size and the thinning (None: chosen to bound memory). The keywords of
    :func:`metropolis` (these defaults) and :func:`image_walk` (``chains=1, sigma=0.02``)."""

    chains: int = 64
    sigma: float = 0.01
    p_large: float = 0.1
    n_bootstrap: int = N_BOOTSTRAP
    thin: int | None = None


#: :func:`image_walk`'s defaults: one chain, larger small steps.
IMAGE_WALK = WalkSettings(chains=1, sigma=0.02)


def metropolis(f: Callable, dim: int, n_steps: int, settings: WalkSettings | None = None, *, rng=None,
               **options) -> Chain:
    """Metropolis-Hastings sampling of ``f / b`` on ``[0, 1)^dim`` with Kelemen's mutations.

    Parameters
    ----------
    f : callable
        ``f(points (m, dim)) -> (m,)``: a finite, non-negative target
        density up to scale (vectorised: ``m`` is the number of chains, or of
        bootstrap candidates). Negative, NaN or infinite values raise.
    dim : int
        Dimension of the state.
    n_steps : int
        Mutations per chain, ``>= 1``.
    settings : WalkSettings, optional
        ``chains``, ``sigma``, ``p_large``, ``n_bootstrap`` and ``thin`` as
        one record; those keywords replace its fields.
    rng : None, int, SeedSequence or Generator

    Other Parameters
    ----------------
    chains : int
        Independent chains run at once (vectorised).
    sigma : float
        Standard deviation of the small step in units of the domain (the
        unit cube), per coordinate; the step wraps around the torus.
        Default 0.01 as pbrt-v4's ``sigma``.
    p_large : float
        Probability, per step, of a large step: a fresh uniform point.
        ``p_large = 0`` is allowed and can make the chain non-ergodic in
        practice (it cannot cross regions where ``f = 0`` wider than a few
        ``sigma``).
    n_bootstrap : int
        Independent candidates of the bootstrap.
    thin : int, optional
        Keep every ``thin``-th step; default 1 unless the run would store
        more than :data:`MAX_STORED` numbers.

    Returns
    -------
    Chain

    Notes
    -----
    The slide's rule: from ``x`` propose ``y``; accept with probability
    ``a = min(1, f(y) / f(x))``, else stay (and count ``x`` again). Both
    mutations are symmetric (``T(x -> y) = T(y -> x)``: a wrapped Gaussian,
    a uniform point) and so is their mixture, so this ratio satisfies detailed
    balance for ``f / b`` (Kelemen et al. 2002, section 3; Veach 1997,
    section 11.2). The large step makes every open set reachable in one step
    (ergodicity).

    **Bootstrap** (Veach 1997, 11.3.3; pbrt-v4 13.4): ``n_bootstrap``
    uniform candidates ``u_i`` give ``b ≈ mean f(u_i)`` (an iid estimate,
    with its standard error in ``Chain.b``), and the chains' starting states
    are drawn from the candidates with probability ``f(u_i) / sum f``: an
    approximate draw from ``f / b``, so there is no start-up bias to burn
    off (exact as ``n_bootstrap -> inf``; the resampled starts are a
    sampling-importance-resampling draw).

    Examples
    --------
    >>> c = metropolis(lambda u: 1.0 + np.cos(2 * np.pi * u[:, 0]), 1, 2000, rng=1)
    >>> round(c.b.mean, 1)
    1.0
    """
    if not callable(f):
        raise TypeError(f"f must be callable; got {type(f).__name__}")
    opts = settings_with(WalkSettings, settings, options, "metropolis")
    dim, n_steps, chains, sigma, p_large, n_bootstrap = _check_walk(dim, n_steps, opts.chains, opts.sigma,
                                                                    opts.p_large, opts.n_bootstrap)
    thin = _stride(n_steps, chains, dim, opts.thin)
    check_walk_budget(dim, chains, n_bootstrap, n_steps, thin)
    rng = as_rng(rng)

    def evaluate(u):
        return _evaluate(f, u), None

    x, fx, _, b = _bootstrap(evaluate, dim, chains, n_bootstrap, rng)
    samples, values, accepted, n_acc, done = _walk(evaluate, (x, fx, None), n_steps, (sigma, p_large), rng,
                                                   thin=thin)
    return Chain(samples, values, accepted, n_acc / (done * chains), b, thin, done)


# ---------------------------------------------------------------------------
# The lecture's image walk

def _luminance(image) -> np.ndarray:
    img = as_array(image, "image", nonnegative=True)
    if img.ndim == 3 and img.shape[2] == 3:
        img = img @ np.asarray(LUMINANCE_WEIGHTS)
    elif img.ndim != 2:
        raise ValueError(f"image must have shape (H, W) or (H, W, 3); got {img.shape}")
    if not img.sum() > 0.0:
        raise ValueError("image must have a positive pixel (an all-black image is no density)")
    return img


def _pixel_index(u: np.ndarray, height: int, width: int) -> np.ndarray:
    col = np.minimum((u[:, 0] * width).astype(np.intp), width - 1)
    row = np.minimum((u[:, 1] * height).astype(np.intp), height - 1)
    return row * width + col


def image_walk(image, n_steps: int, settings: WalkSettings | None = None, *, rng=None, splat: str = "plain",
               **options) -> Chain:
    """The lecture's 'Sampling An Image': a Metropolis walk whose visits reproduce ``image``.

    Parameters
    ----------
    image : array_like, shape (H, W) or (H, W, 3)
        Non-negative, finite; an RGB image is reduced to its luminance
        ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` (linear values assumed).
    n_steps : int
        Steps per chain.
    splat : {'plain', 'expected'}
        How visits build ``Chain.histogram``:

        * ``'plain'``: each step adds 1 at the pixel of the state after the
          step (accepted proposal or repeated current state);
        * ``'expected'``: each step adds ``1 - a`` at the current state's
          pixel and ``a`` at the proposal's (Veach 1997, 11.3.2, 'expected
          values'; pbrt-v4's MLT film), the expectation of the plain splat
          over the accept/reject coin, so the same walk with less noise,
          and rejected proposals still inform the image.

    Other Parameters
    ----------------
    chains : int
        Chains at once (the lecture's walk is one chain).
    sigma, p_large, rng, n_bootstrap, thin
        As in :func:`metropolis`; ``sigma`` is in units of the image width
        (x) and height (y).

    Returns
    -------
    Chain
        ``samples[..., 0]`` is x (column, left to right) and
        ``samples[..., 1]`` is y (row, top to bottom), both in [0, 1);
        ``histogram`` is the normalised splatted density, shape (H, W),
        comparable with ``image / image.sum()`` by :func:`tv_distance`.

    Notes
    -----
    ``f(x, y)`` is the luminance of the nearest pixel: pixel column
    ``floor(x W)``, row ``floor(y H)``. Each pixel is a cell of area
    ``1 / (H W)``, so the stationary distribution gives each pixel the
    probability ``Y_pixel / sum Y``.
    """
    lum = _luminance(image)
    height, width = lum.shape
    check_choice(splat, "splat", ("plain", "expected"))
    opts = settings_with(WalkSettings, IMAGE_WALK if settings is None else settings, options, "image_walk")
    dim, n_steps, chains, sigma, p_large, n_bootstrap = _check_walk(2, n_steps, opts.chains, opts.sigma,
                                                                    opts.p_large, opts.n_bootstrap)
    thin = _stride(n_steps, chains, dim, opts.thin)
    check_walk_budget(dim, chains, n_bootstrap, n_steps, thin, payload_words=1)
    rng = as_rng(rng)
    flat = lum.ravel()

    def evaluate(u):
        pix = _pixel_index(u, height, width)
        return flat[pix], pix

    hist = np.zeros(height * width)
    n_pix = hist.size

    if splat == "expected":
        def visit(x, fx, px, y, fy, py, a, acc):
            hist[:] += np.bincount(px, weights=1.0 - a, minlength=n_pix)
            hist[:] += np.bincount(py, weights=a, minlength=n_pix)
    else:
        def visit(x, fx, px, y, fy, py, a, acc):
            hist[:] += np.bincount(np.where(acc, py, px), minlength=n_pix)

    x, fx, px, b = _bootstrap(evaluate, dim, chains, n_bootstrap, rng)
    samples, values, accepted, n_acc, done = _walk(evaluate, (x, fx, px), n_steps, (sigma, p_large), rng,
                                                   visit=visit, thin=thin)
    hist = hist.reshape(height, width) / hist.sum()
    return Chain(samples, values, accepted, n_acc / (done * chains), b, thin, done,
                 histogram=hist, splat=splat)
