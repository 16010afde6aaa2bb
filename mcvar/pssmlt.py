"""Primary-sample-space Metropolis light transport (PSSMLT).

The lecture's 'Metropolis Light Transport' slide, in the form of Kelemen et
al. [1]_ and pbrt's MLT integrator [2]_: the Markov chain of
:mod:`mcvar.mcmc` runs on the *primary sample space*, the vector ``u`` of
uniform numbers a path tracer turns into one camera path, and its target is
the luminance of that path's contribution. Every step splats the current and
the proposed path onto the film (expected-value splatting); the bootstrap's
``b`` (mean luminance of the image) sets the scale.

State and path function
-----------------------
``u = (u_0 .. u_{STATE_DIM-1})``: ``u[0:2]`` the film position over the
**whole image** (x = column left to right, y = row top to bottom: pixel and
offset inside it), ``u[2:4]`` the first vertex's light sample and ``u[4:6]``
its BSDF sample (the sample dimensions :func:`mcvar.integrators.trace_paths`
takes for the first vertex). Later vertices, and the Russian-roulette coins,
are drawn *fresh* from ``rng`` at every evaluation (see :func:`pssmlt_film`,
Notes, for why this is still a correct Metropolis-Hastings chain).

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

import time
from dataclasses import dataclass

import numpy as np

from ._validation import as_rng, check_choice, check_count, check_positive, check_probability
from .envmap import LUMINANCE_WEIGHTS
from .integrators import Render, trace_paths
from .mcmc import _walk
from .scene import Scene
from .tracer import Tracer

__all__ = ["STATE_DIM", "OPTIONS", "pssmlt_film", "render_pssmlt", "PssmltFilm"]

#: Dimensions of the Markov chain's state: film position (2) + the first
#: vertex's light (2) and BSDF (2) samples. Dimensions beyond are fresh iid.
STATE_DIM = 6

#: The method's options and defaults (the registry's ``Method.options``).
#: ``sigma`` and ``p_large`` as pbrt-v4 (0.01, 0.3); 4096 chains run at once (a
#: wavefront of 4096 paths per step: measured on cornell-door 32 x 32, 3-4x the
#: speed of 1024 chains at equal MSE).
#: ``n_bootstrap=None``: ``max(4 * chains, mutations // 4)`` paths.
OPTIONS = {"chains": 4096, "sigma": 0.01, "p_large": 0.3, "n_bootstrap": None,
           "bootstrap": True, "splat": "expected"}

_LUM = np.asarray(LUMINANCE_WEIGHTS)


@dataclass(frozen=True)
class PssmltFilm:
    """One PSSMLT run: ``image = sum / spp`` (the :class:`BatchResult` convention).

    Attributes
    ----------
    sum : ndarray, shape (n_pix, 3)
        Splats, scaled so that ``sum / spp`` is the image.
    spp : float
        Mutations per pixel (``chains * n_steps / n_pix``).
    rays : int
        Rays traced, bootstrap included.
    b : float
        The bootstrap's estimate of the image's mean luminance.
    b_stderr : float
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


def _path_function(scene: Scene, res, tracer: Tracer, max_depth, rng, counter):
    """``evaluate(u (n, STATE_DIM)) -> (luminance (n,), payload (n, 4) = [pixel, r, g, b])``."""
    width, height = res
    position = scene.camera.position

    def evaluate(u):
        col = np.minimum((u[:, 0] * width).astype(np.intp), width - 1)
        row = np.minimum((u[:, 1] * height).astype(np.intp), height - 1)
        pixel = row * width + col
        offsets = np.stack([u[:, 0] * width - col, u[:, 1] * height - row], axis=1)
        d = scene.camera.ray_directions_soa(res, pixel, offsets).T
        o = np.broadcast_to(position, d.shape)
        radiance, rays = trace_paths(scene, o, d, u[:, 2:], integrator="path", max_depth=max_depth,
                                     rng=rng, tracer=tracer)
        counter[0] += rays
        payload = np.empty((u.shape[0], 4))
        payload[:, 0] = pixel
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


def pssmlt_film(scene: Scene, res, spp: float, *, rng=None, max_depth=None, tracer=None,
                chains: int = OPTIONS["chains"], sigma: float = OPTIONS["sigma"],
                p_large: float = OPTIONS["p_large"], n_bootstrap: int = OPTIONS["n_bootstrap"],
                bootstrap: bool = OPTIONS["bootstrap"], splat: str = OPTIONS["splat"]) -> PssmltFilm:
    """Run ``chains`` PSSMLT chains for ``spp`` mutations per pixel on average.

    Parameters
    ----------
    scene : Scene
    res : (int, int)
        ``(W, H)``.
    spp : float
        Mutations per pixel: ``n_steps = ceil(spp * W * H / chains)`` per chain.
    rng, max_depth, tracer
        As in :func:`mcvar.integrators.trace_paths` (``max_depth=None``:
        Russian roulette).
    chains : int
        Chains run at once (one vectorised wavefront of ``chains`` paths per
        step); capped at ``spp * W * H``.
    sigma, p_large
        Kelemen's mutations (:func:`mcvar.mcmc.metropolis`).
    n_bootstrap : int or None
        Independent paths that estimate ``b`` and seed the chains; None:
        ``max(4 * chains, N // 4)`` for ``N`` mutations (pbrt uses 100 000
        for images of ~10^8 mutations; here images are small, so the
        bootstrap is a fixed fraction of the work, and its relative error in
        ``b``, a global scale on the image, stays below ``sqrt(4 / N)`` times
        the coefficient of variation of ``f``).
    bootstrap : bool
        True: start the chains at bootstrap paths resampled ``∝ f`` (no
        start-up bias). False: start each at a uniformly drawn bootstrap
        path with ``f > 0`` (start-up bias: the first ~tau steps of each
        chain follow the uniform distribution, not ``f / b``). ``b`` comes
        from the bootstrap paths in both cases.
    splat : {'expected', 'plain'}
        Expected-value splatting (current with ``1 - a``, proposal with
        ``a``) or the state after each step.

    Notes
    -----
    **Estimator** (Veach 1997 eq. 11.7, Kelemen 2002 section 4): with ``c``
    the RGB contribution of path ``u``, ``f = Y(c)`` its luminance and
    ``b = integral f du`` (the image's mean luminance), pixel ``j``'s value
    ``I_j = integral n_pix 1_j(u) c(u) du = b E_{f/b}[n_pix 1_j c / f]``, so

        I_j ≈ b / spp * sum over steps of 1_j(u_k) c(u_k) / f(u_k)

    with ``spp = N / n_pix`` for ``N`` steps over all chains. The image's
    mean luminance equals ``b`` exactly (``Y(c) / f = 1``): PSSMLT
    distributes the bootstrap's estimate over the pixels.

    **Fresh tail dimensions.** The state holds :data:`STATE_DIM` numbers;
    the numbers of later vertices ``v`` and the roulette coins are redrawn
    iid at every evaluation. This is Metropolis-Hastings on the extended
    space ``(u, v)`` with target ``f(u, v)``: the proposal
    ``(u, v) -> (u', v')`` with ``u'`` from Kelemen's symmetric mutation and
    ``v'`` fresh uniform has density ``T(u -> u') * 1``, which is symmetric,
    so the acceptance ``min(1, f(u', v') / f(u, v))`` (with ``f(u, v)`` the
    *stored* value of the current path, never re-evaluated) keeps
    ``f(u, v) / b`` invariant, and its ``u``-marginal is the right one. The
    tail mutates only by 'large steps': paths whose light arrives after many
    bounces are explored less locally than in full PSSMLT (pbrt's
    ``MLTSampler`` mutates every dimension), but the estimate stays
    consistent. Paths of any length are allowed (no depth cap: the state
    size is fixed, the tail is not).
    """
    rng = as_rng(rng)
    width, height = res
    n_pix = width * height
    if not (np.isfinite(spp) and spp > 0):
        raise ValueError(f"spp must be finite and > 0; got {spp}")
    chains = check_count(chains, "chains")
    sigma = check_positive(sigma, "sigma")
    p_large = check_probability(p_large, "p_large")
    check_choice(splat, "splat", ("expected", "plain"))
    if not isinstance(bootstrap, (bool, np.bool_)):
        raise TypeError(f"bootstrap must be True or False; got {bootstrap!r}")
    n_mut = max(1, int(round(spp * n_pix)))
    chains = min(chains, n_mut)
    n_steps = -(-n_mut // chains)
    if n_bootstrap is None:
        n_bootstrap = max(4 * chains, n_mut // 4)
    n_bootstrap = check_count(n_bootstrap, "n_bootstrap")
    tracer = tracer if tracer is not None else Tracer(scene)
    counter = [0]
    evaluate = _path_function(scene, res, tracer, max_depth, rng, counter)

    cand = rng.random((n_bootstrap, STATE_DIM))
    fc, pc = evaluate(cand)
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

    _, _, _, n_acc, n_done = _walk(evaluate, x, fx, px, n_steps, sigma, p_large, rng, visit=visit,
                                   thin=n_steps)
    done = chains * n_done / n_pix
    # image = b / spp * film  ->  sum = b * film, so that sum / spp is the image
    return PssmltFilm(sum=film * b, spp=done, rays=counter[0], b=float(b), b_stderr=float(b_se),
                      acceptance_rate=n_acc / (chains * n_done), interrupted=n_done < n_steps)


def render_pssmlt(scene: Scene, *, spp: int = 16, res=64, rng=None, max_depth=None, batches: int = 1,
                  progress: bool = False, **options) -> Render:
    """Render ``scene`` by PSSMLT: ``batches`` independent runs of ``spp / batches`` mutations per pixel.

    Returns a :class:`mcvar.integrators.Render` (``integrator='pssmlt'``);
    its ``variance`` is the per-pixel variance an iid estimator would need
    to match the scatter of the ``batches`` independent runs
    (``spp * Var(batch images) / batches``, so that ``standard_error`` is the
    standard error of the mean image); None for one batch. Options: those of
    :data:`OPTIONS` (see :func:`pssmlt_film`). ``progress=True`` shows a tqdm
    bar over batches; Ctrl-C keeps the finished batches (``interrupted=True``).
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a mcvar.scene.Scene; got {type(scene).__name__}")
    unknown = set(options) - set(OPTIONS)
    if unknown:
        raise ValueError(f"unknown pssmlt option(s) {sorted(unknown)}; accepted: {sorted(OPTIONS)}")
    spp = check_count(spp, "spp")
    batches = check_count(batches, "batches")
    if isinstance(res, (int, np.integer)):
        res = (check_count(res, "res"), check_count(res, "res"))
    width, height = int(res[0]), int(res[1])
    opts = {**OPTIONS, **options}
    tracer = Tracer(scene)
    start = time.perf_counter()
    images, rays, done = [], 0, 0.0
    interrupted = False
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=batches, unit="batch", desc=f"{scene.name} pssmlt", leave=False)
    try:
        for stream in as_rng(rng).spawn(batches):
            run = pssmlt_film(scene, (width, height), spp / batches, rng=stream, max_depth=max_depth,
                              tracer=tracer, **opts)
            images.append(run.sum / run.spp)
            rays += run.rays
            done += run.spp
            if bar is not None:
                bar.update(1)
            if run.interrupted:
                raise KeyboardInterrupt
    except KeyboardInterrupt:
        if not images:
            raise
        interrupted = True                     # Ctrl-C keeps the finished batches
    finally:
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - start
    stack = np.stack(images)
    image = stack.mean(axis=0).reshape(height, width, 3)
    variance = None
    if len(images) >= 2:
        variance = (done * stack.var(axis=0, ddof=1) / len(images)).reshape(height, width, 3)
    return Render(image=image, spp=int(round(done)), seconds=seconds, interrupted=interrupted, variance=variance,
                  rays=rays, scene=scene.name, integrator="pssmlt", sampler="random", res=(width, height),
                  max_depth=max_depth, heuristic="power", batch_spp=int(round(done / len(images))), workers=1,
                  precision="float32")
