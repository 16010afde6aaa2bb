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
SPPM with iterations, radiosity with a finer mesh. Each chart method has a
:class:`Knob`: what its level counts, the levels of the quick and the default
chart, and ``options(level) -> dict`` of keyword arguments of
:func:`mcvar.integrators.render` (the integrator name, ``spp`` and the
method's own options). :data:`KNOBS` holds the built-in ones; a method that
registers later declares its own with :func:`register_knob` (a method without
one is measured in spp). A knob whose options the registered method does not
accept falls back to spp, and the row's note says so.

Which methods
-------------
The chart's rows are :data:`CHART_METHODS` (``raster, path, path_depth3,
light, bdpt, pssmlt, photon, sppm, radiosity``; ``path_depth3`` is ``path``
with ``max_depth=3``) whose integrator is registered, followed by any other
registered method that declares both a chart knob (:func:`register_knob`) and
a lecture claim (``Method.lecture`` of the integrator registry). A method that
is not registered has no row; it gets one when it registers.

The lecture's claim of a chart method is the slide's (:data:`LECTURE_CHART`):
the chart quotes the lecture, so a registry claim for a method the slide
names does not replace it (``path`` registers ``Method.lecture = ('yes',
'yes')``, what theory says, while the slide says 'almost'). Other methods
take ``Method.lecture``.
"""
from __future__ import annotations

import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from typing import Callable

import numpy as np

from .._validation import check_bool, check_count
from .targets import Target, _check_reference_settings, _scene
from .runs import SerialExecutor
from .reference import compute_reference
from .sweeps import sweep
from .analysis import image_bias_verdict

__all__ = ["CHART_METHODS", "LECTURE_CHART", "LECTURE_ROWS", "THEORY", "KNOBS", "CHART_COLUMNS",
           "QUICK", "DEFAULT", "BLOCK", "Knob", "ChartRow", "ChartResult", "register_knob", "chart_methods",
           "lecture_chart_claim", "chart_target", "emitter_pixels", "measure_chart"]

#: The chart's methods in the lecture's order: method -> the lecture's row it answers.
CHART_METHODS = {
    "raster": "Rasterization",
    "path": "Path Tracing",
    "path_depth3": "Path Tracing",
    "light": "Path Tracing",
    "bdpt": "Bidirectional Path Tracing",
    "pssmlt": "Metropolis Light Transport",
    "photon": "Photon Mapping",
    "sppm": "Photon Mapping",
    "radiosity": "Finite Element Radiosity",
}

#: The lecture's chart: row -> (consistent?, unbiased?).
LECTURE_ROWS = {
    "Rasterization": ("no", "no"),
    "Path Tracing": ("almost", "almost"),
    "Bidirectional Path Tracing": ("yes", "yes"),
    "Metropolis Light Transport": ("yes", "yes"),
    "Photon Mapping": ("yes", "no"),
    "Finite Element Radiosity": ("no", "no"),
}

#: The lecture's claim per chart method (consistent?, unbiased?), as on the slide; methods the
#: slide does not name take ``Method.lecture`` of the integrator registry.
LECTURE_CHART = {method: LECTURE_ROWS[row] for method, row in CHART_METHODS.items()}

#: What theory says of each chart method, measured with its knob: (consistent, unbiased, why).
#: ``why`` is the one-line reason shown where the measurement differs from the lecture.
THEORY = {
    "raster": ("no", "no", "one unshadowed bounce: no sample count brings back the missing shadows "
                           "and interreflections"),
    "path": ("yes", "yes", "with Russian roulette path tracing is unbiased (and so consistent), not "
                           "'almost': every path length is kept, its probability divided out"),
    "path_depth3": ("no", "no", "a fixed depth (3) drops the light of longer paths: biased, and the MSE "
                                "levels off at that bias, so not consistent either"),
    "light": ("yes", "yes", "light tracing is path tracing started at the lights: with Russian "
                            "roulette unbiased and consistent"),
    "bdpt": ("yes", "yes", "every (s, t) connection strategy weighted by MIS: unbiased and consistent"),
    "pssmlt": ("yes", "no", "MLT's start-up bias: each chain starts from a bootstrap sample, not from "
                            "its stationary distribution; the bias vanishes as the chains grow"),
    "photon": ("no", "no", "at a fixed radius the density estimate keeps its blur whatever the photon "
                           "count: photon mapping is consistent only progressively (sppm)"),
    "sppm": ("yes", "no", "progressive photon mapping shrinks the radius: biased at every iteration, "
                          "consistent"),
    "radiosity": ("yes", "no", "radiosity's mesh: piecewise-constant patches bias the image; the bias "
                               "falls only as the mesh is refined (its knob here), never with spp"),
}

#: The columns of ``chart.csv``, in order.
CHART_COLUMNS = ("method", "lecture_consistent", "lecture_unbiased", "consistent", "unbiased",
                 "mse_x_time", "note")


@dataclass(frozen=True)
class Knob:
    """A method's accuracy knob: what to render at level ``n``.

    Parameters
    ----------
    counts : str
        What a level counts (``'spp'``, ``'photons x 4096'``, ``'iterations'``,
        ``'mesh refinement'``), shown in the chart's settings.
    options : callable
        ``options(level) -> dict`` of keyword arguments of
        :func:`mcvar.integrators.render`: ``integrator``, ``spp`` and the
        method's own options (``max_depth``, ``photons``, ``radius`` ...).
        A module-level function or a :func:`functools.partial` of one, so
        other processes can run it.
    quick, default : tuple of int
        Increasing levels of the quick (``--quick``) and the default chart.
    """

    counts: str
    options: Callable
    quick: tuple = (1, 4, 16, 64, 256)
    default: tuple = (1, 4, 16, 64, 256)


def _spp_options(integrator: str, level: int, **fixed) -> dict:
    return dict(integrator=integrator, spp=level, **fixed)


# The photon, sppm and radiosity settings follow branch photon's tuning of its registered methods
# (options photons/radius, photons/radius/alpha, patch_size/rays_per_side/emitter_rays).
def _photon_options(level: int) -> dict:
    # more photons at a fixed gather radius: the blur stays
    return dict(integrator="photon", spp=4, photons=2048 * level, radius=40.0)


def _sppm_options(level: int) -> dict:
    # one progressive run of `level` iterations (one batch: the radius keeps shrinking). 8192
    # photons per iteration: with 2048 the block bias test saw SPPM's bias in only one of two
    # seeds at the quick settings (10 replicates); 4x the photons quarter the photon noise and
    # keep the first iteration's radius, so its blur stands out
    return dict(integrator="sppm", spp=level, batch_spp=level, photons=8192, radius=40.0)


def _radiosity_options(level: int) -> dict:
    # patch size halves as the level quadruples; form-factor rays, emitter rays and pixel samples
    # refined with it (at fixed spp the pixel-sampling noise would hide the shrinking mesh bias)
    root = float(np.sqrt(level))
    return dict(integrator="radiosity", spp=4 * level, patch_size=280.0 / root, rays_per_side=int(round(16 * root)),
                emitter_rays=4096 * level)


def spp_knob(integrator: str, **fixed) -> Knob:
    """The default knob: ``level`` samples per pixel of ``integrator`` (with ``fixed`` options)."""
    return Knob("spp", partial(_spp_options, integrator, **fixed))


#: Built-in knobs of the chart methods. Extend with :func:`register_knob`.
KNOBS: dict = {
    "raster": spp_knob("raster"),
    "path": spp_knob("path"),
    "path_depth3": spp_knob("path", max_depth=3),
    "light": spp_knob("light"),
    "bdpt": spp_knob("bdpt"),
    "pssmlt": spp_knob("pssmlt"),
    "photon": Knob("photons (x 2048, radius 40)", _photon_options, (1, 4, 16), (1, 4, 16, 64)),
    "sppm": Knob("iterations (8192 photons each)", _sppm_options, (1, 4, 16), (1, 4, 16, 64)),
    "radiosity": Knob("mesh refinement (patch size 280 / sqrt(level))", _radiosity_options,
                      (1, 4, 16), (1, 4, 16, 64)),
}

#: Side in pixels of the blocks of the chart's block bias test
#: (:func:`~mcvar.experiments.analysis.block_bias_test`; docs/chart.md says why 4).
BLOCK = 4

#: Settings of ``mcvar chart --quick`` and ``mcvar chart``: resolution, replicates per level,
#: reference spp per chunk and reference chunks.
QUICK = dict(res=16, replicates=10, reference_spp=2048, reference_chunks=8)
DEFAULT = dict(res=32, replicates=12, reference_spp=4096, reference_chunks=8)


def register_knob(method: str, knob: Knob) -> Knob:
    """Declare ``method``'s accuracy knob for the chart (replaces a built-in one).

    Examples
    --------
    >>> from mcvar.experiments.chart import Knob, register_knob, spp_knob
    >>> register_knob("path", spp_knob("path"))                 # doctest: +ELLIPSIS
    Knob(counts='spp', ...)
    """
    if not isinstance(method, str) or not method:
        raise TypeError(f"method must be a non-empty string; got {method!r}")
    if not isinstance(knob, Knob):
        raise TypeError(f"knob must be a Knob; got {type(knob).__name__}")
    for name in ("quick", "default"):
        levels = getattr(knob, name)
        if len(levels) < 2 or list(levels) != sorted(set(levels)) or min(levels) < 1:
            raise ValueError(f"knob.{name} must hold >= 2 increasing positive levels; got {levels!r}")
    KNOBS[method] = knob
    return knob


def _registry() -> tuple[dict, tuple]:
    """(METHODS of the integrator registry or {}, names of every registered integrator)."""
    import mcvar.integrators as integrators

    methods = dict(getattr(integrators, "METHODS", None) or {})
    names = tuple(methods) if methods else tuple(integrators.INTEGRATORS)
    return methods, names


def _base(method: str) -> str:
    return _spp_integrator(KNOBS[method]) if method in KNOBS else method


def _spp_integrator(knob: Knob) -> str:
    return knob.options(1)["integrator"]


def chart_methods() -> tuple:
    """The chart's rows: :data:`CHART_METHODS` whose integrator is registered, in
    the lecture's order, then any other registered method with a chart knob
    (:func:`register_knob`) and a lecture claim (``Method.lecture``)."""
    registry, names = _registry()
    rows = [m for m in CHART_METHODS if _base(m) in names]
    rows += [name for name, m in registry.items() if name not in rows and name in KNOBS
             and getattr(m, "lecture", None) is not None]
    return tuple(rows)


def lecture_chart_claim(method: str) -> tuple[str, str]:
    """The lecture's ``(consistent, unbiased)`` for a chart method: the slide's
    (:data:`LECTURE_CHART`), else ``Method.lecture`` of the integrator registry."""
    if method in LECTURE_CHART:
        return LECTURE_CHART[method]
    registry, _ = _registry()
    claim = getattr(registry.get(method), "lecture", None)
    if claim is not None:
        return tuple(str(c) for c in claim)
    raise ValueError(f"method {method!r} has no lecture claim (not in LECTURE_CHART, no Method.lecture)")


def _knob_for(method: str) -> tuple[Knob, str]:
    """The method's knob, or spp when its declared options are not accepted by the registered method."""
    knob = KNOBS.get(method) or spp_knob(method)
    registry, _ = _registry()
    options = dict(knob.options(knob.quick[0]))
    entry = registry.get(options["integrator"])
    accepted = set(getattr(entry, "options", {}) or {})
    own = set(options) - {"integrator", "spp", "batch_spp", "max_depth", "sampler", "heuristic"}
    missing = sorted(own - accepted) if entry is not None else []
    if not missing:
        return knob, ""
    fallback = spp_knob(options["integrator"])
    return (Knob("spp", fallback.options, knob.quick, knob.default),
            f"knob options {missing} not accepted by the registered method: measured in spp")


def emitter_pixels(scene: str = "cornell", res: int = 16, *, subpixels: int = 8,
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


def _chart_evaluate(scene: str, res: int, knobs: dict, method: str, sampler: str, level: int, rng):
    from ..integrators import render

    options = dict(knobs[method].options(level))
    result = render(_scene(scene), res=res, sampler=sampler, rng=rng, progress=False, workers=1, **options)
    return np.asarray(result.image, dtype=np.float64)


def _chart_reference(scene: str, res: int, spp: int, rng):
    from ..integrators import render

    result = render(_scene(scene), integrator="path", spp=spp, res=res, sampler="random", rng=rng,
                    progress=False, workers=1)
    return np.asarray(result.image, dtype=np.float64)


def chart_target(scene: str = "cornell", *, res: int = 16, reference_spp: int = 1024,
                 reference_chunks: int = 8, knobs: dict | None = None) -> Target:
    """The chart's :class:`~mcvar.experiments.targets.Target`: ``scene`` rendered by a
    chart method at a level of its knob (the sweep's ``spp`` is the level).

    The reference is unbiased path tracing (Russian roulette) in
    ``reference_chunks`` independent chunks of ``reference_spp`` spp, the
    same for every method (cached with the runs when a sweep has a cache).
    """
    res = check_count(res, "res")
    reference_spp, reference_chunks = _check_reference_settings(reference_spp, reference_chunks)
    _scene(scene)
    knobs = dict(knobs if knobs is not None else {m: _knob_for(m)[0] for m in chart_methods()})
    # each knob's options at levels 1 and 4 describe it in the cache key
    described = ";".join(f"{m}={k.counts}:{sorted(k.options(1).items())}:{sorted(k.options(4).items())}"
                         for m, k in sorted(knobs.items()))
    return Target(name=f"{scene} chart", evaluate=partial(_chart_evaluate, scene, res, knobs),
                  key=f"chart;scene={scene};res={res};{described}", methods=tuple(knobs),
                  samplers=("random",), spp=(1, 4, 16, 64),
                  reference_task=partial(_chart_reference, scene, res, reference_spp),
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
    theory = THEORY.get(method)
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


def measure_chart(*, quick: bool = False, methods=None, res: int | None = None,
                  replicates: int | None = None, levels=None, seed: int = 0, alpha: float = 1e-3,
                  workers: int | None = None, cache_dir=None, progress: bool = True,
                  reference_spp: int | None = None, reference_chunks: int | None = None,
                  scene: str = "cornell") -> ChartResult:
    """Measure the lecture's chart for every registered method.

    Parameters
    ----------
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
    seed, alpha, workers, cache_dir, progress
        As in :func:`~mcvar.experiments.sweeps.sweep`. One executor serves
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
    seed = check_count(seed, "seed", allow_zero=True)
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
        methods = tuple(dict.fromkeys(methods))
        known = tuple(CHART_METHODS) + tuple(m for m in available if m not in CHART_METHODS)
        unknown = [m for m in methods if m not in known]
        if unknown:
            raise ValueError(f"methods must be chart methods {known}; got unknown {unknown}")
        missing = [m for m in methods if m not in available]
        if missing:
            raise ValueError(f"methods {missing} are not registered integrators (registered chart "
                             f"methods: {available})")
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
    targets = {m: chart_target(scene, res=settings["res"], reference_spp=settings["reference_spp"],
                               reference_chunks=settings["reference_chunks"],
                               knobs={m: knobs[m]} if m else {})
               for m in (None, *methods)}
    n_workers = workers or os.cpu_count() or 1
    executor = SerialExecutor() if n_workers == 1 else ProcessPoolExecutor(max_workers=n_workers)
    try:
        reference = compute_reference(targets[None], seed=seed, executor=executor, cache_dir=cache_dir,
                                      progress=progress)
        mask = ~emitter_pixels(scene, settings["res"])
        sweeps, rows = {}, []
        for m in methods:
            knob = knobs[m]
            mlevels = levels or (knob.quick if quick else knob.default)
            t0 = time.perf_counter()
            result = sweep(targets[m], methods=[m], samplers=["random"], spp=mlevels,
                           replicates=settings["replicates"], seed=seed, reference=reference,
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
            rows.append(ChartRow(method=m, lecture_row=CHART_METHODS.get(m, m), lecture_consistent=lecture[0],
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
