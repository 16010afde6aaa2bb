"""The driver: :func:`render` (argument checks, memory guard, seeds, tracer,
executors, progress, Ctrl-C) and :class:`WorkerPool`, a local process pool
with a lifetime.

Every method and both sample allocations run through :func:`render`: the
allocation (:mod:`mcvar.integrators.allocation`: uniform spp batches, or
adaptive two-stage sampling) decides the stages and their batches, the driver
runs them. Batch ``b`` of a stage is a picklable description (the method, the
render's shared data: scene, tracer, prepared data; its pixels, its seed and its
slice of the sample pattern) that any ``concurrent.futures.Executor``-like object
runs (``executor.submit``); descriptions are made lazily, a bounded window of them
in flight. The render's own :class:`WorkerPool` receives the shared data once per
process, when it starts (:class:`_Shared`), and its batches carry only a token: a
tracer of 100k triangles (26 MB) is not pickled into every batch. Results reach the film in batch order, so the image does not depend
on which executor ran the batches or in what order they finished.
"""
from __future__ import annotations

import os
import time
import uuid
from collections import deque
from concurrent.futures import Executor, ProcessPoolExecutor
from contextlib import closing
from dataclasses import dataclass, fields
from typing import Callable

import numpy as np

from .._validation import MEMORY_BUDGET, as_rng, check_choice, check_count
from ..samplers import SAMPLERS
from ..scene import Scene
from ..tracer import Tracer
from .allocation import PATHS_PER_BATCH, get_allocation
from .film import BatchJob, Render
from .registry import Method, get_method, pop_method_name
from .settings import PATH_OPTIONS, PathSettings
from .stream import CAMERA_DIMS, SAMPLER_DIM, batch_stream, stream_dim

__all__ = ["render", "WorkerPool", "PATHS_PER_BATCH", "MAX_RENDER_BYTES", "BYTES_PER_PATH",
           "estimate_render_bytes"]

#: Default memory budget of one render (bytes): :func:`render` refuses a render
#: whose :func:`estimate_render_bytes` exceeds it, before allocating anything
#: (``render(..., max_memory=...)`` overrides it). The same number as every other
#: size check's, :data:`mcvar._validation.MEMORY_BUDGET` (4 GiB).
MAX_RENDER_BYTES = MEMORY_BUDGET
#: Working memory per path of a batch in flight (state, temporaries, shadow
#: rays, sample stream), bytes: an upper estimate. Measured (tracemalloc peak
#: of one 2^16-path Cornell batch, film included): 400 B/path for the
#: Lambertian kernel, 660 for the general loop, 740 with the sobol sampler;
#: 2048 leaves room for deeper scenes and other methods.
BYTES_PER_PATH = 2048


def estimate_render_bytes(n_pixels: int, batch_paths: int, dim: int, workers: int = 1,
                          whole_floats: int = 0, films: int = 1) -> int:
    """Memory a render needs (bytes): per film (adaptive renders keep two: the
    pilot's and the image's) four ``(n_pixels, 3)`` float64 arrays (sums,
    squared sums, image, variance) and the per-pixel counts, ``workers``
    batches in flight (:data:`BYTES_PER_PATH` plus ``dim`` float64 sample
    dimensions per path) and the kept sample pattern (``whole_floats``
    float64 numbers)."""
    return int(films * n_pixels * (3 * 8 * 4 + 8) + workers * batch_paths * (BYTES_PER_PATH + 8 * dim)
               + 8 * whole_floats)


# ---------------------------------------------------------------------------
# Worker processes

def _pool_context():
    """``fork`` where the platform has it: workers start in milliseconds and
    inherit the tracer; elsewhere the platform default."""
    import multiprocessing

    if "fork" in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("fork")
    return None


class _Claims:
    """Which batches of a pool have been started, shared by the calling process
    and the pool's processes (a lock and a ring of sequence numbers in shared memory).

    ``concurrent.futures.ProcessPoolExecutor`` hands a process its next batch
    before it finishes the current one (the call queue holds ``workers + 1``
    items), and such a batch can no longer be cancelled: at the end of a
    stage the caller, out of batches it could take, waited for the pool's
    running batch *and* the one queued behind it. With claims, whoever starts
    a batch first claims its number (:meth:`claim`); a pool process that finds
    its batch claimed by the caller skips it, so the caller may take any batch
    the pool has not started (docs/performance.md, 'Two workers: the end of a
    stage').
    """

    #: sequence numbers kept: more than the batches ever in flight (:func:`_window`)
    RING = 1 << 12

    def __init__(self, ctx):
        self._lock = ctx.Lock()
        self._ring = ctx.RawArray("q", [-1] * self.RING)
        self._next = 0

    def number(self) -> int:
        """A new batch's sequence number (the calling process only)."""
        self._next += 1
        return self._next - 1

    def claim(self, seq: int) -> bool:
        """True for the first process that claims batch ``seq``, False after that."""
        slot = seq % self.RING
        with self._lock:
            if self._ring[slot] == seq:
                return False
            self._ring[slot] = seq
            return True


class WorkerPool(Executor):
    """A local process pool with a lifetime, for one render or many.

    ``render(..., workers=n)`` makes one of ``n - 1`` processes for the render
    (the calling process is the n-th worker: it takes the oldest batch no
    pool process has received, else one a pool process holds but has not
    started, while the pool works from the front, so two workers on a machine
    whose second core is busy cost little more than one) and shuts it down at the end. Passed as ``executor``, a pool does all
    the work and the caller waits. To keep warm processes over several renders (a fresh process
    spends its first batch at about half speed touching new memory), make
    one and pass it::

        with WorkerPool(2) as pool:
            a = render(scene, spp=64, executor=pool)
            b = render(scene, spp=64, executor=pool)

    Processes are started (``fork`` where available) on the first
    :meth:`submit`; :meth:`shutdown` (or leaving the ``with`` block) ends them.
    They start holding the scene, tracer and prepared data of the render that
    first used the pool (:meth:`bind`), whose batches then carry none of it;
    later renders on a kept pool send those inside every batch (for a scene
    of 100k triangles, 26 MB a batch: give such renders a pool each).
    """

    def __init__(self, workers: int):
        #: processes (the driver keeps ``2 workers + 2`` batches in flight)
        self.workers = check_count(workers, "workers")
        self._executor: ProcessPoolExecutor | None = None
        self._shared: _Shared | None = None
        #: set by :meth:`share_claims` (the render's own pool, whose caller takes batches too)
        self.claims: _Claims | None = None

    def share_claims(self) -> None:
        """Let the calling process take batches this pool has queued but not
        started (:class:`_Claims`); before the processes start."""
        if self._executor is None and self.claims is None:
            import multiprocessing

            self.claims = _Claims(_pool_context() or multiprocessing.get_context())

    def bind(self, shared: "_Shared") -> bool:
        """Hand a render's :class:`_Shared` data to the processes once, when they start.

        True when the processes hold ``shared``: they are not started yet (they
        will get it at their start: inherited under ``fork``, pickled once per
        process otherwise) or were started with it; from then on a batch
        pickles ``shared`` as its token. False when they were started for
        another render (a kept pool): batches then carry everything.
        """
        if self._executor is None and self._shared is None:
            self._shared = shared
            shared.in_workers = True
        return self._shared is shared

    def submit(self, fn, /, *args, **kwargs):
        if self._executor is None:
            init = {} if self._shared is None and self.claims is None else dict(
                initializer=_WorkerSlot.install,
                initargs=(None if self._shared is None else self._shared.payload(), self.claims))
            self._executor = ProcessPoolExecutor(max_workers=self.workers, mp_context=_pool_context(), **init)
        return self._executor.submit(fn, *args, **kwargs)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        if self._executor is not None:
            executor, self._executor = self._executor, None
            executor.shutdown(wait=wait, cancel_futures=cancel_futures)


# ---------------------------------------------------------------------------
# Batches

class _Shared:
    """What every batch of one render reads and none changes: the scene, the
    render's tracer (built once: ~20 kB for the Cornell box, ~26 MB at 87k
    triangles) and what the method's ``prepare`` made.

    Pickled in full (a batch is then self-contained: any executor runs it),
    except once :meth:`WorkerPool.bind` gave it to a pool's processes at their
    start: then it pickles as its token, and the process that unpickles it
    finds it in its :class:`_WorkerSlot`. So the render's own pool receives the
    tracer once per process, not once per batch.
    """

    def __init__(self, scene: Scene, tracer: Tracer, prepared, token: str | None = None):
        self.scene, self.tracer, self.prepared = scene, tracer, prepared
        #: names this render's data across processes
        self.token = uuid.uuid4().hex if token is None else token
        #: set by :meth:`WorkerPool.bind`: the pool's processes hold it
        self.in_workers = False

    def payload(self) -> tuple:
        """The arguments that rebuild it in a worker (:meth:`_WorkerSlot.install`)."""
        return self.scene, self.tracer, self.prepared, self.token

    def __reduce__(self):
        if self.in_workers:
            return _WorkerSlot.get, (self.token,)
        return _Shared, self.payload()


class _WorkerSlot:
    """The :class:`_Shared` data a pool's process received at its start.

    One slot per process, filled by the pool's initializer
    (:meth:`install`) and read by every batch the process unpickles
    (:meth:`get`); its lifetime is the worker process's, which is the
    :class:`WorkerPool`'s (the render's own pool ends with the render). The
    calling process never fills it.
    """

    shared: _Shared | None = None
    #: the pool's :class:`_Claims` (None: batches are not claimed)
    claims: _Claims | None = None

    @staticmethod
    def install(payload: tuple | None, claims: "_Claims | None" = None) -> None:
        if payload is not None:
            _WorkerSlot.shared = _Shared(*payload)
        _WorkerSlot.claims = claims

    @staticmethod
    def get(token: str) -> _Shared:
        shared = _WorkerSlot.shared
        if shared is None or shared.token != token:
            raise RuntimeError("a batch names render data this worker process was not started with "
                               "(a WorkerPool's processes hold the data of the render they were started for)")
        return shared


@dataclass(frozen=True, eq=False)
class _Batch:
    """One batch, picklable: what crosses to the process that runs it (the
    render's :class:`_Shared` data in full, or only its token when the pool's
    processes hold it)."""

    method: Method
    shared: _Shared
    res: tuple
    pixels: np.ndarray | None
    spp: int
    sampler: str
    dim: int
    whole: np.ndarray | None
    seed: np.random.SeedSequence
    bit_generator: type
    settings: PathSettings
    options: dict

    @property
    def paths(self) -> int:
        n = self.res[0] * self.res[1] if self.pixels is None else self.pixels.shape[0]
        return n * self.spp


def _run_batch(batch: _Batch):
    """Build the :class:`BatchJob` (sample stream, generator) and run the method."""
    rng = np.random.Generator(batch.bit_generator(batch.seed))
    n_pix = batch.res[0] * batch.res[1] if batch.pixels is None else batch.pixels.shape[0]
    u = batch_stream(batch.sampler, n_pix, batch.spp, batch.dim, batch.whole, rng)
    shared = batch.shared
    job = BatchJob(scene=shared.scene, tracer=shared.tracer, res=batch.res, spp=batch.spp, sampler=batch.sampler,
                   u=u, rng=rng, settings=batch.settings, options=dict(batch.options), prepared=shared.prepared,
                   pixels=batch.pixels)
    return batch.method.run_batch(job)


def _run_claimed(batch: _Batch, seq: int):
    """:func:`_run_batch` in a pool process, unless the caller claimed batch ``seq``
    first (then None, at once: the caller runs it)."""
    claims = _WorkerSlot.claims
    if claims is not None and not claims.claim(seq):
        return None
    return _run_batch(batch)


def _child(stream: np.random.Generator, i: int) -> np.random.SeedSequence:
    """What ``stream.spawn(i + 1)[i]`` would seed, made alone (spawning 2^28
    generators up front would cost minutes and gigabytes)."""
    seq = stream.bit_generator.seed_seq
    return np.random.SeedSequence(seq.entropy, spawn_key=tuple(seq.spawn_key) + (seq.n_children_spawned + i,),
                                  pool_size=seq.pool_size)


def _window(executor, parent_works: bool) -> int:
    """Batches in flight: two per worker and two more (bounded, whatever the render's size)."""
    n = getattr(executor, "workers", None) or getattr(executor, "_max_workers", None) or os.cpu_count() or 1
    return 2 * (int(n) + parent_works) + 2


def _in_order(batches, executor, parent_works: bool):
    """Run ``batches`` (an iterator, read lazily) and yield ``(batch, result)`` in order.

    ``executor`` None: in this process. Otherwise a bounded window is
    submitted; with ``parent_works`` this process, while the oldest batch
    is still running, takes the oldest batch no worker has received
    (cancelled), else, where the pool shares :class:`_Claims`, the newest one
    a pool process holds but has not started (claimed first), and runs it
    itself. A batch's result depends only on its description, so
    neither who ran it nor when changes the image.
    """
    if executor is None:
        for batch in batches:
            yield batch, _run_batch(batch)
        return
    window = _window(executor, parent_works)
    claims = getattr(executor, "claims", None) if parent_works else None
    pending = deque()            # [batch, future, (result,) if this process ran it, sequence number]
    source = iter(batches)
    try:
        while True:
            # the window counts batches without a result here: those this process
            # ran wait only for their turn (results in order), and must not keep
            # the pool from getting new batches while the oldest is still running
            # (at most 8 windows of results held, should a pool process stall)
            while sum(e[2] is None for e in pending) < window and len(pending) < 8 * window:
                batch = next(source, None)
                if batch is None:
                    break
                seq = None if claims is None else claims.number()
                future = executor.submit(_run_batch, batch) if claims is None else \
                    executor.submit(_run_claimed, batch, seq)
                if not all(callable(getattr(future, a, None)) for a in ("result", "done", "cancel")):
                    raise TypeError(f"executor.submit must return a concurrent.futures.Future (result, done, "
                                    f"cancel); {type(executor).__name__}.submit returned {type(future).__name__}")
                pending.append([batch, future, None, seq])
            if not pending:
                return
            head = pending[0]
            if head[2] is None and parent_works and not head[1].done():
                # the oldest batch no worker has received (so that the second stage's
                # small last batches stay last for both processes), else the newest
                # one queued in a pool process but not started (claimed first)
                stolen = next((e for e in pending if e[2] is None and e[1].cancel()), None)
                if stolen is None and claims is not None:
                    stolen = next((e for e in reversed(pending) if e[2] is None and not e[1].done()
                                   and claims.claim(e[3])), None)
                if stolen is not None:
                    stolen[2] = (_run_batch(stolen[0]),)
                    continue
            pending.popleft()
            yield head[0], head[2][0] if head[2] is not None else head[1].result()
    finally:
        for entry in pending:       # never leave a render's batches running
            entry[1].cancel()


# ---------------------------------------------------------------------------
# The request and the render in progress

@dataclass(frozen=True)
class _RunOptions:
    """How a render is run (not what it computes): the keywords of :func:`render` below."""

    batch_spp: int | None = None
    workers: int = 1
    executor: object = None
    progress: object = False
    precision: str = "float32"
    max_memory: int | None = None
    sampler_dim: int | None = None

    def __post_init__(self):
        if self.batch_spp is not None:
            object.__setattr__(self, "batch_spp", check_count(self.batch_spp, "batch_spp"))
        object.__setattr__(self, "workers", check_count(self.workers, "workers"))
        if self.executor is not None and not callable(getattr(self.executor, "submit", None)):
            raise TypeError(f"executor must have a submit(fn, *args) method (a concurrent.futures.Executor); "
                            f"got {type(self.executor).__name__}")
        if not (isinstance(self.progress, (bool, np.bool_)) or callable(self.progress)):
            raise TypeError(f"progress must be a bool or a callable(done, total); got {type(self.progress).__name__}")
        check_choice(self.precision, "precision", ("float32", "float64"))
        for key in ("max_memory", "sampler_dim"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, check_count(getattr(self, key), key))

    @classmethod
    def from_keywords(cls, given: dict) -> "_RunOptions":
        return cls(**{f.name: given.pop(f.name) for f in fields(cls) if f.name in given})


@dataclass(frozen=True, eq=False)
class _Plan:
    """A checked render request."""

    scene: Scene
    method: Method
    spp: int
    res: tuple
    sampler: str
    settings: PathSettings
    options: dict
    run: _RunOptions
    dim: int

    @property
    def n_pixels(self) -> int:
        return self.res[0] * self.res[1]


def _as_res(res) -> tuple:
    if isinstance(res, (int, np.integer)) and not isinstance(res, (bool, np.bool_)):
        r = check_count(res, "res")
        return (r, r)
    if isinstance(res, (tuple, list)) and len(res) == 2:
        return (check_count(res[0], "res[0] (width)"), check_count(res[1], "res[1] (height)"))
    raise TypeError(f"res must be an int (square image) or a (width, height) pair; got {res!r}")


def _sampler_dim(method: Method, settings: PathSettings, options: dict, sampler_dim: int) -> int:
    """Columns of the sample stream the ``sampler`` feeds for ``method`` (:attr:`Method.stream_dims`)."""
    dims = method.sampler_columns(options)
    if dims is not None:
        return min(dims, sampler_dim)
    if method.kind != "camera":
        return CAMERA_DIMS
    depth = method.fixed_depth if method.fixed_depth is not None else settings.max_depth
    need = stream_dim(depth)
    return sampler_dim if need is None else max(CAMERA_DIMS, min(sampler_dim, need))


def _path_settings(method: Method, kw: dict) -> tuple[PathSettings, dict]:
    """The render's :class:`PathSettings` and the method's options, from the keywords left in ``kw``."""
    whole = kw.pop("settings", None)
    given = {f.name: kw.pop(f.name) for f in fields(PathSettings) if f.name in kw}
    if whole is not None:
        if not isinstance(whole, PathSettings):
            raise TypeError(f"settings must be a PathSettings; got {type(whole).__name__}")
        if given:
            raise ValueError(f"give settings=PathSettings(...) or its fields ({', '.join(sorted(given))}) "
                             "as keywords, not both")
        default = PathSettings()
        given = {f.name: getattr(whole, f.name) for f in fields(PathSettings)
                 if getattr(whole, f.name) != getattr(default, f.name)}
    # the fields beyond depth and heuristic are options of the methods that read them
    opts = method.resolve_options({**kw, **{k: v for k, v in given.items() if k in PATH_OPTIONS}})
    settings = PathSettings(max_depth=given.get("max_depth"), heuristic=given.get("heuristic", "power"),
                            **{k: opts[k] for k in PATH_OPTIONS if k in opts})
    if settings.max_depth is not None:
        if not method.uses_max_depth:
            raise ValueError(f"max_depth does not apply to the method {method.name!r}; got {settings.max_depth}")
        if method.fixed_depth is not None and settings.max_depth != method.fixed_depth:
            raise ValueError(f"max_depth must be None or {method.fixed_depth} for {method.name!r}; "
                             f"got {settings.max_depth}")
    return settings, opts


def _plan(scene, method, spp, res, sampler, allocation, keywords: dict):
    """Check everything about a request before any work: ``(plan, allocation)``."""
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a mcvar.scene.Scene (see load_scene); got {type(scene).__name__}")
    kw = dict(keywords)
    method = get_method(pop_method_name(kw, method, "render"))
    sampler = check_choice(sampler, "sampler", tuple(SAMPLERS))
    spp = check_count(spp, "spp")
    size = _as_res(res)
    allocation = get_allocation(allocation)
    run = _RunOptions.from_keywords(kw)
    settings, opts = _path_settings(method, kw)
    default_dim = allocation.sampler_dim or SAMPLER_DIM
    dim = _sampler_dim(method, settings, opts, default_dim if run.sampler_dim is None
                       else max(CAMERA_DIMS, run.sampler_dim))
    plan = _Plan(scene, method, spp, size, sampler, settings, opts, run, dim)
    allocation = allocation.check(plan)
    mem = allocation.memory(plan)
    budget = MAX_RENDER_BYTES if run.max_memory is None else run.max_memory
    need = estimate_render_bytes(plan.n_pixels, mem["batch_paths"], 0 if sampler == "random" else dim,
                                 run.workers if run.executor is None else 1, mem["whole_floats"], mem["films"])
    if need > budget:
        # name the option that asks for the memory: the sample stream's columns when they alone
        # exceed the budget (sampler_dim=2**40), else the image and its batches
        columns = 8 * dim * mem["batch_paths"] * (run.workers if run.executor is None else 1)
        cause = (f"sampler_dim = {run.sampler_dim} ({dim} sample columns per path)"
                 if run.sampler_dim is not None and columns > budget else "lower res or batch_spp")
        raise ValueError(f"render of {size[0]} x {size[1]} pixels ({allocation.name} allocation, "
                         f"{mem['batch_paths']} paths per batch) needs about {need / 2 ** 30:.3g} GiB (film and "
                         f"batch memory), more than max_memory = {budget / 2 ** 30:.3g} GiB; "
                         + (f"lower {cause}" if cause.startswith("sampler_dim") else cause) + ", or raise max_memory")
    if method.check_scene is not None:
        method.check_scene(scene, opts)
    return plan, allocation


@dataclass
class _Streams:
    """The render's random streams: ``as_rng(rng).spawn(5)`` (the fifth, the caustic
    light paths', came last: the first four are what ``spawn(4)`` gave)."""

    prepare: np.random.Generator
    pattern: np.random.Generator
    stage: tuple
    caustics: np.random.Generator


class _Render:
    """One render in progress, with a lifetime (a ``with`` block): the tracer
    (built once, owned here with the scene and prepared data as :class:`_Shared`,
    handed to its pool's processes once), the worker pool it
    made, the progress bar; :meth:`stage` runs batches, :meth:`result` makes
    the :class:`Render`."""

    def __init__(self, plan: _Plan, allocation, rng):
        self.plan, self.allocation = plan, allocation
        root = as_rng(rng).spawn(5)
        self.streams = _Streams(root[0], root[1], (root[2], root[3]), root[4])
        self.prepared = plan.method.prepare(plan.scene, plan.options, self.streams.prepare) \
            if plan.method.prepare is not None else None
        self.tracer = Tracer(plan.scene, dtype=plan.run.precision)
        if plan.method.warm is not None:       # caches every batch reads, built before workers fork
            plan.method.warm(plan.scene, self.tracer, plan.settings)
        self.shared = _Shared(plan.scene, self.tracer, self.prepared)
        self.interrupted = False
        self.done = 0
        self.total = 0
        self._bar = None
        self._pool = None
        self._start = time.perf_counter()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self._pool is not None:
            self._pool.shutdown(wait=not self.interrupted and exc[0] is None, cancel_futures=True)
        if self._bar is not None:
            self._bar.close()
        return False

    def start(self, *, total: int) -> None:
        """Progress over ``total`` units (the allocation's ``progress_unit``); the clock starts."""
        self.total = total
        if self.plan.run.progress is True:
            from tqdm.auto import tqdm

            unit = self.allocation.progress_unit
            self._bar = tqdm(total=total, unit=unit, unit_scale=unit == "path", leave=False,
                             desc=f"{self.plan.scene.name} {self.plan.method.name}")
        self._start = time.perf_counter()

    def _executor(self, n_batches: int):
        """``(executor, parent_works)`` for a stage of ``n_batches``."""
        run = self.plan.run
        if run.executor is not None:
            if isinstance(run.executor, WorkerPool):
                run.executor.bind(self.shared)      # a pool not yet started takes the render's data once
            return run.executor, False
        if run.workers > 1 and n_batches > 1:
            if self._pool is None:
                self._pool = WorkerPool(run.workers - 1)
                self._pool.bind(self.shared)
                self._pool.share_claims()
            return self._pool, True
        return None, False

    def stage(self, specs, n_batches: int, stream, sink, *, settings: PathSettings | None = None,
              method: Method | None = None) -> None:
        """Run the batches ``specs`` (an iterator of ``Spec(pixels, spp, whole)``), seeded
        by child ``i`` of ``stream``; ``sink(spec, result)`` in order, then progress.
        ``method``: another method's batches (the caustic light paths; no sample stream)."""
        plan = self.plan
        settings = plan.settings if settings is None else settings
        bitgen = type(stream.bit_generator)
        dim = plan.dim if method is None else 0
        method = plan.method if method is None else method
        batches = (_Batch(method, self.shared, plan.res, spec.pixels, spec.spp, plan.sampler,
                          dim, spec.whole, _child(stream, i), bitgen, settings, plan.options)
                   for i, spec in enumerate(specs))
        executor, parent_works = self._executor(n_batches)
        unit_spp = self.allocation.progress_unit == "spp"
        callback = plan.run.progress if callable(plan.run.progress) else None
        with closing(_in_order(batches, executor, parent_works)) as results:
            for batch, result in results:
                sink(batch, result)
                if dim == 0 and batch.method is not plan.method:
                    continue                # an auxiliary stage: not in the progress total
                step = batch.spp if unit_spp else batch.paths
                self.done += step
                if self._bar is not None:
                    self._bar.update(step)
                if callback is not None:
                    callback(self.done, self.total)

    def result(self, cls=Render, **fields) -> Render:
        """The :class:`Render` (or ``cls``) of ``fields`` (image, variance, spp, rays,
        batch_spp, extra, ...) and the render's settings, time and interruption."""
        plan = self.plan
        return cls(seconds=time.perf_counter() - self._start, interrupted=self.interrupted, scene=plan.scene.name,
                   method=plan.method.name, sampler=plan.sampler, res=plan.res, max_depth=plan.settings.max_depth,
                   heuristic=plan.settings.heuristic, workers=plan.run.workers, precision=plan.run.precision,
                   options=plan.options, **fields)


# ---------------------------------------------------------------------------
# render()

def render(scene: Scene, *, method: str | None = None, spp: int = 16, res=64, sampler: str = "random", rng=None,
           allocation="uniform", **settings) -> Render:
    """Render ``scene`` with one method: the mean radiance of ``spp`` samples per pixel.

    Parameters
    ----------
    scene : Scene
        From :func:`mcvar.scene.load_scene`.
    method : str
        A registered method, one of :data:`mcvar.integrators.METHODS`
        (``path``, the default, ``direct``, ... see docs/integrators.md);
        ``integrator=`` is an accepted alias (both given: ``ValueError``).
    spp : int
        Samples per pixel, >= 1 (for splatting and Markov-chain methods the
        same work: ``W H spp`` paths; adaptive allocation: the average).
    res : int or (int, int)
        Square side, or ``(width, height)``.
    sampler : str
        A sampler of :data:`mcvar.samplers.SAMPLERS`; it feeds the first
        ``sampler_dim`` columns of every path's sample stream (pixel position,
        then per vertex light, BSDF, roulette and emitter choice:
        :mod:`mcvar.integrators.stream`; only the columns the method reads,
        :attr:`Method.stream_dims`), iid beyond.
    rng : None, int, SeedSequence or Generator
        The same seed gives the same image, for any ``workers`` or ``executor``.
    allocation : {'uniform', 'adaptive'} or an allocation object
        How samples are spread over pixels
        (:mod:`mcvar.integrators.allocation`): ``uniform`` (``spp`` in every
        pixel) or ``adaptive`` (unbiased two-stage sampling: a pilot decides,
        the second stage's samples alone make the image; camera-kind
        methods; returns an :class:`AdaptiveRender` with ``spp_map``);
        ``Adaptive(pilot_spp=..., min_spp=..., max_spp=..., exponent=...)``
        sets its parameters.
    **settings
        Path settings, the fields of :class:`PathSettings` (``max_depth``,
        ``heuristic``, and for the path methods ``kernel``,
        ``light_sampling``, ``rr_depth``, ``rr_threshold``,
        ``visible_lights``), or ``settings=PathSettings(...)``; run
        settings: ``batch_spp`` (uniform: samples per pixel per batch;
        default all of them if the batch holds at most
        :data:`PATHS_PER_BATCH` paths, else a power of two, of four for grid
        / jittered, that fits), ``workers`` (processes: the caller and
        ``workers - 1`` of a :class:`WorkerPool` made for this render; the
        image is the same as with 1), ``executor`` (anything with
        ``submit(fn, *args)``: a :class:`WorkerPool`, a
        ``ProcessPoolExecutor``, Dask's ``Client.get_executor()`` ...; the
        image is the same whichever runs the batches), ``progress`` (True: a
        tqdm bar; a callable is called as ``progress(done, total)`` after
        each batch, in spp for uniform and in paths for adaptive
        allocation), ``precision`` (``'float32'`` or ``'float64'`` ray
        geometry; radiance is always float64), ``max_memory`` (bytes,
        default :data:`MAX_RENDER_BYTES`: a render whose
        :func:`estimate_render_bytes` exceeds it is refused with a
        ``ValueError`` before anything is allocated), ``sampler_dim``
        (columns the sampler feeds, default
        :data:`~mcvar.integrators.stream.SAMPLER_DIM` = 20 for uniform and
        :data:`~mcvar.integrators.allocation.ADAPTIVE_DIM` = 6 for adaptive
        renders; at most what the method reads); and the method's own options
        (``METHODS[method].options``); any other keyword is a ``ValueError``.

    Returns
    -------
    Render
        The image (H, W, 3), float64 linear radiance, row 0 at the top, with
        spp completed, wall time, per-pixel sample variance and the settings.

    Notes
    -----
    ``as_rng(rng).spawn(4)``: stream 0 goes to the method's ``prepare``,
    stream 1 draws the kept sample pattern
    (:func:`mcvar.integrators.stream.whole_pattern`), streams 2 and 3 are the
    stages' (uniform: one; adaptive: the pilot, the second stage), batch
    ``b`` of a stage seeded by the stage stream's child ``b`` (the same
    whatever the number of batches). Batch descriptions are made lazily, at
    most ``2 workers + 2`` in flight, and results are added in batch order.
    Ctrl-C (``KeyboardInterrupt``, also when raised by a ``progress``
    callback) stops the render and returns the batches finished so far with
    ``interrupted=True``.

    Examples
    --------
    >>> from mcvar.scene import load_scene
    >>> r = render(load_scene("cornell"), spp=2, res=8, rng=1)
    >>> r.image.shape, r.spp
    ((8, 8, 3), 2)
    """
    plan, allocation = _plan(scene, method, spp, res, sampler, allocation, settings)
    with _Render(plan, allocation, rng) as run:
        return allocation.render(run)
