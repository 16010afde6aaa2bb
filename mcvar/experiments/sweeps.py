"""The sweep: every method x sampler x spp level x replicate of a target, run
on any executor and measured (layer 6, module 5 of :mod:`mcvar.experiments`)."""
from __future__ import annotations

import os
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .._validation import check_bool, check_count, check_probability, seed_alias, settings_with
from .targets import make_target, parse_method
from .runs import CACHE_VERSION, SerialExecutor, _atomic_save, _digest, _map, _run, root_seed, run_seed
from .reference import Reference, compute_reference
from .denoising import DENOISE_SUFFIX, denoised_target
from .analysis import ConfigMetrics, _config_metrics, _fits, _image_quality, _verdicts, _with_detection


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


@dataclass(frozen=True)
class SweepSettings:
    """What a sweep runs and how it tests it (the keywords of :func:`sweep`).

    Attributes
    ----------
    methods, samplers, spp : sequence, optional
        Defaults: the target's (``spp`` sorted, duplicates dropped).
    replicates : int
        Independent runs per configuration, >= 3 (the jackknife needs 3).
    rng : int
        Root seed of every stream (:func:`run_seed`): an integer >= 0, since
        finished runs are cached by it.
    res : int
        Resolution of scene targets given by name.
    alpha : float
        Family-wise significance of the bias tests of one method.
    image_metrics : bool
        Also measure PSNR and SSIM of every image replicate.
    workers : int or None
        Processes of the sweep's own pool (all cores when None; 1: in this
        process) when no executor is given.
    progress : bool
        One tqdm bar for the whole sweep.
    """

    methods: tuple | None = None
    samplers: tuple | None = None
    spp: tuple | None = None
    replicates: int = 8
    rng: int = 0
    res: int = 32
    alpha: float = 1e-3
    image_metrics: bool = False
    workers: int | None = None
    progress: bool = True


@dataclass(frozen=True)
class _Plan:
    target: object
    methods: tuple
    samplers: tuple
    levels: tuple
    replicates: int
    seed: int
    alpha: float

    @property
    def configs(self) -> list:
        return [(m, s, n) for m in self.methods for s in self.samplers for n in self.levels]


def _plan(target, settings: SweepSettings) -> _Plan:
    """The sweep's target and configurations, every setting checked before any work."""
    target = make_target(target, res=settings.res)
    methods = settings.methods
    if methods is not None and any(str(m).endswith(DENOISE_SUFFIX) for m in
                                   ([methods] if isinstance(methods, str) else methods)):
        target = denoised_target(target)
    methods = _as_names(methods if methods is not None else target.methods, "methods")
    _check_methods(target, methods)
    check_bool(settings.progress, "progress")
    check_bool(settings.image_metrics, "image_metrics")
    samplers = _as_names(settings.samplers if settings.samplers is not None else target.samplers, "samplers")
    levels = _as_levels(settings.spp if settings.spp is not None else target.spp)
    replicates = check_count(settings.replicates, "replicates")
    if replicates < 3:
        raise ValueError(f"replicates must be >= 3 (variance and its jackknife error); got {replicates}")
    seed = root_seed(settings.rng)
    alpha = check_probability(settings.alpha, "alpha")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must lie in (0, 1); got {alpha}")
    return _Plan(target, methods, samplers, levels, replicates, seed, alpha)


def _executor(executor, workers):
    """(executor, owned by the sweep?, submission window)."""
    if workers is not None:
        workers = check_count(workers, "workers")
    if executor is not None and not isinstance(executor, Executor):
        raise TypeError(f"executor must be a concurrent.futures.Executor; got {type(executor).__name__}")
    if executor is not None:
        return executor, False, 1 << 30
    n_workers = workers or os.cpu_count() or 1
    return (SerialExecutor() if n_workers == 1 else ProcessPoolExecutor(max_workers=n_workers)), True, 2 * n_workers


def _runs(plan: _Plan, executor, window: int, cache, progress: bool):
    """Every replicate of every configuration: loaded from ``cache`` or computed.
    Returns ``(values, seconds, computed, cached)``."""
    target = plan.target
    values: dict = {}
    secs: dict = {}
    jobs, where = [], []
    cached = 0
    for m, s, n in plan.configs:
        values[(m, s, n)] = [None] * plan.replicates
        secs[(m, s, n)] = np.zeros(plan.replicates)
        for r, stream in enumerate(run_seed(plan.seed, target.key, m, s, n, plan.replicates)):
            path = None
            if cache is not None:
                path = cache / "runs" / f"{_digest(CACHE_VERSION, target.key, m, s, n, r, plan.seed)}.npz"
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

    total = len(plan.configs) * plan.replicates
    with tqdm(total=total, initial=cached, desc=f"{target.name} sweep", disable=not progress,
              unit="run") as bar:
        _map(executor, _run, jobs, window=window, on_done=keep, progress_bar=bar)
    return values, secs, len(jobs), cached


def _measure(plan: _Plan, values: dict, secs: dict, ref, image_metrics: bool, counts: tuple) -> "SweepResult":
    """Metrics, fits and verdicts of the finished runs."""
    stacked = {k: np.stack(v) for k, v in values.items()}
    for k, v in stacked.items():
        if v.shape[1:] != ref.value.shape:
            raise ValueError(f"estimates of {k} have shape {v.shape[1:]} but the reference has "
                             f"{ref.value.shape}")
    metrics = [_config_metrics(m, s, n, stacked[(m, s, n)], secs[(m, s, n)], ref) for m, s, n in plan.configs]
    per_method = len(plan.samplers) * len(plan.levels)
    alpha_family = 1.0 - (1.0 - plan.alpha) ** (1.0 / per_method)
    metrics = tuple(_with_detection(m, alpha_family) for m in metrics)
    if image_metrics and ref.value.ndim == 3:
        metrics = tuple(replace(m, **dict(zip(("psnr", "ssim"), _image_quality(
            stacked[(m.method, m.sampler, m.spp)], ref.value)))) for m in metrics)
    fits = {}
    for m in plan.methods:
        for s in plan.samplers:
            rows = [x for x in metrics if x.method == m and x.sampler == s]
            fits[(m, s)] = _fits(m, s, rows, plan.alpha)
    verdicts = _verdicts(plan.methods, metrics, fits, alpha_family)
    return SweepResult(plan.target.name, plan.methods, plan.samplers, plan.levels, plan.replicates, plan.seed,
                       ref, metrics, fits, verdicts, stacked, secs, computed=counts[0], cached=counts[1],
                       alpha=plan.alpha, alpha_family=alpha_family)


def _check_methods(target, methods) -> None:
    """Every method name is one the target can run (a ValueError naming the
    unknown ones and the known ones, before any run): an integrand's own
    methods, a scene's registered integrators (``'integrator[:max_depth]'``,
    optionally denoised); a user target's names are its own business."""
    plain = [m[:-len(DENOISE_SUFFIX)] if m.endswith(DENOISE_SUFFIX) else m for m in methods]
    if target.key.startswith("integrand="):
        unknown = [m for m, p in zip(methods, plain) if p not in target.methods]
        if unknown:
            raise ValueError(f"methods {unknown} are not methods of the integrand {target.name!r}; "
                             f"it has {tuple(target.methods)}")
    elif target.key.startswith("scene="):
        from ..integrators import METHODS

        unknown = [m for m, p in zip(methods, plain) if parse_method(p)[0] not in METHODS]
        if unknown:
            raise ValueError(f"methods {unknown} are not registered integrators; methods are "
                             f"'integrator[:max_depth]' with integrator one of {tuple(METHODS)}")


def sweep(target, settings: SweepSettings | None = None, *, reference=None, executor: Executor | None = None,
          cache_dir=None, **options) -> SweepResult:
    """Run ``target`` for every method x sampler x spp level x replicate and measure it.

    Parameters
    ----------
    target : Target or str
        A :class:`Target`, or a name for :func:`make_target` (an integrand of
        ``mcvar.examples.PROBLEMS`` or a scene).
    settings : SweepSettings, optional
        What to run; the keywords ``methods``, ``samplers``, ``spp``,
        ``replicates``, ``rng``, ``res``, ``alpha``, ``image_metrics``,
        ``workers`` and ``progress`` (its fields, documented there and
        below) replace its fields. Any other keyword is a ``TypeError``.
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

    Other Parameters
    ----------------
    methods, samplers : sequence of str, optional
        Defaults: the target's.
    spp : sequence of int, optional
        Samples (per pixel) levels; sorted, duplicates dropped. Default: the
        target's.
    replicates : int
        Independent runs per configuration, >= 3 (the jackknife needs 3).
    rng : int
        Root seed of every stream (:func:`run_seed`), >= 0 (runs are cached
        by it). ``seed=`` is its deprecated alias.
    res : int
        Resolution of scene targets given by name.
    alpha : float
        Family-wise significance of the bias tests of one method.
    progress : bool
        One tqdm bar for the whole sweep.
    image_metrics : bool
        Also measure PSNR and SSIM (:func:`mcvar.metrics.structural_similarity`)
        of every image replicate against the reference, as displayed: the
        ``psnr`` and ``ssim`` of each :class:`ConfigMetrics` (NaN otherwise,
        and for scalar targets).

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
    settings = settings_with(SweepSettings, settings, seed_alias(options, "sweep"), "sweep")
    plan = _plan(target, settings)
    executor, own, window = _executor(executor, settings.workers)
    progress = settings.progress
    cache = Path(cache_dir) if cache_dir is not None else None
    try:
        if isinstance(reference, Reference):
            ref = reference
        else:
            ref = compute_reference(plan.target, rng=plan.seed, executor=executor, cache_dir=cache,
                                    path=reference, progress=progress)
        values, secs, computed, cached = _runs(plan, executor, window, cache, progress)
    finally:
        if own:
            executor.shutdown(wait=True, cancel_futures=True)
    return _measure(plan, values, secs, ref, settings.image_metrics, (computed, cached))
