"""Multiplexed Metropolis light transport: the ``mmlt`` method (kind ``chain``).

Hachisuka, Kaplanyan and Dachsbacher [1]_, in the structure of pbrt-v4's
``MLTIntegrator`` [2]_: a Markov chain on the random numbers of
*bidirectional* path tracing (:mod:`mcvar.integrators.bdpt`). A chain's
state holds three streams, as pbrt's:

* the **camera** stream: the film position over the whole image (2 numbers)
  and two numbers per scattering camera vertex;
* the **light** stream: the origin on the light (4 numbers) and two per
  scattering light vertex;
* the **connection** stream: one number that picks the strategy.

Each chain has a fixed depth ``d`` (segments, mcvar's convention: ``d =
s + t - 1``; pbrt's depth is ``d - 1``). The strategy ``(s, t)`` with ``s + t
= d + 1`` is picked uniformly from the ``d + 1`` there are, the subpaths of
``t`` camera and ``s`` light vertices are traced from the streams (no
Russian roulette: the state has a fixed size, so ``max_depth`` is finite),
and the target is that one strategy's MIS-weighted contribution times the
number of strategies, ``f_d(u) = (d + 1) Y(w_{s,t} C_{s,t}(u))``, whose
integral ``b_d`` is the mean luminance of the image's depth-``d`` part. The
multiplexing: a small step of the connection number changes the strategy,
and the chain spends its time on the strategies whose MIS-weighted
contribution is large, the ones that sample the path well.

Chains run **in lockstep**: every chain proposes, every proposal is traced in
one wavefront (a bounce iteration serves every chain whose path has that
vertex), every chain accepts or rejects at once; chains are processed
:data:`CHAIN_CHUNK` at a time to bound memory; on Lambertian scenes the
states are evaluated by the kernel of :mod:`mcvar.integrators.mmlt_lambertian`
(the same values, one vectorised pass over every strategy). One shared
**bootstrap** (``n_bootstrap`` uniform states stratified per pixel,
:func:`stratified_states`, each a BDPT sample joined in every strategy of
every depth, :func:`bootstrap_values`) estimates every ``b_d`` with its
standard error; chains are given depths in proportion to ``b_d`` (largest
remainders, at least one chain per lit depth) and start at bootstrap
candidates (state, strategy) of their depth drawn ``∝ f_d``
(sampling-importance resampling: no start-up bias to burn off). With
``direct_depth=k`` depths ``1 .. k`` are rendered by a stratified BDPT pass
instead and the chains run at the depths above (docs/mcmc.md, 'Direct
lighting apart').

References
----------
.. [1] T. Hachisuka, A. S. Kaplanyan, C. Dachsbacher, "Multiplexed
   Metropolis Light Transport", ACM Transactions on Graphics 33(4)
   (SIGGRAPH 2014).
.. [2] M. Pharr, W. Jakob, G. Humphreys, "Physically Based Rendering", 4th
   ed., MIT Press 2023, section 13.4 (``MLTIntegrator``, ``MLTSampler``).
.. [3] C. Kelemen, L. Szirmay-Kalos, G. Antal, F. Csonka, "A Simple and
   Robust Mutation Strategy for the Metropolis Light Transport Algorithm",
   Computer Graphics Forum 21(3), 2002.
.. [4] E. Veach, "Robust Monte Carlo Methods for Light Transport
   Simulation", PhD thesis, Stanford 1997, chapter 11.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_rng, check_bool, check_count, check_positive, check_probability, settings_with
from ..envmap import LUMINANCE_WEIGHTS
from ..mcmc import check_walk_budget, integrated_time
from ..scene import Scene
from ..tracer import Tracer
from .emitters import LightOrigins
from .film import BatchJob, BatchResult
from .light import CHUNK_PATHS, _Context, check_scene
from .mmlt_lambertian import Workspace, lambertian_scene
from .mmlt_states import KERNELS, _kernel, bootstrap_splats, bootstrap_values, evaluate_states, strategy_columns
from .registry import Method, register

__all__ = ["OPTIONS", "DEFAULT_MAX_DEPTH", "CHAIN_CHUNK", "BOOTSTRAP_CHUNK", "BOOTSTRAP_SHARE", "MIN_TAU_STEPS",
           "MmltSettings", "MmltFilm", "StateLayout", "mmlt_film", "stratified_states", "kelemen_mutate", "lockstep",
           "run_batch"]

#: The method's options and defaults: Kelemen's small step ``sigma`` (pbrt-v4:
#: 0.01), the large-step probability ``p_large`` (pbrt-v4: 0.3; here 0.03: the chains start
#: ``∝ f`` from the bootstrap, which does the large steps' work of spreading them, and on
#: cornell-door a large step is accepted 0.2-0.4 % of the time, so 0.3 spent 30 % of the
#: evaluations on almost nothing: 0.03 measured 1.06-1.35x lower MSE, docs/mcmc.md), the chains run
#: in lockstep, the bootstrap states per depth (None: see :func:`mmlt_film`),
#: whether the chains start from the bootstrap (False: start-up bias), the
#: evaluation kernel, and the depths rendered by BDPT instead of the chains
#: (``direct_depth``, 0: none) with that pass's samples per mutation.
OPTIONS = {"chains": 16384, "sigma": 0.01, "p_large": 0.03, "n_bootstrap": None, "bootstrap": True,
           "kernel": "auto", "direct_depth": 0, "direct_share": 1.0}

#: The depth (segments) a render with ``max_depth=None`` uses: the state has a
#: fixed size, so MMLT needs a finite depth (pbrt-v4's ``maxdepth`` 5 bounces
#: is 6 segments; 5 segments carry the cornell-door's light through the slit
#: and two bounces in the room).
DEFAULT_MAX_DEPTH = 5

#: Fewest bootstrap states by default (a small render still finds lit paths).
MIN_BOOTSTRAP = 1024

#: Bootstrap states per mutation by default (``n_bootstrap=None``; each state is one BDPT sample
#: that serves every depth: docs/mcmc.md, 'MMLT').
BOOTSTRAP_SHARE = 0.2

#: Steps per chain below which no autocorrelation time is reported (NaN):
#: Sokal's window needs chains longer than a few ``tau``.
MIN_TAU_STEPS = 16

#: Chains stepped at once (one wavefront); more are run chunk after chunk.
CHAIN_CHUNK = CHUNK_PATHS

#: Bootstrap states evaluated at once: each is joined in every strategy of every depth (20 at depth 5),
#: so a chunk holds 20x as many connections as states.
BOOTSTRAP_CHUNK = 8192

_LUM = np.asarray(LUMINANCE_WEIGHTS)


@dataclass(frozen=True)
class StateLayout:
    """Where the three streams lie in a state of ``max_depth`` segments.

    ``camera``: columns 0, 1 the film position over the whole image (x =
    column, y = row), then two per scattering camera vertex (``max_depth -
    1`` of them); ``light``: four for the origin, two per scattering light
    vertex (``max_depth - 2``); ``strategy``: the last column.
    """

    max_depth: int

    @property
    def camera_vertices(self) -> slice:
        return slice(2, 2 + 2 * max(self.max_depth - 1, 0))

    @property
    def light_origin(self) -> slice:
        a = self.camera_vertices.stop
        return slice(a, a + 4)

    @property
    def light_vertices(self) -> slice:
        a = self.light_origin.stop
        return slice(a, a + 2 * max(self.max_depth - 2, 0))

    @property
    def strategy(self) -> int:
        return self.light_vertices.stop

    @property
    def dim(self) -> int:
        return self.strategy + 1


def kelemen_mutate(x: np.ndarray, sigma: float, p_large: float, rng):
    """Kelemen's mutation of every chain: ``(y, large)``.

    A small step ``y = x + N(0, sigma^2 I)`` wrapped on the torus ``[0, 1)^dim``,
    or, for the chains of ``large`` (each with probability ``p_large``), a
    uniform state. Both are symmetric (``T(x -> y) = T(y -> x)``), so is the
    mixture. A large step's value ``f(y)`` is an iid sample of ``f`` under
    the uniform density: MMLT adds it to the bootstrap's estimate of ``b``
    (Kelemen et al. 2002, section 4).
    """
    # float32 normals (half the generator's time); their law is symmetric, so is the step
    y = rng.standard_normal(x.shape, dtype=np.float32)
    y *= np.float32(sigma)
    y = x + y
    y -= np.floor(y)
    large = rng.random(x.shape[0]) < p_large if p_large > 0.0 else np.zeros(x.shape[0], dtype=bool)
    k = int(large.sum())
    if k:
        y[large] = rng.random((k, x.shape[1]))
    np.minimum(y, np.nextafter(1.0, 0.0), out=y)   # floor(y) may round 1 - 1e-17 up to 1
    return y, large


def lockstep(evaluate, start, n_steps: int, mutation, rng, visit=None):
    """Metropolis-Hastings for all chains at once: ``n_steps`` steps of Kelemen's mutation.

    Every chain proposes (:func:`kelemen_mutate`: a Gaussian step of size
    ``sigma`` wrapped on the torus, or with probability ``p_large`` a uniform
    state), ``evaluate(y) -> (f, payload)`` traces all proposals together,
    and every chain accepts with ``a = min(1, f(y) / f(x))`` at once (the
    proposal is symmetric, so ``f`` is invariant: detailed balance).
    ``start = (x, fx, payload)``: the chains' states, their values and a
    tuple of per-chain payload arrays; ``mutation = (sigma, p_large)``.
    ``visit(px, py, a, fy, large)`` sees each step's current and proposed
    payloads, the acceptance probabilities (for expected-value splatting),
    the proposals' values and which were large steps. Returns the
    final states, their values, the values after every step ``(n_steps,
    chains)`` (for the autocorrelation time) and each chain's number of accepted moves.
    """
    x, fx, payload = start
    sigma, p_large = mutation
    chains = x.shape[0]
    values = np.empty((n_steps, chains))
    n_acc = np.zeros(chains, dtype=np.int64)
    for step in range(n_steps):
        y, large = kelemen_mutate(x, sigma, p_large, rng)
        fy, py = evaluate(y)
        with np.errstate(divide="ignore", invalid="ignore"):
            a = np.where(fx > 0.0, np.minimum(1.0, fy / fx), 1.0)
        acc = rng.random(chains) < a
        if visit is not None:
            visit(payload, py, a, fy, large)
        x = np.where(acc[:, None], y, x)
        fx = np.where(acc, fy, fx)
        payload = tuple(np.where(acc.reshape((-1,) + (1,) * (p.ndim - 1)), q, p) for p, q in zip(payload, py))
        values[step] = fx
        n_acc += acc
    return x, fx, values, n_acc


@dataclass(frozen=True)
class MmltSettings:
    """The settings of one MMLT run (:func:`mmlt_film`'s keywords; defaults :data:`OPTIONS`)."""

    max_depth: int = DEFAULT_MAX_DEPTH
    heuristic: str = "power"
    chains: int = OPTIONS["chains"]
    sigma: float = OPTIONS["sigma"]
    p_large: float = OPTIONS["p_large"]
    n_bootstrap: int | None = OPTIONS["n_bootstrap"]
    bootstrap: bool = OPTIONS["bootstrap"]
    kernel: str = OPTIONS["kernel"]
    direct_depth: int = OPTIONS["direct_depth"]
    direct_share: float = OPTIONS["direct_share"]


@dataclass(frozen=True)
class MmltFilm:
    """One MMLT run: ``image = sum / spp`` (the :class:`BatchResult` convention), and its diagnostics.

    Attributes
    ----------
    sum : ndarray, shape (n_pix, 3)
    spp : float
        Mutations per pixel done (``chains * n_steps / n_pix``).
    rays : int
        Rays traced, bootstrap included.
    b, b_stderr : ndarray, shape (max_depth,)
        Per depth ``d = 1 .. max_depth``: the bootstrap's ``b_d`` (mean
        luminance of the depth-``d`` image) and its standard error.
    chains : ndarray of int, shape (max_depth,)
        Chains per depth.
    acceptance_rate : float
        Over all chains and steps.
    acceptance : ndarray, shape (max_depth,)
        Per depth (NaN where no chain runs).
    acceptance_large, acceptance_small : ndarray, shape (max_depth,)
        Per depth, the mean acceptance probability ``min(1, f(y) / f(x))`` of the large steps
        (fresh uniform states) and of the small steps (NaN where none was proposed): how often a
        chain jumps elsewhere, and how often a perturbation keeps the path lit.
    tau, ess : ndarray, shape (max_depth,)
        Integrated autocorrelation time (steps) of ``f`` along the chains of
        each depth (:func:`mcvar.mcmc.integrated_time`, Sokal's window;
        window-limited, a lower bound, when chains are shorter than ~5 tau)
        and the effective sample size ``chains_d n_steps / tau_d``.
    n_steps : int
        Steps per chain.
    depth_sum, direct_sum : ndarray, shape (max_depth, n_pix, 3) and (n_pix, 3)
        ``sum`` split into the chains' part of each depth ``d = 1 .. max_depth`` (``b_d`` times the
        chains' splats; zero for ``d <= direct_depth``) and the direct pass's:
        ``depth_sum.sum(axis=0) + direct_sum == sum``. With ``b_d`` known exactly, ``depth_sum[d - 1] *
        b_true / b[d - 1]`` is the image with the bootstrap's scale error removed (docs/mcmc.md).
    """

    sum: np.ndarray
    spp: float
    rays: int
    b: np.ndarray
    b_stderr: np.ndarray
    chains: np.ndarray
    acceptance_rate: float
    acceptance: np.ndarray
    acceptance_large: np.ndarray
    acceptance_small: np.ndarray
    tau: np.ndarray
    ess: np.ndarray
    n_steps: int
    depth_sum: np.ndarray | None = None
    direct_sum: np.ndarray | None = None


def stratified_states(n: int, dim: int, res, rng) -> np.ndarray:
    """``n`` bootstrap states, each uniform on ``[0, 1)^dim``, stratified per pixel.

    State ``i`` lies in pixel ``perm(i mod n_pix)`` (every pixel gets ``n / n_pix`` states, to one),
    and inside its pixel each pair of columns ``(0, 1), (2, 3), ...`` (the film position, then a
    2D sample per vertex and the light origin's position and direction) is stratified on a ``g x g``
    grid, ``g = ceil(sqrt(k))`` for ``k`` states per pixel: the pixel's states take ``k`` distinct
    cells drawn at random, jittered, independently per pair (padded 2D stratification, Kollig and
    Keller 2002); a last single column (the strategy number) is stratified in ``k`` strata per
    pixel. Each state is marginally uniform (every cell is equally likely), so ``mean f`` stays an
    unbiased estimate of ``b`` and resampling ``∝ f`` still starts the chains near ``f / b``; the
    variance of ``b`` from *which pixel* a state lands in is gone (on the door scene the slit's
    pixels are 1 % of the image and hold half its light: with iid states, ``b_2`` had a 15 %
    standard error from 16 384 states), and the light sample of the pixels lit directly through
    the slit is stratified (BDPT's ``b_2`` standard error 2.6x lower at 64 states per pixel).
    """
    width, height = res
    n_pix = width * height
    x = np.empty((n, dim))
    i = np.arange(n)
    pix = rng.permutation(n_pix)[i % n_pix]
    rnd = i // n_pix
    k = -(-n // n_pix)
    g = int(np.ceil(np.sqrt(k)))

    def cells(count):
        return np.argsort(rng.random((n_pix, count)), axis=1)[pix, rnd]

    for c in range(0, dim - 1, 2):
        cell = cells(g * g)
        x[:, c] = (cell % g + rng.random(n)) / g
        x[:, c + 1] = (cell // g + rng.random(n)) / g
    if dim % 2:
        x[:, dim - 1] = (cells(k) + rng.random(n)) / k
    x[:, 0] = (pix % width + x[:, 0]) / width                 # the film position over the whole image
    x[:, 1] = (pix // width + x[:, 1]) / height
    np.minimum(x, np.nextafter(1.0, 0.0), out=x)
    return x


def _starts(fb, film, res, per_depth, max_depth: int, bootstrap: bool, rng):
    """The bootstrap candidates the chains start at: ``(rows, depth, s)`` per chain.

    ``fb`` (n, n_strategies): :func:`bootstrap_values`. The chains of depth
    ``d`` pick among the ``n (d + 1)`` candidates (row, strategy) of that
    depth ``∝ f`` (sampling-importance resampling; ``bootstrap=False``:
    uniformly among the lit ones, for the start-up bias).
    """
    n = fb.shape[0]
    cols = strategy_columns(max_depth)
    order = np.argsort(_morton(film, res), kind="stable")
    rows, dep, strat = [], [], []
    for d in range(1, max_depth + 1):
        c = int(per_depth[d - 1])
        if c == 0:
            continue
        js = [j for j, (dd, _) in enumerate(cols) if dd == d]
        w = fb[:, js].ravel()                              # candidate r * (d + 1) + s
        if bootstrap:
            cand = _systematic(w, c, order, d + 1, rng)
        else:
            lit = np.flatnonzero(w > 0)
            cand = lit[rng.integers(0, lit.size, size=c)]
        rows.append(cand // (d + 1))
        strat.append(cand % (d + 1))
        dep.append(np.full(c, d))
    return np.concatenate(rows), np.concatenate(dep), np.concatenate(strat)


def _morton(film, res):
    """Each film position's pixel as its Morton (Z-order) code: nearby pixels, nearby codes."""
    width, height = res
    ix = np.minimum((film[:, 0] * width).astype(np.int64), width - 1)
    iy = np.minimum((film[:, 1] * height).astype(np.int64), height - 1)
    code = np.zeros(film.shape[0], dtype=np.int64)
    for bit in range(max(width, height).bit_length()):
        code |= ((ix >> bit) & 1) << (2 * bit) | ((iy >> bit) & 1) << (2 * bit + 1)
    return code


def _systematic(w, c: int, order, k: int, rng):
    """``c`` draws among candidates ``∝ w`` by systematic resampling (Kitagawa 1996) along ``order``.

    Candidate ``r k + s`` is row ``r``'s strategy ``s``; the rows are visited in ``order`` (by
    pixel, :func:`_morton`). One uniform offset places ``c`` equally spaced points on the cumulative
    weight: candidate ``i`` is drawn ``c w_i / sum(w)`` times in expectation (the property the
    bootstrap's unbiasedness needs, as for independent draws), but every run of the order holding a
    share ``q`` of the weight gets ``c q`` draws to within one, where independent draws scatter
    them by ``sqrt(c q (1 - q))``. On cornell-door the pixels seen through the slit hold about
    half of ``b_2`` and ``b_3`` and the chains rarely leave them, so that scatter was a scale
    error on those pixels like ``b``'s own (docs/mcmc.md).
    """
    idx = (order[:, None] * k + np.arange(k)).ravel()
    cum = np.cumsum(w[idx])
    at = (rng.random() + np.arange(c)) * (cum[-1] / c)
    return idx[np.minimum(np.searchsorted(cum, at, side="right"), idx.size - 1)]


def _allocate(b, chains):
    """Chains per depth ``∝ b`` (largest remainders), at least one per depth with ``b > 0``."""
    lit = b > 0.0
    n_lit = int(lit.sum())
    if chains < n_lit:
        raise ValueError(f"chains must be >= the number of depths that carry light ({n_lit}); got {chains}")
    share = np.where(lit, b / b.sum() * (chains - n_lit), 0.0)
    c = np.floor(share).astype(np.int64)
    rest = chains - n_lit - int(c.sum())
    c[np.argsort(-(share - c), kind="stable")[:rest]] += 1
    return c + lit


def _per_depth(values_d, acc_d, n_steps):
    """Acceptance rate and ``tau`` per depth from the chains' values (lists of (n_steps, chains_d)
    blocks per depth) and accepted moves; NaN where no chain ran, ``tau`` NaN below :data:`MIN_TAU_STEPS`."""
    depths = len(values_d)
    acceptance, tau = np.full(depths, np.nan), np.full(depths, np.nan)
    for d in range(depths):
        if values_d[d]:
            v = np.concatenate(values_d[d], axis=1)
            if n_steps >= MIN_TAU_STEPS:
                tau[d] = max(integrated_time(v)[0], 1.0)
            acceptance[d] = acc_d[d] / v.size
    return acceptance, tau


def _check(opts: MmltSettings):
    """Every setting's type and value (a ValueError or TypeError naming it)."""
    depth = check_count(opts.max_depth, "max_depth")
    chains = check_count(opts.chains, "chains")
    sigma = check_positive(opts.sigma, "sigma")
    if not sigma <= 1.0:
        raise ValueError(f"sigma must be in (0, 1] (a step on the unit torus); got {sigma}")
    p_large = check_probability(opts.p_large, "p_large")
    n_boot = None if opts.n_bootstrap is None else check_count(opts.n_bootstrap, "n_bootstrap")
    check_bool(opts.bootstrap, "bootstrap")
    if isinstance(opts.direct_depth, bool) or not isinstance(opts.direct_depth, (int, np.integer)):
        raise TypeError(f"direct_depth must be an int; got {type(opts.direct_depth).__name__} {opts.direct_depth!r}")
    if not 0 <= opts.direct_depth <= depth:
        raise ValueError(f"direct_depth must be an int in [0, max_depth={depth}]; got {opts.direct_depth!r}")
    check_positive(opts.direct_share, "direct_share")
    if opts.heuristic not in ("balance", "power"):
        raise ValueError(f"heuristic must be 'balance' or 'power'; got {opts.heuristic!r}")
    if not isinstance(opts.kernel, str) or opts.kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {KERNELS}; got {opts.kernel!r}")
    layout = StateLayout(depth)
    check_walk_budget(layout.dim, min(chains, CHAIN_CHUNK), n_boot, payload_words=len(strategy_columns(depth)),
                      dim_name="max_depth", dim_value=depth)
    return depth, chains, sigma, p_large, n_boot, layout


def _bootstrap(ctx, layout, n_boot: int, kernel: str, work, rng):
    """The bootstrap: ``n_boot`` states stratified per pixel, every strategy of every depth of each (one
    BDPT sample per state): ``(states, f (n_boot, n_strategies), b, b_stderr, rays)``."""
    depth_max = layout.max_depth
    cand = stratified_states(n_boot, layout.dim, ctx.res, rng)
    fb = np.empty((n_boot, len(strategy_columns(depth_max))))
    rays = 0
    for a in range(0, n_boot, BOOTSTRAP_CHUNK):
        fb[a:a + BOOTSTRAP_CHUNK], r = bootstrap_values(ctx, layout, cand[a:a + BOOTSTRAP_CHUNK], kernel, work)
        rays += r
    # BDPT's per-depth estimate of each bootstrap sample: sum_s w_{s,t} Y(C_{s,t}) = sum_s f_{d,s} / (d + 1)
    fd = np.stack([fb[:, [j for j, (dd, _) in enumerate(strategy_columns(depth_max)) if dd == d]].sum(axis=1)
                   / (d + 1) for d in range(1, depth_max + 1)])
    b = fd.mean(axis=1)
    b_se = fd.std(axis=1, ddof=1) / np.sqrt(n_boot) if n_boot > 1 else np.full(depth_max, np.inf)
    return cand, fb, b, b_se, rays


def _direct_image(ctx, n: int, depth: int, kernel: str, work, rng):
    """The image of depths ``1 .. depth`` by BDPT (the direct lighting by standard Monte Carlo and
    Metropolis for the rest, as in Veach and Guibas's MLT paper): ``n`` states of :class:`StateLayout` ``(depth)``
    stratified per pixel (:func:`stratified_states`), each one BDPT sample of subpaths of ``depth + 1``
    camera and ``depth`` light vertices joined in every strategy of those depths
    (:func:`~mcvar.integrators.mmlt_states.bootstrap_splats`). ``(image (n_pix, 3), rays)``; ``depth``
    0: a zero image."""
    width, height = ctx.res
    n_pix = width * height
    if depth == 0:
        return np.zeros((n_pix, 3)), 0
    layout = StateLayout(depth)
    x = stratified_states(n, layout.dim, ctx.res, rng)
    inv = 1.0 / np.array([d + 1 for d, _ in strategy_columns(depth)])
    image, rays = np.zeros((n_pix, 3)), 0
    for a in range(0, n, BOOTSTRAP_CHUNK):
        _, pix, rgb, r = bootstrap_splats(ctx, layout, x[a:a + BOOTSTRAP_CHUNK], kernel, work)
        rays += r
        ok = pix >= 0
        w = np.broadcast_to(inv, pix.shape)[ok]
        for c in range(3):
            image[:, c] += np.bincount(pix[ok], weights=w * rgb[..., c][ok], minlength=n_pix)
    return image * (n_pix / n), rays


def mmlt_film(scene: Scene, res, spp: float, *, rng=None, tracer=None, settings: MmltSettings | None = None,
              **options) -> MmltFilm:
    """Run MMLT for ``spp`` mutations per pixel on average.

    Parameters
    ----------
    scene : Scene
    res : (int, int)
        ``(W, H)``.
    spp : float
        Mutations per pixel: ``n_steps = ceil(spp W H / chains)`` per chain.
    settings : MmltSettings, optional
        The settings below as one record; keywords replace its fields.

    Other Parameters
    ----------------
    rng : None, int, SeedSequence or Generator
    tracer : Tracer, optional
    max_depth : int
        Segments of the longest path (finite: the state has ``StateLayout(max_depth).dim`` numbers).
    heuristic : {'power', 'balance'}
        BDPT's MIS weights.
    chains : int
        Chains run in lockstep (capped at the number of mutations).
    sigma : float
        Kelemen's small-step size on the unit torus, in (0, 1].
    p_large : float
        Probability of a large step (a fresh uniform state), in [0, 1].
    n_bootstrap : int or None
        Bootstrap states, each one BDPT sample joined in every strategy of every depth
        (:func:`bootstrap_values`); None: ``max(chains, BOOTSTRAP_SHARE N, 1024)`` for ``N``
        mutations. The bootstrap's error in ``b_d``, a scale on the whole depth-``d`` image,
        dominates the MSE on cornell-door (about 70 % of it at ``0.2 N``); a bootstrap sample costs
        about five mutations, and ``0.2 N`` balanced the two at equal time (docs/mcmc.md, 'MMLT').
    bootstrap : bool
        True: start the chains at bootstrap states resampled ``∝ f_d``; False: at uniformly
        drawn lit bootstrap states of their depth (start-up bias, for the measurement).
    direct_depth : int
        Depths ``1 .. direct_depth`` (2: emission seen and direct light) by BDPT (:func:`_direct_image`,
        stratified per pixel), the chains at the depths above only (0: every depth by the chains).
    direct_share : float
        BDPT samples of the direct part per mutation (``direct_depth > 0``).

    Notes
    -----
    **Estimator** (Veach 1997 eq. 11.7; Hachisuka et al. 2014 eq. 4): with
    ``N_d`` mutations at depth ``d`` (``chains_d n_steps``), pixel ``j`` is

        I_j = sum_d b_d / N_d * sum_k n_pix [(1 - a_k) 1_j(x_k) c(x_k) / f(x_k) + a_k 1_j(y_k) c(y_k) / f(y_k)]

    (expected-value splatting of the current state ``x_k`` and the proposal ``y_k``; ``c = rgb``,
    ``f = Y(c)``), so the image's mean luminance is ``sum_d b_d`` exactly. ``b_d`` comes from the
    bootstrap (an unbiased estimate, a global scale per depth).
    """
    opts = settings_with(MmltSettings, settings, options, "mmlt_film")
    depth_max, chains, sigma, p_large, n_boot, layout = _check(opts)
    rng = as_rng(rng)
    width, height = res
    n_pix = width * height
    if not (np.isfinite(spp) and spp > 0):
        raise ValueError(f"spp must be finite and > 0; got {spp}")
    n_mut = max(1, int(round(spp * n_pix)))
    chains = min(chains, n_mut)
    n_steps = -(-n_mut // chains)
    if n_boot is None:
        n_boot = max(chains, int(BOOTSTRAP_SHARE * n_mut), MIN_BOOTSTRAP)
        check_walk_budget(layout.dim, min(chains, CHAIN_CHUNK), n_boot, dim_name="max_depth",
                          payload_words=len(strategy_columns(depth_max)), dim_value=depth_max)
    tracer = tracer if tracer is not None else Tracer(scene)
    ctx = _Context(scene, tracer, LightOrigins(scene), res, opts.heuristic, True)
    rays = [0]

    _kernel(ctx, opts.kernel)                  # kernel='lambertian' on another scene: the error, before work
    work = Workspace()

    def evaluate(x, depth):
        f, pix, rgb, r = evaluate_states(ctx, layout, x, depth, opts.kernel, work)
        rays[0] += r
        return f, (pix, rgb)

    # the bootstrap: n_boot uniform camera and light numbers, every strategy of every depth of each
    # (one BDPT sample per state): b_d and the candidates the chains start at
    cand, fb, b, b_se, r = _bootstrap(ctx, layout, n_boot, opts.kernel, work, rng)
    rays[0] += r
    direct_depth = int(opts.direct_depth)
    direct, r = _direct_image(ctx, max(n_pix, round(opts.direct_share * n_mut)), direct_depth, opts.kernel, work, rng)
    rays[0] += r
    b_chain = np.where(np.arange(1, depth_max + 1) <= direct_depth, 0.0, b)     # the chains' depths only
    if not (b_chain.sum() > 0.0 or direct_depth):
        raise ValueError(f"none of the {n_boot} bootstrap paths carries light: cannot start the "
                         "chains (raise n_bootstrap)")
    if b_chain.sum() > 0.0:
        per_depth = _allocate(b_chain, chains)
        rows, dep, strat = _starts(fb, cand[:, :2], res, per_depth, depth_max, opts.bootstrap, rng)
    else:                                              # the direct part holds every lit depth: no chain
        per_depth, rows, dep, strat = np.zeros(depth_max, dtype=np.int64), *np.zeros((3, 0), dtype=np.intp)
    x0 = cand[rows]
    del cand, fb
    # the strategy number uniform in the candidate's stratum (below its top, so floor(u (d + 1)) = s)
    x0[:, layout.strategy] = (strat + rng.random(rows.size) * (1.0 - 1e-9)) / (dep + 1)
    # per depth: the splats' sum / N_d (times b_d at the end)
    inv_n = np.zeros(depth_max + 1)
    inv_n[1:] = np.divide(1.0, per_depth * n_steps, out=np.zeros(depth_max), where=per_depth > 0)
    films = np.zeros(((depth_max + 1) * n_pix, 3))

    def splat(payload, weight, dd):
        pix, rgb = payload
        lum = rgb @ _LUM
        ok = (pix >= 0) & (weight > 0.0)
        w = weight[ok] * inv_n[dd[ok]] / lum[ok]
        at = dd[ok] * n_pix + pix[ok]
        for c in range(3):
            films[:, c] += np.bincount(at, weights=w * rgb[ok, c], minlength=films.shape[0])

    n_acc = 0
    acc_d = np.zeros(depth_max)
    moves = np.zeros((2, 2, depth_max + 1))         # (large, small) x (proposals, sum of acceptance) per depth
    values_d = [[] for _ in range(depth_max)]
    for a in range(0, int(per_depth.sum()), CHAIN_CHUNK):
        dd = dep[a:a + CHAIN_CHUNK]
        xa = x0[a:a + CHAIN_CHUNK]
        fa, pa = evaluate(xa, dd)                  # the starts' values: the bootstrap's (tested)

        def visit(px, py, acc_prob, fy, large, dd=dd):
            splat(px, 1.0 - acc_prob, dd)
            splat(py, acc_prob, dd)
            for kind, sel in ((0, large), (1, ~large)):
                moves[kind, 0] += np.bincount(dd[sel], minlength=depth_max + 1)
                moves[kind, 1] += np.bincount(dd[sel], weights=acc_prob[sel], minlength=depth_max + 1)

        x, fx, values, n = lockstep(lambda y, dd=dd: evaluate(y, dd), (xa, fa, pa), n_steps, (sigma, p_large),
                                    rng, visit=visit)
        n_acc += int(n.sum())
        for d in range(depth_max):
            cols = np.flatnonzero(dd == d + 1)
            if cols.size:
                values_d[d].append(values[:, cols])
                acc_d[d] += n[cols].sum()
    acceptance, tau = _per_depth(values_d, acc_d, n_steps)
    depth_image = n_pix * films.reshape(depth_max + 1, n_pix, 3)[1:] * b_chain[:, None, None]
    image = depth_image.sum(axis=0) + direct
    done = int(per_depth.sum()) * n_steps or n_mut
    ess = per_depth * n_steps / tau
    with np.errstate(invalid="ignore", divide="ignore"):
        acc_kind = np.where(moves[:, 0, 1:] > 0, moves[:, 1, 1:] / moves[:, 0, 1:], np.nan)
    return MmltFilm(sum=image * (done / n_pix), spp=done / n_pix, rays=rays[0], b=b, b_stderr=b_se,
                    chains=per_depth, acceptance_rate=n_acc / done if per_depth.sum() else np.nan,
                    acceptance=acceptance,
                    acceptance_large=acc_kind[0], acceptance_small=acc_kind[1], tau=tau, ess=ess, n_steps=n_steps,
                    depth_sum=depth_image * (done / n_pix), direct_sum=direct * (done / n_pix))


def run_batch(job: BatchJob) -> BatchResult:
    """One independent MMLT run of ``job.spp`` mutations per pixel (the registry's ``run_batch``).

    ``job.u`` is not used (the chains' states are their own random numbers);
    ``max_depth=None`` is :data:`DEFAULT_MAX_DEPTH`. ``extra`` holds the
    diagnostics (spp-weighted over batches): ``b`` (total), ``b_depth``,
    ``b_stderr_depth``, ``chains_depth``, ``acceptance_rate``, ``tau_depth``, ``ess_depth``.
    """
    depth = DEFAULT_MAX_DEPTH if job.max_depth is None else job.max_depth
    run = mmlt_film(job.scene, job.res, job.spp, rng=job.rng, tracer=job.tracer, max_depth=depth,
                    heuristic=job.heuristic, **job.options)
    if not np.all(np.isfinite(run.sum)):
        raise FloatingPointError("mmlt produced non-finite radiance (a bug, please report)")
    w = job.spp
    extra = {"b": np.array([run.b.sum() * w]), "b_depth": run.b * w, "b_stderr_depth": run.b_stderr * w,
             "chains_depth": run.chains * w, "acceptance_rate": np.array([run.acceptance_rate * w]),
             "tau_depth": np.nan_to_num(run.tau) * w, "ess_depth": np.nan_to_num(run.ess) * w}
    return BatchResult(sum=run.sum * (job.spp / run.spp), sum_sq=None, rays=run.rays, extra=extra)


def _check_options(scene, options) -> None:
    """``check_scene`` of ``mmlt``: a light to start light subpaths from, and every option's type and value."""
    check_scene(scene, options, "mmlt")
    _check(MmltSettings(chains=options["chains"], sigma=options["sigma"], p_large=options["p_large"],
                        n_bootstrap=options["n_bootstrap"], bootstrap=options["bootstrap"], kernel=options["kernel"],
                        direct_depth=options["direct_depth"], direct_share=options["direct_share"]))
    if options["kernel"] == "lambertian" and not lambertian_scene(scene):
        raise ValueError(f"kernel='lambertian' needs Lambertian materials and area lights only; scene "
                         f"{scene.name!r} has other materials, a point light or an environment map")


register(Method("mmlt", "chain", run_batch,
                "multiplexed Metropolis light transport (Hachisuka 2014): lockstep chains on BDPT's camera, "
                "light and strategy numbers, one MIS-weighted strategy per state, a BDPT bootstrap for every depth "
                f"(max_depth=None: {DEFAULT_MAX_DEPTH})",
                options=OPTIONS, check_scene=_check_options, stream_dims=0))
