"""The lecture's 'Rendering Algorithm Chart', measured (issue 13).

The lecture's closing slide answers 'consistent?' and 'unbiased?' for six
families of methods. :func:`measure_chart` runs every registered method that
has a row in :data:`CHART_METHODS` on the Cornell box with the machinery of
``mcvar converge`` (:func:`~mcvar.experiments.sweeps.sweep`): replicates at
increasing levels of the method's accuracy knob, the Welch bias test and the
consistency test of :mod:`~mcvar.experiments.analysis` (plus a second bias
test on the per-pixel squared bias, since blur conserves the image mean), and MSE x time at
the largest level, all against one cached path-traced reference. Pixels
that see the light are left out (:func:`light_pixels`): their value is the
light's radiance for every method, and their variance would hide the
transport errors.

The accuracy knob of each method at level ``n`` (``n`` in ``levels``):

=================  ==========================================================
``raster``,        ``n`` samples per pixel
``path``, ``light``,
``bdpt``, ``pssmlt``
``path_depth3``    path tracing with ``max_depth = 3``, ``n`` spp
``photon``         ``n x`` :data:`PHOTON_BASE` photons, fixed gather radius
                   :data:`PHOTON_RADIUS`, 4 spp
``sppm``           ``n`` iterations (one render batch: a single progressive
                   run), :data:`SPPM_PHOTONS` photons per iteration, initial
                   radius :data:`PHOTON_RADIUS`
``radiosity``      patch size ``280 / sqrt(n)``, ``16 sqrt(n)`` rays per patch
                   side, ``4096 n`` emitter rays, 4 spp (mesh and rays refined
                   together)
=================  ==========================================================

Methods not registered (yet) are left out: their rows appear when they
register.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache, partial

import numpy as np
from scipy import stats

from .._validation import check_count
from .reference import compute_reference
from .sweeps import sweep
from .targets import Target, _scene

__all__ = ["CHART_METHODS", "LECTURE_CHART", "ChartRow", "ChartResult", "chart_target", "measure_chart",
           "registered_chart_methods", "light_pixels"]

#: The lecture's chart: row -> (consistent?, unbiased?).
LECTURE_CHART = {
    "Rasterization": ("no", "no"),
    "Path Tracing": ("almost", "almost"),
    "Bidirectional Path Tracing": ("yes", "yes"),
    "Metropolis Light Transport": ("yes", "yes"),
    "Photon Mapping": ("yes", "no"),
    "Finite Element Radiosity": ("no", "no"),
}
#: Chart method -> the lecture's row it answers.
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
#: Photons emitted per level unit by ``photon`` (level n: n x PHOTON_BASE).
PHOTON_BASE = 1 << 11
#: ``photon``'s fixed gather radius and SPPM's initial one (scene units; the Cornell box is ~550 wide).
PHOTON_RADIUS = 40.0
#: Photons per SPPM iteration.
SPPM_PHOTONS = 1 << 11
#: Radiosity's coarsest patch size (level 1).
RADIOSITY_PATCH = 280.0
#: What theory says each chart method is, with its own accuracy knob: (consistent, unbiased).
EXPECTED = {
    "raster": ("no", "no"),
    "path": ("yes", "yes"),
    "path_depth3": ("no", "no"),
    "light": ("yes", "yes"),
    "bdpt": ("yes", "yes"),
    "pssmlt": ("yes", "no"),
    "photon": ("no", "no"),
    "sppm": ("yes", "no"),
    "radiosity": ("yes", "no"),
}
#: Why theory (and, when it agrees, the measurement) differs from the lecture's answer (one line each).
REASONS = {
    "raster": "one unshadowed bounce: its bias is the missing shadows and interreflections, "
              "no sample count removes it",
    "path": "with Russian roulette path tracing is unbiased and consistent, not 'almost'; "
            "the lecture's 'almost' is a fixed depth (path_depth3)",
    "path_depth3": "a fixed depth drops every longer path: biased, and the MSE levels off at that bias",
    "light": "light tracing (forward path tracing connected to the camera) is unbiased like path tracing",
    "bdpt": "every (s, t) strategy weighted by MIS: unbiased and consistent",
    "pssmlt": "MLT's start-up bias: chains start from a bootstrap sample, exact only as the run grows",
    "photon": "a fixed gather radius keeps its blur whatever the photon count: consistent only "
              "progressively (sppm)",
    "sppm": "the radius shrinks with the iterations: consistent; its blur (bias) conserves energy, so "
            "the image-mean bias test may miss it (per-pixel squared bias in chart.html)",
    "radiosity": "consistent under mesh refinement (patch size and rays refined together), never in spp: "
                 "radiosity's mesh",
}


def registered_chart_methods() -> tuple:
    """Chart methods whose integrator is registered, in chart order."""
    from ..integrators import render  # noqa: F401  (imports the registry)
    import mcvar.integrators as integ

    known = tuple(getattr(integ, "METHODS", None) or integ.INTEGRATORS)
    out = []
    for name in CHART_METHODS:
        base = "path" if name == "path_depth3" else name
        if base in known:
            out.append(name)
    return tuple(out)


def _knob(method: str, level: int) -> dict:
    """``render`` keyword arguments of ``method`` at accuracy level ``level``."""
    if method == "path_depth3":
        return dict(integrator="path", spp=level, max_depth=3)
    if method == "photon":
        return dict(integrator="photon", spp=4, photons=PHOTON_BASE * level, radius=PHOTON_RADIUS)
    if method == "sppm":
        return dict(integrator="sppm", spp=level, batch_spp=level, photons=SPPM_PHOTONS, radius=PHOTON_RADIUS)
    if method == "radiosity":
        return dict(integrator="radiosity", spp=4, patch_size=RADIOSITY_PATCH / math.sqrt(level),
                    rays_per_side=int(round(16 * math.sqrt(level))), emitter_rays=(1 << 12) * level)
    return dict(integrator=method, spp=level)


@lru_cache(maxsize=8)
def light_pixels(scene: str, res: int) -> np.ndarray:
    """Pixels (res, res) bool that see an emitter, or touch one that does.

    Their value is the light's radiance seen through the pixel footprint for
    every method alike (pixel sampling, no transport); left in, their large
    variance would drown the transport errors the chart is about. Found from
    8 x 8 stratified first hits per pixel, dilated by one pixel.
    """
    from scipy.ndimage import binary_dilation

    from ..tracer import Tracer

    sc = _scene(scene)
    tracer = Tracer(sc)
    g = (np.arange(8) + 0.5) / 8
    off = np.tile(np.stack(np.meshgrid(g, g), -1).reshape(-1, 2), (res * res, 1))
    d = sc.camera.ray_directions((res, res), np.repeat(np.arange(res * res), 64), off)
    hit = tracer.intersect(np.broadcast_to(sc.camera.position, d.shape), d)
    emits = (hit.prim >= 0) & (np.take(sc.prim_emission.sum(axis=1), np.maximum(hit.prim, 0)) > 0)
    return binary_dilation(emits.reshape(res * res, 64).any(axis=1).reshape(res, res))


def _chart_evaluate(scene: str, res: int, method: str, sampler: str, spp: int, rng) -> np.ndarray:
    """One image of ``method`` at level ``spp``: the pixels that do not see the light, (P, 3)."""
    from ..integrators import render

    kw = _knob(method, spp)
    result = render(_scene(scene), res=res, sampler=sampler, rng=rng, progress=False, workers=1, **kw)
    return np.asarray(result.image, dtype=np.float64)[~light_pixels(scene, res)]


def _chart_reference(scene: str, res: int, spp: int, rng) -> np.ndarray:
    return _chart_evaluate(scene, res, "path", "random", spp, rng)


def chart_target(scene: str = "cornell", *, res: int = 16, reference_spp: int = 512,
                 reference_chunks: int = 8) -> Target:
    """The chart's :class:`Target`: ``scene`` rendered by each chart method at its knob's level.

    The reference is path tracing (Russian roulette, unbiased) with
    ``reference_chunks`` independent chunks of ``reference_spp`` spp.
    """
    res = check_count(res, "res")
    _scene(scene)
    return Target(name=f"{scene} chart", evaluate=partial(_chart_evaluate, scene, res),
                  key=f"chart;masked;scene={scene};res={res};photon={PHOTON_BASE},{PHOTON_RADIUS};"
                      f"sppm={SPPM_PHOTONS};radiosity={RADIOSITY_PATCH}",
                  methods=registered_chart_methods(), samplers=("random",), spp=(1, 4, 16, 64),
                  reference_task=partial(_chart_reference, scene, res, check_count(reference_spp,
                                                                                   "reference_spp")),
                  reference_chunks=check_count(reference_chunks, "reference_chunks"),
                  reference_settings=f"integrator=path;spp={reference_spp};sampler=random")


@dataclass(frozen=True)
class ChartRow:
    """One row of the measured chart (the columns of ``chart.csv``, plus evidence)."""

    method: str
    lecture_row: str
    lecture_consistent: str
    lecture_unbiased: str
    consistent: str
    unbiased: str
    mse_x_time: float
    note: str
    evidence: str
    seconds: float

    @property
    def differs(self) -> bool:
        return (self.consistent, self.unbiased) != (self.lecture_consistent, self.lecture_unbiased)


@dataclass(frozen=True)
class ChartResult:
    """The measured chart: rows in chart order, the sweep behind them and its settings."""

    rows: tuple
    sweep: object
    levels: tuple
    replicates: int
    res: int
    seconds: float


def _note(method, measured, lecture, evidence) -> str:
    """One line: empty when the measurement agrees with the lecture; the reason when it
    agrees with theory instead; otherwise what theory expects and which test lacked power."""
    if measured == lecture:
        return ""
    if measured == EXPECTED[method]:
        return REASONS[method]
    exp = EXPECTED[method]
    parts = []
    if measured[1] != exp[1]:
        parts.append("the bias test " + ("did not detect the bias" if exp[1] == "no" else "rejected zero bias"))
    if measured[0] != exp[0]:
        parts.append("the consistency test " + ("did not show the error falling" if exp[0] == "yes"
                                                 else "saw the error fall over these levels"))
    return (f"theory: consistent {exp[0]}, unbiased {exp[1]}; at these settings " + " and ".join(parts)
            + " (see the evidence; more replicates or levels raise the tests' power)")


def measure_chart(*, quick: bool = False, methods=None, levels=None, replicates: int | None = None,
                  res: int | None = None, seed: int = 0, workers: int | None = None, cache_dir=None,
                  progress: bool = True) -> ChartResult:
    """Measure every registered chart method on the Cornell box.

    Parameters
    ----------
    quick : bool
        16 x 16 pixels, levels (1, 4, 16, 64), 6 replicates (under 2 minutes
        on 2 cores); default 24 x 24, levels (1, 4, 16, 64, 256), 8 replicates.
    methods : sequence of str, optional
        Subset of :data:`CHART_METHODS` (default: every registered one).
    levels, replicates, res : optional
        Override the mode's.
    seed, workers, cache_dir, progress
        As in :func:`~mcvar.experiments.sweeps.sweep`; ``cache_dir`` also
        caches the reference.

    Returns
    -------
    ChartResult
    """
    import time

    res = res if res is not None else (16 if quick else 24)
    levels = tuple(levels) if levels is not None else ((1, 4, 16, 64) if quick else (1, 4, 16, 64, 256))
    replicates = replicates if replicates is not None else (6 if quick else 8)
    available = registered_chart_methods()
    if methods is None:
        methods = available
    else:
        methods = tuple(methods)
        unknown = [m for m in methods if m not in CHART_METHODS]
        if unknown:
            raise ValueError(f"methods must be chart methods {tuple(CHART_METHODS)}; got {unknown}")
        missing = [m for m in methods if m not in available]
        if missing:
            raise ValueError(f"chart method(s) {missing} are not registered integrators; registered: {available}")
    start = time.perf_counter()
    target = chart_target("cornell", res=res, reference_spp=256 if quick else 1024)
    reference = compute_reference(target, seed=seed, cache_dir=cache_dir, progress=progress)
    result = sweep(target, methods=methods, samplers=("random",), spp=levels, replicates=replicates,
                   seed=seed, reference=reference, workers=workers, cache_dir=cache_dir, progress=progress)
    rows = []
    q = stats.t.isf(result.alpha_family, replicates - 1)
    for method in methods:
        verdict = result.verdicts[method]
        mine = [m for m in result.metrics if m.method == method]
        last = [m for m in mine if m.spp == levels[-1]][0]
        # second bias test: the per-pixel squared bias (blur conserves the image mean)
        pix = [m for m in mine if m.bias2_stderr > 0 and m.bias2 > q * m.bias2_stderr]
        evidence = verdict.evidence + (
            f"; per-pixel squared bias > t({replicates - 1}) = {q:.1f} jackknife standard errors at "
            + ", ".join(f"{m.spp} ({m.bias2:.2g} ± {m.bias2_stderr:.1g})" for m in pix)
            if pix else f"; per-pixel squared bias within t({replicates - 1}) = {q:.1f} standard errors "
                        "at every level")
        lc, lu = LECTURE_CHART[CHART_METHODS[method]]
        c, u = ("yes" if verdict.consistent else "no"), ("yes" if verdict.unbiased and not pix else "no")
        note = _note(method, (c, u), (lc, lu), evidence)
        rows.append(ChartRow(method, CHART_METHODS[method], lc, lu, c, u, float(last.figure_of_merit), note,
                             evidence, float(last.seconds)))
    return ChartResult(rows=tuple(rows), sweep=result, levels=levels, replicates=replicates, res=res,
                       seconds=time.perf_counter() - start)
