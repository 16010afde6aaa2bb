"""How :func:`~mcvar.integrators.render` spreads samples over pixels: the
``allocation`` strategies :class:`Uniform` and :class:`Adaptive`.

The driver (:mod:`mcvar.integrators.driver`) checks the request, builds the
tracer, the worker pool and the progress bar, and hands a render in progress
(``run``) to the allocation, which decides the stages and their batches:

* :class:`Uniform`: every pixel gets ``spp`` samples, in spp batches over the
  whole image (slices of one stratified pattern per pixel), added to one film
  in batch order;
* :class:`Adaptive`: unbiased two-stage sampling. A **pilot** of
  ``pilot_spp`` samples per pixel is used *only* to estimate each pixel's
  standard deviation ``sigma_i``; the rest of the budget goes to ``n_i``
  fresh samples per pixel with ``n_i`` proportional to ``sigma_i``
  (Neyman's allocation, which minimises ``sum_i sigma_i^2 / n_i`` for a
  fixed ``sum_i n_i``; Cochran 1977, ch. 5.5 and sec. 5A.7; Veach 1997,
  sec. 2.5), rounded to powers of two (so that Sobol' and other nets stay
  nets), at least ``min_spp``. The image is the mean of the second stage's
  samples alone: the allocation is a function of the pilot and the second
  stage's samples are drawn after it and independently of it, so every
  pixel's estimate is unbiased *given* its ``n_i``, hence unbiased. Keeping
  the pilot's samples with the natural weights ``n0 / (n0 + n_i)`` would be
  biased (a pixel whose pilot came out high gets more stage-two samples and
  so a *smaller* weight on that high pilot); the pilot costs ``pilot_spp /
  spp`` of the budget (1/32 by default) instead.

Both work for any camera-kind method of the registry (adaptive) or any method
(uniform), with the same workers, executors, progress, Ctrl-C and memory guard.
"""
from __future__ import annotations

import dataclasses
import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter

from .._validation import check_count
from ..samplers import SAMPLERS, pixel_samples
from .film import Film, Render
from .settings import STRATEGIES
from .stream import WHOLE_SET_FLOATS, whole_dims, whole_pattern

__all__ = ["Uniform", "Adaptive", "AdaptiveRender", "allocate", "get_allocation", "ALLOCATIONS",
           "PATHS_PER_BATCH", "ADAPTIVE_DIM", "PILOT_MAX_DEPTH", "PILOT_PATHS_PER_BATCH", "PILOT_BATCHES",
           "pilot_batch_paths", "MAIN_PATHS_PER_BATCH", "MAIN_BATCHES", "main_batch_paths", "TAIL_SPLIT"]

#: Paths per batch when ``batch_spp`` is not given: big enough that per-bounce
#: overhead is small, small enough that two processes do not fight over the
#: shared cache and memory bandwidth (measured: 1.8x with 2 workers at 2^16, 1.4x at 2^18).
PATHS_PER_BATCH = 1 << 16

#: Sample dimensions the sampler feeds per path in adaptive renders: the pixel
#: position, then the first vertex's light and BSDF samples (later vertices
#: iid). Feeding more vertices (padded Sobol' pairs) lowered the MSE of a
#: 256-spp Cornell render by 4% for 13% more time (docs/performance.md).
ADAPTIVE_DIM = 6

#: Segments of the pilot's paths when the render's depth is free (None:
#: Russian roulette) and the method takes ``max_depth``. The pilot's samples
#: only rank the pixels; cut paths skip the long tail of nearly empty
#: wavefronts that made a pilot batch cost 2-3x per path what a main batch
#: does (measured: adaptive 256-spp Cornell 0.677 -> 0.643 s, MSE unchanged).
PILOT_MAX_DEPTH = 5

#: Paths per pilot batch at least: smaller than the second stage's so that
#: the pilot, a few spp over the whole image, still spreads over two or more
#: workers.
PILOT_PATHS_PER_BATCH = PATHS_PER_BATCH // 16
#: Batches a large pilot is cut into (:func:`pilot_batch_paths`): enough for
#: two workers to share it evenly.
PILOT_BATCHES = 8


#: Largest batch of an adaptive render's second stage: the Lambertian kernel
#: traces a batch through a wavefront of
#: :data:`~mcvar.integrators.lambertian.WAVEFRONT_PATHS` slots (path
#: regeneration), so a larger batch has fewer nearly empty tail iterations
#: per path (Cornell 128 x 128, 256 spp: docs/performance.md, 'The suite').
MAIN_PATHS_PER_BATCH = 1 << 18
#: Batches a large second stage is cut into at least: enough for two workers
#: to end together (each takes whole batches).
MAIN_BATCHES = 16


def main_batch_paths(paths: int) -> int:
    """Paths per batch of a second stage of ``paths`` paths: :data:`PATHS_PER_BATCH`
    until the stage fills :data:`MAIN_BATCHES` such batches, then the largest
    power of two that still gives ``MAIN_BATCHES``, at most
    :data:`MAIN_PATHS_PER_BATCH` (64 x 64 at 256 spp keeps 65,536; 128 x 128
    at 256 spp and 256 x 256 at 64 spp get 262,144)."""
    per = max(1, paths // MAIN_BATCHES)
    return int(min(MAIN_PATHS_PER_BATCH, max(PATHS_PER_BATCH, 1 << (per.bit_length() - 1))))


def pilot_batch_paths(pilot_paths: int) -> int:
    """Paths per pilot batch of a pilot of ``pilot_paths`` paths (the default
    of :attr:`Adaptive.pilot_paths_per_batch`): :data:`PILOT_PATHS_PER_BATCH`
    until the pilot fills :data:`PILOT_BATCHES` such batches, then the pilot
    in ``PILOT_BATCHES`` batches, at most :data:`PATHS_PER_BATCH` paths each.

    A batch has a fixed cost per bounce (a few dozen NumPy calls whatever its
    size), so a 4,096-path pilot batch cost 1.4-1.5 s per M paths against
    0.7-0.9 in batches of 16,384-65,536 (Cornell box, 256 x 256, 64 spp:
    the pilot's 4 spp are 1/16 of the paths and were 8-10% of the time;
    docs/performance.md, 'Cost per path and image size'). Up to 32,768
    pilot paths (64 x 64 at 256 spp) the batches stay as they were.
    """
    return int(min(PATHS_PER_BATCH, max(PILOT_PATHS_PER_BATCH, pilot_paths // PILOT_BATCHES)))


@dataclass(frozen=True, eq=False)
class AdaptiveRender(Render):
    """A :class:`~mcvar.integrators.Render` of an adaptive render, with
    ``spp_map`` (H, W): the second stage's samples per pixel, and
    ``pilot_spp``: the pilot's (0: none)."""

    spp_map: np.ndarray | None = None
    pilot_spp: int = 0


def allocate(sigma, budget: int, *, min_spp: int, max_spp: int, exponent: float = 1.0) -> np.ndarray:
    """Samples per pixel proportional to ``sigma ** exponent`` (Neyman), in powers of two.

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


@dataclass(frozen=True, eq=False)
class Spec:
    """One batch of a stage: ``spp`` samples of each pixel in ``pixels``
    (None: every pixel), ``whole``: its slice of the kept pattern."""

    pixels: np.ndarray | None
    spp: int
    whole: np.ndarray | None = None


def caustic_stage(run):
    """The caustic light paths of a render with ``caustics='light'`` (the path
    methods that count emission found by BSDF sampling, on scenes where
    :func:`~mcvar.integrators.caustics.light_caustics_apply`), run as a stage of
    splat batches: their film, or None when the render has none.

    ``CAUSTIC_PATH_FRACTION`` light subpaths per camera path of the render, in
    at least two batches (the film's variance comes from their spread).
    """
    from .caustics import CAUSTIC_METHOD, CAUSTIC_PATH_FRACTION
    from .state import light_caustics_apply

    plan = run.plan
    strategies = STRATEGIES.get(plan.method.name)
    depth = plan.settings.max_depth if strategies is None or strategies.depth is None else strategies.depth
    if (plan.settings.caustics != "light" or strategies is None or not strategies.bsdf_hits
            or (depth is not None and depth < 3) or not light_caustics_apply(plan.scene)):
        return None
    n_pix = plan.n_pixels
    spp = max(2, math.ceil(CAUSTIC_PATH_FRACTION * plan.spp))          # light paths per pixel, as spp
    per = max(1, min(PATHS_PER_BATCH // n_pix, -(-spp // 2)))
    specs = [Spec(None, min(per, spp - a)) for a in range(0, spp, per)]
    film = Film(n_pix, per_sample=False)
    run.stage(iter(specs), len(specs), run.streams.caustics, lambda spec, r: film.add(r, spec.spp),
              method=CAUSTIC_METHOD)
    return film


def _with_caustics(image, variance, spp, caustic, res):
    """``image`` plus the caustic film's image, and the variance of the sum in
    per-sample units of ``spp`` camera samples (the two are independent)."""
    if caustic is None or caustic.batches == 0:
        return image, variance
    image = image + caustic.image(res)
    var_c = caustic.variance(res)
    if variance is not None and var_c is not None:
        variance = variance + var_c * (spp / caustic.spp)
    return image, variance


def _batch_spp(spp: int, n_pix: int, batch_spp, sampler: str) -> int:
    """Samples per pixel of a uniform batch (the last one may hold fewer)."""
    if batch_spp is not None:
        return min(batch_spp, spp)
    if n_pix * spp <= PATHS_PER_BATCH:
        return spp
    b = max(1, PATHS_PER_BATCH // n_pix)
    base = 4 if SAMPLERS[sampler].square else 2   # keep squares / powers of two
    return min(base ** int(math.log(b, base) + 1e-9), spp)


@dataclass(frozen=True)
class Uniform:
    """The same ``spp`` in every pixel: spp batches over the whole image.

    ``render(..., allocation='uniform')`` (the default). Batches of
    ``batch_spp`` samples per pixel (default: all of them if the batch holds
    at most :data:`PATHS_PER_BATCH` paths, else a power of two, of four for
    grid / jittered, that fits) trace consecutive slices of one stratified
    pattern per pixel (:func:`~mcvar.integrators.stream.whole_pattern`) and
    are added to one film in batch order.
    """

    name = "uniform"
    sampler_dim = None            # the driver's default (SAMPLER_DIM)
    progress_unit = "spp"

    def check(self, plan) -> "Uniform":
        b = _batch_spp(plan.spp, plan.n_pixels, plan.run.batch_spp, plan.sampler)
        for size in {b, plan.spp % b or b}:   # a sampler that cannot make b points fails here, before any work
            pixel_samples(plan.sampler, 1, size, dim=2, rng=0)
        return self

    def memory(self, plan) -> dict:
        """What the memory guard counts: paths per batch, kept pattern floats, films."""
        b = _batch_spp(plan.spp, plan.n_pixels, plan.run.batch_spp, plan.sampler)
        n_batches = -(-plan.spp // b)
        whole = plan.n_pixels * plan.spp * whole_dims(plan.sampler, plan.n_pixels, plan.spp, n_batches, plan.dim)
        return dict(batch_paths=plan.n_pixels * b, whole_floats=whole, films=1)

    def render(self, run) -> Render:
        plan = run.plan
        spp, n_pix = plan.spp, plan.n_pixels
        b = _batch_spp(spp, n_pix, plan.run.batch_spp, plan.sampler)
        n_batches = -(-spp // b)
        whole = whole_pattern(plan.sampler, n_pix, spp, n_batches, plan.dim, run.streams.pattern)

        def specs():
            for start in range(0, spp, b):        # lazily: 2^28 batches cost nothing up front
                size = min(b, spp - start)
                yield Spec(None, size, None if whole is None else whole[:, start:start + size])

        film = Film(n_pix, per_sample=plan.method.kind in ("camera", "first_hit"))
        run.start(total=spp)
        caustic = None
        try:
            caustic = caustic_stage(run)
            run.stage(specs(), n_batches, run.streams.stage[0], lambda spec, r: film.add(r, spec.spp))
        except KeyboardInterrupt:
            run.interrupted = True
        extra = {k: v / film.spp for k, v in film.extra.items()} if film.spp else {}
        image, variance = film.image(plan.res), film.variance(plan.res)
        image, variance = _with_caustics(image, variance, film.spp, caustic, plan.res)
        return run.result(image=image, variance=variance, spp=film.spp,
                          rays=film.rays + (caustic.rays if caustic else 0), batch_spp=b, extra=extra)


#: The second stage's last batches, a batch's worth of paths, are each cut into
#: this many (:func:`_level_specs`): two workers take whole batches, so the one
#: that finishes first waits for the other's last batch; quarter batches at the
#: end make that wait about a quarter as long (docs/performance.md, 'Two
#: workers: the end of a stage').
TAIL_SPLIT = 4


def _blocks(pixels, width: int):
    """``pixels`` (row-major indices of an image ``width`` wide) in 2 x 2 blocks:
    the blocks in row-major order, each block's pixels in row-major order, so
    that 4 consecutive pixels of a full block are its 4 pixels (the tiles of
    path reuse, :mod:`mcvar.integrators.reuse`)."""
    y, x = np.divmod(pixels, width)
    return pixels[np.lexsort((x & 1, y & 1, x >> 1, y >> 1))]


def _plain_specs(levels, paths_per_batch: int):
    """Batches of at most ``paths_per_batch`` paths for (n, pixels) levels, lazily."""
    for n, pixels in levels:
        if n <= paths_per_batch:
            per = paths_per_batch // n
            for a in range(0, pixels.shape[0], per):
                yield Spec(pixels[a:a + per], n)
        else:
            for p in range(pixels.shape[0]):
                for a in range(0, n, paths_per_batch):
                    yield Spec(pixels[p:p + 1], min(paths_per_batch, n - a))


def _level_specs(levels, paths_per_batch: int, tail_split: int = 1):
    """Batches of at most ``paths_per_batch`` paths for (n, pixels) levels: many
    pixels per batch where ``n`` is small, a pixel's samples in several
    batches where ``n`` exceeds the batch (each its own sample set); made
    lazily (a pilot of 2^35 samples per pixel is 2^28 batches).

    With ``tail_split > 1`` (the second stage: :data:`TAIL_SPLIT`) the last
    batches, from the end until they hold ``paths_per_batch`` paths, are cut
    by pixels into ``tail_split`` pieces each (a batch of one pixel stays
    whole); only those are held back until the end. A pixel's samples of a
    level stay in one batch either way, so each pixel's estimate has the same
    distribution.
    """
    specs = _plain_specs(levels, paths_per_batch)
    if tail_split <= 1:
        yield from specs
        return
    held, paths = deque(), 0
    for spec in specs:
        held.append(spec)
        paths += spec.pixels.shape[0] * spec.spp
        while paths - held[0].pixels.shape[0] * held[0].spp >= paths_per_batch:
            first = held.popleft()
            paths -= first.pixels.shape[0] * first.spp
            yield first
    for spec in held:
        px = spec.pixels
        step = -(-px.shape[0] // tail_split)
        for a in range(0, px.shape[0], step):
            yield Spec(px[a:a + step], spec.spp)


def _count_level_specs(levels, paths_per_batch: int, tail_split: int = 1) -> int:
    """How many batches :func:`_level_specs` makes (without making them)."""
    total = 0
    for n, pixels in levels:
        if n <= paths_per_batch:
            total += -(-pixels.shape[0] // (paths_per_batch // n))
        else:
            total += pixels.shape[0] * -(-n // paths_per_batch)
    if tail_split > 1:
        paths = 0
        for npix, spp in _reversed_sizes(levels, paths_per_batch):
            total += min(tail_split, npix) - 1
            paths += npix * spp
            if paths >= paths_per_batch:
                break
    return total


def _reversed_sizes(levels, paths_per_batch: int):
    """``(pixels, spp)`` of :func:`_plain_specs`' batches, last first, lazily."""
    for n, pixels in reversed(list(levels)):
        size = pixels.shape[0]
        if n <= paths_per_batch:
            per = paths_per_batch // n
            for a in reversed(range(0, size, per)):
                yield min(per, size - a), n
        else:
            for _ in range(size):
                for a in reversed(range(0, n, paths_per_batch)):
                    yield 1, min(paths_per_batch, n - a)


@dataclass(frozen=True, eq=False)
class Adaptive:
    """Unbiased two-stage adaptive sampling (module docstring): a pilot ranks
    the pixels, the second stage's samples alone make the image.

    ``render(..., allocation='adaptive')`` or ``allocation=Adaptive(...)``;
    camera-kind methods only (samples per pixel through the camera). ``spp``
    is the average over the image, pilot included.

    Attributes
    ----------
    pilot_spp : int, optional
        Pilot samples per pixel (default ``max(4, spp // 32)``); they only
        decide the allocation. 0: no pilot, every pixel gets ``spp``: the
        uniform estimator rendered as pixel tiles (each batch draws its own
        pixels' whole sample sets).
    min_spp, max_spp : int, optional
        Bounds on the second stage's samples per pixel (default
        ``max(1, spp // 8)`` and ``64 spp``).
    exponent : float in [0, 1], optional
        ``n_i ~ sigma_i^exponent``. 1 is Neyman's allocation, optimal when a
        pixel's error falls as ``1 / n`` (the default for ``random``);
        stratified and QMC samplers converge faster where the integrand is
        smooth, so the pilot's sample variance overstates what a pixel needs:
        the default there is 0.5 (measured on the Cornell box, 64 x 64, 256
        spp, Sobol': MSE 1.65e-5 uniform, 1.45e-5 at 0.7, 1.20e-5 at 0.5,
        1.22e-5 at 0.3; docs/performance.md).
    pilot_paths_per_batch : int, optional
        Paths per pilot batch (default :func:`pilot_batch_paths` of the
        pilot's paths: :data:`PILOT_PATHS_PER_BATCH`, more for large images).
    paths_per_batch : int, optional
        Paths per second-stage batch (default :func:`main_batch_paths` of the
        render's paths where the Lambertian kernel traces it, whose wavefront
        regenerates paths: up to :data:`MAIN_PATHS_PER_BATCH`; otherwise
        :data:`PATHS_PER_BATCH`). It does not depend on ``workers``.
    spp_map : ndarray of int (H, W), optional
        The second stage's samples per pixel, given instead of found by a
        pilot (then ``pilot_spp`` must be None or 0): an oracle allocation,
        or a previous render's ``spp_map``; with the same ``rng`` the second
        stage is that render's second stage, sample for sample.

    Notes
    -----
    A pixel next to a high-variance one may have missed what made it high
    (a light edge the pilot's few samples did not cross): ``sigma`` is
    dilated by a 3 x 3 maximum filter before allocating. Ctrl-C returns
    ``interrupted=True`` with the finished batches; pixels whose second
    stage did not finish show their pilot mean (still unbiased: which pixels
    finished depends on timing, not on sample values).
    """

    pilot_spp: int | None = None
    min_spp: int | None = None
    max_spp: int | None = None
    exponent: float | None = None
    pilot_paths_per_batch: int | None = None
    spp_map: np.ndarray | None = None
    paths_per_batch: int | None = None

    name = "adaptive"
    sampler_dim = ADAPTIVE_DIM
    progress_unit = "path"

    def __post_init__(self):
        if self.pilot_spp is not None:
            if isinstance(self.pilot_spp, (int, np.integer)) and not isinstance(self.pilot_spp, bool) \
                    and self.pilot_spp == 0:
                object.__setattr__(self, "pilot_spp", 0)
            else:
                object.__setattr__(self, "pilot_spp", check_count(self.pilot_spp, "pilot_spp"))
            if self.pilot_spp == 1:
                raise ValueError("pilot_spp must be 0 (no pilot: uniform spp) or >= 2 (a variance needs two "
                                 "samples); got 1")
        for key in ("min_spp", "max_spp"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, check_count(getattr(self, key), key))
        if self.exponent is not None:
            e = self.exponent
            if isinstance(e, (bool, np.bool_)) or not isinstance(e, (int, float, np.integer, np.floating)):
                raise TypeError(f"exponent must be a number in [0, 1]; got {type(e).__name__}")
            if not 0.0 <= float(e) <= 1.0:
                raise ValueError(f"exponent must be in [0, 1]; got {e}")
            object.__setattr__(self, "exponent", float(e))
        for key in ("pilot_paths_per_batch", "paths_per_batch"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, check_count(getattr(self, key), key))
        if self.spp_map is not None:
            m = np.asarray(self.spp_map)
            if m.ndim != 2 or not np.issubdtype(m.dtype, np.integer) or m.size == 0 or m.min() < 1:
                raise ValueError(f"spp_map must be an (H, W) array of integers >= 1; got {m.dtype} {m.shape}")
            if self.pilot_spp:
                raise ValueError("give spp_map or pilot_spp, not both (spp_map replaces the pilot)")
            object.__setattr__(self, "spp_map", m.astype(np.int64))
            object.__setattr__(self, "pilot_spp", 0)

    def check(self, plan) -> "Adaptive":
        """This allocation with its defaults resolved for ``plan``; ValueError for what it cannot do."""
        method, spp, sampler = plan.method, plan.spp, plan.sampler
        if method.kind != "camera":
            raise ValueError(f"allocation='adaptive' needs a camera-kind method (samples per pixel through the "
                             f"camera); method (integrator) {method.name!r} is of kind {method.kind!r}")
        if SAMPLERS[sampler].square:
            raise ValueError(f"sampler {sampler!r} needs square sample counts; adaptive allocation uses powers "
                             "of two (use sobol, random, multi_jittered, ...)")
        if plan.run.batch_spp is not None:
            raise ValueError("batch_spp applies to allocation='uniform' (adaptive batches are cut by paths)")
        main = self.paths_per_batch
        if main is None:
            from .state import lambertian_scene     # layer: the wavefront's tables (as caustic_stage)
            regenerates = (method.name in STRATEGIES and plan.settings.kernel != "general"
                           and lambertian_scene(plan.scene))
            main = main_batch_paths(plan.n_pixels * spp) if regenerates else PATHS_PER_BATCH
        if self.spp_map is not None:
            w, h = plan.res
            if self.spp_map.shape != (h, w):
                raise ValueError(f"spp_map must have the image's shape (H, W) = {(h, w)}; got {self.spp_map.shape}")
            return dataclasses.replace(self, paths_per_batch=main)
        pilot = max(4, spp // 32) if self.pilot_spp is None else self.pilot_spp
        lo = max(1, spp // 8) if self.min_spp is None else self.min_spp
        hi = 64 * spp if self.max_spp is None else self.max_spp
        exponent = (1.0 if sampler == "random" else 0.5) if self.exponent is None else self.exponent
        if pilot + lo > spp:
            raise ValueError(f"pilot_spp + min_spp must be <= spp; got {pilot} + {lo} > {spp}")
        if hi < lo:
            raise ValueError(f"max_spp must be >= min_spp; got {hi} < {lo}")
        per_batch = pilot_batch_paths(plan.n_pixels * pilot) if self.pilot_paths_per_batch is None \
            else self.pilot_paths_per_batch
        return dataclasses.replace(self, pilot_spp=pilot, min_spp=lo, max_spp=hi, exponent=exponent,
                                   pilot_paths_per_batch=per_batch, paths_per_batch=main)

    def memory(self, plan) -> dict:
        return dict(batch_paths=self.paths_per_batch or PATHS_PER_BATCH, whole_floats=0, films=2)

    def _pilot_settings(self, plan):
        s = plan.settings
        m = plan.method
        if s.max_depth is None and m.uses_max_depth and m.fixed_depth is None and PILOT_MAX_DEPTH:
            return dataclasses.replace(s, max_depth=PILOT_MAX_DEPTH)
        return s

    def render(self, run) -> Render:
        plan = run.plan
        n_pix, spp, pilot = plan.n_pixels, plan.spp, self.pilot_spp
        w, h = plan.res
        pilot_film, film = Film(n_pix, True), Film(n_pix, True)
        caustic = None
        counts = np.full(n_pix, spp, dtype=np.int64) if self.spp_map is None else self.spp_map.reshape(-1)
        run.start(total=int(counts.sum()) if self.spp_map is not None else n_pix * spp)

        def sink(target):
            return lambda spec, r: target.add(r, spec.spp, spec.pixels)

        try:
            if pilot:
                # the pilot only ranks pixels: its paths are cut at PILOT_MAX_DEPTH
                # segments, and the image never sees them
                levels = [(pilot, _blocks(np.arange(n_pix), w))]
                run.stage(_level_specs(levels, self.pilot_paths_per_batch),
                          _count_level_specs(levels, self.pilot_paths_per_batch), run.streams.stage[0],
                          sink(pilot_film), settings=self._pilot_settings(plan))
                s, sq = pilot_film.total, pilot_film.total_sq
                var = np.maximum(sq - s * s / pilot, 0.0) / (pilot - 1)
                sigma = maximum_filter(np.sqrt(var.mean(axis=1)).reshape(h, w), size=3, mode="nearest")
                counts = allocate(sigma.reshape(-1), n_pix * (spp - pilot), min_spp=self.min_spp,
                                  max_spp=self.max_spp, exponent=self.exponent)
            # most samples per pixel first (seeds go by batch index: the image does not depend on the order)
            levels = [(int(n), _blocks(np.flatnonzero(counts == n), w)) for n in np.unique(counts)[::-1]]
            caustic = caustic_stage(run)
            per = self.paths_per_batch
            run.stage(_level_specs(levels, per, TAIL_SPLIT), _count_level_specs(levels, per, TAIL_SPLIT),
                      run.streams.stage[1], sink(film))
        except KeyboardInterrupt:
            run.interrupted = True
        return self._result(run, pilot_film, film, counts, caustic)

    def _result(self, run, pilot_film: Film, film: Film, counts, caustic=None) -> AdaptiveRender:
        """The second stage's per-pixel means; where a pixel's second stage did not
        run (Ctrl-C), its pilot mean (or 0 without one)."""
        plan = run.plan
        w, h = plan.res
        n_pix = plan.n_pixels
        back = film.counts == 0
        total = np.where(back[:, None], pilot_film.total, film.total)
        total_sq = np.where(back[:, None], pilot_film.total_sq, film.total_sq)
        used = np.where(back, pilot_film.counts, film.counts)
        n_i = np.maximum(used[:, None], 1).astype(np.float64)
        spent = max(1, int(round((pilot_film.counts.sum() + film.counts.sum()) / n_pix)))
        with np.errstate(invalid="ignore", divide="ignore"):
            var_i = np.where(n_i > 1, np.maximum(total_sq - total * total / n_i, 0.0) / np.maximum(n_i - 1, 1), 0.0)
        variance = var_i * (spent / n_i)          # variance / spp = s_i^2 / n_i
        image, variance = _with_caustics((total / n_i).reshape(h, w, 3), variance.reshape(h, w, 3), spent, caustic,
                                         plan.res)
        return run.result(image=image, variance=variance, spp=spent,
                          rays=pilot_film.rays + film.rays + (caustic.rays if caustic else 0),
                          batch_spp=int(counts.max()), cls=AdaptiveRender,
                          spp_map=used.reshape(h, w), pilot_spp=self.pilot_spp)


#: Allocation strategies by name.
ALLOCATIONS = {"uniform": Uniform, "adaptive": Adaptive}


def get_allocation(allocation):
    """An allocation object from a name (``'uniform'``, ``'adaptive'``) or an object with
    ``check``, ``memory`` and ``render`` (returned as is)."""
    if isinstance(allocation, str):
        if allocation not in ALLOCATIONS:
            raise ValueError(f"allocation must be one of {tuple(ALLOCATIONS)} or an allocation object; "
                             f"got {allocation!r}")
        return ALLOCATIONS[allocation]()
    if all(callable(getattr(allocation, k, None)) for k in ("check", "memory", "render")):
        return allocation
    raise TypeError(f"allocation must be 'uniform', 'adaptive', Uniform() or Adaptive(...); "
                    f"got {type(allocation).__name__}")
