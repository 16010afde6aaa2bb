"""Unbiased adaptive sampling: a pilot pass decides how many samples each pixel gets (layer 6).

On the Cornell box at 64 x 64 most of a uniform render's error sits in a few
dozen pixels: those that see the light's edge (a pixel partly covering a
radiance-17 emitter) and the bright ceiling next to it. Spending the same
number of samples on every pixel wastes most of them. :func:`render_adaptive`
renders in two stages (a two-stage allocation, Cochran 1977, ch. 5.5 and
sec. 5A.7; Veach 1997, sec. 2.5 on sample allocation):

1. a **pilot** of ``pilot_spp`` samples per pixel, used *only* to estimate
   each pixel's standard deviation ``sigma_i``;
2. the rest of the budget, ``n_i`` fresh samples per pixel with ``n_i``
   proportional to ``sigma_i`` (Neyman's allocation, which minimises
   ``sum_i sigma_i^2 / n_i`` for a fixed ``sum_i n_i``; for QMC samplers
   ``sigma_i^0.5``, see ``exponent``), rounded to powers of two (so that
   Sobol' and other nets stay nets), at least ``min_spp``.

The image is the mean of the second stage's samples alone. The allocation is
a function of the pilot, and the second stage's samples are drawn after it
and independently of it, so every pixel's estimate is unbiased *given* its
``n_i``, hence unbiased. Keeping the pilot's samples in the average with the
natural weights ``n0 / (n0 + n_i)`` would be biased (a pixel whose pilot
came out high gets a larger ``sigma_i``, more stage-two samples and so a
*smaller* weight on that high pilot); the pilot costs ``pilot_spp / spp`` of
the budget (1/32 by default) instead.

Batches (pixels of one allocation level, cut so that a batch holds at most
:data:`mcvar.integrators.PATHS_PER_BATCH` paths) draw from their own seeds,
spawned in a fixed order, so the image does not depend on ``workers``.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import time
import uuid
from concurrent.futures import ProcessPoolExecutor
from typing import Callable

import numpy as np
from scipy.ndimage import maximum_filter

from ._validation import as_rng, check_choice, check_count
from .integrators import HEURISTICS, LIGHT_SAMPLING, PATHS_PER_BATCH, VISIBLE_LIGHTS, Render, VisibleLights, trace_paths
from .integrators.path import _check_rr_threshold
from .samplers import SAMPLERS, _pixel_sample_columns
from .scene import Scene
from .tracer import Tracer

__all__ = ["render_adaptive", "allocate", "AdaptiveRender"]

#: Sample dimensions the sampler feeds per path: the pixel position, then the
#: first vertex's light and BSDF samples (later vertices iid). Feeding more
#: vertices (padded Sobol' pairs) lowered the MSE of a 256-spp Cornell render
#: by 4% for 13% more time (docs/performance.md): not worth it.
ADAPTIVE_DIM = 6

#: Russian roulette start of adaptive renders (the integrators' default 3).
ADAPTIVE_RR_DEPTH = 3
#: Weight-window lower bound of adaptive renders' Russian roulette
#: (:func:`mcvar.integrators.state.roulette`; 1 is pbrt's rule). pbrt's rule
#: from 3 segments on put a large share of a 256-spp Cornell render's MSE
#: into roulette (a path of throughput 0.04 survives with q = 0.04 and is
#: weighted 25x); starting it later (7 segments) halved that for +30% time,
#: the window 0.2 from 3 segments gives a lower MSE for less time
#: (docs/performance.md).
ADAPTIVE_RR_THRESHOLD = 0.2

#: Light-transport integrators the adaptive driver can run.
ADAPTIVE_INTEGRATORS = ("path", "path_bsdf", "direct", "direct_light", "direct_bsdf")


@dataclass(frozen=True, eq=False)
class AdaptiveRender(Render):
    """A :class:`~mcvar.integrators.Render` of :func:`render_adaptive`, with
    ``spp_map`` (H, W): the second stage's samples per pixel, and
    ``pilot_spp``: the pilot's (0: none)."""

    spp_map: np.ndarray | None = None
    pilot_spp: int = 0


def allocate(sigma, budget: int, *, min_spp: int, max_spp: int, exponent: float = 1.0) -> np.ndarray:
    """Samples per pixel proportional to ``sigma`` (Neyman), in powers of two.

    Parameters
    ----------
    sigma : ndarray, shape (n,)
        Estimated standard deviation per pixel (>= 0).
    budget : int
        Total samples to hand out (the result's sum is at most this, and at
        least ``n min_spp``).
    min_spp, max_spp : int
        Bounds per pixel (powers of two are not required).

    Returns
    -------
    ndarray of int64, shape (n,)
        ``n_i = clip(2^round(log2(c sigma_i)), min_spp, max_spp)`` with the
        largest scale ``c`` whose total fits the budget (bisection on
        ``log c``).
    """
    sigma = np.asarray(sigma, dtype=np.float64)
    n = sigma.shape[0]
    lo_total = n * min_spp
    if budget <= lo_total or not np.any(sigma > 0):
        return np.full(n, max(min_spp, budget // max(n, 1)), dtype=np.int64) if budget > lo_total \
            else np.full(n, min_spp, dtype=np.int64)
    pos = sigma[sigma > 0]
    log_s = exponent * np.log2(np.where(sigma > 0, sigma, pos.min()))

    def counts(log_c):
        e = np.rint(log_s + log_c)
        return np.clip(np.exp2(e), min_spp, max_spp).astype(np.int64)

    a = np.log2(min_spp) - log_s.max() - 1.0       # every pixel at min_spp
    b = np.log2(max_spp) - log_s.min() + 1.0       # every pixel at max_spp
    for _ in range(60):
        mid = 0.5 * (a + b)
        if counts(mid).sum() <= budget:
            a = mid
        else:
            b = mid
    return counts(a)


#: Per-process tracer of the adaptive render in progress, by token (one entry).
_TRACERS: dict = {}


def _run_level(token, scene, integrator, sampler, res, max_depth, heuristic, precision, light_sampling,
               rr_depth, visible_lights, rr_threshold, pixels, n, seed):
    """Render ``n`` samples of each pixel in ``pixels``: per-pixel (sum, sum of squares), rays."""
    tracer = _TRACERS.get(token)
    if tracer is None:
        tracer = Tracer(scene, dtype=precision)
        _TRACERS.clear()
        _TRACERS[token] = tracer
    rng = np.random.default_rng(seed)
    m = pixels.shape[0]
    dim = ADAPTIVE_DIM if sampler != "random" else 2
    cols = _pixel_sample_columns(sampler, m, n, dim=dim, rng=rng)      # (dim, m n): rows, no transposes
    pixel = np.repeat(pixels, n)
    d = scene.camera.ray_directions_soa(res, pixel, cols[0:2].T).T
    o = np.broadcast_to(scene.camera.position, d.shape)
    radiance, rays = trace_paths(scene, o, d, cols[2:].T, integrator=integrator, max_depth=max_depth,
                                 heuristic=heuristic, rng=rng, tracer=tracer, light_sampling=light_sampling,
                                 rr_depth=rr_depth, visible_lights=visible_lights, rr_threshold=rr_threshold)
    if visible_lights == "exact":
        radiance += VisibleLights(scene).image(res)[pixel]
    per = radiance.reshape(m, n, 3)
    return per.sum(axis=1), np.einsum("psc,psc->pc", per, per), rays


#: Segments of the pilot's paths (None: as the render, Russian roulette). The
#: pilot's samples only rank the pixels; cut paths skip the long tail of
#: nearly empty wavefronts that made a pilot batch cost 2-3x per path what a
#: main batch does (measured: adaptive 256-spp Cornell 0.677 -> 0.643 s, MSE
#: unchanged).
PILOT_MAX_DEPTH = 5

#: Paths per pilot batch: smaller than the second stage's so that the pilot,
#: a few spp over the whole image, still spreads over two or more workers
#: (a process pool hands its first ``workers`` + 1 batches out at once, beyond
#: the parent's reach: 8 batches of the 64 x 64, 8-spp pilot, not 2).
PILOT_PATHS_PER_BATCH = PATHS_PER_BATCH // 16


def _jobs(levels_of_pixels, paths_per_batch=PATHS_PER_BATCH):
    """Cut each level's pixels into batches of at most ``paths_per_batch`` paths."""
    out = []
    for n, pixels in levels_of_pixels:
        per = max(1, paths_per_batch // n)
        for a in range(0, pixels.shape[0], per):
            out.append((pixels[a:a + per], n))
    return out


def render_adaptive(scene: Scene, *, integrator: str = "path", spp: int = 256, res=64, sampler: str = "sobol",
                    rng=None, pilot_spp: int | None = None, min_spp: int | None = None,
                    max_spp: int | None = None, exponent: float | None = None, max_depth: int | None = None, heuristic: str = "power",
                    workers: int = 1, executor=None, progress: bool | Callable[[int, int], None] = False,
                    precision: str = "float32", light_sampling: str = "area",
                    rr_depth: int | None = ADAPTIVE_RR_DEPTH, visible_lights: str = "exact",
                    rr_threshold: float = ADAPTIVE_RR_THRESHOLD) -> Render:
    """Render with the same total work as ``spp`` samples per pixel, spent where the pilot saw variance.

    Parameters
    ----------
    scene : Scene
    integrator : str
        One of ``path``, ``path_bsdf``, ``direct``, ``direct_light``, ``direct_bsdf``.
    spp : int
        Average samples per pixel of the whole render, pilot included.
    res : int or (int, int)
    sampler : str
        A sampler of :data:`mcvar.samplers.SAMPLERS` (pilot and second stage).
    rng : None, int, SeedSequence or Generator
        The same seed gives the same image for any ``workers``.
    pilot_spp : int, optional
        Pilot samples per pixel (default ``max(4, spp // 32)``); they only
        decide the allocation. 0: no pilot, every pixel gets ``spp``: the
        uniform estimator of :func:`~mcvar.integrators.render`, rendered as
        pixel tiles (each batch draws its own pixels' whole sample sets, so
        no shared pattern is built in the parent and shipped to workers:
        measured 1.7x with two workers where spp batches gave 1.0-1.2x).
    min_spp, max_spp : int, optional
        Bounds on the second stage's samples per pixel (default
        ``max(1, spp // 8)`` and ``64 spp``).
    exponent : float in [0, 1], optional
        ``n_i ~ sigma_i^exponent``. 1 is Neyman's allocation, optimal when a
        pixel's error falls as ``1 / n`` (the ``random`` sampler, the
        default there); stratified and QMC samplers converge faster where the
        integrand is smooth, so the pilot's sample variance overstates what a
        pixel needs: the default there is 0.5 (measured on the Cornell box,
        64 x 64, 256 spp, Sobol': MSE 1.65e-5 uniform, 1.45e-5 at 0.7,
        1.20e-5 at 0.5, 1.22e-5 at 0.3; docs/performance.md).
    max_depth, heuristic, precision, light_sampling
        As for :func:`mcvar.integrators.render`.
    rr_depth : int or None
        Path segments before Russian roulette starts (None: the integrators'
        :data:`~mcvar.integrators.RR_START_DEPTH`); default
        :data:`ADAPTIVE_RR_DEPTH`.
    workers : int
        Processes for the batches: the calling process and ``workers - 1``
        local ones (``fork``); the caller takes batches from the end of the
        queue while the pool takes them from the front, so two workers on a
        machine whose second core is busy cost little more than one.
        Ignored when ``executor`` is given (the caller then only waits).
    executor : concurrent.futures.Executor-like, optional
        Runs the batches (``submit``); the image does not depend on it.
    progress : bool or callable
        True: a tqdm bar over paths; a callable gets ``(paths_done, paths_total)``.

    Returns
    -------
    Render
        ``image`` is the second stage's per-pixel mean; ``spp`` the average
        samples per pixel spent (pilot included); ``variance`` is scaled so
        that ``variance / spp`` is each pixel's variance of the mean
        (``s_i^2 / n_i``): :attr:`Render.standard_error` stays per pixel.
        An :class:`AdaptiveRender`: ``spp_map`` holds the second stage's
        samples per pixel, (H, W).

    Notes
    -----
    Unbiased: see the module docstring (the pilot's samples are not in the
    image). Ctrl-C (``KeyboardInterrupt``, also from a ``progress``
    callback) returns ``interrupted=True`` with the finished batches; pixels
    whose second stage did not finish show their pilot mean (still unbiased:
    which pixels finished depends on timing, not on sample values).
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a mcvar.scene.Scene (see load_scene); got {type(scene).__name__}")
    integrator = check_choice(integrator, "integrator", ADAPTIVE_INTEGRATORS)
    sampler = check_choice(sampler, "sampler", tuple(SAMPLERS))
    heuristic = check_choice(heuristic, "heuristic", tuple(HEURISTICS))
    precision = check_choice(precision, "precision", ("float32", "float64"))
    light_sampling = check_choice(light_sampling, "light_sampling", LIGHT_SAMPLING)
    visible_lights = check_choice(visible_lights, "visible_lights", VISIBLE_LIGHTS)
    rr_threshold = _check_rr_threshold(rr_threshold)
    if rr_depth is not None:
        rr_depth = check_count(rr_depth, "rr_depth")
    spp = check_count(spp, "spp")
    if sampler in ("grid", "jittered"):
        raise ValueError(f"sampler {sampler!r} needs square sample counts; render_adaptive uses powers of two "
                         "(use sobol, random, multi_jittered, ...)")
    if isinstance(res, (int, np.integer)) and not isinstance(res, (bool, np.bool_)):
        size = (check_count(res, "res"), check_count(res, "res"))
    elif isinstance(res, (tuple, list)) and len(res) == 2:
        size = (check_count(res[0], "res[0] (width)"), check_count(res[1], "res[1] (height)"))
    else:
        raise TypeError(f"res must be an int (square image) or a (width, height) pair; got {res!r}")
    if pilot_spp is None:
        pilot = max(4, spp // 32)
    elif isinstance(pilot_spp, (int, np.integer)) and not isinstance(pilot_spp, bool) and pilot_spp == 0:
        pilot = 0
    else:
        pilot = check_count(pilot_spp, "pilot_spp")
    lo = check_count(min_spp, "min_spp") if min_spp is not None else max(1, spp // 8)
    hi = check_count(max_spp, "max_spp") if max_spp is not None else 64 * spp
    if exponent is None:
        exponent = 1.0 if sampler == "random" else 0.5
    exponent = float(exponent)
    if not 0.0 <= exponent <= 1.0:
        raise ValueError(f"exponent must be in [0, 1]; got {exponent}")
    if pilot == 1:
        raise ValueError(f"pilot_spp must be 0 (no pilot: uniform spp) or >= 2 (a variance needs two "
                         f"samples); got {pilot}")
    if pilot + lo > spp:
        raise ValueError(f"pilot_spp + min_spp must be <= spp; got {pilot} + {lo} > {spp}")
    if hi < lo:
        raise ValueError(f"max_spp must be >= min_spp; got {hi} < {lo}")
    if max_depth is not None:
        max_depth = check_count(max_depth, "max_depth")
        if integrator.startswith("direct") and max_depth != 2:
            raise ValueError(f"max_depth must be None or 2 for {integrator!r}; got {max_depth}")
    workers = check_count(workers, "workers")
    w, h = size
    n_pix = w * h
    root = as_rng(rng)
    token = uuid.uuid4().hex
    own = None
    if executor is None and workers > 1:
        import multiprocessing

        # the parent is one of the ``workers``: it renders batches too (see run)
        ctx = multiprocessing.get_context("fork") if "fork" in multiprocessing.get_all_start_methods() else None
        executor = own = ProcessPoolExecutor(max_workers=workers - 1, mp_context=ctx)
    common = (token, scene, integrator, sampler, size, max_depth, heuristic, precision, light_sampling,
              rr_depth, visible_lights, rr_threshold)
    total_paths = n_pix * spp
    bar = None
    if progress is True:
        from tqdm.auto import tqdm

        bar = tqdm(total=total_paths, unit="path", unit_scale=True, desc=f"{scene.name} adaptive", leave=False)
    callback = progress if callable(progress) else None
    done_paths = 0

    def run(batches, stream, sink, common=common):
        """Run (pixels, n) batches with seeds spawned from ``stream``; ``sink(pixels, result)``
        for each as it finishes (a Ctrl-C leaves the finished ones sunk). A batch's
        result depends only on its index's seed, so neither the order nor who ran it
        changes the image."""
        nonlocal done_paths
        seeds = stream.spawn(len(batches))
        futures = []

        def finish(i, r):
            nonlocal done_paths
            px, n = batches[i]
            sink(px, r)
            done_paths += px.shape[0] * n
            if bar is not None:
                bar.update(px.shape[0] * n)
            if callback is not None:
                callback(done_paths, total_paths)

        try:
            if executor is None:
                for i, ((px, n), seed) in enumerate(zip(batches, seeds)):
                    finish(i, _run_level(*common, px, n, seed))
                return
            # largest batches first (the image does not depend on the order: seeds go by index)
            order = sorted(range(len(batches)), key=lambda i: -batches[i][0].shape[0] * batches[i][1])
            futures = [None] * len(batches)
            for i in order:
                (px, n), seed = batches[i], seeds[i]
                futures[i] = executor.submit(_run_level, *common, px, n, seed)
            pending = list(range(len(batches)))
            if own is not None:
                # Our own pool has workers - 1 processes; the parent takes batches
                # from the small end of the queue until it meets the pool's:
                # a batch it can still cancel has not started anywhere. When
                # the other core is busy (a shared machine) the parent just does
                # most of the work itself instead of waiting on a starved worker.
                for i in reversed(order):
                    if not futures[i].cancel():
                        break
                    finish(i, _run_level(*common, *batches[i], seeds[i]))
                    pending.remove(i)
            for i in pending:
                finish(i, futures[i].result())
        finally:
            for f in futures:             # never leave a render's batches running
                f.cancel()

    s = np.zeros((n_pix, 3))
    sq = np.zeros((n_pix, 3))
    total = np.zeros((n_pix, 3))
    total_sq = np.zeros((n_pix, 3))
    pilot_done = np.zeros(n_pix, dtype=bool)
    done = np.zeros(n_pix, dtype=bool)
    counts = np.full(n_pix, spp, dtype=np.int64)
    rays = 0
    interrupted = False

    def pilot_sink(px, r):
        nonlocal rays
        s[px], sq[px] = r[0], r[1]
        rays += r[2]
        pilot_done[px] = True

    def main_sink(px, r):
        nonlocal rays
        total[px], total_sq[px] = r[0], r[1]
        rays += r[2]
        done[px] = True

    start = time.perf_counter()
    try:
        pilot_stream, main_stream = root.spawn(2)
        if pilot:
            # the pilot only ranks pixels: paths cut at PILOT_MAX_DEPTH segments
            # (no roulette, no long tail of nearly empty wavefronts) estimate
            # sigma_i well enough, and the image never sees them
            pilot_common = common
            if max_depth is None and integrator in ("path", "path_bsdf") and PILOT_MAX_DEPTH:
                pilot_common = common[:5] + (PILOT_MAX_DEPTH,) + common[6:]
            run(_jobs([(pilot, np.arange(n_pix))], PILOT_PATHS_PER_BATCH), pilot_stream, pilot_sink,
                pilot_common)
            var = np.maximum(sq - s * s / pilot, 0.0) / (pilot - 1)
            sigma = np.sqrt(var.mean(axis=1)).reshape(h, w)
            # a pixel next to a high-variance one may have missed what made it
            # high (a light edge the pilot's few samples did not cross): dilate
            sigma = maximum_filter(sigma, size=3, mode="nearest").reshape(-1)
            counts = allocate(sigma, n_pix * (spp - pilot), min_spp=lo, max_spp=hi, exponent=exponent)
        levels = [(int(n), np.flatnonzero(counts == n)) for n in np.unique(counts)]
        run(_jobs(levels), main_stream, main_sink)
    except KeyboardInterrupt:
        # Pixels whose second-stage batch did not finish fall back to their
        # pilot mean (or 0 without one): which pixels did depends on timing,
        # not on sample values, so every pixel's estimate stays unbiased.
        interrupted = True
        back = ~done & pilot_done
        total[back], total_sq[back] = s[back], sq[back]
        counts = np.where(done, counts, np.where(pilot_done, pilot, 0))
    finally:
        if own is not None:
            own.shutdown(wait=not interrupted, cancel_futures=True)
        _TRACERS.pop(token, None)
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - start
    n_i = np.maximum(counts[:, None], 1).astype(np.float64)
    image = total / n_i
    spent = max(1, int(round((n_pix * pilot * pilot_done.mean() + counts[done].sum()) / n_pix)))
    with np.errstate(invalid="ignore", divide="ignore"):
        var_i = np.where(n_i > 1, np.maximum(total_sq - total * total / n_i, 0.0) / np.maximum(n_i - 1, 1), 0.0)
    variance = var_i * (spent / n_i)          # variance / spp = s_i^2 / n_i
    fields = {f.name for f in dataclasses.fields(Render)}
    kw = dict(image=image.reshape(h, w, 3), spp=spent, seconds=seconds, interrupted=interrupted,
              variance=variance.reshape(h, w, 3), rays=rays, scene=scene.name, integrator=integrator,
              sampler=sampler, res=size, max_depth=max_depth, heuristic=heuristic, batch_spp=int(counts.max()),
              workers=workers, precision=precision, spp_map=counts.reshape(h, w), pilot_spp=pilot)
    return AdaptiveRender(**{k: v for k, v in kw.items() if k in fields or k in ("spp_map", "pilot_spp")})
