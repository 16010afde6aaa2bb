"""Convergence experiments: sweeps, replicates, references, verdicts (layer 6).

A *sweep* runs one target (an integrand of :mod:`mcvar.examples` or a scene
rendered by :func:`mcvar.integrators.render`) for every combination of
method x sampler x spp level x replicate, and turns the replicates into the
numbers the lecture's 'Variance', 'Bias & Consistency' and 'Rendering
Algorithm Chart' slides talk about: per-pixel variance, squared bias, MSE,
relative MSE, wall time, efficiency ``1 / (MSE x time)``, log-log convergence
rates with their standard errors, a test of whether the bias is zero, and a
verdict per method (unbiased, consistent, both or neither).

Runs are independent tasks submitted to any :class:`concurrent.futures.Executor`
(a process pool by default, :class:`SerialExecutor` in-process, or a Dask
client's ``client.get_executor()``). Each replicate's random stream is derived
from the seed and the configuration, never from the order of execution, so the
numbers are identical whichever executor runs them. Finished runs can be cached
on disk, so an interrupted sweep resumes where it stopped.
"""
from __future__ import annotations

import hashlib
import os
import re
import time
from concurrent.futures import Executor, Future, FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field, replace
from functools import lru_cache, partial
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from scipy import stats

from ._validation import as_array, check_count, check_probability
from .metrics import LogLogFit, loglog_fit, relative_mse

__all__ = [
    "Target",
    "Reference",
    "ConfigMetrics",
    "MethodFits",
    "Verdict",
    "SweepResult",
    "SerialExecutor",
    "integrand_target",
    "lecture_target",
    "scene_target",
    "make_target",
    "parse_method",
    "run_seed",
    "compute_reference",
    "sweep",
]

#: Bumped when the meaning of a cached run or reference changes.
CACHE_VERSION = 1


# --------------------------------------------------------------------------
# Targets
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class Target:
    """Something to estimate, with the methods and samplers that estimate it.

    Parameters
    ----------
    name : str
        Shown in reports.
    evaluate : callable
        ``evaluate(method, sampler, spp, rng) -> ndarray``: one independent
        estimate (a scalar integral as shape ``(1,)``, or an image
        ``(H, W, 3)``) from ``spp`` samples (per pixel) drawn with the named
        sampler from the Generator ``rng``. Must be picklable (a module-level
        function or a :func:`functools.partial` of one) to run in other
        processes.
    key : str
        A stable description of everything ``evaluate`` depends on besides its
        arguments (scene, resolution, ...); hashed into cache file names.
    methods, samplers, spp : tuple
        Defaults of a sweep when the caller gives none.
    exact : ndarray, optional
        The known exact value (for integrands); then no reference is rendered.
    reference_task : callable, optional
        ``reference_task(rng) -> ndarray``: one chunk of a high-sample
        reference; :func:`compute_reference` averages ``reference_chunks`` of
        them from independent streams.
    reference_chunks : int
        Number of independent reference chunks (their spread gives the
        reference's own variance).
    reference_settings : str
        Description of ``reference_task`` (integrator, spp ...), part of the
        reference's cache key.
    """

    name: str
    evaluate: Callable
    key: str
    methods: tuple = ()
    samplers: tuple = ("random",)
    spp: tuple = (1, 4, 16, 64, 256)
    exact: np.ndarray | None = None
    reference_task: Callable | None = None
    reference_chunks: int = 8
    reference_settings: str = ""


def _integrand_evaluate(problem: str, method: str, sampler: str, spp: int, rng) -> np.ndarray:
    from .examples import PROBLEMS
    from .samplers import DETERMINISTIC, digital_shift, get_sampler

    points = get_sampler(sampler)(spp, rng=rng)
    if sampler in DETERMINISTIC:
        # the same points for every replicate would make the replicate spread
        # zero and the error bars meaningless: shift each replicate randomly
        points = np.minimum(digital_shift(points, rng=rng), np.nextafter(1.0, 0.0))
    contributions = np.asarray(PROBLEMS[problem].methods[method](points), dtype=np.float64)
    return np.array([contributions.mean()])


def integrand_target(name: str) -> Target:
    """A :class:`Target` for the integrand ``mcvar.examples.PROBLEMS[name]``.

    Its methods are the problem's estimators (the contribution functions
    ``f(X) / p(X)``); one estimate is their mean over ``spp`` points of the
    sampler. The reference is the problem's exact value (variance 0).
    Default samplers: random, jittered, sobol; default N: 4^0 ... 4^6 (powers
    of 4 are perfect squares, as jittered needs, and powers of 2, as Sobol
    needs for its balance properties).
    """
    from .examples import PROBLEMS

    if not isinstance(name, str):
        raise TypeError(f"name must be a string naming a problem; got {type(name).__name__}")
    if name not in PROBLEMS:
        raise ValueError(f"name must be one of {tuple(PROBLEMS)}; got {name!r}")
    problem = PROBLEMS[name]
    return Target(name=name, evaluate=partial(_integrand_evaluate, name),
                  key=f"integrand={name};exact={float(problem.exact)!r}",
                  methods=tuple(problem.methods), samplers=("random", "jittered", "sobol"),
                  spp=tuple(4 ** k for k in range(7)), exact=np.array([float(problem.exact)]))


def _to_board(u):
    """[0, 1)^2 -> the lecture's [0, 2)^2 board (uniform, pdf 1/4)."""
    return 2.0 * u


_BOARD = dict(lower=(0.0, 0.0), upper=(2.0, 2.0))


def _lecture_evaluate(method: str, sampler: str, spp: int, rng) -> np.ndarray:
    from .examples import PROBLEMS, checkerboard, fixed_grid_estimate, single_sample_estimate, \
        undivided_estimate
    from .samplers import get_sampler

    if method == "uniform":
        points = get_sampler(sampler)(spp, rng=rng)
        return np.array([PROBLEMS["checkerboard"].methods["uniform"](points).mean()])
    if method == "grid":
        m = int(np.sqrt(spp))
        if m * m != spp:
            raise ValueError(f"spp must be a perfect square for the 'grid' estimator; got {spp}")
        return np.array([fixed_grid_estimate(checkerboard, m, **_BOARD)])
    if method == "single":
        return np.array([single_sample_estimate(checkerboard, rng=rng, **_BOARD)])
    if method == "undivided":
        return np.array([undivided_estimate(checkerboard, sample=_to_board, n=spp, sampler=sampler,
                                            rng=rng).mean])
    raise ValueError(f"method must be one of ('uniform', 'grid', 'single', 'undivided'); got {method!r}")


def lecture_target() -> Target:
    """The lecture's estimators of the checkerboard integral (exact value 2).

    Methods, one per cell of the 'Bias & Consistency' / 'Consistent Or
    Unbiased?' / 'Biased vs. Unbiased Example' slides:

    * ``'uniform'``: plain Monte Carlo, ``4 f(2u)`` averaged over N points of
      the sampler: unbiased and consistent;
    * ``'grid'``: the fixed ``m x m`` grid, ``m = sqrt(N)``
      (:func:`mcvar.examples.fixed_grid_estimate`): consistent but biased
      (by ``2 / m^2`` for odd ``m``), deterministic;
    * ``'single'``: one random sample times the area, whatever N
      (:func:`mcvar.examples.single_sample_estimate`): unbiased, not
      consistent;
    * ``'undivided'``: the mean of ``f(X)`` without dividing by the pdf
      (:func:`mcvar.examples.undivided_estimate`): converges to 1/2, not 2,
      neither unbiased nor consistent.

    Default N: odd squares 1, 9, 49, 225, 961 (so the grid's bias is not 0).
    The name for :func:`make_target` is ``'lecture'``.
    """
    from .examples import CHECKERBOARD_INTEGRAL

    return Target(name="lecture", evaluate=_lecture_evaluate, key="lecture-checkerboard-v1",
                  methods=("uniform", "grid", "single", "undivided"), samplers=("random",),
                  spp=(1, 9, 49, 225, 961), exact=np.array([float(CHECKERBOARD_INTEGRAL)]))


_METHOD = re.compile(r"^([a-z_]+)(?::(\d+))?$")


def parse_method(method: str) -> tuple[str, int | None]:
    """Split a scene method ``'integrator[:max_depth]'``.

    ``'path'`` is path tracing with Russian roulette (unbiased), ``'path:3'``
    the same integrator stopped after 3 bounces (``max_depth=3``: biased,
    light carried by longer paths is missing).

    Examples
    --------
    >>> parse_method("path:3")
    ('path', 3)
    >>> parse_method("direct")
    ('direct', None)
    """
    if not isinstance(method, str):
        raise TypeError(f"method must be a string 'integrator[:max_depth]'; got {type(method).__name__}")
    m = _METHOD.match(method)
    if m is None or (m.group(2) is not None and int(m.group(2)) < 1):
        raise ValueError(f"method must look like 'path' or 'path:3' (integrator[:max_depth >= 1]); "
                         f"got {method!r}")
    return m.group(1), (int(m.group(2)) if m.group(2) is not None else None)


@lru_cache(maxsize=8)
def _scene(name: str):
    from .scene import load_scene

    return load_scene(name)


def _scene_evaluate(scene: str, res: int, method: str, sampler: str, spp: int, rng) -> np.ndarray:
    from .integrators import render

    integrator, max_depth = parse_method(method)
    result = render(_scene(scene), integrator=integrator, spp=spp, res=res, sampler=sampler,
                    rng=rng, max_depth=max_depth, progress=False, workers=1)
    return np.asarray(result.image, dtype=np.float64)


def _scene_reference(scene: str, res: int, integrator: str, spp: int, sampler: str, rng) -> np.ndarray:
    return _scene_evaluate(scene, res, integrator, sampler, spp, rng)


def scene_target(name: str, *, res: int = 32, reference_spp: int = 1024, reference_chunks: int = 8,
                 reference_integrator: str = "path") -> Target:
    """A :class:`Target` rendering the scene ``name`` at ``res x res`` pixels.

    Methods are integrator names of :func:`mcvar.integrators.render`, with an
    optional fixed depth (:func:`parse_method`). The reference is rendered by
    the unbiased ``reference_integrator`` (path tracing with Russian roulette)
    with ``reference_spp`` spp per chunk, ``reference_chunks`` chunks from
    independent streams, sampler ``random``.
    """
    if not isinstance(name, str):
        raise TypeError(f"name must be a scene name string; got {type(name).__name__}")
    res = check_count(res, "res")
    reference_spp = check_count(reference_spp, "reference_spp")
    reference_chunks = check_count(reference_chunks, "reference_chunks")
    if reference_chunks < 2:
        raise ValueError(f"reference_chunks must be >= 2 (their spread is the reference's "
                         f"variance); got {reference_chunks}")
    parse_method(reference_integrator)
    _scene(name)  # fail early on an unknown scene
    return Target(name=name, evaluate=partial(_scene_evaluate, name, res),
                  key=f"scene={name};res={res}",
                  methods=("path", "path:2", "direct"), samplers=("random", "jittered", "sobol"),
                  spp=(1, 4, 16, 64),
                  reference_task=partial(_scene_reference, name, res, reference_integrator,
                                         reference_spp, "random"),
                  reference_chunks=reference_chunks,
                  reference_settings=f"integrator={reference_integrator};spp={reference_spp};"
                                     f"sampler=random")


def make_target(name, *, res: int = 32) -> Target:
    """A :class:`Target` from a name: ``'lecture'`` (:func:`lecture_target`), an
    integrand of ``mcvar.examples.PROBLEMS``, otherwise a scene of
    ``mcvar.scene.load_scene``; a :class:`Target` is returned as is."""
    if isinstance(name, Target):
        return name
    if not isinstance(name, str):
        raise TypeError(f"target must be a Target or a name string; got {type(name).__name__}")
    from .examples import PROBLEMS

    if name == "lecture":
        return lecture_target()
    if name in PROBLEMS:
        return integrand_target(name)
    try:
        return scene_target(name, res=res)
    except (KeyError, ValueError) as exc:
        raise ValueError(f"target must be an integrand {tuple(PROBLEMS)} or a scene name; "
                         f"got {name!r} ({exc})") from exc


# --------------------------------------------------------------------------
# Streams, executors, caches
# --------------------------------------------------------------------------

def _h32(text: str) -> int:
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], "little")


def _digest(*parts) -> str:
    return hashlib.sha256("|".join(map(str, parts)).encode()).hexdigest()[:24]


def run_seed(seed: int, target_key: str, method: str, sampler: str, spp: int, replicates: int):
    """The ``replicates`` independent streams of one configuration.

    ``SeedSequence(seed, spawn_key=(h(target), h(method), h(sampler), spp))``
    spawned ``replicates`` times, with ``h`` the first 32 bits of SHA-256: the
    streams depend only on the seed and the configuration, never on the order
    in which runs execute, and distinct configurations get distinct streams.
    """
    seed = check_count(seed, "seed", allow_zero=True)
    root = np.random.SeedSequence(seed, spawn_key=(_h32(target_key), _h32(method),
                                                  _h32(sampler), int(spp)))
    return root.spawn(check_count(replicates, "replicates"))


class SerialExecutor(Executor):
    """A :class:`concurrent.futures.Executor` that runs each task in this
    process when it is submitted (for debugging, tests and one-core runs)."""

    def submit(self, fn, /, *args, **kwargs):
        future = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except Exception as exc:  # KeyboardInterrupt propagates
            future.set_exception(exc)
        return future


def _run(evaluate, method, sampler, spp, seed_seq):
    rng = np.random.default_rng(seed_seq)
    start = time.perf_counter()
    value = np.asarray(evaluate(method, sampler, spp, rng), dtype=np.float64)
    seconds = time.perf_counter() - start
    return value, seconds


def _atomic_save(path: Path, **arrays) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def _map(executor, fn, jobs, *, window, on_done, progress_bar):
    """Submit ``fn(*job)`` for every job, at most ``window`` pending at once;
    call ``on_done(index, result)`` as each finishes. On any exception (or
    KeyboardInterrupt) pending tasks are cancelled and it is re-raised."""
    pending: dict = {}
    jobs = list(jobs)
    nxt = 0
    try:
        while nxt < len(jobs) or pending:
            while nxt < len(jobs) and len(pending) < window:
                pending[executor.submit(fn, *jobs[nxt])] = nxt
                nxt += 1
            done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
            for fut in sorted(done, key=pending.__getitem__):
                index = pending.pop(fut)
                on_done(index, fut.result())
                progress_bar.update(1)
    except BaseException:
        for fut in pending:
            fut.cancel()
        raise


# --------------------------------------------------------------------------
# References
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class Reference:
    """The value a sweep's estimates are compared with.

    Attributes
    ----------
    value : ndarray
        Exact value, or the mean of the reference chunks.
    variance : ndarray
        Variance of ``value`` itself per element (0 when exact or unknown):
        the sample variance across chunks divided by the number of chunks.
    mean_variance : float
        Variance of the element-mean of ``value`` (from the chunks' means, so
        correlations between pixels are included).
    chunks : int
        Independent chunks averaged (0 when exact or loaded without chunks).
    source : str
        ``'exact'``, ``'rendered: ...'``, ``'cache: ...'`` or ``'file: ...'``.
    """

    value: np.ndarray
    variance: np.ndarray
    mean_variance: float
    chunks: int
    source: str


def _reference_from_file(path: Path) -> Reference:
    if not path.is_file():
        raise FileNotFoundError(f"reference file {path} does not exist")
    if path.suffix == ".npz":
        with np.load(path) as data:
            value = as_array(data["value"], "reference value")
            variance = as_array(data["variance"], "reference variance", nonnegative=True) \
                if "variance" in data else np.zeros_like(value)
            mean_var = float(data["mean_variance"]) if "mean_variance" in data else 0.0
            chunks = int(data["chunks"]) if "chunks" in data else 0
        return Reference(value, variance, mean_var, chunks, f"file: {path}")
    if path.suffix == ".npy":
        value = as_array(np.load(path), "reference image", nonnegative=True)
        return Reference(value, np.zeros_like(value), 0.0, 0, f"file: {path} (variance unknown, taken as 0)")
    raise ValueError(f"reference must be a .npy image or an .npz with 'value' (and 'variance'); got {path}")


def compute_reference(target: Target, *, seed: int = 0, executor: Executor | None = None,
                      cache_dir=None, path=None, progress: bool = False) -> Reference:
    """The reference for ``target``: exact, loaded from ``path``, or rendered.

    A rendered reference averages ``target.reference_chunks`` chunks, each
    ``target.reference_task(rng)`` with its own spawned stream, and is cached
    in ``cache_dir`` under a hash of the target's key, the reference settings,
    the chunk count and the seed; a second call loads it.

    Parameters
    ----------
    path : str or Path, optional
        A user-supplied reference: ``.npy`` (an image; its variance is taken
        as 0) or ``.npz`` with ``value`` and optionally ``variance``,
        ``mean_variance``, ``chunks``.
    """
    if path is not None:
        return _reference_from_file(Path(path))
    if target.exact is not None:
        value = as_array(target.exact, "target.exact")
        return Reference(value, np.zeros_like(value), 0.0, 0, "exact")
    if target.reference_task is None:
        raise ValueError(f"target {target.name!r} has neither an exact value nor a reference_task; "
                         "pass reference=PATH")
    chunks = check_count(target.reference_chunks, "target.reference_chunks")
    key = _digest("reference", CACHE_VERSION, target.key, target.reference_settings, chunks, seed)
    cache = Path(cache_dir) / f"reference-{key}.npz" if cache_dir is not None else None
    if cache is not None and cache.is_file():
        ref = _reference_from_file(cache)
        return Reference(ref.value, ref.variance, ref.mean_variance, ref.chunks, f"cache: {cache}")
    streams = np.random.SeedSequence(seed, spawn_key=(_h32("reference"), _h32(target.key))).spawn(chunks)
    results: list = [None] * chunks
    executor = SerialExecutor() if executor is None else executor

    def keep(i, res):
        results[i] = res

    from tqdm.auto import tqdm

    with tqdm(total=chunks, desc=f"{target.name} reference", disable=not progress) as bar:
        _map(executor, _run, [(_ref_adapter(target.reference_task), "", "", 0, s) for s in streams],
             window=chunks, on_done=keep, progress_bar=bar)
    stack = np.stack([r[0] for r in results])
    value = stack.mean(axis=0)
    variance = stack.var(axis=0, ddof=1) / chunks
    means = stack.reshape(chunks, -1).mean(axis=1)
    mean_variance = float(means.var(ddof=1) / chunks)
    seconds = sum(r[1] for r in results)
    source = f"rendered: {target.reference_settings}, {chunks} chunks, {seconds:.1f} s"
    if cache is not None:
        _atomic_save(cache, value=value, variance=variance, mean_variance=mean_variance, chunks=chunks)
    return Reference(value, variance, mean_variance, chunks, source)


def _ref_adapter(task):
    return partial(_call_reference, task)


def _call_reference(task, method, sampler, spp, rng):
    return task(rng)


# --------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class ConfigMetrics:
    """Measurements of one configuration (method, sampler, spp) over R replicates.

    Attributes
    ----------
    variance, variance_stderr : float
        Mean over pixels (elements) of the per-pixel variance across
        replicates (ddof = 1), and its jackknife standard error.
    bias2, bias2_stderr : float
        Mean over pixels of the squared bias, corrected for the noise of the
        replicate mean and of the reference (can be slightly negative when the
        bias is 0); jackknife standard error.
    mse, mse_stderr : float
        ``variance + bias2``: the mean squared error against the truth.
    rel_mse : float
        Relative MSE (:func:`mcvar.metrics.relative_mse`, eps = 1e-2), averaged
        over replicates, minus the reference's own contribution.
    seconds : float
        Mean wall time of one run (one estimate / image).
    efficiency : float
        ``1 / (mse * seconds)`` (``inf`` when the measured MSE is <= 0).
    bias, bias_stderr, bias_z, bias_dof, bias_pvalue : float
        Bias of the element-mean (mean image value minus the reference's), its
        standard error, Welch t statistic, degrees of freedom and two-sided
        p-value.
    bias_detected : bool
        ``bias_pvalue < alpha_family`` (Sidak-corrected over the method's
        configurations; see :func:`sweep`).
    rounding : float
        Floating-point floor of the bias test's standard error,
        ``64 eps |value|``: an error below it is rounding, not bias or noise.
    """

    method: str
    sampler: str
    spp: int
    replicates: int
    variance: float
    variance_stderr: float
    bias2: float
    bias2_stderr: float
    mse: float
    mse_stderr: float
    rel_mse: float
    seconds: float
    efficiency: float
    bias: float
    bias_stderr: float
    bias_z: float
    bias_dof: float
    bias_pvalue: float
    bias_detected: bool = False
    rounding: float = 0.0

    @property
    def figure_of_merit(self) -> float:
        """``MSE x time`` (seconds): lower is better; ``1 / efficiency``."""
        return max(self.mse, 0.0) * self.seconds


def _moments(x, ref, ref_var):
    """variance, bias2, mse of replicates ``x`` (R, P) against ``ref``."""
    r = x.shape[0]
    s2 = x.var(axis=0, ddof=1)
    b = x.mean(axis=0) - ref
    variance = float(s2.mean())
    bias2 = float(np.mean(b * b - s2 / r - ref_var))
    return variance, bias2, variance + bias2


def _config_metrics(method, sampler, spp, values, seconds, ref: Reference) -> ConfigMetrics:
    r = values.shape[0]
    x = values.reshape(r, -1)
    ref_v = ref.value.reshape(-1)
    ref_var = ref.variance.reshape(-1)
    variance, bias2, mse = _moments(x, ref_v, ref_var)
    jack = np.array([_moments(np.delete(x, i, axis=0), ref_v, ref_var) for i in range(r)])
    stderr = np.sqrt((r - 1) / r * np.sum((jack - jack.mean(axis=0)) ** 2, axis=0))
    eps = 1e-2
    rel = float(np.mean([relative_mse(ref_v, xi, eps=eps) for xi in x])
                - np.mean(ref_var / (ref_v ** 2 + eps)))
    sec = float(np.mean(seconds))
    eff = 1.0 / (mse * sec) if mse > 0 and sec > 0 else float("inf")
    # Welch t test of the element-mean against the reference's element-mean.
    t_r = x.mean(axis=1)
    a = t_r.var(ddof=1) / r
    bvar = ref.mean_variance
    diff = float(t_r.mean() - ref_v.mean())
    # A float64 mean carries rounding of order eps * |value|. Without this floor
    # an exact, zero-variance estimator (importance sampling with the integrand
    # as its pdf) would be 'biased' at z = inf by its last bit; a real bias of a
    # zero-variance estimator (the fixed grid's 2 / m^2) still stands out.
    rounding = 64.0 * np.finfo(np.float64).eps * max(abs(float(t_r.mean())), abs(float(ref_v.mean())))
    se = np.sqrt(a + bvar + rounding ** 2)
    if se > 0:
        z = diff / se
        den = a * a / (r - 1) + (bvar * bvar / (ref.chunks - 1) if ref.chunks > 1 else 0.0)
        dof = float((a + bvar) ** 2 / den) if den > 0 else float("inf")
        p = float(2 * stats.t.sf(abs(z), dof))
    else:  # no scatter at all: any difference is certain
        z = 0.0 if diff == 0 else float(np.copysign(np.inf, diff))
        dof, p = float("inf"), (1.0 if diff == 0 else 0.0)
    return ConfigMetrics(method, sampler, int(spp), r, variance, float(stderr[0]), bias2,
                         float(stderr[1]), mse, float(stderr[2]), rel, sec, eff, diff, float(se),
                         float(z), dof, p, rounding=float(rounding))


# --------------------------------------------------------------------------
# Fits and verdicts
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class MethodFits:
    """Log-log convergence fits of one (method, sampler) over its spp levels.

    Each is a :class:`mcvar.metrics.LogLogFit` (slope and its standard error)
    or None when fewer than 3 levels have a positive value.
    """

    method: str
    sampler: str
    variance: LogLogFit | None
    mse: LogLogFit | None
    mse_time: LogLogFit | None
    bias2: LogLogFit | None
    consistent: bool
    evidence: str


@dataclass(frozen=True)
class Verdict:
    """The measured answer to the 'Rendering Algorithm Chart' for one method.

    ``label`` is ``'both'`` (unbiased and consistent), ``'unbiased'``,
    ``'consistent'`` or ``'neither'``; ``evidence`` says which measurements
    decided it.
    """

    method: str
    unbiased: bool
    consistent: bool
    label: str
    evidence: str


def _fit(x, y):
    x, y = np.asarray(x, float), np.asarray(y, float)
    keep = np.isfinite(y) & (y > 0)
    if keep.sum() < 3:
        return None
    fit = loglog_fit(x[keep], y[keep])
    if not np.isfinite(fit.slope_stderr):  # points exactly on a flat line: no residual
        fit = LogLogFit(fit.slope, fit.intercept, 0.0, fit.n)
    return fit


def _decreases(first: ConfigMetrics, last: ConfigMetrics, name: str, alpha: float) -> bool:
    """One-sided z test that ``name`` (mse or bias2) is lower at ``last`` than at
    ``first``, with their jackknife standard errors (independent replicates)."""
    a, b = getattr(first, name), getattr(last, name)
    s = float(np.hypot(getattr(first, f"{name}_stderr"), getattr(last, f"{name}_stderr")))
    if s == 0:
        return bool(a > b)
    return bool(a - b > stats.norm.ppf(1 - alpha) * s)


def _fits(method, sampler, rows: Sequence[ConfigMetrics], alpha: float) -> MethodFits:
    spp = [m.spp for m in rows]
    mse = [m.mse for m in rows]
    f_var = _fit(spp, [m.variance for m in rows])
    f_mse = _fit(spp, mse)
    f_time = _fit([m.seconds for m in rows], mse)
    f_b2 = _fit(spp, [m.bias2 for m in rows])
    first, last = rows[0], rows[-1]
    if all(abs(m.mse) <= m.rounding ** 2 for m in rows):
        return MethodFits(method, sampler, f_var, f_mse, f_time, f_b2, True,
                          "exact at every level (error within floating-point rounding)")
    if len(rows) < 2:
        return MethodFits(method, sampler, f_var, f_mse, f_time, f_b2, False,
                          "one spp level: consistency cannot be measured")
    # The MSE falls if its log-log slope is negative by a one-sided t test over
    # every level (needs >= 4 levels for power), or if the last level's MSE is
    # below the first's by a z test: with a handful of replicates the first
    # level's MSE is too noisy for the z test alone (a scalar integrand's MSE
    # at 1 sample from 8 replicates has a relative error of ~0.5).
    slope_falls = bool(f_mse is not None and f_mse.n >= 4 and f_mse.slope_stderr > 0
                       and f_mse.slope / f_mse.slope_stderr < -stats.t.ppf(1 - alpha, f_mse.n - 2))
    mse_falls = slope_falls or _decreases(first, last, "mse", alpha)
    bias_falls = _decreases(first, last, "bias2", alpha)
    bias_gone = (not last.bias_detected) or bias_falls
    words = [f"MSE {first.mse:.3g} at {first.spp} -> {last.mse:.3g} at {last.spp} spp "
             f"({'falls' if mse_falls else 'does not fall'} significantly"
             + (f"; slope {f_mse.slope:.2f} ± {f_mse.slope_stderr:.2f})" if f_mse else ")"),
             f"bias at {last.spp} spp {'detected' if last.bias_detected else 'not detected'} "
             f"(t = {last.bias_z:.1f})"]
    if last.bias_detected:
        words.append(f"bias² {first.bias2:.3g} -> {last.bias2:.3g} "
                     f"({'falls' if bias_falls else 'does not fall'} significantly)")
    return MethodFits(method, sampler, f_var, f_mse, f_time, f_b2, bool(mse_falls and bias_gone),
                      "; ".join(words))


def _verdicts(methods, metrics, fits, alpha_family) -> dict:
    out = {}
    for method in methods:
        rows = [m for m in metrics if m.method == method]
        mfits = [f for f in fits.values() if f.method == method]
        detected = [m for m in rows if m.bias_detected]
        unbiased = not detected
        consistent = all(f.consistent for f in mfits)
        label = {(True, True): "both", (True, False): "unbiased",
                 (False, True): "consistent", (False, False): "neither"}[(unbiased, consistent)]
        worst = max(rows, key=lambda m: abs(m.bias_z))
        ev = [f"bias test: {len(detected)} of {len(rows)} configurations reject zero bias at "
              f"Sidak-corrected p < {alpha_family:.2g} (largest |t| = {abs(worst.bias_z):.1f} at "
              f"{worst.sampler}, {worst.spp} spp)"]
        ev += [f"{f.sampler}: {'consistent' if f.consistent else 'not consistent'} ({f.evidence})"
               for f in mfits]
        out[method] = Verdict(method, unbiased, consistent, label, "; ".join(ev))
    return out


# --------------------------------------------------------------------------
# The sweep
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class SweepResult:
    """Everything a sweep measured.

    Attributes
    ----------
    metrics : tuple of ConfigMetrics
        One per (method, sampler, spp), in sweep order.
    fits : dict
        ``(method, sampler) -> MethodFits``.
    verdicts : dict
        ``method -> Verdict``.
    values : dict
        ``(method, sampler, spp) -> ndarray (R, ...)``: every replicate.
    seconds : dict
        ``(method, sampler, spp) -> ndarray (R,)``: wall time of each run.
    computed, cached : int
        Runs computed by this call and runs loaded from the cache.
    alpha, alpha_family : float
        Family-wise significance of the bias tests and the per-test level
        after the Sidak correction.
    """

    target: str
    methods: tuple
    samplers: tuple
    spp: tuple
    replicates: int
    seed: int
    reference: Reference
    metrics: tuple
    fits: dict
    verdicts: dict
    values: dict = field(repr=False)
    seconds: dict = field(repr=False)
    computed: int = 0
    cached: int = 0
    alpha: float = 1e-3
    alpha_family: float = 1e-3

    def pixel_variance(self, method: str, sampler: str, spp: int) -> np.ndarray:
        """Per-pixel variance across replicates (ddof = 1), shape of one estimate."""
        return self.values[(method, sampler, spp)].var(axis=0, ddof=1)

    def rows(self) -> list[dict]:
        """One dict per configuration: every number, for a CSV."""
        out = []
        for m in self.metrics:
            row = {"target": self.target, **{k: getattr(m, k) for k in ConfigMetrics.__dataclass_fields__}}
            row["mse_x_time"] = m.figure_of_merit
            out.append(row)
        return out


def _as_levels(spp) -> tuple:
    if isinstance(spp, (int, np.integer)):
        spp = [spp]
    levels = [check_count(s, "spp") for s in spp]
    if len(levels) == 0:
        raise ValueError("spp must hold at least one level")
    return tuple(sorted(set(levels)))


def _as_names(names, what: str) -> tuple:
    if isinstance(names, str):
        names = [names]
    names = tuple(names)
    if not names or not all(isinstance(n, str) for n in names):
        raise ValueError(f"{what} must be a non-empty sequence of strings; got {names!r}")
    return tuple(dict.fromkeys(names))


def sweep(target, *, methods=None, samplers=None, spp=None, replicates: int = 8, seed: int = 0,
          reference=None, executor: Executor | None = None, workers: int | None = None,
          cache_dir=None, res: int = 32, alpha: float = 1e-3, progress: bool = True) -> SweepResult:
    """Run ``target`` for every method x sampler x spp level x replicate and measure it.

    Parameters
    ----------
    target : Target or str
        A :class:`Target`, or a name for :func:`make_target` (an integrand of
        ``mcvar.examples.PROBLEMS`` or a scene).
    methods, samplers : sequence of str, optional
        Defaults: the target's.
    spp : sequence of int, optional
        Samples (per pixel) levels; sorted, duplicates dropped. Default: the
        target's.
    replicates : int
        Independent runs per configuration, >= 3 (the jackknife needs 3).
    seed : int
        Root of every stream (:func:`run_seed`).
    reference : Reference, str or Path, optional
        The comparison value; default :func:`compute_reference` (exact, or
        rendered and cached in ``cache_dir``).
    executor : concurrent.futures.Executor, optional
        Runs the tasks: e.g. ``client.get_executor()`` of a Dask client.
        Default: a :class:`~concurrent.futures.ProcessPoolExecutor` with
        ``workers`` processes (all cores when None), or a
        :class:`SerialExecutor` when ``workers == 1``.
    cache_dir : str or Path, optional
        Folder for finished runs and references; runs found there are not
        recomputed (an interrupted sweep resumes). None: no disk cache.
    res : int
        Resolution of scene targets given by name.
    alpha : float
        Family-wise significance of the bias tests of one method.
    progress : bool
        One tqdm bar for the whole sweep.

    Returns
    -------
    SweepResult

    Notes
    -----
    With ``X_r`` the R replicates of one configuration (per pixel), ``s^2``
    their sample variance, ``b = mean_r X_r - ref`` and ``v_ref`` the variance
    of the reference itself, the sweep reports per configuration (averaged
    over pixels)

    * variance ``s^2`` (unbiased for Var X: the lecture's 'Variance' slide),
    * squared bias ``b^2 - s^2 / R - v_ref`` (unbiased for beta^2, because
      ``E[b^2] = beta^2 + Var(X)/R + v_ref``),
    * MSE = variance + squared bias, efficiency ``1 / (MSE x time)``
      [Veach 1997, sec. 2.4.3],

    with jackknife standard errors over replicates.

    *Bias test.* The element-mean of an estimate (the mean image value) has
    replicates ``T_r``; Welch's t statistic ``(mean T - T_ref) / sqrt(var(T)/R
    + Var(T_ref))`` with Welch-Satterthwaite degrees of freedom gives a
    two-sided p-value. A method's bias is declared distinguishable from zero
    at a configuration when p < 1 - (1 - alpha)^(1/m), the Sidak level for its
    m configurations; the method is *unbiased* when no configuration rejects
    ('Bias & Consistency': E[I - I_n] = 0 even for one sample). A bias that
    cancels over the image escapes this test (the per-pixel squared bias is
    reported beside it).

    *Consistency.* Per sampler: the MSE falls (MSE at the largest spp below
    the MSE at the smallest, one-sided z test with their jackknife errors at
    level ``alpha``) and the bias vanishes (not detected at the largest spp,
    or its square falls significantly by the same test). A fixed-depth path
    tracer's MSE levels off at its squared bias: not consistent. 'Not
    consistent' means consistency was not shown by these measurements.

    References
    ----------
    .. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
       Simulation", PhD thesis, Stanford University, 1997, sec. 1.4.4, 2.4.3.
    .. [2] B. L. Welch, "The generalization of 'Student's' problem when several
       different population variances are involved", Biometrika 34, 1947.
    .. [3] B. Efron, C. Stein, "The jackknife estimate of variance", Annals of
       Statistics 9(3), 1981.
    """
    target = make_target(target, res=res)
    methods = _as_names(methods if methods is not None else target.methods, "methods")
    samplers = _as_names(samplers if samplers is not None else target.samplers, "samplers")
    levels = _as_levels(spp if spp is not None else target.spp)
    replicates = check_count(replicates, "replicates")
    if replicates < 3:
        raise ValueError(f"replicates must be >= 3 (variance and its jackknife error); got {replicates}")
    seed = check_count(seed, "seed", allow_zero=True)
    alpha = check_probability(alpha, "alpha")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must lie in (0, 1); got {alpha}")
    if workers is not None:
        workers = check_count(workers, "workers")
    if executor is not None and not isinstance(executor, Executor):
        raise TypeError(f"executor must be a concurrent.futures.Executor; got {type(executor).__name__}")
    cache = Path(cache_dir) if cache_dir is not None else None

    own = executor is None
    if own:
        n_workers = workers or os.cpu_count() or 1
        executor = SerialExecutor() if n_workers == 1 else ProcessPoolExecutor(max_workers=n_workers)
        window = 2 * n_workers
    else:
        window = 1 << 30
    try:
        if isinstance(reference, Reference):
            ref = reference
        else:
            ref = compute_reference(target, seed=seed, executor=executor, cache_dir=cache,
                                    path=reference, progress=progress)
        configs = [(m, s, n) for m in methods for s in samplers for n in levels]
        values: dict = {}
        secs: dict = {}
        jobs, where = [], []
        cached = 0
        for m, s, n in configs:
            streams = run_seed(seed, target.key, m, s, n, replicates)
            values[(m, s, n)] = [None] * replicates
            secs[(m, s, n)] = np.zeros(replicates)
            for r, stream in enumerate(streams):
                path = None
                if cache is not None:
                    path = cache / "runs" / f"{_digest(CACHE_VERSION, target.key, m, s, n, r, seed)}.npz"
                    if path.is_file():
                        with np.load(path) as data:
                            values[(m, s, n)][r] = data["value"]
                            secs[(m, s, n)][r] = float(data["seconds"])
                        cached += 1
                        continue
                jobs.append((target.evaluate, m, s, n, stream))
                where.append(((m, s, n), r, path))

        def keep(i, result):
            key, r, path = where[i]
            value, seconds = result
            if value.size == 0 or not np.all(np.isfinite(value)):
                raise ValueError(f"target {target.name!r} returned a non-finite or empty estimate for "
                                 f"{key} replicate {r}")
            values[key][r] = value
            secs[key][r] = seconds
            if path is not None:
                _atomic_save(path, value=value, seconds=seconds)

        from tqdm.auto import tqdm

        total = len(configs) * replicates
        with tqdm(total=total, initial=cached, desc=f"{target.name} sweep", disable=not progress,
                  unit="run") as bar:
            _map(executor, _run, jobs, window=window, on_done=keep, progress_bar=bar)
    finally:
        if own:
            executor.shutdown(wait=True, cancel_futures=True)

    stacked = {k: np.stack(v) for k, v in values.items()}
    for k, v in stacked.items():
        if v.shape[1:] != ref.value.shape:
            raise ValueError(f"estimates of {k} have shape {v.shape[1:]} but the reference has "
                             f"{ref.value.shape}")
    metrics = [_config_metrics(m, s, n, stacked[(m, s, n)], secs[(m, s, n)], ref) for m, s, n in configs]
    per_method = len(samplers) * len(levels)
    alpha_family = 1.0 - (1.0 - alpha) ** (1.0 / per_method)
    metrics = tuple(_with_detection(m, alpha_family) for m in metrics)
    fits = {}
    for m in methods:
        for s in samplers:
            rows = [x for x in metrics if x.method == m and x.sampler == s]
            fits[(m, s)] = _fits(m, s, rows, alpha)
    verdicts = _verdicts(methods, metrics, fits, alpha_family)
    return SweepResult(target.name, methods, samplers, levels, replicates, seed, ref, metrics, fits,
                       verdicts, stacked, secs, computed=len(jobs), cached=cached, alpha=alpha,
                       alpha_family=alpha_family)


def _with_detection(m: ConfigMetrics, alpha_family: float) -> ConfigMetrics:
    return replace(m, bias_detected=bool(m.bias_pvalue < alpha_family))
