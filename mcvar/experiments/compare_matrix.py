"""The matrix: every method on every scene at equal time, one shared reference per scene (issue 21).

``mse`` is the mean over pixels and channels of ``(image - reference)^2`` (optionally inside a
region), the median over ``seeds`` runs; efficiency is ``1 / (mse x seconds)`` of the medians
(Veach 1997, sec. 1.4.4). A method that cannot render a scene (its ``check_scene`` raises
ValueError) gets that reason in its cell instead of a number.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from .compare_args import (DEFAULT_SCENES, _names, _options, _registered, _seed_sequence, check_compare_args,
                           default_methods)
from .equal_time import equal_time_render
from .scene_references import scene_reference

__all__ = ["COMPARE_COLUMNS", "RUN_COLUMNS", "Cell", "CompareResult", "CompareSettings", "compare_settings",
           "measure_compare"]

#: Columns of ``compare.csv`` (one row per scene x method) and ``compare_runs.csv`` (one row per seed).
COMPARE_COLUMNS = ("scene", "method", "reference_method", "region", "reference_noise", "seeds", "spp",
                   "seconds", "mse",
                   "mean_ratio", "mse_x_time", "efficiency", "relative_efficiency", "winner", "reason")
RUN_COLUMNS = ("scene", "method", "seed", "spp", "seconds", "rounds", "max_round_seconds", "mse", "mean_ratio",
               "interrupted")


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
        Scene names (:func:`~mcvar.experiments.compare_args.compare_scenes`;
        default :data:`~mcvar.experiments.compare_args.DEFAULT_SCENES`, the
        scenes of issue 21) and registered methods (default
        :func:`~mcvar.experiments.compare_args.default_methods`: every
        registered light-transport method, also one registered later).
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

    scenes: object = DEFAULT_SCENES
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
        methods = default_methods()
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

