"""The lecture's slide pairs, measured (issue 21).

* :data:`PAIRS`: methods set against each other at equal time on the scene
  made for the claim (:func:`measure_pairs`, each a
  :class:`~mcvar.experiments.compare_matrix.CompareResult` with the
  matrix's references);
* :func:`forward_pinhole_hits`: forward (light) tracing *without* the
  connection to the camera, the lecture's 'Fails: cannot intersect pinhole
  camera' (slide 'Previous Methods'), counted on the light paths themselves;
* :func:`measure_strategy_grid`: bidirectional path tracing's (s, t)
  strategies on ``cornell-caustic``, which of them carry the caustic (the
  lecture's 'Bidirectional Path Tracing' slides; Veach 1997, fig. 10.3).

References
----------
.. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
   Simulation", PhD thesis, Stanford University, 1997, ch. 10.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .._validation import check_count
from . import compare_args as _args
from .compare_args import _names, _seed_sequence, compare_methods
from .compare_matrix import _region_slices, measure_compare

__all__ = ["CAUSTIC_REGION", "SPHERES_CAUSTIC_REGION", "METROPOLIS_METHODS", "PAIRS", "measure_pairs",
           "metropolis_methods", "forward_pinhole_hits", "StrategyGrid", "measure_strategy_grid",
           "STRATEGY_COLUMNS", "caustic_pixels"]

#: The caustic on ``cornell-caustic``'s floor: (row0, row1, col0, col1) fractions of the image
#: (0-based rows 27-29, columns 8-23 of 32 pixels: the floor within two sphere radii of the contact
#: point, the rows that see the sphere itself left out: :func:`caustic_pixels`).
CAUSTIC_REGION = (0.845, 0.935, 0.25, 0.75)

def caustic_pixels(scene, res: int) -> np.ndarray:
    """The pixels of ``cornell-caustic``'s caustic, as a ``(res, res)`` boolean mask.

    Those whose centre ray first hits the floor within two sphere radii of the
    glass sphere's contact point (where the focused light lands). Pixels that
    see the sphere itself are left out (they hit the sphere first): through
    the glass they see the small light, whose slivers are heavy-tailed for
    every method alike. :data:`CAUSTIC_REGION` is this mask's bounding box at
    32 x 32; ``benchmarks/bench_caustic.py`` and ``tests/test_cornell_caustic.py``
    measure on it.
    """
    from ..tracer import Tracer

    res = check_count(res, "res")
    pix = np.arange(res * res)
    d = scene.camera.ray_directions((res, res), pix, np.full((pix.size, 2), 0.5))
    o = np.broadcast_to(scene.camera.position, d.shape)
    hit = Tracer(scene).intersect(o, d)
    p = o + d * np.where(np.isfinite(hit.t), hit.t, 0.0)[:, None]
    c, r = scene.sphere_centers[0], scene.sphere_radii[0]
    near = (np.abs(p[:, 1]) < 1.0) & (np.hypot(p[:, 0] - c[0], p[:, 2] - c[2]) < 2.0 * r)
    return near.reshape(res, res)


#: The caustic under ``cornell-spheres``' glass sphere (rows 26-31, columns 17-24 of 32 pixels;
#: where the BDPT reference exceeds depth-2 path tracing).
SPHERES_CAUSTIC_REGION = (0.84, 0.97, 0.56, 0.78)

#: Metropolis methods the 'metropolis' pair measures when registered (any other registered method
#: whose chart row is 'Metropolis Light Transport' joins them: :func:`metropolis_methods`).
METROPOLIS_METHODS = ("pssmlt", "mmlt")

#: Slide pairs measured at equal time: name -> (scene, methods, region or None, the lecture's claim).
PAIRS = {
    "point light": ("cornell-point", ("path", "path_bsdf", "light"), None,
                    "a point light is reached only by connecting to it (next-event estimation, light "
                    "tracing); BSDF sampling alone (path_bsdf) never hits it: black"),
    "bdpt caustic": ("cornell-caustic", ("path", "bdpt"), CAUSTIC_REGION,
                     "bidirectional tracing reaches lights that are hard to find: its light subpaths carry "
                     "the caustic that path tracing finds only when a refracted BSDF sample hits the small "
                     "light"),
    "bdpt point light": ("cornell-point", ("path", "bdpt"), None,
                         "bidirectional tracing connects light subpaths from the point light, where path "
                         "tracing's paths off the ceiling next to the light carry huge weights"),
    "metropolis": ("cornell-door", ("path",) + METROPOLIS_METHODS, None,
                   "Metropolis finds the light through the door and beats path tracing rendered in the "
                   "same time"),
    "caustic": ("cornell-caustic", ("path", "sppm"), CAUSTIC_REGION,
                "photon mapping is for caustics: SPPM beats path tracing on the caustic under the glass "
                "sphere"),
}


def metropolis_methods() -> tuple:
    """The registered Metropolis methods: :data:`METROPOLIS_METHODS` and any registered method whose
    chart row is 'Metropolis Light Transport'."""
    reg = _args._registered()
    named = [m for m in METROPOLIS_METHODS if m in reg]
    return tuple(named + [m for m, e in reg.items() if e.chart_row == "Metropolis Light Transport"
                          and m not in named])


def _pair_methods(name, methods) -> list:
    if name == "metropolis":
        methods = ("path",) + metropolis_methods()
    return [m for m in methods if m in compare_methods()]


def measure_pairs(*, seconds: float, res: int = 32, seeds: int = 3, seed: int = 0, cache_dir=None,
                  progress: bool = True, pairs=None, reference_spp=None) -> dict:
    """Each slide pair of :data:`PAIRS` at equal time: name -> :class:`CompareResult`.

    The references are those of :func:`measure_compare` (the same cache
    keys), so pairs measured after the matrix render no new reference.
    ``pairs`` names a subset of :data:`PAIRS`; ``reference_spp`` is as in
    :func:`measure_compare`. The 'metropolis' pair measures path tracing and
    every registered Metropolis method (:func:`metropolis_methods`).
    """
    chosen = tuple(PAIRS) if pairs is None else _names(pairs, "pairs", tuple(PAIRS))
    out = {}
    for name in chosen:
        scene, methods, region, _ = PAIRS[name]
        out[name] = measure_compare([scene], _pair_methods(name, methods), seconds=seconds, res=res, seeds=seeds,
                                    seed=seed, cache_dir=cache_dir, progress=progress,
                                    reference_spp=reference_spp, regions={scene: region} if region else None)
        if out[name].interrupted:
            break
    return out


# --------------------------------------------------------------------------
# forward tracing without the camera connection
# --------------------------------------------------------------------------

def _distance_to_rays(c, a, d, length):
    """Distance of the point ``c`` from the segments ``a + u d``, ``0 <= u <= length`` (``d`` unit)."""
    u = np.clip(np.einsum("ij,ij->i", c - a, d), 0.0, length)
    return np.linalg.norm(a + d * u[:, None] - c, axis=1)


def forward_pinhole_hits(scene: str = "cornell-point", *, n_paths: int = 1 << 16, seed: int = 0,
                         radii=(1.0, 10.0, 50.0)) -> dict:
    """Forward (light) tracing without the camera connection: how many light rays hit the pinhole.

    Traces ``n_paths`` light subpaths of ``scene`` (BSDF sampling, Russian
    roulette, rays that leave the scene kept as rays to infinity:
    :func:`mcvar.integrators.light.light_subpath` with ``escape=True``) and
    measures, for every ray of every subpath, its distance from the camera's
    pinhole. Without the connection to the camera a light path reaches the
    image only through a ray that passes *through* the pinhole, a point:
    probability 0, so the image is black (the lecture's 'Fails: cannot
    intersect pinhole camera'); light tracing (``light``) connects every
    vertex to the pinhole instead.

    Returns
    -------
    dict
        ``scene``, ``paths``, ``rays`` (segments and escaping rays tested),
        ``escaping`` (rays that leave the scene), ``hits`` (rays through the
        pinhole: distance exactly 0), ``energy_fraction`` (the image's
        energy over the reference's: ``hits`` carry it, 0 without them),
        ``closest`` (the smallest distance of a ray from the pinhole, scene
        units), ``within`` (radius -> fraction of rays passing closer than
        it: it falls with the radius, to 0 at the pinhole's 0), ``seconds``.
    """
    from ..integrators.emitters import LightOrigins
    from ..integrators.light import RR_MAX_VERTICES, light_subpath
    from ..scene import load_scene
    from ..tracer import Tracer

    n_paths = check_count(n_paths, "n_paths")
    radii = tuple(float(r) for r in radii)
    if any(not (r > 0 and np.isfinite(r)) for r in radii):
        raise ValueError(f"radii must be finite and > 0; got {radii}")
    sc = load_scene(scene)
    t0 = time.perf_counter()
    rng = np.random.default_rng(_seed_sequence("forward", scene, seed))
    L = light_subpath(sc, Tracer(sc), LightOrigins(sc), n_paths, RR_MAX_VERTICES, rng, roulette=True,
                      escape=True)
    c = np.asarray(sc.camera.position, dtype=np.float64)
    dists, escaping = [], 0
    for i in range(int(L.length.max()) - 1):
        idx = np.flatnonzero(L.length > i + 1)
        a = L.p[i, idx]
        inf = L.infinite[i + 1, idx]
        d = np.where(inf[:, None], L.ng[i + 1, idx], L.p[i + 1, idx] - a)
        length = np.where(inf, np.inf, np.linalg.norm(d, axis=1))
        d = d / np.where(inf, 1.0, np.maximum(length, 1e-300))[:, None]
        dists.append(_distance_to_rays(c, a, d, length))
        escaping += int(inf.sum())
    dist = np.concatenate(dists) if dists else np.zeros(0)
    hits = int(np.count_nonzero(dist == 0.0))
    return dict(scene=scene, paths=n_paths, rays=int(dist.size), escaping=escaping, hits=hits,
                energy_fraction=0.0 if hits == 0 else float("nan"),
                closest=float(dist.min()) if dist.size else float("inf"),
                within={r: float(np.mean(dist < r)) if dist.size else 0.0 for r in radii},
                seconds=time.perf_counter() - t0)


# --------------------------------------------------------------------------
# BDPT's (s, t) strategies on the caustic
# --------------------------------------------------------------------------

#: Columns of ``strategies.csv`` (one row per (s, t) strategy).
STRATEGY_COLUMNS = ("s", "t", "depth", "energy", "share", "region_energy", "region_share", "region_variance",
                    "pixel_variance")


@dataclass(frozen=True)
class StrategyGrid:
    """BDPT's strategies measured over ``renders`` independent renders of ``spp``.

    ``image`` (H, W, 3) is the mean BDPT image, ``strategies`` ``(s, t) ->``
    mean weighted image (they sum to ``image``: every strategy of depth <=
    ``max_depth`` is kept, :data:`mcvar.integrators.bdpt.STRATEGY_DEPTH`),
    ``rows`` the numbers of :data:`STRATEGY_COLUMNS` per strategy:
    ``energy`` its image mean, ``share`` of the BDPT image's mean,
    ``region_energy`` / ``region_share`` the same inside ``region``,
    ``region_variance`` the variance of one render's region mean (over the
    renders) and ``pixel_variance`` the mean over the region's pixels of one
    render's pixel variance: what the strategy adds to the noise there.
    """

    scene: str
    spp: int
    renders: int
    max_depth: int
    region: tuple
    image: np.ndarray = field(repr=False)
    strategies: dict = field(repr=False)
    rows: tuple = field(repr=False)
    seconds: float = 0.0

    def carriers(self, share: float = 0.05) -> tuple:
        """The strategies ``(s, t)`` that carry more than ``share`` of the region's energy."""
        return tuple((r["s"], r["t"]) for r in self.rows if r["region_share"] > share)


def measure_strategy_grid(scene: str = "cornell-caustic", *, res: int = 32, spp: int = 32, renders: int = 8,
                          max_depth: int = 4, region=CAUSTIC_REGION, seed: int = 0,
                          progress: bool = False) -> StrategyGrid:
    """Which of BDPT's (s, t) strategies carry the caustic of ``scene``, and with what variance.

    Renders ``scene`` ``renders`` times with ``bdpt`` at ``spp``, fixed
    ``max_depth`` (<= :data:`~mcvar.integrators.bdpt.STRATEGY_DEPTH`, so the
    strategies kept are all of them and sum to the image) and
    ``strategies=True``; see :class:`StrategyGrid`.
    """
    from ..integrators.bdpt import STRATEGY_DEPTH, strategies_from_extra
    from ..scene import load_scene

    res, spp, renders = check_count(res, "res"), check_count(spp, "spp"), check_count(renders, "renders")
    max_depth = check_count(max_depth, "max_depth")
    if renders < 2:
        raise ValueError(f"renders must be >= 2 (the variances come from their spread); got {renders}")
    if max_depth > STRATEGY_DEPTH:
        raise ValueError(f"max_depth must be <= STRATEGY_DEPTH ({STRATEGY_DEPTH}) so that the strategies kept "
                         f"sum to the image; got {max_depth}")
    rows_, cols_ = _region_slices(region, res)
    sc = load_scene(scene)
    streams = _seed_sequence("strategies", scene, seed).spawn(renders)
    images, per = [], []
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=renders, desc=f"bdpt strategies on {scene}", unit="render", leave=False)
    t0 = time.perf_counter()
    try:
        for stream in streams:
            r = _args._render(sc, integrator="bdpt", spp=spp, res=res, max_depth=max_depth, strategies=True,
                              rng=stream, progress=False)
            if r.interrupted:
                raise KeyboardInterrupt
            images.append(np.asarray(r.image, dtype=np.float64))
            per.append(strategies_from_extra(r.extra, r.res))
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    keys = sorted(set().union(*per), key=lambda st: (st[0] + st[1], st[0]))
    zero = np.zeros_like(images[0])
    stack = {k: np.stack([p.get(k, zero) for p in per]) for k in keys}
    image = np.mean(images, axis=0)
    total, total_region = float(image.mean()), float(image[rows_, cols_].mean())
    rows = []
    for (s, t), imgs in stack.items():
        reg = imgs[:, rows_, cols_]
        energy, region_energy = float(imgs.mean()), float(reg.mean())
        rows.append(dict(s=s, t=t, depth=s + t - 1, energy=energy, share=energy / total if total > 0 else 0.0,
                         region_energy=region_energy,
                         region_share=region_energy / total_region if total_region > 0 else 0.0,
                         region_variance=float(reg.mean(axis=(1, 2, 3)).var(ddof=1)),
                         pixel_variance=float(reg.var(axis=0, ddof=1).mean())))
    return StrategyGrid(scene, spp, renders, max_depth, tuple(region), image,
                        {k: v.mean(axis=0) for k, v in stack.items()}, tuple(rows), time.perf_counter() - t0)
