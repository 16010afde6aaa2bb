"""Primary-sample-space Metropolis light transport: the ``pssmlt`` method (kind ``chain``).

The lecture's 'Metropolis Light Transport' slide, in the form of Kelemen et
al. [1]_ and pbrt's MLT integrator [2]_: the Markov chain of
:mod:`mcvar.mcmc` runs on the *primary sample space*, the vector ``u`` of
uniform numbers the path tracer turns into one camera path
(:func:`mcvar.integrators.trace_camera_paths`), and its target is the
luminance of that path's contribution. Every step splats the current and the
proposed path onto the film (expected-value splatting); the bootstrap's ``b``
(mean luminance of the image) sets the scale. Each batch of a render is an
independent PSSMLT run (its own bootstrap and chains), so the film's
variance comes from independent batches.

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
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_rng, check_bool, check_choice, check_count, check_positive, check_probability, settings_with
from ..envmap import LUMINANCE_WEIGHTS
from ..mcmc import _evaluate_chunked, _walk, check_walk_budget
from ..scene import Scene
from ..tracer import Tracer
from .film import BatchJob, BatchResult
from .path import trace_camera_paths
from .registry import Method, register
from .stream import CAMERA_DIMS, stream_dim

__all__ = ["OPTIONS", "PssmltFilm", "PssmltSettings", "pssmlt_film", "state_dim", "run_batch"]

#: The method's options and defaults. ``sigma`` and ``p_large`` as pbrt-v4
#: (0.01, 0.3); 4096 chains run at once (a wavefront of 4096 paths per step:
#: measured on cornell-door 32 x 32, 3-4x the speed of 1024 chains at equal
#: MSE); ``n_bootstrap=None``: ``max(4 * chains, mutations // 4)`` paths;
#: ``state_depth``: path segments whose numbers are in the chain's state.
OPTIONS = {"chains": 4096, "sigma": 0.01, "p_large": 0.3, "n_bootstrap": None,
           "bootstrap": True, "splat": "expected", "state_depth": 6}

_LUM = np.asarray(LUMINANCE_WEIGHTS)


def state_dim(state_depth: int, max_depth: int | None = None) -> int:
    """Numbers in the chain's state: ``stream_dim(min(state_depth, max_depth))``."""
    depth = check_count(state_depth, "state_depth")
    if max_depth is not None:
        depth = min(depth, max_depth)
    return max(CAMERA_DIMS, stream_dim(depth))


@dataclass(frozen=True)
class PssmltFilm:
    """One PSSMLT run: ``image = sum / spp`` (the :class:`BatchResult` convention).

    Attributes
    ----------
    sum : ndarray, shape (n_pix, 3)
        Splats, scaled so that ``sum / spp`` is the image.
    spp : float
        Mutations per pixel done (``chains * n_steps / n_pix``).
    rays : int
        Rays traced, bootstrap included.
    b, b_stderr : float
        The bootstrap's estimate of the image's mean luminance and its error.
    acceptance_rate : float
    interrupted : bool
        Ctrl-C stopped the chains early (``spp`` counts the finished steps).
    """

    sum: np.ndarray
    spp: float
    rays: int
    b: float
    b_stderr: float
    acceptance_rate: float
    interrupted: bool = False


def _path_function(scene: Scene, res, tracer: Tracer, max_depth, heuristic, rng, counter):
    """``evaluate(u (n, D)) -> (luminance (n,), payload (n, 4) = [pixel, r, g, b])``."""
    width, height = res

    def evaluate(u):
        col = np.minimum((u[:, 0] * width).astype(np.intp), width - 1)
        row = np.minimum((u[:, 1] * height).astype(np.intp), height - 1)
        path_u = u.copy()
        path_u[:, 0] = u[:, 0] * width - col                 # the offset inside the pixel
        path_u[:, 1] = u[:, 1] * height - row
        radiance, rays = trace_camera_paths(scene, res, row * width + col, path_u, integrator="path",
                                            max_depth=max_depth, heuristic=heuristic, rng=rng, tracer=tracer)
        counter[0] += rays
        payload = np.empty((u.shape[0], 4))
        payload[:, 0] = row * width + col
        payload[:, 1:] = radiance
        return radiance @ _LUM, payload

    return evaluate


def _splat(film, n_pix, payload, weight):
    """Add ``weight * rgb / luminance`` at each payload's pixel (0 where the weight is 0)."""
    pix = payload[:, 0].astype(np.intp)
    rgb = payload[:, 1:]
    lum = rgb @ _LUM
    w = np.divide(weight, lum, out=np.zeros_like(lum), where=(lum > 0) & (weight > 0))
    for c in range(3):
        film[:, c] += np.bincount(pix, weights=w * rgb[:, c], minlength=n_pix)


@dataclass(frozen=True)
class PssmltSettings:
    """The settings of one PSSMLT run (:func:`pssmlt_film`'s keywords; defaults :data:`OPTIONS`)."""

    max_depth: int | None = None
    heuristic: str = "power"
    chains: int = OPTIONS["chains"]
    sigma: float = OPTIONS["sigma"]
    p_large: float = OPTIONS["p_large"]
    n_bootstrap: int | None = OPTIONS["n_bootstrap"]
    bootstrap: bool = OPTIONS["bootstrap"]
    splat: str = OPTIONS["splat"]
    state_depth: int = OPTIONS["state_depth"]


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
        Chains run at once (one vectorised wavefront of ``chains`` paths per
        step); capped at ``spp * W * H``.
    sigma : float
        Kelemen's small-step size (:func:`mcvar.mcmc.metropolis`).
    p_large : float
        Probability of a large step (a fresh uniform state).
    n_bootstrap : int or None
        Independent paths that estimate ``b`` and seed the chains; None:
        ``max(4 * chains, N // 4)`` for ``N`` mutations (pbrt uses 100 000
        for images of ~10^8 mutations; here images are small, so the
        bootstrap is a fixed fraction of the work; its relative error in
        ``b``, a global scale on the image, is ``sqrt(4 / N)`` times the
        coefficient of variation of ``f``).
    bootstrap : bool
        True: start the chains at bootstrap paths resampled ``∝ f`` (no
        start-up bias). False: start each at a uniformly drawn bootstrap
        path with ``f > 0`` (start-up bias: the first ~tau steps of each
        chain follow that distribution, not ``f / b``). ``b`` comes from the
        bootstrap paths in both cases.
    splat : {'expected', 'plain'}
        Expected-value splatting (current with ``1 - a``, proposal with
        ``a``) or the state after each step.
    state_depth : int
        Path segments whose random numbers are in the state (see the module
        docstring); dimensions beyond are fresh iid.

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
    """
    opts = settings_with(PssmltSettings, settings, options, "pssmlt_film")
    max_depth, heuristic, chains, sigma, p_large = (opts.max_depth, opts.heuristic, opts.chains, opts.sigma,
                                                    opts.p_large)
    n_bootstrap, bootstrap, splat, state_depth = opts.n_bootstrap, opts.bootstrap, opts.splat, opts.state_depth
    rng = as_rng(rng)
    width, height = res
    n_pix = width * height
    if not (np.isfinite(spp) and spp > 0):
        raise ValueError(f"spp must be finite and > 0; got {spp}")
    chains = check_count(chains, "chains")
    sigma = check_positive(sigma, "sigma")
    p_large = check_probability(p_large, "p_large")
    check_choice(splat, "splat", ("expected", "plain"))
    check_bool(bootstrap, "bootstrap")
    dim = state_dim(state_depth, max_depth)
    n_mut = max(1, int(round(spp * n_pix)))
    chains = min(chains, n_mut)
    n_steps = -(-n_mut // chains)
    if n_bootstrap is None:
        n_bootstrap = max(4 * chains, n_mut // 4)
    n_bootstrap = check_count(n_bootstrap, "n_bootstrap")
    check_walk_budget(dim, chains, n_bootstrap, payload_words=4, dim_name="state_depth", dim_value=state_depth)
    tracer = tracer if tracer is not None else Tracer(scene)
    counter = [0]
    evaluate = _path_function(scene, res, tracer, max_depth, heuristic, rng, counter)

    cand = rng.random((n_bootstrap, dim))
    fc, pc = _evaluate_chunked(evaluate, cand)
    total = fc.sum()
    if not total > 0.0:
        raise ValueError(f"none of the {n_bootstrap} bootstrap paths carries light: cannot start the "
                         "chains (raise n_bootstrap)")
    b = fc.mean()
    b_se = fc.std(ddof=1) / np.sqrt(n_bootstrap)
    if bootstrap:
        pick = rng.choice(n_bootstrap, size=chains, p=fc / total)
    else:
        lit = np.flatnonzero(fc > 0)
        pick = lit[rng.integers(0, lit.size, size=chains)]
    x, fx, px = cand[pick], fc[pick], pc[pick]

    film = np.zeros((n_pix, 3))
    if splat == "expected":
        def visit(x, fx, px, y, fy, py, a, acc):
            _splat(film, n_pix, px, 1.0 - a)
            _splat(film, n_pix, py, a)
    else:
        def visit(x, fx, px, y, fy, py, a, acc):
            _splat(film, n_pix, np.where(acc[:, None], py, px), np.ones(acc.shape[0]))

    _, _, _, n_acc, n_done = _walk(evaluate, (x, fx, px), n_steps, (sigma, p_large), rng, visit=visit,
                                   thin=n_steps)
    done = chains * n_done / n_pix
    # image = b / spp * film  ->  sum = b * film, so that sum / spp is the image
    return PssmltFilm(sum=film * b, spp=done, rays=counter[0], b=float(b), b_stderr=float(b_se),
                      acceptance_rate=n_acc / (chains * n_done), interrupted=n_done < n_steps)


def run_batch(job: BatchJob) -> BatchResult:
    """One independent PSSMLT run of ``job.spp`` mutations per pixel (the registry's ``run_batch``).

    ``job.u`` is not used: the chains draw their own states from ``job.rng``.
    Ctrl-C inside the run is re-raised (the render keeps the finished batches).
    """
    run = pssmlt_film(job.scene, job.res, job.spp, rng=job.rng, max_depth=job.max_depth,
                      heuristic=job.heuristic, tracer=job.tracer, **job.options)
    if run.interrupted:
        raise KeyboardInterrupt
    extra = {"b": np.array([run.b * job.spp]), "acceptance_rate": np.array([run.acceptance_rate * job.spp])}
    return BatchResult(sum=run.sum * (job.spp / run.spp), sum_sq=None, rays=run.rays, extra=extra)


def _check_options(scene, options) -> None:
    """``check_scene`` of ``pssmlt``: every option's type and value, and the
    chains' and a given ``n_bootstrap``'s memory against the budget."""
    chains = check_count(options["chains"], "chains")
    check_positive(options["sigma"], "sigma")
    check_probability(options["p_large"], "p_large")
    check_choice(options["splat"], "splat", ("expected", "plain"))
    check_bool(options["bootstrap"], "bootstrap")
    dim = state_dim(check_count(options["state_depth"], "state_depth"))
    n_bootstrap = None if options["n_bootstrap"] is None else check_count(options["n_bootstrap"], "n_bootstrap")
    check_walk_budget(dim, chains, n_bootstrap, payload_words=4, dim_name="state_depth",
                      dim_value=options["state_depth"])


register(Method("pssmlt", "chain", run_batch,
                "primary-sample-space Metropolis light transport (Kelemen 2002): chains on the path "
                "tracer's random numbers, expected-value splatting, bootstrap",
                options=OPTIONS, check_scene=_check_options, lecture=("yes", "yes"),
                chart_row="Metropolis Light Transport",
                theory=("yes", "no", "MLT's start-up bias: each chain starts from a bootstrap sample, not from "
                                     "its stationary distribution; the bias vanishes as the chains grow"),
                stream_dims=0))
