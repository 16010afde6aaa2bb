"""The driver: :func:`render` (argument checks, batches, seeds, executors) and
:class:`WorkerPool`, a local process pool with a lifetime.

A render is split into spp batches; batch ``b`` is a picklable description
(the method, the scene, its seeds and its slice of the sample pattern) that
any ``concurrent.futures.Executor``-like object runs (``executor.submit``).
Batch results are added to the :class:`~mcvar.integrators.film.Film` in batch
order, so the image does not depend on which executor ran the batches or in
what order they finished.
"""
from __future__ import annotations

import math
import time
import uuid
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np

from .._validation import as_rng, check_choice, check_count
from ..samplers import SAMPLERS, pixel_samples
from ..scene import Scene
from ..tracer import Tracer
from .film import BatchJob, Film, Render
from .path import HEURISTICS
from .registry import METHODS, Method, get_method
from .stream import CAMERA_DIMS, SAMPLER_DIM, WHOLE_SET_FLOATS, batch_stream, sample_slices, stream_dim

__all__ = ["render", "WorkerPool", "PATHS_PER_BATCH", "MAX_RENDER_BYTES", "BYTES_PER_PATH",
           "estimate_render_bytes"]

#: Paths per spp batch when ``batch_spp`` is not given: big enough that per-bounce
#: overhead is small, small enough that two processes do not fight over the
#: shared cache and memory bandwidth (measured: 1.8x with 2 workers at 2^16, 1.4x at 2^18).
PATHS_PER_BATCH = 1 << 16
#: Default memory budget of one render (bytes): :func:`render` refuses a render
#: whose :func:`estimate_render_bytes` exceeds it, before allocating anything
#: (``render(..., max_memory=...)`` overrides it).
MAX_RENDER_BYTES = 4 * 2 ** 30
#: Working memory per path of a batch in flight (state, temporaries, shadow
#: rays), bytes: an upper estimate (tracemalloc peak of a 2^16-path Cornell
#: batch, benchmarks/bench_render.py, divided by its paths, rounded up).
BYTES_PER_PATH = 2048


def estimate_render_bytes(n_pixels: int, batch_paths: int, dim: int, workers: int = 1,
                          whole_floats: int = 0) -> int:
    """Memory a render needs (bytes): the film's four ``(n_pixels, 3)`` float64
    arrays (sums, squared sums, image, variance), ``workers`` batches in flight
    (:data:`BYTES_PER_PATH` plus ``dim`` float64 sample dimensions per path) and
    the kept sample pattern (``whole_floats`` float64 numbers)."""
    return int(n_pixels * 3 * 8 * 4 + workers * batch_paths * (BYTES_PER_PATH + 8 * dim) + 8 * whole_floats)


# ---------------------------------------------------------------------------
# Worker processes

def _pool_context():
    """``fork`` where the platform has it: workers start in milliseconds and
    inherit the tracer; elsewhere the platform default."""
    import multiprocessing

    if "fork" in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("fork")
    return None


class WorkerPool(Executor):
    """A local process pool with a lifetime, for one render or many.

    ``render(..., workers=n)`` makes one for the render and shuts it down at
    the end. To keep warm processes over several renders (a fresh process
    spends its first batch at about half speed touching new memory), make
    one and pass it::

        with WorkerPool(2) as pool:
            a = render(scene, spp=64, executor=pool)
            b = render(scene, spp=64, executor=pool)

    Processes are started (``fork`` where available) on the first
    :meth:`submit`; :meth:`shutdown` (or leaving the ``with`` block) ends them.
    """

    def __init__(self, workers: int):
        self.workers = check_count(workers, "workers")
        self._executor: ProcessPoolExecutor | None = None

    def submit(self, fn, /, *args, **kwargs):
        if self._executor is None:
            self._executor = ProcessPoolExecutor(max_workers=self.workers, mp_context=_pool_context())
        return self._executor.submit(fn, *args, **kwargs)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        if self._executor is not None:
            executor, self._executor = self._executor, None
            executor.shutdown(wait=wait, cancel_futures=cancel_futures)


#: Per-process cache of the render in progress' tracer, by render token (one
#: entry): built once per render and process instead of once per batch
#: (processes forked after it was built inherit it).
_TRACER_CACHE: dict = {}


def _tracer(token: str, scene, precision: str) -> Tracer:
    tracer = _TRACER_CACHE.get(token)
    if tracer is None:
        tracer = Tracer(scene, dtype=precision)
        _TRACER_CACHE.clear()
        _TRACER_CACHE[token] = tracer
    return tracer


@dataclass(frozen=True)
class _Batch:
    """One batch, picklable: what crosses to the process that runs it."""

    method: Method
    scene: Scene
    precision: str
    token: str
    res: tuple
    spp: int
    sampler: str
    dim: int
    whole: np.ndarray | None
    rng: np.random.Generator
    max_depth: int | None
    heuristic: str
    options: dict
    prepared: object


def _run_batch(batch: _Batch):
    """Build the :class:`BatchJob` (tracer, sample stream) and run the method."""
    n_pix = batch.res[0] * batch.res[1]
    u = batch_stream(batch.sampler, n_pix, batch.spp, batch.dim, batch.whole, batch.rng)
    job = BatchJob(scene=batch.scene, tracer=_tracer(batch.token, batch.scene, batch.precision),
                   res=batch.res, spp=batch.spp, sampler=batch.sampler, u=u, rng=batch.rng,
                   max_depth=batch.max_depth, heuristic=batch.heuristic, options=dict(batch.options),
                   prepared=batch.prepared)
    return batch.method.run_batch(job)


# ---------------------------------------------------------------------------
# render()

def _as_res(res) -> tuple:
    if isinstance(res, (int, np.integer)) and not isinstance(res, (bool, np.bool_)):
        r = check_count(res, "res")
        return (r, r)
    if isinstance(res, (tuple, list)) and len(res) == 2:
        return (check_count(res[0], "res[0] (width)"), check_count(res[1], "res[1] (height)"))
    raise TypeError(f"res must be an int (square image) or a (width, height) pair; got {res!r}")


def _batch_sizes(spp: int, n_pix: int, batch_spp, sampler: str) -> list[int]:
    if batch_spp is None:
        if n_pix * spp <= PATHS_PER_BATCH:
            b = spp
        else:
            b = max(1, PATHS_PER_BATCH // n_pix)
            base = 4 if sampler in ("grid", "jittered") else 2   # keep squares / powers of two
            b = base ** int(math.log(b, base) + 1e-9)
    else:
        b = check_count(batch_spp, "batch_spp")
    b = min(b, spp)
    sizes = [b] * (spp // b)
    if spp % b:
        sizes.append(spp % b)
    return sizes


def _sampler_dim(method: Method, max_depth) -> int:
    """Columns of the sample stream the ``sampler`` feeds for ``method``."""
    if method.kind == "first_hit":
        return CAMERA_DIMS
    depth = method.fixed_depth if method.fixed_depth is not None else max_depth
    need = stream_dim(depth)
    return SAMPLER_DIM if need is None else max(CAMERA_DIMS, min(SAMPLER_DIM, need))


def render(scene: Scene, *, integrator: str = "path", spp: int = 16, res=64, sampler: str = "random",
           rng=None, max_depth: int | None = None, heuristic: str = "power", batch_spp: int | None = None,
           workers: int = 1, executor=None, progress: bool | Callable[[int, int], None] = False,
           precision: Literal["float32", "float64"] = "float32", max_memory: int | None = None,
           **options) -> Render:
    """Render ``scene`` with one method: the mean radiance of ``spp`` samples per pixel.

    Parameters
    ----------
    scene : Scene
        From :func:`mcvar.scene.load_scene`.
    integrator : str
        A registered method, one of :data:`mcvar.integrators.METHODS`
        (``path``, ``direct``, ... see docs/integrators.md).
    spp : int
        Samples per pixel, >= 1 (for splatting and Markov-chain methods the
        same work: ``W H spp`` paths).
    res : int or (int, int)
        Square side, or ``(width, height)``.
    sampler : str
        A sampler of :data:`mcvar.samplers.SAMPLERS`; it feeds the first
        :data:`~mcvar.integrators.stream.SAMPLER_DIM` columns of every path's
        sample stream (pixel position, then per vertex light, BSDF, roulette
        and emitter choice: :mod:`mcvar.integrators.stream`), iid beyond.
    rng : None, int, SeedSequence or Generator
        The same seed gives the same image, for any ``workers`` or ``executor``.
    max_depth : int or None
        Maximum path segments (1 = emitters seen directly, 2 = + direct
        light, ...; fixed depth is biased); None: Russian roulette
        (unbiased). Methods with their own depth (``direct*``: 2) accept only
        None or that depth; first-hit methods only None.
    heuristic : {'power', 'balance'}
        MIS weights (Veach's power heuristic with beta = 2, or balance).
    batch_spp : int, optional
        Samples per pixel per batch; default: all of them if the batch holds at
        most :data:`PATHS_PER_BATCH` paths, else a power of two (of four for
        grid / jittered) that fits.
    workers : int
        Shorthand for ``executor=WorkerPool(workers)`` for this render
        (processes, ``fork`` where available). The image is the same as with
        ``workers=1``; it pays only for renders of two or more batches.
    executor : concurrent.futures.Executor-like, optional
        Runs the batches (anything with ``submit(fn, *args)`` returning a
        future with ``result()``: a :class:`WorkerPool`, a
        ``ProcessPoolExecutor``, Dask's ``Client.get_executor()`` ...). The
        image is the same whichever runs them.
    progress : bool or callable
        True: a tqdm progress bar; a callable is called as
        ``progress(spp_done, spp_total)`` after each batch.
    precision : {'float32', 'float64'}
        Ray-geometry precision of the intersection tests (radiance is always
        accumulated in float64).
    max_memory : int, optional
        Memory budget in bytes (default :data:`MAX_RENDER_BYTES`): a render
        whose :func:`estimate_render_bytes` exceeds it is refused with a
        ``ValueError`` before anything is allocated.
    **options
        The method's own options (``METHODS[integrator].options``, e.g.
        ``kernel='general'`` for the path methods); any other is a ``ValueError``.

    Returns
    -------
    Render
        The image (H, W, 3), float64 linear radiance, row 0 at the top, with
        spp completed, wall time, per-pixel sample variance and the settings.

    Notes
    -----
    ``as_rng(rng).spawn(n_batches + 2)``: stream 0 goes to the method's
    ``prepare``, stream 1 draws the kept sample pattern
    (:func:`mcvar.integrators.stream.sample_slices`), stream ``2 + b`` is batch
    ``b``'s (the same whatever the total number of batches). Batch results
    are added in batch order. Ctrl-C (``KeyboardInterrupt``, also when
    raised by a ``progress`` callback) stops the render and returns the
    batches finished so far with ``interrupted=True``.

    Examples
    --------
    >>> from mcvar.scene import load_scene
    >>> r = render(load_scene("cornell"), spp=2, res=8, rng=1)
    >>> r.image.shape, r.spp
    ((8, 8, 3), 2)
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a mcvar.scene.Scene (see load_scene); got {type(scene).__name__}")
    method = get_method(integrator)
    sampler = check_choice(sampler, "sampler", tuple(SAMPLERS))
    heuristic = check_choice(heuristic, "heuristic", tuple(HEURISTICS))
    precision = check_choice(precision, "precision", ("float32", "float64"))
    spp = check_count(spp, "spp")
    size = _as_res(res)
    workers = check_count(workers, "workers")
    if executor is not None and not callable(getattr(executor, "submit", None)):
        raise TypeError(f"executor must have a submit(fn, *args) method (a concurrent.futures.Executor); "
                        f"got {type(executor).__name__}")
    opts = method.resolve_options(options)
    if max_depth is not None:
        max_depth = check_count(max_depth, "max_depth")
        if not method.uses_max_depth:
            raise ValueError(f"max_depth does not apply to the first-hit method {method.name!r}; got {max_depth}")
        if method.fixed_depth is not None and max_depth != method.fixed_depth:
            raise ValueError(f"max_depth must be None or {method.fixed_depth} for {method.name!r}; got {max_depth}")
    n_pix = size[0] * size[1]
    sizes = _batch_sizes(spp, n_pix, batch_spp, sampler)
    dim = _sampler_dim(method, max_depth)
    budget = MAX_RENDER_BYTES if max_memory is None else check_count(max_memory, "max_memory")
    whole_dims = 0 if sampler == "random" or len(sizes) == 1 else \
        min(dim, WHOLE_SET_FLOATS // (n_pix * spp)) // 2 * 2
    need = estimate_render_bytes(n_pix, n_pix * sizes[0], 0 if sampler == "random" else dim,
                                 workers if executor is None else 1, n_pix * spp * whole_dims)
    if need > budget:
        raise ValueError(f"render of {size[0]} x {size[1]} pixels at {sizes[0]} spp per batch needs about "
                         f"{need / 2 ** 30:.3g} GiB (film and batch memory), more than max_memory = "
                         f"{budget / 2 ** 30:.3g} GiB; lower res or batch_spp, or raise max_memory")
    for b in set(sizes):  # a sampler that cannot make b points fails here, before any work
        pixel_samples(sampler, 1, b, dim=2, rng=0)
    if method.check_scene is not None:
        method.check_scene(scene, opts)
    streams = as_rng(rng).spawn(len(sizes) + 2)
    prepared = method.prepare(scene, opts, streams[0]) if method.prepare is not None else None
    slices = sample_slices(sampler, n_pix, spp, sizes, dim, streams[1])
    token = uuid.uuid4().hex
    _tracer(token, scene, precision)          # built once here; forked workers inherit it
    batches = [_Batch(method, scene, precision, token, size, b, sampler, dim, whole, stream, max_depth,
                      heuristic, opts, prepared)
               for b, whole, stream in zip(sizes, slices, streams[2:])]

    film = Film(n_pix, per_sample=method.kind in ("camera", "first_hit"))
    interrupted = False
    bar = None
    if progress is True:
        from tqdm.auto import tqdm

        bar = tqdm(total=spp, unit="spp", desc=f"{scene.name} {method.name}", leave=False)
    callback = progress if callable(progress) else None
    start = time.perf_counter()

    def collect(result, k):
        film.add(result, sizes[k])
        if bar is not None:
            bar.update(sizes[k])
        if callback is not None:
            callback(film.spp, spp)

    own_pool = None
    if executor is None and workers > 1 and len(batches) > 1:
        executor = own_pool = WorkerPool(workers)
    finished = False
    try:
        if executor is None:
            for k, batch in enumerate(batches):
                collect(_run_batch(batch), k)
        else:
            futures = [executor.submit(_run_batch, batch) for batch in batches]
            try:
                for k, fut in enumerate(futures):
                    collect(fut.result(), k)
            finally:
                for fut in futures:       # never leave a render's batches running
                    fut.cancel()
        finished = True
    except KeyboardInterrupt:
        interrupted = True
    finally:
        if own_pool is not None:
            own_pool.shutdown(wait=finished, cancel_futures=True)
        _TRACER_CACHE.pop(token, None)
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - start
    extra = {k: v / film.spp for k, v in film.extra.items()} if film.spp else {}
    return Render(image=film.image(size), spp=film.spp, seconds=seconds, interrupted=interrupted,
                  variance=film.variance(size), rays=film.rays, scene=scene.name, integrator=method.name,
                  sampler=sampler, res=size, max_depth=max_depth, heuristic=heuristic, batch_spp=sizes[0],
                  workers=workers, precision=precision, options=opts, extra=extra)
