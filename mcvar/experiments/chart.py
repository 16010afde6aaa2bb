"""The lecture's 'Rendering Algorithm Chart', measured (layer 6, module 6 of
:mod:`mcvar.experiments`; ``mcvar chart``).

The lecture closes with a chart answering 'consistent?' and 'unbiased?' for
six families of rendering methods (rasterization no/no, path tracing
almost/almost, BDPT yes/yes, MLT yes/yes, photon mapping yes/no, finite
element radiosity no/no). :func:`measure_chart` measures both answers for
every registered method on the Cornell box with the machinery of
``mcvar converge``: one :func:`~mcvar.experiments.sweeps.sweep` per method
(replicates at increasing levels of the method's accuracy knob, the Welch
bias test with the Sidak correction, the consistency test) plus the block
bias test (:func:`~mcvar.experiments.analysis.block_bias_test`), all against one
cached path-traced reference, and MSE x time at the largest level.

The accuracy knob
-----------------
Most methods get better with samples per pixel; photon mapping with photons,
SPPM with iterations, radiosity with a finer mesh. A method declares its
:class:`~mcvar.integrators.knobs.Knob` in its registration
(``Method(..., knob=...)``): what its level counts, the levels of the quick and
the default chart, and ``options(level) -> dict`` of keyword arguments of
:func:`mcvar.integrators.render`. A method without one is measured in spp. A
knob whose options the registered method does not accept falls back to spp,
and the row's note says so.

Which methods
-------------
Everything about a method's row is in its registry record: ``Method.chart_row``
(the lecture's row it answers), ``Method.knob``, ``Method.theory`` (what theory
says, with the reason shown where the lecture differs) and
``Method.chart_depths`` (fixed depths also charted: ``path`` charts
``'path:3'``, path tracing with ``max_depth=3``; ``'path_depth3'`` is accepted
as an alias of ``'path:3'``). :func:`chart_methods` lists the rows in the
lecture's order, then any other registered method with both a knob and a
lecture claim (``Method.lecture``). A method that is not registered has no row;
it gets one when it registers.

The lecture's claim of a chart method is the slide's (:data:`LECTURE_ROWS` of its
``chart_row``): the chart quotes the lecture, so ``path``'s registered
``Method.lecture = ('almost', 'almost')`` and theory's ``('yes', 'yes')`` are
both kept. Methods on no slide row take ``Method.lecture``.
"""
from __future__ import annotations

import os
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from types import MappingProxyType

import numpy as np

from .._validation import check_bool, check_count, seed_alias, settings_with
from ..integrators.knobs import Knob, depth_knob, spp_knob
from .targets import Target, _check_reference_settings, _scene, parse_method
from .runs import SerialExecutor, root_seed
from .reference import compute_reference
from .sweeps import sweep
from .analysis import image_bias_verdict

__all__ = ["LECTURE_ROWS", "CHART_COLUMNS", "QUICK", "DEFAULT", "BLOCK", "Knob", "spp_knob", "ChartRow",
           "ChartResult", "ChartSettings", "register_knob", "chart_methods", "chart_knob", "chart_theory", "chart_lecture_row",
           "lecture_chart_claim", "split_row", "row_name", "chart_target", "emitter_pixels", "measure_chart"]

#: The lecture's chart: row -> (consistent?, unbiased?).
LECTURE_ROWS = {
    "Rasterization": ("no", "no"),
    "Path Tracing": ("almost", "almost"),
    "Bidirectional Path Tracing": ("yes", "yes"),
    "Metropolis Light Transport": ("yes", "yes"),
    "Photon Mapping": ("yes", "no"),
    "Finite Element Radiosity": ("no", "no"),
}

#: The columns of ``chart.csv``, in order.
CHART_COLUMNS = ("method", "lecture_consistent", "lecture_unbiased", "consistent", "unbiased",
                 "mse_x_time", "note")


#: Side in pixels of the blocks of the chart's block bias test
#: (:func:`~mcvar.experiments.analysis.block_bias_test`; docs/chart.md says why 4).
BLOCK = 4

#: Settings of ``mcvar chart --quick`` and ``mcvar chart``: resolution, replicates per level,
#: reference spp per chunk and reference chunks.
QUICK = dict(res=16, replicates=10, reference_spp=2048, reference_chunks=8)
DEFAULT = dict(res=32, replicates=12, reference_spp=4096, reference_chunks=8)


def register_knob(method: str, knob: Knob) -> Knob:
    """Set the chart knob of the registered ``method`` (its ``Method.knob``; a depth row
    ``'path:3'`` sets its base method's). Prefer ``Method(..., knob=...)`` in the
    method's registration; this replaces the record in the registry.

    Examples
    --------
    >>> from mcvar.experiments.chart import register_knob, spp_knob
    >>> register_knob("path", spp_knob("path"))                 # doctest: +ELLIPSIS
    Knob(counts='spp', ...)
    """
    if not isinstance(method, str) or not method:
        raise TypeError(f"method must be a non-empty string; got {method!r}")
    if not isinstance(knob, Knob):
        raise TypeError(f"knob must be a Knob; got {type(knob).__name__}")
    base, _ = split_row(method)
    methods = _registry()
    if base not in methods:
        raise ValueError(f"method {base!r} is not registered: declare its knob in its Method(..., knob=...)")
    methods[base] = methods[base].replace(knob=knob)
    return knob


def _registry() -> dict:
    """The live integrator registry (:data:`mcvar.integrators.METHODS`; importing the
    package registers the built-in methods)."""
    from .. import integrators

    return integrators.METHODS


def split_row(name: str) -> tuple[str, int | None]:
    """A chart row's ``(method, fixed depth or None)``: ``'path'`` -> ``('path', None)``,
    ``'path:3'`` -> ``('path', 3)``; the alias ``'path_depth3'`` is ``'path:3'``
    (:func:`~mcvar.experiments.targets.parse_method`). A registered method's own name,
    whatever its spelling, is ``(name, None)``; anything else unparsable is a ValueError."""
    if isinstance(name, str) and name in _registry():
        return name, None
    return parse_method(name)


def row_name(name: str) -> str:
    """The canonical spelling of a chart row (``'path_depth3'`` -> ``'path:3'``)."""
    base, depth = split_row(name)
    return base if depth is None else f"{base}:{depth}"


def chart_methods() -> tuple:
    """The chart's rows: every registered method with a ``chart_row``, in the order of the
    lecture's rows (:data:`LECTURE_ROWS`; registration order within a row), each followed
    by its fixed-depth rows ``'name:depth'`` (``Method.chart_depths``), then any other
    registered method with both a chart ``knob`` and a ``lecture`` claim."""
    order = {row: i for i, row in enumerate(LECTURE_ROWS)}
    methods = list(_registry().values())
    charted = sorted((m for m in methods if getattr(m, "chart_row", None)),
                     key=lambda m: order.get(m.chart_row, len(order)))
    rows = []
    for m in charted:
        rows += [m.name] + [f"{m.name}:{d}" for d in getattr(m, "chart_depths", {})]
    rows += [m.name for m in methods if m.name not in rows and getattr(m, "knob", None) is not None
             and getattr(m, "lecture", None) is not None]
    return tuple(rows)


def _record(name: str):
    base, depth = split_row(name)
    method = _registry().get(base)
    if method is None:
        raise ValueError(f"method {base!r} is not a registered integrator")
    return method, depth


def chart_lecture_row(method: str) -> str:
    """The lecture's chart row a chart method answers (``Method.chart_row``; else its name)."""
    record, _ = _record(method)
    return getattr(record, "chart_row", None) or row_name(method)


def lecture_chart_claim(method: str) -> tuple[str, str]:
    """The lecture's ``(consistent, unbiased)`` for a chart method: the slide's row
    (:data:`LECTURE_ROWS` of its ``Method.chart_row``; a depth row takes its method's),
    else ``Method.lecture`` of the integrator registry."""
    try:
        record, _ = _record(method)
    except (TypeError, ValueError):
        record = None
    row = getattr(record, "chart_row", None)
    if row in LECTURE_ROWS:
        return LECTURE_ROWS[row]
    claim = getattr(record, "lecture", None)
    if claim is not None:
        return tuple(str(c) for c in claim)
    raise ValueError(f"method {method!r} has no lecture claim (no Method.chart_row on the slide, "
                     "no Method.lecture)")


def chart_theory(method: str):
    """What theory says of a chart method, ``(consistent, unbiased, why)``, or None:
    ``Method.theory``, or for a depth row ``'path:3'`` ``Method.chart_depths[3]``."""
    record, depth = _record(method)
    if depth is None:
        return getattr(record, "theory", None)
    return getattr(record, "chart_depths", {}).get(depth)


def chart_knob(method: str) -> Knob:
    """A chart method's knob: ``Method.knob`` (else spp), with ``max_depth`` for a depth row."""
    record, depth = _record(method)
    knob = getattr(record, "knob", None) or spp_knob(record.name)
    return knob if depth is None else depth_knob(knob, depth)


def __getattr__(name):
    """``KNOBS``, ``THEORY``, ``CHART_METHODS`` and ``LECTURE_CHART``: the former tables, now
    read-only snapshots of the registry (each method's record holds its own)."""
    views = {"KNOBS": chart_knob, "THEORY": chart_theory, "CHART_METHODS": chart_lecture_row,
             "LECTURE_CHART": lecture_chart_claim}
    if name in views:
        warnings.warn(f"mcvar.experiments.chart.{name} is a snapshot of the integrator registry: "
                      "read Method.knob / theory / chart_row, or chart_knob() etc.", DeprecationWarning,
                      stacklevel=2)
        return MappingProxyType({m: views[name](m) for m in chart_methods()})
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _knob_for(method: str) -> tuple[Knob, str]:
    """The method's knob, or spp when its declared options are not accepted by the registered method."""
    knob = chart_knob(method)
    options = dict(knob.options(knob.quick[0]))
    entry = _registry().get(options["integrator"])
    accepted = set(getattr(entry, "options", {}) or {})
    own = set(options) - {"integrator", "spp", "batch_spp", "max_depth", "sampler", "heuristic"}
    missing = sorted(own - accepted) if entry is not None else []
    if not missing:
        return knob, ""
    fallback = spp_knob(options["integrator"])
    depth = split_row(method)[1]
    if depth is not None:
        fallback = depth_knob(fallback, depth)
    return (Knob("spp", fallback.options, knob.quick, knob.default),
            f"knob options {missing} not accepted by the registered method: measured in spp")


def emitter_pixels(scene="cornell", res: int = 16, *, subpixels: int = 8,
                   refine: int = 256) -> np.ndarray:
    """Pixels that see an emitter directly, shape ``(res, res)`` bool.

    A pixel is flagged when a camera ray through it first hits the front of an
    emitting primitive (:meth:`mcvar.scene.Scene.emission` nonzero). Rays at
    the centres of ``subpixels x subpixels`` cells of every pixel find the
    emitters; the 8 neighbours of a flagged pixel are then probed with
    ``refine x refine`` rays each, to catch the thin slivers of a light's edge
    (on the 16 x 16 Cornell box the row above the light sees it in 0.5 to
    1.2 % of its area: too little for the coarse grid, enough to make that
    pixel's value heavy-tailed at a few spp). The chart's block bias test
    leaves these pixels out: their variance is huge and their replicate
    distribution far from the normal law the t test assumes.
    """
    from scipy import ndimage

    from ..tracer import Tracer

    res = check_count(res, "res")
    subpixels = check_count(subpixels, "subpixels")
    refine = check_count(refine, "refine")
    sc = _scene(scene)
    tracer = Tracer(sc)

    def sees(pixels, sub):
        """For each pixel: does any of its sub x sub cell-centre rays see an emitter's front?"""
        cells = (np.arange(sub) + 0.5) / sub
        offsets = np.stack(np.meshgrid(cells, cells, indexing="ij"), axis=-1).reshape(-1, 2)
        pixel = np.repeat(pixels, offsets.shape[0])
        d = sc.camera.ray_directions((res, res), pixel, np.tile(offsets, (len(pixels), 1)))
        o = np.ascontiguousarray(np.broadcast_to(sc.camera.position, d.shape))
        hit = tracer.intersect(o, d)
        rows = np.flatnonzero(hit.prim >= 0)
        emits = np.zeros(pixel.shape, bool)
        if rows.size:
            prim = hit.prim[rows]
            p = o[rows] + hit.t[rows, None] * d[rows]
            emits[rows] = sc.emission(prim, p, tracer.normals(prim, p), d[rows]).max(axis=1) > 0
        return emits.reshape(len(pixels), -1).any(axis=1)

    flagged = sees(np.arange(res * res), subpixels).reshape(res, res)
    around = np.flatnonzero(ndimage.binary_dilation(flagged, np.ones((3, 3), bool)) & ~flagged)
    for pixel in around:  # a few pixels, each one batch of refine^2 rays
        flagged.flat[pixel] = sees(np.array([pixel]), refine)[0]
    return flagged


def _chart_evaluate(scene, res: int, knobs: dict, method: str, sampler: str, level: int, rng):
    from ..integrators import render

    options = dict(knobs[method].options(level))
    result = render(_scene(scene), res=res, sampler=sampler, rng=rng, progress=False, workers=1, **options)
    return np.asarray(result.image, dtype=np.float64)


def _chart_reference(scene, res: int, spp: int, rng):
    from ..integrators import render

    result = render(_scene(scene), integrator="path", spp=spp, res=res, sampler="random", rng=rng,
                    progress=False, workers=1)
    return np.asarray(result.image, dtype=np.float64)


def chart_target(scene="cornell", *, res: int = 16, reference_spp: int = 1024,
                 reference_chunks: int = 8, knobs: dict | None = None) -> Target:
    """The chart's :class:`~mcvar.experiments.targets.Target`: ``scene`` rendered by a
    chart method at a level of its knob (the sweep's ``spp`` is the level).

    The reference is unbiased path tracing (Russian roulette) in
    ``reference_chunks`` independent chunks of ``reference_spp`` spp, the
    same for every method (cached with the runs when a sweep has a cache).
    """
    res = check_count(res, "res")
    reference_spp, reference_chunks = _check_reference_settings(reference_spp, reference_chunks)
    loaded = _scene(scene)          # the target owns the loaded scene
    scene = loaded.name if not isinstance(scene, str) else scene
    knobs = dict(knobs if knobs is not None else {m: _knob_for(m)[0] for m in chart_methods()})
    # each knob's options at levels 1 and 4 describe it in the cache key
    described = ";".join(f"{m}={k.counts}:{sorted(k.options(1).items())}:{sorted(k.options(4).items())}"
                         for m, k in sorted(knobs.items()))
    return Target(name=f"{scene} chart", evaluate=partial(_chart_evaluate, loaded, res, knobs),
                  key=f"chart;scene={scene};res={res};{described}", methods=tuple(knobs),
                  samplers=("random",), spp=(1, 4, 16, 64),
                  reference_task=partial(_chart_reference, loaded, res, reference_spp),
                  reference_chunks=reference_chunks,
                  reference_settings=f"integrator=path;spp={reference_spp};sampler=random;res={res}")


@dataclass(frozen=True)
class ChartRow:
    """One measured row: the columns of ``chart.csv`` and what is behind them."""

    method: str
    lecture_row: str
    lecture_consistent: str
    lecture_unbiased: str
    consistent: str
    unbiased: str
    mse_x_time: float
    note: str
    knob: str
    levels: tuple
    evidence: str
    seconds: float

    @property
    def differs(self) -> bool:
        """True where the measured answers are not the lecture's."""
        return (self.consistent, self.unbiased) != (self.lecture_consistent, self.lecture_unbiased)

    def csv_row(self) -> dict:
        return {c: getattr(self, c) for c in CHART_COLUMNS}


@dataclass(frozen=True)
class ChartResult:
    """The measured chart: its rows in chart order, every method's sweep and the settings."""

    rows: tuple
    sweeps: dict = field(repr=False)
    reference: object = field(repr=False)
    quick: bool = False
    res: int = 16
    replicates: int = 6
    seed: int = 0
    alpha: float = 1e-3
    seconds: float = 0.0
    command: str = ""


def _note(method: str, measured: tuple, lecture: tuple, fallback: str) -> str:
    """One line: empty when measured == lecture; else theory's reason when the
    measurement agrees with theory; else which test fell short of theory."""
    extra = f" ({fallback})" if fallback else ""
    if measured == lecture:
        return fallback
    theory = chart_theory(method)
    if theory is None:
        return "measured differs from the lecture's claim (see the evidence)" + extra
    if measured == theory[:2]:
        return theory[2] + extra
    parts = []
    if measured[1] != theory[1]:
        parts.append("the bias test " + ("missed the bias" if theory[1] == "no" else "rejected zero bias"))
    if measured[0] != theory[0]:
        parts.append("the consistency test " + ("did not see the error vanish" if theory[0] == "yes"
                                                 else "saw the error fall over these levels"))
    return (f"theory says consistent {theory[0]}, unbiased {theory[1]}; at these settings "
            + " and ".join(parts) + " (more replicates or levels give the tests more power)" + extra)


def _canonical_rows(methods) -> list:
    out = []
    for m in methods:
        try:
            out.append(row_name(m))
        except (TypeError, ValueError):
            out.append(m)
    return out


@dataclass(frozen=True)
class ChartSettings:
    """What :func:`measure_chart` measures (its keywords; see there)."""

    quick: bool = False
    methods: tuple | None = None
    res: int | None = None
    replicates: int | None = None
    levels: tuple | None = None
    rng: int | None = None
    alpha: float = 1e-3
    workers: int | None = None
    progress: bool = True
    reference_spp: int | None = None
    reference_chunks: int | None = None
    scene: str = "cornell"


def measure_chart(settings: ChartSettings | None = None, *, cache_dir=None, **options) -> ChartResult:
    """Measure the lecture's chart for every registered method.

    Parameters
    ----------
    settings : ChartSettings, optional
        The keywords below are its fields and replace them (any other keyword
        is a ``TypeError``).

    Other Parameters
    ----------------
    quick : bool
        :data:`QUICK` settings and each knob's quick levels (``mcvar chart
        --quick``), else :data:`DEFAULT` and the default levels.
    methods : sequence of str, optional
        Chart methods to measure (default :func:`chart_methods`: every
        registered one). A name that is no chart method, or whose integrator
        is not registered, raises ValueError.
    res, replicates, reference_spp, reference_chunks : int, optional
        Override the mode's settings.
    levels : sequence of int, optional
        The same levels for every method instead of each knob's.
    rng, alpha, workers, cache_dir, progress
        As in :func:`~mcvar.experiments.sweeps.sweep` (``seed=`` is the
        deprecated alias of ``rng``). One executor serves
        the reference and every method's sweep; ``cache_dir`` caches both, so
        a second call only computes what is missing.
    scene : str
        Scene name (default the Cornell box).

    Returns
    -------
    ChartResult

    Notes
    -----
    Per method: *unbiased* when, at no level, the image mean differs from
    the reference's (Welch's t test, as in ``mcvar converge``) nor do the
    means of :data:`BLOCK` x :data:`BLOCK` pixel blocks
    (:func:`~mcvar.experiments.analysis.block_bias_test`, pixels that see an
    emitter directly left out: :func:`emitter_pixels`), each of the ``2 L``
    tests at the Sidak level for family-wise ``alpha``
    (:func:`~mcvar.experiments.analysis.image_bias_verdict`). The block test
    sees the biases that cancel in the image mean: the blur of photon
    mapping and SPPM, the flat patches of radiosity. *consistent* when the
    MSE falls over the levels and the bias vanishes at the last level (or its
    square falls) [1]_. ``mse_x_time`` is the MSE times the seconds of one
    render at the largest level, ``1 / efficiency`` [1]_.

    References
    ----------
    .. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
       Simulation", PhD thesis, Stanford University, 1997, sec. 1.4.4, 2.4.3.
    """
    opts = settings_with(ChartSettings, settings, seed_alias(options, "measure_chart"), "measure_chart")
    quick, methods, levels, alpha, workers, progress = (opts.quick, opts.methods, opts.levels, opts.alpha,
                                                         opts.workers, opts.progress)
    seed, scene = root_seed(opts.rng, where="measure_chart"), opts.scene
    res, replicates, reference_spp, reference_chunks = (opts.res, opts.replicates, opts.reference_spp,
                                                        opts.reference_chunks)
    check_bool(quick, "quick")
    check_bool(progress, "progress")
    settings = dict(QUICK if quick else DEFAULT)
    for name, value in (("res", res), ("replicates", replicates), ("reference_spp", reference_spp),
                        ("reference_chunks", reference_chunks)):
        if value is not None:
            settings[name] = check_count(value, name)
    available = chart_methods()
    if methods is None:
        methods = available
    else:
        if isinstance(methods, str):
            methods = [methods]
        methods = tuple(dict.fromkeys(_canonical_rows(methods)))
        unknown = [m for m in methods if m not in available]
        if unknown:
            raise ValueError(f"methods must be chart methods {available} (a method declares its chart row "
                             f"in its registration, Method.chart_row); got unknown {unknown}")
    if not methods:
        raise ValueError("methods: no chart method is registered")
    if workers is not None:
        workers = check_count(workers, "workers")
    knobs, fallbacks = {}, {}
    for m in methods:
        knobs[m], fallbacks[m] = _knob_for(m)
    if levels is not None:
        levels = tuple(check_count(n, "levels") for n in levels)
        if len(levels) < 2:
            raise ValueError(f"levels must hold >= 2 levels; got {levels}")
    start = time.perf_counter()
    # one target per method, its key naming that method's knob only, and the reference's
    # target naming none: cached runs and the reference do not depend on which methods run
    loaded = _scene(scene)      # one Scene for every target of this chart
    targets = {m: chart_target(loaded, res=settings["res"], reference_spp=settings["reference_spp"],
                               reference_chunks=settings["reference_chunks"],
                               knobs={m: knobs[m]} if m else {})
               for m in (None, *methods)}
    n_workers = workers or os.cpu_count() or 1
    executor = SerialExecutor() if n_workers == 1 else ProcessPoolExecutor(max_workers=n_workers)
    try:
        reference = compute_reference(targets[None], rng=seed, executor=executor, cache_dir=cache_dir,
                                      progress=progress)
        mask = ~emitter_pixels(loaded, settings["res"])
        sweeps, rows = {}, []
        for m in methods:
            knob = knobs[m]
            mlevels = levels or (knob.quick if quick else knob.default)
            t0 = time.perf_counter()
            result = sweep(targets[m], methods=[m], samplers=["random"], spp=mlevels,
                           replicates=settings["replicates"], rng=seed, reference=reference,
                           executor=executor, cache_dir=cache_dir, alpha=alpha, progress=progress)
            sweeps[m] = result
            verdict = result.verdicts[m]
            last = [c for c in result.metrics if c.spp == result.spp[-1]][0]
            lecture = lecture_chart_claim(m)
            # unbiased: neither the image mean's test nor the block test rejects at any level
            unbiased, block_words, _ = image_bias_verdict(
                {n: result.values[(m, "random", n)] for n in result.spp}, result.metrics, reference,
                alpha=alpha, block=BLOCK, mask=mask)
            measured = ("yes" if verdict.consistent else "no", "yes" if unbiased else "no")
            rows.append(ChartRow(method=m, lecture_row=chart_lecture_row(m), lecture_consistent=lecture[0],
                                 lecture_unbiased=lecture[1], consistent=measured[0], unbiased=measured[1],
                                 mse_x_time=float(last.figure_of_merit),
                                 note=_note(m, measured, lecture, fallbacks[m]), knob=knob.counts,
                                 levels=tuple(result.spp), evidence=block_words + "; " + verdict.evidence,
                                 seconds=time.perf_counter() - t0))
    finally:
        executor.shutdown(wait=True, cancel_futures=True)
    return ChartResult(rows=tuple(rows), sweeps=sweeps, reference=reference, quick=quick,
                       res=settings["res"], replicates=settings["replicates"], seed=seed, alpha=alpha,
                       seconds=time.perf_counter() - start)
