"""Every method on every scene at equal wall time (layer 6, module 7 of
:mod:`mcvar.experiments`; ``mcvar compare``, issue 21).

The lecture says what each rendering method is *for*: bidirectional tracing
reaches lights that are hard to find, Metropolis 'rendered in the same time'
beats path tracing, photon mapping is for caustics, radiosity for diffuse
light. :func:`measure_compare` measures those claims the way they are made:
each method renders each scene for the same wall time ``seconds``, and its
image is compared with one shared high-spp reference of that scene.

Equal time
----------
A method renders in *rounds*: independent renders of ``b`` samples per pixel
(fresh random streams, so the rounds are independent estimates), combined as
the spp-weighted mean, until the time spent reaches ``seconds``. The first
round has 1 spp; each next round is sized from the measured rate to take
``min(remaining, seconds / 4)``, so the time used exceeds ``seconds`` by at
most the last round. Two exceptions, because their estimate is not a mean of
independent rounds:

* ``sppm`` (:data:`PROGRESSIVE`) shrinks its radius over the iterations of
  one run: a 1-iteration pilot measures the cost of an iteration, then one
  run of as many iterations as fit in the time left (pilot time counted,
  its image discarded).
* ``radiosity`` (:data:`REUSE_PREPARED`) solves once (``Method.prepare``)
  and every round looks the same solve up: the solve is view independent,
  re-solving per round would only repeat it. The solve's time is counted.

Error and efficiency
--------------------
``mse`` is the mean over pixels and channels of ``(image - reference)^2``
(optionally inside a region of the image), the median over ``seeds``
independent runs; ``seconds`` is the median wall time used; efficiency is
``1 / (mse x seconds)`` [1]_ (lecture, 'Efficiency'). The reference is
rendered once per scene and resolution by the method whose estimate is
close to normal there (:data:`REFERENCES`; heavy-tailed path tracing would
make a reference whose error hides in a few pixels), in independent chunks
whose spread gives its own noise (``reference_noise``: compare it with the
MSEs), and is cached on disk keyed by every setting that changes it.

A method that cannot render a scene (its ``check_scene`` raises ValueError)
gets that reason in its cell instead of a number.

References
----------
.. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
   Simulation", PhD thesis, Stanford University, 1997, sec. 1.4.4 (efficiency).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
import zlib
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from .._validation import check_count
from .chart import emitter_pixels

__all__ = ["DEFAULT_METHODS", "REFERENCES", "COMPARE_OPTIONS", "PROGRESSIVE", "REUSE_PREPARED",
           "COMPARE_COLUMNS", "RUN_COLUMNS", "SceneReference", "TimedRender", "Cell", "CompareResult",
           "CompareSettings", "compare_settings", "check_compare_args", "scene_reference", "equal_time_render", "measure_compare",
           "radiosity_views", "compare_scenes", "compare_methods", "CAUSTIC_REGION", "PAIRS", "measure_pairs"]

#: The light-transport methods measured by default (those registered, in this order).
DEFAULT_METHODS = ("path", "path_bsdf", "direct", "light", "bdpt", "pssmlt", "photon", "sppm", "radiosity")

#: Per scene: (reference method, total reference spp, why that method). Scenes not listed use path tracing.
REFERENCES = {
    "cornell": ("path", 4096, "a large area light that next-event estimation finds from every point: "
                              "path tracing's pixel estimates are close to normal"),
    "cornell-spheres": ("bdpt", 4096, "the glass sphere's caustic reaches path tracing only when a refracted "
                                      "BSDF sample hits the light (heavy-tailed pixels under the sphere); "
                                      "BDPT's light subpaths carry it. 4096 spp: at 512 the reference's own "
                                      "noise in the caustic (8.1e-4) was a third of the MSEs measured there "
                                      "and made SPPM look like the winner"),
    "cornell-point": ("bdpt", 512, "path tracing is heavy-tailed at this point light under the ceiling: six "
                                   "16 x 16 images of 256 spp had means from 0.038 to 0.169 and pixels up to "
                                   "33, where six of BDPT at 16 spp had means from 0.0709 to 0.0721 and no "
                                   "pixel above 3.1 (and light tracing agrees with BDPT)"),
    "cornell-door": ("bdpt", 512, "the light reaches the room only through the door: next-event estimation is "
                                  "blocked from most points and path tracing finds the light through BSDF "
                                  "samples (heavy-tailed); BDPT's light subpaths enter through the door"),
    "quad-environment": ("path", 4096, "a smooth environment that BSDF and environment sampling find from "
                                       "every point: path tracing's pixel estimates are close to normal "
                                       "(light subpaths from the environment are far noisier: 7.7e-3 against "
                                       "1.3e-5 at 2 s, docs/compare.md)"),
}

#: Options of the methods in the comparison (low accuracy per round, so that rounds fit in seconds).
COMPARE_OPTIONS = {
    "photon": {"photons": 16384},
    "sppm": {"photons": 8192},
    "radiosity": {"patch_size": 140.0, "rays_per_side": 32, "emitter_rays": 16384},
}

#: Methods whose estimate is one progressive run (its bias falls with the iterations of that run).
PROGRESSIVE = frozenset({"sppm"})
#: Methods whose ``prepare`` is solved once and reused by every round (view-independent solves).
REUSE_PREPARED = frozenset({"radiosity"})

#: Columns of ``compare.csv`` (one row per scene x method) and ``compare_runs.csv`` (one row per seed).
COMPARE_COLUMNS = ("scene", "method", "reference_method", "region", "reference_noise", "seeds", "spp",
                   "seconds", "mse",
                   "mean_ratio", "mse_x_time", "efficiency", "relative_efficiency", "winner", "reason")
RUN_COLUMNS = ("scene", "method", "seed", "spp", "seconds", "rounds", "max_round_seconds", "mse", "mean_ratio",
               "interrupted")

#: Version of the cached reference files' layout (part of their key).
_REFERENCE_FORMAT = 2


def _render(scene, **kwargs):
    """:func:`mcvar.integrators.render` (one name, so tests can count the calls)."""
    from ..integrators import render

    return render(scene, **kwargs)


def _registered() -> dict:
    from ..integrators import METHODS

    return METHODS


def compare_scenes() -> tuple:
    """Scene names :func:`measure_compare` accepts (those of :data:`mcvar.scene.SCENES`)."""
    from ..scene import SCENES

    return tuple(SCENES)


def compare_methods() -> tuple:
    """Methods :func:`measure_compare` accepts: every registered one (:data:`mcvar.integrators.METHODS`)."""
    return tuple(_registered())


def _names(value, name: str, known: tuple) -> tuple:
    if isinstance(value, str):
        value = [v.strip() for v in value.split(",") if v.strip()]
    try:
        value = tuple(dict.fromkeys(value))
    except TypeError:
        raise TypeError(f"{name} must be a comma-separated string or a sequence of names; got {value!r}") from None
    if not value:
        raise ValueError(f"{name} must name at least one of {known}")
    unknown = [v for v in value if v not in known]
    if unknown:
        raise ValueError(f"{name}: unknown {unknown}; expected names from {known}")
    return value


def check_compare_args(scenes, methods, seconds, res, seeds=1) -> tuple:
    """Validate the comparison's arguments before any work: ``(scenes, methods, seconds, res, seeds)``.

    Unknown scene or method names, ``seconds <= 0`` (or not finite), ``res <= 0``
    and ``seeds <= 0`` are a ValueError naming the argument.
    """
    scenes = _names(scenes, "scenes", compare_scenes())
    methods = _names(methods, "methods", compare_methods())
    try:
        seconds = float(seconds)
    except (TypeError, ValueError):
        raise TypeError(f"seconds must be a number; got {seconds!r}") from None
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds must be finite and > 0; got {seconds}")
    res = check_count(res, "res")
    seeds = check_count(seeds, "seeds")
    return scenes, methods, seconds, res, seeds


def _options(method: str, options=None) -> dict:
    """The comparison's options of ``method`` that the registered method accepts."""
    wanted = dict(COMPARE_OPTIONS.get(method, {}))
    wanted.update((options or {}).get(method, {}))
    accepted = _registered()[method].options
    return {k: v for k, v in wanted.items() if k in accepted}


def _seed_sequence(*parts) -> np.random.SeedSequence:
    return np.random.SeedSequence([p if isinstance(p, int) else zlib.crc32(str(p).encode()) for p in parts])


# --------------------------------------------------------------------------
# the shared reference
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class SceneReference:
    """A scene's shared reference image.

    ``value`` (H, W, 3) is the mean of ``chunks`` independent renders of
    ``spp / chunks`` spp by ``method``; ``variance`` (H, W, 3) the variance
    of that mean per pixel (from the chunks' spread) and ``noise`` its mean
    over pixels and channels, the floor under every MSE measured against it;
    ``cached`` whether it was read from the cache instead of rendered.
    """

    scene: str
    method: str
    spp: int
    chunks: int
    value: np.ndarray = field(repr=False)
    variance: np.ndarray = field(repr=False)
    noise: float
    seconds: float
    why: str
    key: str
    cached: bool = False


def _code_key() -> str:
    """A hash of the renderer's source (integrators, scene, tracer, BSDFs, environment maps): a
    reference cached by other code is not reused (read once per reference, a few ms)."""
    root = Path(__file__).resolve().parents[1]
    files = sorted(p for pattern in ("integrators/*.py", "scene*.py", "scene*/*.py", "tracer.py", "bsdf.py",
                                     "envmap.py", "optics.py", "warps.py", "samplers.py")
                   for p in root.glob(pattern))
    digest = hashlib.sha256()
    for f in files:
        digest.update(f.name.encode() + f.read_bytes())
    return digest.hexdigest()[:16]


def _reference_key(scene, res, method, spp, chunks, seed, options) -> str:
    text = json.dumps(dict(v=_REFERENCE_FORMAT, code=_code_key(), scene=scene, res=res, method=method, spp=spp,
                           chunks=chunks,
                           seed=seed, options=sorted((k, repr(v)) for k, v in options.items())), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def scene_reference(scene: str, res: int, *, method: str | None = None, spp: int | None = None,
                    chunks: int = 4, seed: int = 0, cache_dir=None, progress: bool = False) -> SceneReference:
    """The shared reference of ``scene`` at ``res`` (rendered, or read from ``cache_dir``).

    Parameters
    ----------
    scene : str
        A scene name.
    res : int
        Image side in pixels.
    method, spp : optional
        Reference method and total spp; default :data:`REFERENCES` (path
        tracing at 4096 spp for unlisted scenes).
    chunks : int
        Independent renders the spp are split into (their spread gives ``noise``).
    seed : int
        Seed of the reference's streams.
    cache_dir : path, optional
        Folder of ``reference-<scene>-<key>.npz``; the key hashes scene, res,
        method, spp, chunks, seed, the method's options and the renderer's
        source, so a change of any renders a new reference.
    """
    from ..scene import load_scene

    (scene,), _, _, res, chunks = check_compare_args([scene], ["path"], 1.0, res, chunks)
    default = REFERENCES.get(scene, ("path", 4096, "path tracing (no reference chosen for this scene)"))
    method = default[0] if method is None else _names([method], "method", compare_methods())[0]
    spp = default[1] if spp is None else check_count(spp, "spp")
    why = default[2] if method == default[0] else f"{method} (chosen by the caller)"
    if spp < chunks:
        raise ValueError(f"spp must be >= chunks ({chunks}); got {spp}")
    options = _options(method)
    key = _reference_key(scene, res, method, spp, chunks, seed, options)
    path = None
    if cache_dir is not None:
        path = Path(cache_dir) / f"reference-{scene}-{key}.npz"
        if path.exists():
            with np.load(path) as data:
                return SceneReference(scene, method, spp, chunks, data["value"], data["variance"],
                                      float(data["noise"]),
                                      float(data["seconds"]), why, key, cached=True)
    sc = load_scene(scene)
    per = spp // chunks
    streams = _seed_sequence("reference", scene, seed).spawn(chunks)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=chunks, desc=f"reference {scene} ({method}, {spp} spp)", unit="chunk", leave=False)
    start = time.perf_counter()
    images = []
    try:
        for stream in streams:
            r = _render(sc, integrator=method, spp=per, res=res, rng=stream, progress=False, **options)
            if r.interrupted:
                raise KeyboardInterrupt
            images.append(np.asarray(r.image, dtype=np.float64))
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - start
    stack = np.stack(images)
    value = stack.mean(axis=0)
    variance = stack.var(axis=0, ddof=1) / chunks if chunks > 1 else np.full_like(value, np.nan)
    noise = float(variance.mean())
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, value=value, variance=variance, noise=noise, seconds=seconds)
        tmp.replace(path)
    return SceneReference(scene, method, per * chunks, chunks, value, variance, noise, seconds, why, key)


# --------------------------------------------------------------------------
# equal time
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class TimedRender:
    """One equal-time render: the combined image, the spp and the wall time actually used."""

    image: np.ndarray = field(repr=False)
    spp: int
    seconds: float
    rounds: int
    max_round_seconds: float
    prepare_seconds: float = 0.0


def _prepared(value, scene, options, rng):
    """``Method.prepare`` that hands out a solve made earlier (:data:`REUSE_PREPARED`)."""
    return value


def equal_time_render(scene, method: str, *, seconds: float, res: int, rng, options=None) -> TimedRender:
    """Render ``scene`` with ``method`` for ``seconds`` of wall time (rounds of spp; module docstring).

    ``scene`` is a :class:`mcvar.scene.Scene`; ``options`` the method's
    options. Raises ValueError when the method refuses the scene (before any
    work) and KeyboardInterrupt when a round was interrupted.
    """
    entry = _registered()[method]
    options = dict(options or {})
    resolved = entry.resolve_options(options)
    if entry.check_scene is not None:
        entry.check_scene(scene, resolved)
    streams = rng if isinstance(rng, np.random.SeedSequence) else np.random.SeedSequence(rng)
    start = time.perf_counter()
    integrator, prepare_seconds = method, 0.0
    if method in REUSE_PREPARED and entry.prepare is not None:
        solve = entry.prepare(scene, resolved, np.random.default_rng(
            np.random.SeedSequence(streams.entropy, spawn_key=streams.spawn_key + (2**31,))))
        prepare_seconds = time.perf_counter() - start
        integrator = dataclasses.replace(entry, prepare=partial(_prepared, solve))

    one = partial(_round, scene, integrator, res, streams, options)
    if method in PROGRESSIVE:
        _, _, pilot = one(1, 0)
        left = seconds - (time.perf_counter() - start)
        n = max(1, int(0.9 * left / pilot)) if left > 0 else 1
        image, spp, t = one(n, 1)
        return TimedRender(image, spp, time.perf_counter() - start, 2, max(pilot, t))
    total = np.zeros((res, res, 3))
    done, rounds, longest, size = 0, 0, 0.0, 1
    while True:
        image, spp, t = one(size, rounds)
        total += image * spp
        done += spp
        rounds += 1
        longest = max(longest, t)
        elapsed = time.perf_counter() - start
        if elapsed >= seconds:
            break
        target = min(seconds - elapsed, seconds / 4)
        size = int(np.clip(np.floor(spp / max(t, 1e-9) * target), 1, 4 * spp))
    return TimedRender(total / done, done, elapsed, rounds, longest, prepare_seconds)


def _round(scene, integrator, res, streams, options, spp, k):
    """One round: ``spp`` samples per pixel of ``integrator`` in one render (one batch for
    progressive methods, so the radius keeps shrinking); (image, spp, seconds)."""
    t0 = time.perf_counter()
    name = integrator if isinstance(integrator, str) else integrator.name
    batch = {"batch_spp": spp} if name in PROGRESSIVE else {}
    r = _render(scene, integrator=integrator, spp=spp, res=res, rng=np.random.SeedSequence(streams.entropy, spawn_key=streams.spawn_key + (k,)),
                progress=False, **batch, **options)
    if r.interrupted:
        raise KeyboardInterrupt
    return np.asarray(r.image, dtype=np.float64), r.spp, time.perf_counter() - t0


# --------------------------------------------------------------------------
# the matrix
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class Cell:
    """One scene x method cell: its runs (one per seed) or the reason it has none."""

    scene: str
    method: str
    runs: tuple = ()
    reason: str = ""
    image: np.ndarray | None = field(default=None, repr=False)

    @property
    def rendered(self) -> bool:
        return not self.reason and len(self.runs) > 0

    def _median(self, key):
        return float(np.median([r[key] for r in self.runs])) if self.runs else float("nan")

    @property
    def mse(self) -> float:
        """Median MSE over the seeds."""
        return self._median("mse")

    @property
    def seconds(self) -> float:
        """Median wall time used over the seeds."""
        return self._median("seconds")

    @property
    def spp(self) -> float:
        return self._median("spp")

    @property
    def mean_ratio(self) -> float:
        """Median of (image mean / reference mean): 1 when the method gets the brightness right."""
        return self._median("mean_ratio")

    @property
    def mse_x_time(self) -> float:
        return self.mse * self.seconds

    @property
    def efficiency(self) -> float:
        """``1 / (mse x seconds)`` of the medians; 0 when no run finished."""
        m = self.mse_x_time
        return 1.0 / m if self.rendered and m > 0 else (math.inf if self.rendered else 0.0)


@dataclass(frozen=True)
class CompareResult:
    """The measured matrix: ``cells[(scene, method)]``, the references and the settings."""

    scenes: tuple
    methods: tuple
    cells: dict = field(repr=False)
    references: dict = field(repr=False)
    seconds: float
    res: int
    seeds: int
    seed: int
    regions: dict = field(default_factory=dict)
    interrupted: bool = False
    wall_seconds: float = 0.0

    def winner(self, scene: str) -> str | None:
        """The method of the highest efficiency on ``scene`` (None when no method rendered it)."""
        best = [(self.cells[(scene, m)].efficiency, m) for m in self.methods
                if (scene, m) in self.cells and self.cells[(scene, m)].rendered]
        return max(best)[1] if best else None

    def relative_efficiency(self, scene: str, method: str) -> float:
        """Efficiency divided by the column winner's (1 for the winner, nan when not rendered)."""
        w = self.winner(scene)
        cell = self.cells.get((scene, method))
        if w is None or cell is None or not cell.rendered:
            return float("nan")
        return cell.efficiency / self.cells[(scene, w)].efficiency

    def reference_noise(self, scene: str) -> float:
        """Mean variance of the reference's pixel means inside the scene's region (the MSE floor)."""
        ref = self.references[scene]
        rows, cols = _region_slices(self.regions.get(scene), self.res)
        return float(ref.variance[rows, cols].mean())

    def rows(self) -> list[dict]:
        """The rows of ``compare.csv`` (:data:`COMPARE_COLUMNS`), scenes outer, methods inner."""
        out = []
        for s in self.scenes:
            ref, w = self.references.get(s), self.winner(s)
            for m in self.methods:
                cell = self.cells.get((s, m))
                if cell is None:
                    continue
                out.append(dict(scene=s, method=m, reference_method=ref.method if ref else "",
                                region=_region_text(self.regions.get(s)),
                                reference_noise=self.reference_noise(s), seeds=len(cell.runs),
                                spp=cell.spp, seconds=cell.seconds, mse=cell.mse, mean_ratio=cell.mean_ratio,
                                mse_x_time=cell.mse_x_time if cell.rendered else float("nan"),
                                efficiency=cell.efficiency if cell.rendered else float("nan"),
                                relative_efficiency=self.relative_efficiency(s, m),
                                winner="yes" if m == w else "", reason=cell.reason))
        return out

    def run_rows(self) -> list[dict]:
        """The rows of ``compare_runs.csv`` (:data:`RUN_COLUMNS`): every seed of every cell."""
        return [{c: r[c] for c in RUN_COLUMNS} for key in self.cells for r in self.cells[key].runs]


def _region_text(region) -> str:
    return "" if region is None else "rows {:.2f}-{:.2f}, columns {:.2f}-{:.2f}".format(*region)


def _region_slices(region, res):
    if region is None:
        return slice(None), slice(None)
    y0, y1, x0, x1 = region
    if not (0 <= y0 < y1 <= 1 and 0 <= x0 < x1 <= 1):
        raise ValueError(f"regions: each region is (row0, row1, col0, col1) fractions in [0, 1], "
                         f"increasing; got {region}")
    rows = slice(int(np.floor(y0 * res)), max(int(np.floor(y0 * res)) + 1, int(np.ceil(y1 * res))))
    cols = slice(int(np.floor(x0 * res)), max(int(np.floor(x0 * res)) + 1, int(np.ceil(x1 * res))))
    return rows, cols


@dataclass(frozen=True)
class CompareSettings:
    """What :func:`measure_compare` measures (the fields are its keyword settings).

    Attributes
    ----------
    scenes, methods : str (comma-separated) or sequence of str
        Scene names (:func:`compare_scenes`) and registered methods (default
        :data:`DEFAULT_METHODS` that are registered).
    seconds : float
        Wall time of every method on every scene, per seed (> 0).
    res : int
        Image side in pixels.
    seeds : int
        Independent runs per cell; the cell reports the medians.
    seed : int
        Root seed (runs and references derive their streams from it and the names).
    references, reference_spp : dict, optional
        Per scene: reference method and total spp instead of :data:`REFERENCES`.
    regions : dict, optional
        Per scene: ``(row0, row1, col0, col1)`` fractions of the image the
        MSE is measured in (a caustic, say); default the whole image.
    options : dict, optional
        Per method: options that update :data:`COMPARE_OPTIONS`.
    """

    scenes: object = ("cornell",)
    methods: object = None
    seconds: float = 2.0
    res: int = 32
    seeds: int = 3
    seed: int = 0
    references: object = None
    reference_spp: object = None
    regions: object = None
    options: object = None


def compare_settings(settings=None, scenes=None, methods=None, **fields) -> CompareSettings:
    """``settings`` (default :class:`CompareSettings`) with the given fields replaced (None keeps
    a field); an unknown field is a TypeError naming it."""
    if settings is None:
        settings = CompareSettings()
    elif not isinstance(settings, CompareSettings):
        raise TypeError(f"settings must be a CompareSettings; got {type(settings).__name__}")
    known = {f.name for f in dataclasses.fields(CompareSettings)}
    unknown = sorted(set(fields) - known)
    if unknown:
        raise TypeError(f"unknown compare setting(s) {unknown}; the settings are {sorted(known)}")
    changes = {k: v for k, v in dict(fields, scenes=scenes, methods=methods).items() if v is not None}
    return dataclasses.replace(settings, **changes)


def measure_compare(scenes=None, methods=None, settings=None, *, cache_dir=None, progress: bool = True,
                    **fields) -> CompareResult:
    """Every method on every scene at equal wall time, against one shared reference per scene.

    Parameters
    ----------
    scenes, methods, settings, **fields
        What to measure: a :class:`CompareSettings` and/or its fields
        (``seconds``, ``res``, ``seeds``, ``seed``, ``references``,
        ``reference_spp``, ``regions``, ``options``; ``scenes`` and
        ``methods`` also by position).
    cache_dir : path, optional
        Where the references are cached (:func:`scene_reference`).
    progress : bool
        A tqdm bar over the runs.

    Returns
    -------
    CompareResult
        Ctrl-C stops the measurement and returns the cells finished so far
        with ``interrupted=True``.
    """
    from ..scene import load_scene

    st = compare_settings(settings, scenes, methods, **fields)
    methods = st.methods
    if methods is None:
        methods = [m for m in DEFAULT_METHODS if m in compare_methods()]
    scenes, methods, seconds, res, seeds = check_compare_args(st.scenes, methods, st.seconds, st.res, st.seeds)
    seed, options = st.seed, st.options
    regions = dict(st.regions or {})
    for s, region in regions.items():
        _names([s], "regions", scenes)
        _region_slices(region, res)
    references, reference_spp = dict(st.references or {}), dict(st.reference_spp or {})
    start = time.perf_counter()
    cells, refs, interrupted = {}, {}, False
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(scenes) * len(methods) * seeds, desc="mcvar compare", unit="run")
    try:
        for s in scenes:
            sc = load_scene(s)
            ref = refs[s] = scene_reference(s, res, method=references.get(s), spp=reference_spp.get(s),
                                            seed=seed, cache_dir=cache_dir, progress=progress)
            rows, cols = _region_slices(regions.get(s), res)
            ref_crop = ref.value[rows, cols]
            ref_mean = float(ref_crop.mean())
            for m in methods:
                opts = _options(m, options)
                entry = _registered()[m]
                try:
                    if entry.check_scene is not None:
                        entry.check_scene(sc, entry.resolve_options(opts))
                except ValueError as exc:
                    cells[(s, m)] = Cell(s, m, reason=str(exc))
                    if bar is not None:
                        bar.update(seeds)
                    continue
                runs, image = [], None
                try:
                    for i in range(seeds):
                        if bar is not None:
                            bar.set_postfix_str(f"{s} {m} seed {i}")
                        tr = equal_time_render(sc, m, seconds=seconds, res=res,
                                               rng=_seed_sequence(seed, s, m, i), options=opts)
                        crop = tr.image[rows, cols]
                        runs.append(dict(scene=s, method=m, seed=i, spp=tr.spp, seconds=tr.seconds,
                                         rounds=tr.rounds, max_round_seconds=tr.max_round_seconds,
                                         mse=float(np.mean((crop - ref_crop) ** 2)),
                                         mean_ratio=float(crop.mean() / ref_mean) if ref_mean > 0 else float("nan"),
                                         interrupted=False))
                        image = tr.image if image is None else image
                        if bar is not None:
                            bar.update(1)
                except ValueError as exc:  # refused while rendering (e.g. no bootstrap path carries light)
                    cells[(s, m)] = Cell(s, m, reason=f"render failed: {exc}")
                    continue
                finally:
                    if runs and (s, m) not in cells:
                        cells[(s, m)] = Cell(s, m, runs=tuple(runs), image=image)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        if bar is not None:
            bar.close()
    done_scenes = tuple(s for s in scenes if s in refs)
    return CompareResult(scenes=done_scenes, methods=methods, cells=cells, references=refs, seconds=seconds,
                         res=res, seeds=seeds, seed=seed, regions={s: r for s, r in regions.items()},
                         interrupted=interrupted, wall_seconds=time.perf_counter() - start)


# --------------------------------------------------------------------------
# radiosity's view independence
# --------------------------------------------------------------------------

def radiosity_views(scene: str = "cornell", *, res: int = 32, spp: int = 4, seed: int = 0, camera=None,
                    options=None, cache_dir=None, reference_spp: int | None = None) -> dict:
    """Radiosity's view independence, timed: one solve, two camera views.

    Solves ``scene`` once (``Method.prepare`` of ``radiosity``, low accuracy:
    :data:`COMPARE_OPTIONS`), renders the scene's camera and a second
    ``camera`` (default: from a corner of the room) from that solve, and
    times the solve, each view, and a full render (solve + view) of the
    second view for comparison. Each view's MSE is against a path-traced
    reference of that view.

    Returns
    -------
    dict
        ``solve_seconds``, ``view1_seconds``, ``view2_seconds``,
        ``full_seconds`` (solve and view 2 from scratch), ``fraction``
        (view2 / full), ``mse1``, ``mse2``, ``mse1_off_emitters`` (view 1
        without the pixels that see the light, whose edges dominate at a few
        spp: :func:`~mcvar.experiments.chart.emitter_pixels`), ``images``
        (view 1, view 2), ``references`` (their references: the scene's
        :func:`scene_reference` and path tracing for view 2).
    """
    from ..scene import Camera, load_scene

    res = check_count(res, "res")
    sc = load_scene(scene)
    if camera is None:
        # from the upper left of the open front, looking down at the right half of the room
        # (the Cornell camera looks along +z from (278, 273, -800))
        camera = Camera((120.0, 420.0, -450.0), (330.0, 160.0, 280.0), (0.0, 1.0, 0.0), 45.0)
    sc2 = dataclasses.replace(sc, camera=camera)
    entry = _registered()["radiosity"]
    opts = entry.resolve_options(_options("radiosity", options))
    entry.check_scene(sc, opts)
    t0 = time.perf_counter()
    solve = entry.prepare(sc, opts, np.random.default_rng(_seed_sequence("radiosity", scene, seed)))
    solve_seconds = time.perf_counter() - t0
    reuse = dataclasses.replace(entry, prepare=partial(_prepared, solve))
    t0 = time.perf_counter()
    v1 = _render(sc, integrator=reuse, spp=spp, res=res, rng=_seed_sequence("view1", seed))
    view1 = time.perf_counter() - t0
    t0 = time.perf_counter()
    v2 = _render(sc2, integrator=reuse, spp=spp, res=res, rng=_seed_sequence("view2", seed))
    view2 = time.perf_counter() - t0
    t0 = time.perf_counter()
    _render(sc2, integrator="radiosity", spp=spp, res=res, rng=_seed_sequence("full", seed),
            **_options("radiosity", options))
    full = time.perf_counter() - t0
    ref1 = scene_reference(scene, res, spp=reference_spp, seed=seed, cache_dir=cache_dir).value
    reference_spp = reference_spp or REFERENCES.get(scene, ("path", 4096))[1]
    # the second view's reference is not a named scene: render it here (path tracing, cached by key)
    key = _reference_key(scene + ":view2:" + repr(np.round(camera.position, 6).tolist())
                         + repr(np.round(camera.look_at, 6).tolist()), res, "path", reference_spp, 1, seed, {})
    path = Path(cache_dir) / f"reference-view2-{key}.npy" if cache_dir is not None else None
    if path is not None and path.exists():
        ref2 = np.load(path)
    else:
        ref2 = np.asarray(_render(sc2, integrator="path", spp=reference_spp, res=res,
                                  rng=_seed_sequence("reference-view2", seed)).image, dtype=np.float64)
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            np.save(path, ref2)
    return dict(solve_seconds=solve_seconds, view1_seconds=view1, view2_seconds=view2, full_seconds=full,
                fraction=view2 / full, mse1=float(np.mean((v1.image - ref1) ** 2)),
                mse2=float(np.mean((v2.image - ref2) ** 2)),
                mse1_off_emitters=float(np.mean(((v1.image - ref1) ** 2)[~emitter_pixels(scene, res)])),
                images=(v1.image, v2.image),
                references=(ref1, ref2), camera=camera)


# --------------------------------------------------------------------------
# the slide pairs that need no new scene
# --------------------------------------------------------------------------

#: The caustic under ``cornell-spheres``' glass sphere: (row0, row1, col0, col1) fractions of the
#: image (0-based rows 26-31, columns 17-24 of 32 pixels; found where the BDPT reference exceeds
#: depth-2 path tracing, brightest at rows 28-29, columns 20-22).
CAUSTIC_REGION = (0.84, 0.97, 0.56, 0.78)

#: Slide pairs measured at equal time: name -> (scene, methods, region or None, the lecture's claim).
PAIRS = {
    "point light": ("cornell-point", ("path", "path_bsdf", "light"), None,
                    "a point light is reached only by connecting to it (next-event estimation, light "
                    "tracing); BSDF sampling alone (path_bsdf) never hits it: black"),
    "metropolis": ("cornell-door", ("path", "pssmlt"), None,
                   "Metropolis finds the light through the door and beats path tracing rendered in the "
                   "same time"),
    "caustic": ("cornell-spheres", ("path", "sppm"), CAUSTIC_REGION,
                "photon mapping is for caustics: SPPM beats path tracing on the caustic under the glass "
                "sphere"),
}


def measure_pairs(*, seconds: float, res: int = 32, seeds: int = 3, seed: int = 0, cache_dir=None,
                  progress: bool = True, pairs=None, reference_spp=None) -> dict:
    """Each slide pair of :data:`PAIRS` at equal time: name -> :class:`CompareResult`.

    The references are those of :func:`measure_compare` (the same cache
    keys), so pairs measured after the matrix render no new reference.
    ``pairs`` names a subset of :data:`PAIRS`; ``reference_spp`` is as in
    :func:`measure_compare`.
    """
    chosen = tuple(PAIRS) if pairs is None else _names(pairs, "pairs", tuple(PAIRS))
    out = {}
    for name in chosen:
        scene, methods, region, _ = PAIRS[name]
        methods = [m for m in methods if m in compare_methods()]
        out[name] = measure_compare([scene], methods, seconds=seconds, res=res, seeds=seeds, seed=seed,
                                    cache_dir=cache_dir, progress=progress, reference_spp=reference_spp,
                                    regions={scene: region} if region else None)
        if out[name].interrupted:
            break
    return out
