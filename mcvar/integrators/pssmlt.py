"""Primary-sample-space Metropolis light transport: the ``pssmlt`` method (kind ``chain``).

The lecture's 'Metropolis Light Transport' slide, in the form of Kelemen et
al. [1]_ and pbrt's MLT integrator [2]_: the Markov chain of
:mod:`mcvar.mcmc` runs on the *primary sample space*, the vector ``u`` of
uniform numbers the path tracer turns into one camera path
(:func:`mcvar.integrators.trace_camera_paths`), and its target is the
luminance of that path's contribution. Every step splats the current and the
proposed path onto the film (expected-value splatting); ``b``, the mean
luminance of the image estimated from the run's independent uniform states
(the bootstrap's and the large steps'), sets the scale. Up to
:data:`CHAIN_CHUNK` chains step in lockstep: one wavefront of paths per step.
Each batch of a render is an independent PSSMLT run (its own bootstrap and
chains), so the film's variance comes from independent batches.

Two ways to start the chains (``start``): ``'resample'`` (the default,
Kelemen / pbrt: chains start at bootstrap paths resampled ``∝ f`` and the
image is scaled by ``b``) and ``'weighted'`` (Veach and Guibas [4]_: the
bootstrap *is* path tracing over the film, stratified per pixel, and every
lit bootstrap path starts one chain of ``chain_length`` steps that carries
the weight ``f(x_0)``; no ``b``, exactly unbiased for any chain length).

State
-----
``u[0:2]``: the film position over the **whole image** (x = column left to
right, y = row top to bottom: the pixel and the offset inside it); then the
path's own stream columns (:mod:`mcvar.integrators.stream`: per vertex the
light sample, the BSDF sample, the Russian-roulette coin and the emitter
choice) for the first ``state_depth - 1`` vertices: ``stream_dim(state_depth)``
numbers in all (``state_depth = 6``: 32). Dimensions beyond the cap, read by
longer paths, are drawn *fresh* at every evaluation (see
:func:`pssmlt_film`, Notes, for why this is still a correct
Metropolis-Hastings chain).

References
----------
.. [1] C. Kelemen, L. Szirmay-Kalos, G. Antal, F. Csonka, "A Simple and
   Robust Mutation Strategy for the Metropolis Light Transport Algorithm",
   Computer Graphics Forum 21(3), 2002.
.. [2] M. Pharr, W. Jakob, G. Humphreys, "Physically Based Rendering",
   3rd ed. section 16.4, 4th ed. section 13.4 (``MLTIntegrator``).
.. [3] E. Veach, "Robust Monte Carlo Methods for Light Transport
   Simulation", PhD thesis, Stanford 1997, chapter 11.
.. [4] E. Veach, L. J. Guibas, "Metropolis Light Transport", SIGGRAPH 1997,
   section 5.1 (eliminating start-up bias: a start ``x_0 ~ p_0`` weighted by
   ``f(x_0) / p_0(x_0)``).
.. [5] D. Cline, J. Talbot, P. Egbert, "Energy Redistribution Path Tracing",
   SIGGRAPH 2005 (chains started at path-traced samples spread their energy
   over nearby paths).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .._validation import as_rng, check_bool, check_budget, check_choice, check_count, check_positive, check_probability, settings_with
from ..envmap import LUMINANCE_WEIGHTS
from ..mcmc import BOOTSTRAP_CHUNK, check_walk_budget
from ..scene import Scene
from ..tracer import Tracer
from .film import BatchJob, BatchResult
from .path import trace_camera_paths
from .registry import Method, register
from .settings import PathSettings
from .stream import CAMERA_DIMS, stream_dim

__all__ = ["CHAIN_CHUNK", "OPTIONS", "PssmltFilm", "PssmltSettings", "pssmlt_film", "state_dim", "run_batch"]

#: The method's options and defaults. ``sigma`` and ``p_large`` as pbrt-v4
#: (0.01, 0.3); ``chains``: 65 536 chains, one lockstep chunk
#: (:data:`CHAIN_CHUNK`), so a step traces as many paths per bounce as a
#: path-tracing batch (docs/mcmc.md, 'Many chains in lockstep', for the
#: chain-count trade); ``n_bootstrap=None``: ``max(4 * chains, mutations // 4)``
#: paths; ``state_depth``: path segments whose numbers are in the chain's state;
#: ``p_large=None``: :data:`P_LARGE` of the ``start``.
OPTIONS = {"chains": 1 << 16, "sigma": 0.01, "p_large": None, "n_bootstrap": None,
           "bootstrap": True, "splat": "expected", "state_depth": 6, "start": "resample", "chain_length": 8}

#: The ways a run starts its chains (:func:`pssmlt_film`, ``start``).
STARTS = ("resample", "weighted")

#: ``p_large`` when not given, per ``start``: pbrt-v4's 0.3 for resampled chains (their only way
#: between bright regions); 0 for weighted chains, whose fresh starts explore (measured on
#: cornell-door, chain_length 16: 1.43x path tracing's CPU efficiency at 0 against 0.82 at 0.3).
P_LARGE = {"resample": 0.3, "weighted": 0.0}

#: Bytes a chain keeps outside its chunk's step: its bootstrap pick and the
#: per-chain means of the diagnostics' observables.
BYTES_PER_CHAIN = 8 * 4

_LUM = np.asarray(LUMINANCE_WEIGHTS)

#: ``start='weighted'``: chains in flight before a round adds no new bootstrap states (it then
#: only steps the chains): a round's wavefront is at most this plus one round's new states.
MAX_CHAINS_IN_FLIGHT = 1 << 17

#: ``start='weighted'``: new bootstrap states per round, rounded down to whole scanline passes
#: (at least one; each round also steps every chain in flight, so a run ends with
#: ``chain_length`` rounds that step only the last chains).
WEIGHTED_ROUND = BOOTSTRAP_CHUNK

#: Chains stepped in lockstep at once: one wavefront of at most this many
#: paths per bounce (the path tracer's batch,
#: :data:`mcvar.integrators.allocation.PATHS_PER_BATCH`), so a
#: bounce iteration serves as many paths as it does for path tracing; more
#: chains run as further chunks of this size, one after the other (memory
#: bounded by the chunk, not by ``chains``).
CHAIN_CHUNK = 1 << 16


def _dot(a, b) -> float:
    """``a · b`` of two vectors without BLAS: OpenBLAS's ``ddot`` on 65 536 numbers took 4.9 ms of
    wall time here (its threads fight the other processes for the two cores) against 0.1 ms for
    ``(a * b).sum()``."""
    return float(np.multiply(a, b).sum())


def state_dim(state_depth: int, max_depth: int | None = None) -> int:
    """Numbers in the chain's state: ``stream_dim(min(state_depth, max_depth))``."""
    depth = check_count(state_depth, "state_depth")
    if max_depth is not None:
        depth = min(depth, max_depth)
    return max(CAMERA_DIMS, stream_dim(depth))


@dataclass(frozen=True)
class PssmltFilm:
    """One PSSMLT run: ``image = sum / spp`` (the :class:`BatchResult` convention), and its diagnostics.

    Attributes
    ----------
    sum : ndarray, shape (n_pix, 3)
        Splats, scaled so that ``sum / spp`` is the image.
    spp : float
        Mutations per pixel done (``chains * n_steps / n_pix``).
    rays : int
        Rays traced, bootstrap included.
    b, b_stderr : float
        The estimate of ``b = ∫ f``, the image's mean luminance, and its
        standard error: the mean of ``f`` over the ``n_b`` independent uniform
        states of the run (the bootstrap's and every large step's proposal,
        Kelemen 2002 section 4), ``s / sqrt(n_b)``.
    n_b : int
        Those states.
    acceptance_rate : float
        Accepted proposals over all proposals.
    interrupted : bool
        Ctrl-C stopped the chains early (``spp`` counts the finished steps).
    chains, n_steps : int
        Chains run (in chunks of :data:`CHAIN_CHUNK`) and steps per chain.
    n_bootstrap : int
        Bootstrap paths traced.
    tau : dict
        Integrated autocorrelation time of the run, in steps, per observable
        of the state after each step: ``'luminance'`` (``f``), ``'film_x'``,
        ``'film_y'`` (the film position); see :func:`pssmlt_film`, Notes.
        NaN where an observable is constant.
    ess : dict
        Effective sample size ``chains * n_steps / tau`` per observable.
    """

    sum: np.ndarray
    spp: float
    rays: int
    b: float
    b_stderr: float
    acceptance_rate: float
    interrupted: bool = False
    chains: int = 0
    n_steps: int = 0
    n_bootstrap: int = 0
    n_b: int = 0
    tau: dict = field(default_factory=dict)
    ess: dict = field(default_factory=dict)


class _PathTarget:
    """The chain's target on the state's columns: ``f`` = luminance of the camera path's RGB.

    ``self(yT)`` takes a wavefront of states ``(D, n)`` (C-contiguous, film
    position in rows 0-1) and returns ``(f (n,), pixel (n,), rgb / f (3, n))``
    (``rgb / f = 0`` where ``f = 0``); ``rays`` counts what it traced. The
    state's rows 0-1 are turned into the offset inside the pixel for the
    tracer and restored (no copy of the state: the tracer's sample stream
    reads the transposed view of ``yT`` as is).
    """

    def __init__(self, scene, res, tracer, settings: PathSettings, rng):
        self.scene, self.res, self.tracer, self.settings, self.rng = scene, res, tracer, settings, rng
        self.rays = 0

    def __call__(self, yT):
        width, height = self.res
        film = yT[:2].copy()
        col = np.minimum((film[0] * width).astype(np.intp), width - 1)
        row = np.minimum((film[1] * height).astype(np.intp), height - 1)
        try:
            yT[0] = film[0] * width - col                    # the offset inside the pixel
            yT[1] = film[1] * height - row
            pix = row * width + col
            radiance, rays = trace_camera_paths(self.scene, self.res, pix, yT.T, rng=self.rng,
                                                tracer=self.tracer, settings=self.settings, method="path")
        finally:
            yT[:2] = film
        self.rays += rays
        f = radiance @ _LUM
        rgbn = np.divide(radiance.T, f, out=np.zeros((3, f.shape[0])), where=f > 0)
        return f, pix, rgbn


def _path_function(scene: Scene, res, tracer: Tracer, max_depth, heuristic, rng, counter):
    """``evaluate(u (n, D)) -> (luminance (n,), payload (n, 4) = [pixel, r, g, b])``: the target
    on row-major states (what :func:`mcvar.mcmc._evaluate_chunked` calls), through :class:`_PathTarget`."""
    target = _PathTarget(scene, res, tracer, PathSettings(max_depth=max_depth, heuristic=heuristic), rng)

    def evaluate(u):
        before = target.rays
        f, pix, rgbn = target(np.ascontiguousarray(np.asarray(u, dtype=np.float64).T))
        counter[0] += target.rays - before
        payload = np.empty((f.shape[0], 4))
        payload[:, 0] = pix
        payload[:, 1:] = (rgbn * f).T
        return f, payload

    return evaluate


def _normals(shape, scale: float, rng) -> np.ndarray:
    """``scale`` times standard normals, float64 ``shape``, by Box-Muller from float32 uniforms
    (each pair ``r cos t, r sin t`` is two independent normals; a quarter the time of
    ``rng.standard_normal`` here, where the 32 numbers of 65 536 chains cost as much as
    tracing their paths)."""
    n = int(np.prod(shape))
    half = (n + 1) // 2
    u = rng.random((2, half), dtype=np.float32)
    r = np.log1p(-u[0])                       # u < 1: finite
    r *= -2.0
    np.sqrt(r, out=r)
    r *= np.float32(scale)
    angle = u[1]
    angle *= np.float32(2.0 * np.pi)
    out = np.empty(2 * half)
    np.multiply(r, np.cos(angle), out=out[:half])
    np.multiply(r, np.sin(angle), out=out[half:])
    return out[:n].reshape(shape)


def _mutate_soa(xT, sigma: float, p_large: float, rng):
    """Kelemen's mutation of states stored as columns ``(D, n)`` (:func:`mcvar.mcmc._mutate`'s
    rule): a Gaussian small step of ``sigma`` wrapped on the torus, or with probability
    ``p_large`` a uniform large step. Returns the proposals ``(D, n)`` and the large-step mask."""
    yT = _normals(xT.shape, sigma, rng)
    yT += xT
    yT -= np.floor(yT)
    large = rng.random(xT.shape[1]) < p_large
    idx = np.flatnonzero(large)
    if idx.size:
        yT[:, idx] = rng.random((xT.shape[0], idx.size))
    np.minimum(yT, np.nextafter(1.0, 0.0), out=yT)      # floor may round 1 - 1e-17 up to 1
    return yT, large


@dataclass(frozen=True, eq=False)
class _Proposal:
    """One lockstep step's proposals: states ``(D, m)``, their ``f``, pixel and ``rgb / f``, the
    large-step mask, the acceptance probabilities ``a = min(1, f(y) / f(x))`` and the coin's verdicts."""

    xT: np.ndarray
    f: np.ndarray
    pix: np.ndarray
    rgbn: np.ndarray
    large: np.ndarray
    a: np.ndarray
    accept: np.ndarray


class _Chains:
    """A chunk of chains stepped in lockstep: states ``xT`` (D, m), their ``f``, pixel and ``rgb / f``.

    :meth:`propose` mutates every chain (Kelemen), evaluates all proposals in
    one call of the target (one wavefront) and draws every accept/reject
    coin; :meth:`move` applies the verdicts in place. The target is any
    ``target(yT) -> (f, pixel, rgb / f)`` (the path tracer's
    :class:`_PathTarget`, or an analytic density in the tests).
    """

    def __init__(self, xT, f, pix, rgbn):
        self.xT, self.f, self.pix, self.rgbn = xT, f, pix, rgbn

    def propose(self, target, sigma: float, p_large: float, rng) -> _Proposal:
        yT, large = _mutate_soa(self.xT, sigma, p_large, rng)
        fy, py, ry = target(yT)
        a = np.minimum(1.0, fy / self.f)               # f > 0: chains only move to f > 0
        return _Proposal(yT, fy, py, ry, large, a, rng.random(fy.shape[0]) < a)

    def move(self, prop: _Proposal) -> None:
        acc = prop.accept
        np.copyto(self.xT, prop.xT, where=acc)
        np.copyto(self.f, prop.f, where=acc)
        np.copyto(self.pix, prop.pix, where=acc)
        np.copyto(self.rgbn, prop.rgbn, where=acc)


class _Splatter:
    """The film of one run, ``(3, n_pix)`` flattened: one ``np.bincount`` per step and splat kind."""

    def __init__(self, n_pix: int):
        self.n_pix = n_pix
        self.film = np.zeros(3 * n_pix)
        self._channel = (np.arange(3) * n_pix)[:, None]

    def add(self, pix, rgbn, weight) -> None:
        """Add ``weight * rgb / f`` at each path's pixel (``rgbn`` (3, n), ``weight`` (n,) or a scalar)."""
        self.add_into(self.film, pix, rgbn, weight)

    def add_into(self, out, pix, rgbn, weight) -> None:
        """:meth:`add` into ``out`` (a film of the same layout) instead of this one."""
        idx = pix + self._channel                              # (3, n)
        out += np.bincount(idx.ravel(), weights=(rgbn * weight).ravel(), minlength=self.film.size)

    def image_sum(self, b: float) -> np.ndarray:
        return (self.film.reshape(3, self.n_pix) * b).T.copy()


@dataclass(frozen=True)
class PssmltSettings:
    """The settings of one PSSMLT run (:func:`pssmlt_film`'s keywords; defaults :data:`OPTIONS`)."""

    max_depth: int | None = None
    heuristic: str = "power"
    chains: int = OPTIONS["chains"]
    sigma: float = OPTIONS["sigma"]
    p_large: float | None = OPTIONS["p_large"]
    n_bootstrap: int | None = OPTIONS["n_bootstrap"]
    bootstrap: bool = OPTIONS["bootstrap"]
    splat: str = OPTIONS["splat"]
    state_depth: int = OPTIONS["state_depth"]
    start: str = OPTIONS["start"]
    chain_length: int = OPTIONS["chain_length"]


class _Moments:
    """Per-chain sums of observables along the chains, for the run's autocorrelation time."""

    def __init__(self):
        self.chain_means = {}          # name -> list of (chunk,) arrays
        self.sums = {}                 # name -> [sum, sum of squares, count]

    def add_chunk(self, name, per_chain_sum, per_chain_sq, n_steps) -> None:
        self.chain_means.setdefault(name, []).append(per_chain_sum / n_steps)
        s = self.sums.setdefault(name, [0.0, 0.0, 0])
        s[0] += float(per_chain_sum.sum())
        s[1] += float(per_chain_sq.sum())
        s[2] += per_chain_sum.shape[0] * n_steps

    def tau(self, n_steps: int) -> dict:
        """``tau = n_steps Var(chain means) / Var(h)`` per observable (NaN if ``h`` is constant)."""
        out = {}
        for name, parts in self.chain_means.items():
            means = np.concatenate(parts)
            total, sq, n = self.sums[name]
            var = sq / n - (total / n) ** 2
            ok = means.size > 1 and var > 1e-300
            out[name] = float(n_steps * means.var(ddof=1) / var) if ok else float("nan")
        return out
class _Run:
    """What one PSSMLT run accumulates over its chunks of chains: the film, the diagnostics'
    moments, the acceptance count, and the sums that estimate ``b`` (the mean of ``f`` over
    iid uniform states: the bootstrap's ``f`` values, then every large step's proposal)."""

    def __init__(self, n_pix: int, expected: bool, f_bootstrap):
        self.film = _Splatter(n_pix)
        self.moments = _Moments()
        self.expected = expected
        self.n_acc = self.done = 0
        self._b = [float(f_bootstrap.sum()), _dot(f_bootstrap, f_bootstrap), f_bootstrap.shape[0]]

    def chunk(self, chains: "_Chains", n_steps: int, target, mutation, rng) -> None:
        """Step one chunk of chains ``n_steps`` times in lockstep, splatting every step."""
        sigma, p_large = mutation
        film = self.film
        m = chains.f.shape[0]
        sums = {name: np.zeros(m) for name in ("luminance", "film_x", "film_y")}
        squares = {name: np.zeros(m) for name in sums}
        for _ in range(n_steps):
            prop = chains.propose(target, sigma, p_large, rng)
            f_large = prop.f[prop.large]
            self._b[0] += float(f_large.sum())
            self._b[1] += _dot(f_large, f_large)
            self._b[2] += f_large.size
            if self.expected:
                film.add(chains.pix, chains.rgbn, 1.0 - prop.a)
                film.add(prop.pix, prop.rgbn, prop.a)
            chains.move(prop)
            if not self.expected:
                film.add(chains.pix, chains.rgbn, 1.0)
            for name, h in (("luminance", chains.f), ("film_x", chains.xT[0]), ("film_y", chains.xT[1])):
                sums[name] += h
                squares[name] += h * h
            self.n_acc += int(prop.accept.sum())
            self.done += m
        for name in sums:
            self.moments.add_chunk(name, sums[name], squares[name], n_steps)

    def b(self):
        """``(b, its standard error, the number of iid states)``."""
        total, sq, n = self._b
        b = total / n
        return b, float(np.sqrt(max(sq / n - b * b, 0.0) / max(n - 1, 1))), n


def _bootstrap(target, dim, chains, n_bootstrap, starts: bool, rng):
    """One shared bootstrap: ``n_bootstrap`` uniform states, ``b``'s first terms, and the
    chains' starting candidates (resampled ``∝ f``, or uniformly among the lit ones).

    Returns ``(candidates (dim, n_bootstrap), f, pixel, rgb / f, pick (chains,))``: the
    candidates as columns, the layout of the chains' states (a chunk's starts are one gather).
    """
    cand = rng.random((dim, n_bootstrap))
    fc = np.empty(n_bootstrap)
    pc = np.empty(n_bootstrap, dtype=np.intp)
    rc = np.empty((3, n_bootstrap))
    for a in range(0, n_bootstrap, BOOTSTRAP_CHUNK):
        z = slice(a, a + BOOTSTRAP_CHUNK)
        part = cand if n_bootstrap <= BOOTSTRAP_CHUNK else np.ascontiguousarray(cand[:, z])
        fc[z], pc[z], rc[:, z] = target(part)
    total = fc.sum()
    if not total > 0.0:
        raise ValueError(f"none of the {n_bootstrap} bootstrap paths carries light: cannot start the "
                         "chains (raise n_bootstrap)")
    if starts:
        pick = rng.choice(n_bootstrap, size=chains, p=fc / total)
    else:
        lit = np.flatnonzero(fc > 0)
        pick = lit[rng.integers(0, lit.size, size=chains)]
    return cand, fc, pc, rc, pick


class _WeightedMoments:
    """Per-chain sums of an observable along weighted chains, for their autocorrelation time.

    Chains started from uniform states carry the weight ``w = f(x_0)``: the stationary mean
    of ``h`` is ``Σ w m / Σ w`` (``m`` a chain's mean of ``h``), and ``tau = T var_w(m) /
    var_w(h)`` with weighted variances (the batch-means estimate of :class:`_Moments`).
    """

    def __init__(self):
        self.parts = {}                # name -> [Σ w m, Σ w m², Σ w Σ_t h, Σ w Σ_t h², Σ w, Σ w², n_chains]

    def add(self, name, w, per_chain_sum, per_chain_sq, n_states) -> None:
        m = per_chain_sum / n_states
        s = self.parts.setdefault(name, [0.0] * 7)
        for i, v in enumerate((_dot(w, m), _dot(w, m * m), _dot(w, per_chain_sum), _dot(w, per_chain_sq), w.sum(),
                                 _dot(w, w))):
            s[i] += float(v)
        s[6] += w.shape[0]

    def tau(self, n_states: int) -> dict:
        """Per observable (NaN for all three when no chain has finished: no light found)."""
        out = {name: float("nan") for name in _WeightedRun._NAMES}
        for name, (wm, wm2, wh, wh2, sw, sw2, n) in self.parts.items():
            ok = n > 1 and sw > 0
            mu = wm / sw if ok else 0.0
            var_h = wh2 / (sw * n_states) - (wh / (sw * n_states)) ** 2 if ok else 0.0
            var_m = wm2 / sw - mu * mu if ok else 0.0
            ok = ok and var_h > 1e-300
            out[name] = float(n_states * max(var_m, 0.0) / var_h) if ok else float("nan")
        return out


class _WeightedRun:
    """A run with ``start='weighted'``: every bootstrap path that carries light starts one chain
    of ``T`` steps, weighted by its ``f`` (Veach and Guibas 1997 [4]_, section 5.1; Cline et al. 2005 [5]_).

    **One wavefront per round.** Each round traces a bootstrap chunk's new uniform states and
    the proposals of every chain in flight *in one call of the target*, so the chains' steps
    ride in the bootstrap's wavefront (on cornell-door about 1.4 % of the paths carry light:
    the chains alone would be wavefronts of a few thousand paths, each bounce iteration paying
    NumPy's per-call cost for few paths). The states born in a round (a *cohort*, lit or not)
    are in flight for the next ``T`` rounds (tail rounds after the bootstrap), then retire.

    **Normalisation.** Every term ``f(x_0) h(x_t)`` (the start at ``t = 0``, each step's
    expected-value splat) has expectation ``∫ f h`` whatever ``t``; ``D`` counts the terms of
    every bootstrap state, lit or not, once per round it is in flight, and the image is
    ``n_pix / D Σ splats``: ``D = n_b (T + 1)`` at the end. An interrupted run counts the rounds
    it finished; as every round's new states are whole scanline passes (one state per pixel
    each), every pixel's strata are equally represented in each cohort, and the schedule does
    not depend on the paths, so that estimate is unbiased too.
    """

    _NAMES = ("luminance", "film_x", "film_y")
    _KEYS = ("x", "f", "pix", "rgbn", "w") + tuple("sum_" + n for n in _NAMES) + tuple("sq_" + n for n in _NAMES)

    def __init__(self, n_pix: int, n_steps: int, target, mutation, rng):
        self.film = _Splatter(n_pix)
        self.moments = _WeightedMoments()
        self.n_steps, self.target, self.mutation, self.rng = n_steps, target, mutation, rng
        self.chains = None            # the chains in flight (dict of arrays, birth order), or None
        self.cohorts = []             # [states born, lit among them, steps made] per round in flight
        self.terms = 0                # D
        self.n_acc = self.n_moves = self.n_chains = 0
        self._b = [0.0, 0.0, 0]

    @property
    def done(self) -> int:
        """Finished terms in bootstrap states' worth, ``D / (T + 1)`` (all of them at the end)."""
        return self.terms // (self.n_steps + 1)

    def spp(self, n_pix: int) -> float:
        return self.terms / ((self.n_steps + 1) * n_pix)

    def births_allowed(self, m: int) -> int:
        """New states the next round may add: ``m``, or 0 (a round that only steps the chains)
        while the chains in flight are :data:`MAX_CHAINS_IN_FLIGHT` or more (memory: a bright
        scene lights nearly every state). All or nothing, so that every round is whole
        scanline passes."""
        alive = 0 if self.chains is None else self.chains["f"].size
        return m if alive < MAX_CHAINS_IN_FLIGHT else 0

    def bootstrap_chunk(self, x) -> None:
        """One round: the new uniform states ``x`` (D, m) traced together with every chain's proposal
        (``m = 0``: the chains' step only)."""
        self._round(x if x.shape[1] else None)

    def finish(self) -> None:
        """Tail rounds until every cohort has made its ``T`` steps."""
        while self.cohorts:
            self._round(None)

    def _round(self, x) -> None:
        sigma, p_large = self.mutation
        ch = self.chains
        m = 0 if x is None else x.shape[1]
        y = None if ch is None else _mutate_soa(ch["x"], sigma, p_large, self.rng)[0]
        parts = [p for p in (x, y) if p is not None]
        if not parts:                                          # cohorts without a lit state: nothing to trace
            f = pix = rgbn = None
        else:
            f, pix, rgbn = self.target(parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1))
        local = np.zeros(3 * self.film.n_pix)
        terms = 0
        if self.cohorts:                                       # the chains' step
            terms += sum(c[0] for c in self.cohorts)           # every state in flight, lit or not
            for c in self.cohorts:
                c[2] += 1
        if ch is not None:
            fy, py, ry = f[m:], pix[m:], rgbn[:, m:]
            a = np.minimum(1.0, fy / ch["f"])
            self.film.add_into(local, ch["pix"], ch["rgbn"], ch["w"] * (1.0 - a))
            self.film.add_into(local, py, ry, ch["w"] * a)
            acc = self.rng.random(a.shape[0]) < a
            for key, new in (("x", y), ("f", fy), ("pix", py), ("rgbn", ry)):
                np.copyto(ch[key], new, where=acc)
            for name, h in zip(self._NAMES, (ch["f"], ch["x"][0], ch["x"][1])):
                ch["sum_" + name] += h
                ch["sq_" + name] += h * h
            self.n_acc += int(acc.sum())
            self.n_moves += a.shape[0]
        new = None
        if x is not None:                                      # t = 0; lit states start chains
            f0 = f[:m]
            self._b[0] += float(f0.sum())
            self._b[1] += _dot(f0, f0)
            self._b[2] += m
            lit = np.flatnonzero(f0 > 0)
            self.film.add_into(local, pix[lit], rgbn[:, lit], f0[lit])
            terms += m
            self.n_chains += lit.size
            if self.n_steps and lit.size:
                h0 = (f0[lit], x[0, lit], x[1, lit])
                new = {"x": np.take(x, lit, axis=1), "f": f0[lit].copy(), "pix": pix[lit],
                       "rgbn": np.take(rgbn[:, :m], lit, axis=1), "w": f0[lit].copy()}
                for name, h in zip(self._NAMES, h0):
                    new["sum_" + name] = h.copy()
                    new["sq_" + name] = h * h
        # the round is finished: film, D and the chains change together
        self.film.film += local
        self.terms += terms
        if self.cohorts and self.cohorts[0][2] == self.n_steps:  # the oldest cohort has made its T steps
            _, k, _ = self.cohorts.pop(0)
            if k:
                for name in self._NAMES:
                    self.moments.add(name, ch["w"][:k], ch["sum_" + name][:k], ch["sq_" + name][:k],
                                     self.n_steps + 1)
                ch = {key: v[..., k:] for key, v in ch.items()}
        if x is not None and self.n_steps:
            self.cohorts.append([m, 0 if new is None else new["f"].size, 0])
            if new is not None:
                ch = new if ch is None or ch["f"].size == 0 else \
                    {key: np.concatenate([ch[key], new[key]], axis=-1) for key in self._KEYS}
        self.chains = ch if ch is not None and ch["f"].size else None

    def image_sum(self, n_pix: int) -> np.ndarray:
        """``sum`` with ``sum / spp`` the image, ``spp = D / ((T + 1) n_pix)``: ``I = n_pix / D Σ``."""
        return (self.film.film.reshape(3, n_pix) / (self.n_steps + 1)).T.copy()

    def b(self):
        total, sq, n = self._b
        b = total / max(n, 1)
        return b, float(np.sqrt(max(sq / max(n, 1) - b * b, 0.0) / max(n - 1, 1))), n


def _stratified_states(res, first: int, m: int, dim: int, rng) -> np.ndarray:
    """States ``first .. first + m - 1`` of a stratified bootstrap in scanline order, ``(dim, m)``.

    Start ``k`` lies in pixel ``k mod n_pix`` (row-major), uniform inside it, and every other
    number is uniform: ``n_pix`` consecutive starts hold one state of every pixel, so a bootstrap
    of ``spp * n_pix`` states gives each pixel ``spp`` uniform states of its own stratum and
    ``n_pix / n_b Σ g(x_k)`` is an unbiased (stratified) estimate of ``n_pix ∫ g``; so is any run
    of whole scanline passes (the rounds of :func:`_weighted_film`). Neighbouring starts are
    neighbouring pixels, so the wavefront's rays are coherent, as in path tracing (measured on
    cornell-door: states uniform over the image traced 2x slower, through the tracer's masks).
    """
    width, height = res
    x = rng.random((dim, m))
    pix = (first + np.arange(m)) % (width * height)
    x[0] += pix % width
    x[0] *= 1.0 / width
    x[1] += pix // width
    x[1] *= 1.0 / height
    np.minimum(x[:2], np.nextafter(1.0, 0.0), out=x[:2])
    return x


def _weighted_film(target, dim: int, res, per_pixel: int, opts: "PssmltSettings", rng) -> PssmltFilm:
    """:func:`pssmlt_film` with ``start='weighted'``: ``per_pixel`` stratified bootstrap states per pixel."""
    n_pix = res[0] * res[1]
    n_b = per_pixel * n_pix
    run = _WeightedRun(n_pix, opts.chain_length, target, (opts.sigma, opts.p_large), rng)
    interrupted = False
    passes = max(1, WEIGHTED_ROUND // n_pix)            # whole scanline passes per round
    try:
        a = 0
        while a < n_b:
            m = run.births_allowed(min(passes * n_pix, n_b - a))
            run.bootstrap_chunk(_stratified_states(res, a, m, dim, rng))
            a += m
        run.finish()
    except KeyboardInterrupt:
        if run.terms == 0:
            raise
        interrupted = True
    b, b_se, b_n = run.b()
    tau = run.moments.tau(opts.chain_length + 1)
    n_states = run.n_chains * (opts.chain_length + 1)
    ess = {name: n_states / t if t > 0 else float("nan") for name, t in tau.items()}
    return PssmltFilm(sum=run.image_sum(n_pix), spp=run.spp(n_pix), rays=target.rays, b=b, b_stderr=b_se,
                      acceptance_rate=run.n_acc / max(run.n_moves, 1),
                      interrupted=interrupted, chains=run.n_chains, n_steps=opts.chain_length, n_bootstrap=n_b,
                      n_b=b_n, tau=tau, ess=ess)


def pssmlt_film(scene: Scene, res, spp: float, *, rng=None, tracer=None, settings: PssmltSettings | None = None,
                **options) -> PssmltFilm:
    """Run ``chains`` PSSMLT chains for ``spp`` mutations per pixel on average.

    Parameters
    ----------
    scene : Scene
    res : (int, int)
        ``(W, H)``.
    spp : float
        Mutations per pixel: ``n_steps = ceil(spp * W * H / chains)`` per chain.
    settings : PssmltSettings, optional
        The settings below as one record; the keywords ``max_depth``,
        ``heuristic``, ``chains``, ``sigma``, ``p_large``, ``n_bootstrap``,
        ``bootstrap``, ``splat`` and ``state_depth`` replace its fields.

    Other Parameters
    ----------------
    rng, max_depth, heuristic, tracer
        As in :func:`mcvar.integrators.trace_camera_paths` (``max_depth=None``:
        Russian roulette).
    chains : int
        Chains (capped at ``spp * W * H``), stepped in lockstep
        :data:`CHAIN_CHUNK` at a time: every chain of a chunk proposes, all
        proposals are traced as one wavefront, every chain accepts or
        rejects; then the next chunk, from the same bootstrap.
    sigma : float
        Kelemen's small-step size (:func:`mcvar.mcmc.metropolis`).
    p_large : float or None
        Probability of a large step (a fresh uniform state); None:
        :data:`P_LARGE` of ``start`` (0.3 resampled, 0 weighted).
    n_bootstrap : int or None
        Independent paths that estimate ``b`` and seed the chains, shared by
        all chunks; None: ``max(4 * chains, N // 4)`` for ``N``
        mutations (pbrt uses 100 000 for images of ~10^8 mutations). The
        resampling gives about ``n_bootstrap / (1 + CV^2)`` distinct starts
        (``CV``: the coefficient of variation of ``f``, about 24 on
        cornell-door), so a bootstrap several times the chains pays: measured
        at equal time on cornell-door, 4 chains' worth beat a quarter or a
        sixteenth of the mutations (docs/mcmc.md).
        Fewer candidates than chains is allowed: chains that draw the same
        start part after their first steps.
    bootstrap : bool
        True: start the chains at bootstrap paths resampled ``∝ f`` (no
        start-up bias). False: start each at a uniformly drawn bootstrap
        path with ``f > 0`` (start-up bias: the first ~tau steps of each
        chain follow that distribution, not ``f / b``). ``b`` comes from the
        bootstrap and the large steps in both cases.
    splat : {'expected', 'plain'}
        Expected-value splatting (current with ``1 - a``, proposal with
        ``a``) or the state after each step.
    state_depth : int
        Path segments whose random numbers are in the state (see the module
        docstring); dimensions beyond are fresh iid.
    start : {'resample', 'weighted'}
        ``'resample'``: the chains above. ``'weighted'``: ``spp`` is the
        bootstrap's paths per pixel (rounded up), stratified (each pixel
        its own ``spp`` uniform states, in scanline order: coherent rays as
        in path tracing); every bootstrap path with ``f > 0`` starts a chain of
        ``chain_length`` steps weighted by ``f(x_0)`` (see Notes); the chains'
        steps are traced in the same wavefronts as the bootstrap's next
        paths. ``chains`` and ``n_bootstrap`` do not apply (``n_bootstrap``
        must be None, ``bootstrap`` True); ``rays`` tells the work done.
    chain_length : int
        ``start='weighted'``: steps per chain, >= 0 (0: path tracing over
        the whole film).

    Returns
    -------
    PssmltFilm
        The splats and the run's diagnostics (acceptance rate, ``b`` and its
        standard error, autocorrelation time and effective sample size).

    Notes
    -----
    **Estimator** (Veach 1997 eq. 11.7, Kelemen 2002 section 4): with ``c``
    the RGB contribution of path ``u``, ``f = Y(c)`` its luminance and
    ``b = ∫ f du`` (the image's mean luminance), pixel ``j``'s value is
    ``I_j = ∫ n_pix 1_j(u) c(u) du = b E_{f/b}[n_pix 1_j c / f]``, so

        I_j ≈ b / spp * Σ_k 1_j(u_k) c(u_k) / f(u_k)

    with ``spp = N / n_pix`` for ``N`` steps over all chains (with
    expected-value splatting, each step's term is the ``a``-weighted mix of
    the current and the proposed path). The image's mean luminance equals
    ``b`` exactly (``Y(c) / f = 1``).

    **Fresh tail dimensions.** The state holds ``state_dim`` numbers; the
    numbers ``v`` of vertices beyond the cap are redrawn iid at every
    evaluation. This is Metropolis-Hastings on the extended space ``(u, v)``
    with target ``f(u, v)``: the proposal ``(u, v) -> (u', v')`` with ``u'``
    from Kelemen's symmetric mutation and ``v'`` fresh uniform has density
    ``T(u -> u') * 1``, which is symmetric, so the acceptance
    ``min(1, f(u', v') / f(u, v))``, with ``f(u, v)`` the *stored* value of
    the current path (never re-evaluated), keeps ``f(u, v) / b`` invariant
    and its ``u``-marginal is the right one. The tail mutates only by
    independent redraws, so very long paths are explored less locally than
    in pbrt's ``MLTSampler`` (which mutates every dimension), but no path
    length is cut off: the estimate stays consistent (Russian roulette
    included). With ``max_depth <= state_depth`` every path is a pure
    function of the state.

    **Weighted start** (``start='weighted'``; Veach and Guibas 1997, 5.1).
    If ``K`` is a Metropolis step that keeps ``f`` invariant (``∫ f(x) K(x,
    y) dx = f(y)``: Kelemen's symmetric mutation with the acceptance above,
    large steps or not) and ``x_0`` is uniform, then ``E[f(x_0) h(x_t)] =
    ∫ f K^t h = ∫ f h`` for every ``t``: no stationary start, no ``b``,
    no ergodicity needed (the fresh starts explore). With ``h = n_pix 1_j c /
    f`` and ``T = chain_length``,

        I_j ≈ n_pix / (n_b (T + 1)) Σ_k f(x_k0) Σ_{t=0..T} 1_j(x_kt) c(x_kt) / f(x_kt)

    (each step's term expected-value splatted); unlit starts contribute
    nothing and are not chained. ``T = 0`` is path tracing; longer chains
    spread a found path's energy over its neighbours.

    **Diagnostics.** The chains start (nearly) in the stationary
    distribution and are independent given the bootstrap, so the variance
    of the run's mean of an observable ``h`` is ``Var(h) tau / N`` with
    ``tau = n_steps Var(chain means of h) / Var(h)`` (batch means, one batch
    per chain: right for short chains, where a lag window cannot be fitted;
    ``tau`` counts the correlation within the run's ``n_steps``, so it is at
    most ``n_steps``). ``ESS = N / tau``.
    """
    opts = settings_with(PssmltSettings, settings, options, "pssmlt_film")
    rng = as_rng(rng)
    n_pix = res[0] * res[1]
    if not (np.isfinite(spp) and spp > 0):
        raise ValueError(f"spp must be finite and > 0; got {spp}")
    chains = check_count(opts.chains, "chains")
    sigma = check_positive(opts.sigma, "sigma")
    check_choice(opts.splat, "splat", ("expected", "plain"))
    check_bool(opts.bootstrap, "bootstrap")
    _check_start(opts.start, opts.chain_length, opts.n_bootstrap, opts.bootstrap)
    p_large = P_LARGE[opts.start] if opts.p_large is None else check_probability(opts.p_large, "p_large")
    opts = replace(opts, p_large=p_large, sigma=sigma)
    dim = state_dim(opts.state_depth, opts.max_depth)
    n_mut = max(1, int(round(spp * n_pix)))
    if opts.start == "weighted":
        _check_weighted_memory(dim, opts.state_depth)
    else:
        chains = min(chains, n_mut)
        n_bootstrap = check_count(max(4 * chains, n_mut // 4) if opts.n_bootstrap is None else opts.n_bootstrap,
                                  "n_bootstrap")
        _check_memory(dim, chains, n_bootstrap, opts.state_depth)
    tracer = tracer if tracer is not None else Tracer(scene)
    target = _PathTarget(scene, res, tracer, PathSettings(max_depth=opts.max_depth, heuristic=opts.heuristic), rng)
    if opts.start == "weighted":
        return _weighted_film(target, dim, res, int(np.ceil(spp - 1e-9)), opts, rng)
    return _resampled_film(target, dim, n_pix, n_mut, chains, n_bootstrap, opts, rng)


def _resampled_film(target, dim: int, n_pix: int, n_mut: int, chains: int, n_bootstrap: int, opts, rng) -> PssmltFilm:
    """``start='resample'``: ``chains`` chains from one bootstrap of ``n_bootstrap`` paths, ``n_mut`` mutations
    in all, stepped :data:`CHAIN_CHUNK` chains at a time (:func:`pssmlt_film`'s estimator)."""
    n_steps = -(-n_mut // chains)
    chunk = min(chains, CHAIN_CHUNK)
    cand, fc, pc, rc, pick = _bootstrap(target, dim, chains, n_bootstrap, opts.bootstrap, rng)
    run = _Run(n_pix, opts.splat == "expected", fc)
    interrupted = False
    try:
        for first in range(0, chains, chunk):
            sel = pick[first:first + chunk]
            run.chunk(_Chains(np.take(cand, sel, axis=1), fc[sel], pc[sel], np.take(rc, sel, axis=1)),
                      n_steps, target, (opts.sigma, opts.p_large), rng)
    except KeyboardInterrupt:
        if run.done == 0:
            raise
        interrupted = True                 # keep the finished steps
    b, b_se, b_n = run.b()
    moments, done, n_acc, film = run.moments, run.done, run.n_acc, run.film
    tau = moments.tau(n_steps)
    ess = {name: done / t if t > 0 else float("nan") for name, t in tau.items()}
    # image = b / spp * film  ->  sum = b * film, so that sum / spp is the image
    return PssmltFilm(sum=film.image_sum(b), spp=done / n_pix, rays=target.rays, b=b, b_stderr=b_se,
                      acceptance_rate=n_acc / max(done, 1), interrupted=interrupted, chains=chains,
                      n_steps=n_steps, n_bootstrap=n_bootstrap, n_b=b_n, tau=tau, ess=ess)


def run_batch(job: BatchJob) -> BatchResult:
    """One independent PSSMLT run of ``job.spp`` mutations per pixel (the registry's ``run_batch``).

    ``job.u`` is not used: the chains draw their own states from ``job.rng``.
    Ctrl-C inside the run is re-raised (the render keeps the finished batches).
    """
    run = pssmlt_film(job.scene, job.res, job.spp, rng=job.rng, max_depth=job.max_depth,
                      heuristic=job.heuristic, tracer=job.tracer, **job.options)
    if run.interrupted:
        raise KeyboardInterrupt
    # the render's extra: spp-weighted means over its batches (Render.extra)
    extra = {"b": np.array([run.b * job.spp]), "b_stderr": np.array([run.b_stderr * job.spp]),
             "acceptance_rate": np.array([run.acceptance_rate * job.spp]),
             "tau": np.array([run.tau["luminance"] * job.spp]),
             "ess_fraction": np.array([run.ess["luminance"] / (run.spp * job.res[0] * job.res[1]) * job.spp])}
    return BatchResult(sum=run.sum * (job.spp / run.spp), sum_sq=None, rays=run.rays, extra=extra)


def _check_memory(dim: int, chains: int, n_bootstrap, state_depth) -> None:
    """The run's memory against the budget before anything is traced: the bootstrap's candidates and
    one chunk's step (:func:`mcvar.mcmc.check_walk_budget`), and every chain's bookkeeping."""
    check_walk_budget(dim, min(chains, CHAIN_CHUNK), n_bootstrap, payload_words=4, dim_name="state_depth",
                      dim_value=state_depth)
    check_budget(f"chains={chains!r} with state_depth={state_depth!r}", None, chains * float(BYTES_PER_CHAIN),
                 per_unit=BYTES_PER_CHAIN, unit_name="chains",
                 what=f"the bootstrap picks and diagnostics of {chains} chains")


def _check_weighted_memory(dim: int, state_depth) -> None:
    """``start='weighted'``: one round's wavefront (the chains in flight and a bootstrap chunk) and
    the chains' sums (six numbers each) against the budget."""
    check_walk_budget(dim, MAX_CHAINS_IN_FLIGHT + BOOTSTRAP_CHUNK, None, payload_words=4 + 7,
                      dim_name="state_depth", dim_value=state_depth)


def _check_start(start, chain_length, n_bootstrap, bootstrap) -> None:
    """``start`` and the options it rules out: a weighted run's bootstrap is its ``spp`` paths."""
    check_choice(start, "start", STARTS)
    check_count(chain_length, "chain_length", allow_zero=True)
    if start == "weighted":
        if n_bootstrap is not None:
            raise ValueError("n_bootstrap must be None with start='weighted' (the bootstrap is the run's "
                             f"spp * W * H uniform paths); got {n_bootstrap!r}")
        if not bootstrap:
            raise ValueError("bootstrap=False (start-up bias) needs start='resample'; weighted chains start "
                             "at every lit bootstrap path")


def _check_options(scene, options) -> None:
    """``check_scene`` of ``pssmlt``: every option's type and value, and the
    chains' and a given ``n_bootstrap``'s memory against the budget."""
    chains = check_count(options["chains"], "chains")
    check_positive(options["sigma"], "sigma")
    if options["p_large"] is not None:
        check_probability(options["p_large"], "p_large")
    check_choice(options["splat"], "splat", ("expected", "plain"))
    check_bool(options["bootstrap"], "bootstrap")
    _check_start(options["start"], options["chain_length"], options["n_bootstrap"], options["bootstrap"])
    dim = state_dim(check_count(options["state_depth"], "state_depth"))
    if options["start"] == "weighted":
        _check_weighted_memory(dim, options["state_depth"])
        return
    n_bootstrap = None if options["n_bootstrap"] is None else check_count(options["n_bootstrap"], "n_bootstrap")
    _check_memory(dim, chains, n_bootstrap, options["state_depth"])


register(Method("pssmlt", "chain", run_batch,
                "primary-sample-space Metropolis light transport (Kelemen 2002): chains on the path "
                "tracer's random numbers, expected-value splatting, bootstrap",
                options=OPTIONS, check_scene=_check_options, lecture=("yes", "yes"),
                chart_row="Metropolis Light Transport",
                theory=("yes", "no", "MLT's start-up bias: each chain starts from a bootstrap sample, not from "
                                     "its stationary distribution; the bias vanishes as the chains grow"),
                stream_dims=0))
