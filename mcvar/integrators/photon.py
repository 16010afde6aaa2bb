"""Photon mapping: the registered method ``photon``, and the parts SPPM shares.

The lecture's 'Photon Mapping' slide: "trace particles from the light,
deposit 'photons' in a KD-tree". Two estimators built on the same parts:

* :func:`trace_photons` emits photons from the area lights, point lights and an environment map
  (:func:`~mcvar.integrators.emitters.sample_le`: an emitter chosen by power,
  a uniform point and a cosine-weighted direction, or a uniform direction
  from a point light),
  follows them through the scene with the BSDFs' ``sample`` (Russian
  roulette after :data:`RR_START_DEPTH` segments keeps the power per photon
  about constant), and yields, batch by batch, a photon at every non-delta
  hit: position, incident direction (pointing away from the surface, back
  where the photon came from), power (flux, RGB) and the segments it travelled.
* :func:`visible_points` follows camera rays through mirrors and glass
  (delta BSDFs, sampled) to their first non-delta hit, collecting emission
  seen on the way.
* :func:`photon_map_radiance` (Jensen 1996) estimates the reflected radiance
  at the visible points by density estimation over the stored photons,
  ``L(x, wo) ~ sum_p f(x, wo, wi_p) Phi_p / (pi r^2)``, with the ``k``
  nearest photons (``r`` = distance to the k-th) or all photons within a
  fixed ``radius``, found with ``scipy.spatial.cKDTree``. Biased: the disk
  averages irradiance over its area (blurred shadows and corners) and
  gathers photons from neighbouring surfaces (light leaking); at fixed ``k``
  or ``radius`` not even consistent in the number of camera samples.
* :func:`~mcvar.integrators.sppm.sppm` (Hachisuka and Jensen 2009): per iteration one visible point
  per pixel and one photon pass; every pixel keeps a radius ``R``, a photon
  count ``N`` and an accumulated flux ``tau``, and after ``M`` new photons
  ``N' = N + alpha M``, ``R' = R sqrt(N' / (N + M))``,
  ``tau' = (tau + phi) R'^2 / R^2``. The radius shrinks so slowly that the
  photon count per pixel still grows: biased at every finite iteration count,
  consistent as it grows.

Memory is bounded: photons are traced and handled :data:`PHOTONS_PER_BATCH`
at a time; a photon *map* (photon mapping proper) stores 10 float64 numbers
and a tree node per stored photon (about 100 bytes), while SPPM never keeps
more than one batch of photons.

References
----------
.. [1] H. W. Jensen, "Global Illumination using Photon Maps", Rendering
   Techniques '96 (Eurographics Workshop on Rendering), 1996.
.. [2] T. Hachisuka, H. W. Jensen, "Stochastic Progressive Photon Mapping",
   ACM Transactions on Graphics 28(5) (SIGGRAPH Asia), 2009.
.. [3] M. Pharr, W. Jakob, G. Humphreys, "Physically Based Rendering",
   3rd ed., sec. 16.2 (SPPM), 2016.
"""
from __future__ import annotations

import itertools
import time
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .._validation import as_rng, check_budget, check_count, check_positive
from ..geometry import Frame
from ..scene import Scene
from ..tracer import Tracer
from .emitters import LightOrigins, sample_le
from .film import BatchJob, BatchResult, camera_result
from .knobs import scaled_knob
from .registry import Method, register
from .stream import camera_rays

__all__ = ["PhotonBatch", "PhotonMap", "VisiblePoints", "trace_photons", "build_photon_map",
           "visible_points", "photon_map_radiance", "check_photon_scene", "check_photon_method_scene",
           "PHOTONS_PER_BATCH", "BYTES_PER_PHOTON", "check_photon_budget", "run_photon_batch",
           "pairs_within", "sees_emitters"]

#: Photons emitted per batch (memory bound of tracing; about 60 MB of temporaries).
PHOTONS_PER_BATCH = 1 << 16
#: Russian roulette starts once a photon has this many segments.
RR_START_DEPTH = 3
#: Safety cap on segments under Russian roulette (as the path tracer's).
RR_MAX_DEPTH = 1024
#: Visible points per density-estimation chunk (k nearest: bounds the (points x k) arrays).
POINTS_PER_CHUNK = 4096
#: (visible point, photon) pairs per chunk of a fixed-radius estimate (~100 MB of temporaries).
PAIRS_PER_CHUNK = 1 << 19
#: Peak bytes per emitted photon while a photon map is built: the stored
#: photon's 74 bytes twice (the batches and their concatenation) and the k-d
#: tree's 32, for one stored photon per emitted one (every photon of a closed
#: scene lands at least once; more bounces store more).
BYTES_PER_PHOTON = 2 * 74 + 32
#: Bytes of temporaries per (visible point, photon) pair of a density estimate
#: (PAIRS_PER_CHUNK pairs take about 100 MB).
BYTES_PER_PAIR = 200
#: Threads of the k-d tree queries (``workers`` of ``cKDTree.query_ball_point``; -1: every core).
KD_WORKERS = -1


def check_photon_budget(photons: int, name: str = "photons") -> int:
    """``photons`` (emitted photons of one map, or of one SPPM iteration) checked
    against the memory budget (:func:`mcvar._validation.check_budget`):
    a map of them needs at least :data:`BYTES_PER_PHOTON` each."""
    photons = check_count(photons, name)
    check_budget(name, photons, float(photons) * BYTES_PER_PHOTON, per_unit=BYTES_PER_PHOTON,
                 what="the photon map: one stored photon per emitted photon at least")
    return photons


def check_photon_scene(scene: Scene) -> None:
    """Raise ``ValueError`` for what photon emission here cannot handle.

    Photons leave the area lights, point lights and an environment map (from
    a disk that covers the scene, pbrt-v4's infinite lights; issue 26) by
    :func:`~mcvar.integrators.emitters.sample_le`. Emitting primitives that
    belong to no area light (the furnace's glowing sphere) are refused: the
    density estimate on such closed curved emitters is not validated here.
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a mcvar.scene.Scene; got {type(scene).__name__}")
    if LightOrigins(scene).empty:
        raise ValueError(f"scene {scene.name!r} has no emitter to emit photons from (no area light, "
                         "point light or environment map with radiance)")
    stray = np.any(scene.prim_emission > 0, axis=1) & (scene.prim_light < 0)
    if np.any(stray):
        raise ValueError(f"scene {scene.name!r} has {int(stray.sum())} emitting primitive(s) that belong to "
                         "no area light; photons are emitted only from area lights, point lights and "
                         "environment maps")


# ---------------------------------------------------------------------------
# Shading helpers

def _shading_frame(scene: Scene, mat, n_g, wo):
    """Shading normals: geometric, flipped towards ``wo`` except for transmissive materials."""
    flips = np.array([not getattr(m, "transmissive", False) for m in scene.materials])
    flip = flips[mat] & (np.einsum("ij,ij->i", n_g, wo) < 0.0)
    return np.where(flip[:, None], -n_g, n_g)


def _sample_bsdf(scene: Scene, mat, n_s, wo, u):
    """BSDF samples per material group: world ``wi`` and ``weight = f cos / pdf``."""
    frame = Frame(n_s)
    wo_l = frame.to_local(wo)
    wi_l = np.zeros_like(wo_l)
    weight = np.zeros_like(wo_l)
    for mi, sel in _groups(mat):
        # the checked arrays of the BSDF contract (unit wo from an orthonormal frame, u in [0, 1)),
        # so the per-call argument checks of ``sample`` are skipped: they were a quarter of its cost
        wi_l[sel], weight[sel], _, _ = scene.materials[mi]._sample(wo_l[sel], u[sel])
    wi = frame.to_world(wi_l)
    return wi / np.linalg.norm(wi, axis=1, keepdims=True).clip(1e-300), weight


def _eval_bsdf(scene: Scene, mat, n_s, wo, wi):
    """``f(wo, wi)`` per material group (world directions; the frame of ``n_s``)."""
    frame = Frame(n_s)
    wo_l, wi_l = frame.to_local(wo), frame.to_local(wi)
    f = np.zeros_like(wo_l)
    for mi, sel in _groups(mat):
        if not scene.materials[mi].is_delta:
            f[sel] = scene.materials[mi]._eval(wo_l[sel], wi_l[sel])    # checked arrays, as in _sample_bsdf
    return f


def _groups(mat):
    """``(material, rows)`` of every material in ``mat``, from one stable sort."""
    order = np.argsort(mat, kind="stable")
    sorted_mat = mat[order]
    cuts = np.flatnonzero(np.diff(sorted_mat)) + 1
    return [(int(sorted_mat[a]), order[a:b]) for a, b in zip(np.r_[0, cuts], np.r_[cuts, mat.size]) if b > a]


def _is_delta(scene: Scene) -> np.ndarray:
    return np.array([bool(getattr(m, "is_delta", False)) for m in scene.materials])


# ---------------------------------------------------------------------------
# Photons

@dataclass(frozen=True, eq=False)
class PhotonBatch:
    """Photons stored at non-delta hits by one batch of emitted photons.

    ``position`` (m, 3), ``direction`` (m, 3) unit, pointing from the
    surface back towards where the photon came from, ``power`` (m, 3) flux
    (already divided by the total number of photons emitted), ``depth``
    (m,) int16, segments travelled (1: direct light).
    """

    position: np.ndarray
    direction: np.ndarray
    power: np.ndarray
    depth: np.ndarray

    @property
    def n(self) -> int:
        return self.position.shape[0]


def _emit(scene: Scene, n: int, n_total: int, rng):
    """``n`` photons leaving the lights (:func:`~mcvar.integrators.emitters.sample_le`).

    An emitter chosen by power with probability ``p_k``; on an area light a
    uniform point and a cosine-weighted direction, flux
    ``Le cos / (pdf_pos pdf_dir) / N = pi A_k Le / (p_k N)``; from a point
    light of intensity ``I`` a uniform direction, flux ``4 pi I / (p_k N)``
    (pbrt-v4, sec. 12.5).
    """
    x, d, nrm, le, pdf_pos, pdf_dir, _ = sample_le(scene, rng.random((n, 2)), rng.random((n, 2)))
    point = ~np.any(nrm != 0.0, axis=1)                 # point lights: no surface, no cosine
    cos = np.where(point, 1.0, np.abs(np.einsum("ij,ij->i", nrm, d)))
    with np.errstate(divide="ignore", invalid="ignore"):
        flux = np.where((pdf_dir * pdf_pos > 0)[:, None], le * (cos / (pdf_pos * pdf_dir * n_total))[:, None], 0.0)
    return x, d, flux, nrm


def trace_photons(scene: Scene, n_photons: int, *, rng=None, tracer: Tracer | None = None,
                  max_depth: int | None = None, batch: int = PHOTONS_PER_BATCH, ray_counter=None):
    """Emit ``n_photons`` from the lights and yield the stored photons batch by batch.

    Parameters
    ----------
    scene : Scene
        With some emitter (:func:`check_photon_scene`).
    n_photons : int
        Photons emitted in total (their power is divided by it).
    rng : None, int, SeedSequence or Generator
    tracer : Tracer, optional
    max_depth : int or None
        Maximum segments of a photon path (a photon stored after ``k``
        segments lights camera paths of ``k + 1`` or more); None: Russian
        roulette with survival ``min(0.95, max_c beta' / max_c beta)``.
    batch : int
        Photons emitted per batch.
    ray_counter : list, optional
        ``ray_counter[0]`` is increased by the rays traced.

    Yields
    ------
    PhotonBatch
    """
    n_photons = check_count(n_photons, "photons")
    batch = check_count(batch, "batch")
    check_photon_scene(scene)
    rng = as_rng(rng)
    tracer = Tracer(scene) if tracer is None else tracer
    delta = _is_delta(scene)
    limit = RR_MAX_DEPTH if max_depth is None else check_count(max_depth, "max_depth")
    eps = float(scene.ray_epsilon)
    for start in range(0, n_photons, batch):
        m = min(batch, n_photons - start)
        o, d, beta, n0 = _emit(scene, m, n_photons, rng)
        o = o + eps * n0
        stored = []
        k = 0
        while o.shape[0] and k < limit:
            k += 1
            hit = tracer.intersect(o, d)
            if ray_counter is not None:
                ray_counter[0] += o.shape[0]
            ok = hit.prim >= 0
            o, d, beta, prim, t = o[ok], d[ok], beta[ok], hit.prim[ok], hit.t[ok]
            if not o.shape[0]:
                break
            p = o + t[:, None] * d
            n_g = tracer.normals(prim, p)
            mat = scene.prim_material[prim]
            keep = ~delta[mat]
            if np.any(keep):
                stored.append(PhotonBatch(p[keep], -d[keep], beta[keep], np.full(keep.sum(), k, np.int16)))
            if k >= limit:
                break
            wo = -d
            n_s = _shading_frame(scene, mat, n_g, wo)
            wi, weight = _sample_bsdf(scene, mat, n_s, wo, rng.random((p.shape[0], 2)))
            new = beta * weight
            alive = new.max(axis=1) > 0.0
            if max_depth is None and k >= RR_START_DEPTH:
                with np.errstate(divide="ignore", invalid="ignore"):
                    q = np.minimum(0.95, new.max(axis=1) / beta.max(axis=1))
                q = np.nan_to_num(q)
                survive = rng.random(q.shape[0]) < q
                new = new / np.where(survive, q, 1.0)[:, None]
                alive &= survive
            side = np.sign(np.einsum("ij,ij->i", wi, n_g))
            o = (p + eps * side[:, None] * n_g)[alive]
            d, beta = wi[alive], new[alive]
        if stored:
            yield _concat(stored)


_FIELDS = ("position", "direction", "power", "depth")


def _concat(parts):
    """One :class:`PhotonBatch` from several, field by field (frees each field's parts as it goes)."""
    out = {}
    for f in _FIELDS:
        out[f] = np.concatenate([getattr(b, f) for b in parts])
    return PhotonBatch(**out)


@dataclass(frozen=True, eq=False)
class PhotonMap:
    """All photons of :func:`trace_photons` and their k-d tree (Jensen's photon map).

    Attributes
    ----------
    photons : PhotonBatch
    tree : scipy.spatial.cKDTree
        Over ``photons.position``.
    emitted : int
    seconds : float
    nbytes : int
        Memory held by the photon arrays: 74 bytes per photon (the tree
        keeps its own float64 copy of the positions and an index, 32 more).
    """

    photons: PhotonBatch
    tree: cKDTree
    emitted: int
    seconds: float

    @property
    def nbytes(self) -> int:
        p = self.photons
        return sum(getattr(p, f).nbytes for f in _FIELDS)


def build_photon_map(scene: Scene, n_photons: int, *, rng=None, tracer: Tracer | None = None,
                     max_depth: int | None = None, batch: int = PHOTONS_PER_BATCH) -> PhotonMap:
    """Trace ``n_photons`` (:func:`trace_photons`) and store them in a ``cKDTree``.

    ``n_photons`` whose map cannot fit the memory budget
    (:data:`BYTES_PER_PHOTON` each) is a ``ValueError`` before any tracing."""
    check_photon_budget(n_photons, "n_photons")
    start = time.perf_counter()
    parts = list(trace_photons(scene, n_photons, rng=rng, tracer=tracer, max_depth=max_depth, batch=batch))
    if parts:
        photons = _concat(parts)
        del parts
    else:
        z = np.zeros((0, 3))
        photons = PhotonBatch(z, z, z, np.zeros(0, np.int16))
    tree = cKDTree(photons.position) if photons.n else None
    return PhotonMap(photons=photons, tree=tree, emitted=n_photons, seconds=time.perf_counter() - start)


# ---------------------------------------------------------------------------
# Camera side

@dataclass(frozen=True, eq=False)
class VisiblePoints:
    """First non-delta hits of camera rays (through mirrors and glass).

    ``valid`` (n,) bool; for valid rows ``position``, ``normal`` (shading
    normal facing ``wo``), ``wo`` (towards the camera side), ``material``,
    ``beta`` (throughput of the delta bounces); ``emitted`` (n, 3) radiance
    of emitters and environment met on the way (for every row).
    """

    valid: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    wo: np.ndarray
    material: np.ndarray
    beta: np.ndarray
    emitted: np.ndarray
    rays: int


def visible_points(scene: Scene, tracer: Tracer, origins, directions, *, rng=None,
                   max_depth: int | None = None) -> VisiblePoints:
    """Follow camera rays through delta BSDFs to their first non-delta hit.

    Emission is added at every hit (``beta Le``) up to and including the
    visible point; rays that leave see the environment. At most
    ``max_depth`` segments (None: :data:`RR_MAX_DEPTH`, with Russian roulette
    after :data:`RR_START_DEPTH` delta bounces as in the path tracer).
    """
    rng = as_rng(rng)
    o = np.array(origins, dtype=np.float64)
    d = np.array(directions, dtype=np.float64)
    n = o.shape[0]
    delta = _is_delta(scene)
    limit = RR_MAX_DEPTH if max_depth is None else max_depth
    eps = float(scene.ray_epsilon)
    out = VisiblePoints(valid=np.zeros(n, bool), position=np.zeros((n, 3)), normal=np.zeros((n, 3)),
                        wo=np.zeros((n, 3)), material=np.zeros(n, np.int64), beta=np.zeros((n, 3)),
                        emitted=np.zeros((n, 3)), rays=0)
    idx = np.arange(n)
    beta = np.ones((n, 3))
    rays = 0
    k = 0
    while idx.size and k < limit:
        k += 1
        hit = tracer.intersect(o, d)
        rays += idx.size
        miss = hit.prim < 0
        if scene.environment is not None and np.any(miss):
            out.emitted[idx[miss]] += beta[miss] * scene.environment.radiance(d[miss])
        ok = ~miss
        o, d, beta, idx, prim = o[ok], d[ok], beta[ok], idx[ok], hit.prim[ok]
        p = o + hit.t[ok, None] * d
        out.emitted[idx] += beta * scene.emission(prim, p, tracer.normals(prim, p), d)
        n_g = tracer.normals(prim, p)
        mat = scene.prim_material[prim]
        wo = -d
        n_s = _shading_frame(scene, mat, n_g, wo)
        stop = ~delta[mat]
        if np.any(stop):
            rows = idx[stop]
            out.valid[rows] = True
            out.position[rows] = p[stop]
            out.normal[rows] = n_s[stop]
            out.wo[rows] = wo[stop]
            out.material[rows] = mat[stop]
            out.beta[rows] = beta[stop]
        go = ~stop
        if not np.any(go) or k >= limit:
            break
        p, n_g, n_s, wo, mat, beta, idx = p[go], n_g[go], n_s[go], wo[go], mat[go], beta[go], idx[go]
        wi, weight = _sample_bsdf(scene, mat, n_s, wo, rng.random((idx.size, 2)))
        beta = beta * weight
        alive = beta.max(axis=1) > 0.0
        if max_depth is None and k >= RR_START_DEPTH:
            q = np.minimum(0.95, beta.max(axis=1))
            survive = rng.random(q.shape[0]) < q
            beta = beta / np.where(survive, q, 1.0)[:, None]
            alive &= survive
        side = np.sign(np.einsum("ij,ij->i", wi, n_g))
        o = (p + eps * side[:, None] * n_g)[alive]
        d, beta, idx = wi[alive], beta[alive], idx[alive]
    return VisiblePoints(valid=out.valid, position=out.position, normal=out.normal, wo=out.wo,
                         material=out.material, beta=out.beta, emitted=out.emitted, rays=rays)


def sees_emitters(scene: Scene, res, *, sub: int = 16, refine: int = 256) -> np.ndarray:
    """Pixels whose camera rays meet emission before their visible point, grown by one pixel.

    Those pixels' values are the ``emitted`` part of :class:`VisiblePoints`
    (pixel sampling of a light, seen directly or through mirrors and glass),
    not a density estimate; every method estimates them alike, and a small
    bright light over a sliver of a pixel makes them heavy-tailed (in
    ``cornell-caustic`` the reference's variance there is 1000 x its mean
    elsewhere). Measurements of the photon estimate leave them out.

    Parameters
    ----------
    scene : Scene
    res : int or (int, int)
        Square side or ``(width, height)``.
    sub : int
        ``sub x sub`` rays per pixel, at the centres of a grid of cells,
        followed by :func:`visible_points` (which picks reflection or
        refraction at random, so both are followed).
    refine : int
        Pixels where one of those rays met a delta surface first are probed
        again with ``refine x refine`` rays (the glass sphere of
        ``cornell-caustic`` shows its light over a ten-thousandth of a pixel).

    Returns
    -------
    ndarray of bool, shape (H, W)
    """
    sub, refine = check_count(sub, "sub"), check_count(refine, "refine")
    if isinstance(res, (int, np.integer)):
        w = h = check_count(res, "res")
    else:
        w, h = check_count(res[0], "res[0]"), check_count(res[1], "res[1]")
    tracer = Tracer(scene)
    delta = _is_delta(scene)
    rng = np.random.default_rng(0)
    lit, glassy = np.zeros(w * h, bool), np.zeros(w * h, bool)

    def probe(pixels, n):
        """Flag ``lit`` and ``glassy`` for ``pixels``, ``n x n`` rays each, about 2^18 rays at a time."""
        cells = (np.arange(n) + 0.5) / n
        off = np.stack(np.meshgrid(cells, cells), -1).reshape(-1, 2)
        step = max(1, (1 << 18) // off.shape[0])
        for a in range(0, pixels.size, step):
            chunk = pixels[a:a + step]
            pix = np.repeat(chunk, off.shape[0])
            d = scene.camera.ray_directions((w, h), pix, np.tile(off, (chunk.size, 1)))
            o = np.broadcast_to(scene.camera.position, d.shape)
            vp = visible_points(scene, tracer, o, d, rng=rng, max_depth=16)
            lit[pix[vp.emitted.max(axis=1) > 0]] = True
            first = tracer.intersect(o, d).prim
            glassy[pix[(first >= 0) & delta[scene.prim_material[np.maximum(first, 0)]]]] = True

    probe(np.arange(w * h), sub)
    probe(np.flatnonzero(glassy), refine)
    return ndimage.binary_dilation(lit.reshape(h, w), iterations=1)


def _flatten(lists, counts):
    """The index lists of ``query_ball_point`` as one int64 array (in order)."""
    return np.fromiter(itertools.chain.from_iterable(lists), np.int64, int(counts.sum()))


def pairs_within(points, radii, photons, *, max_pairs: int | None = None):
    """Every (point, photon) pair within the point's own radius, in chunks of bounded size.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Visible points.
    radii : ndarray, shape (n,)
        Gather radius of every point (> 0).
    photons : ndarray, shape (m, 3)
        Photon positions.
    max_pairs : int, optional
        Pairs per yielded chunk, about (default :data:`PAIRS_PER_CHUNK`; a
        single point with more photons than that is one chunk).

    Yields
    ------
    (i, j) : ndarrays of int64
        Indices into ``points`` and ``photons`` with
        ``|points[i] - photons[j]| <= radii[i]`` (``cKDTree``'s ball); every such pair exactly once.

    Notes
    -----
    One ``scipy.spatial.cKDTree`` over the larger of the two sets, queried
    with the smaller by ``query_ball_point`` (``workers`` =
    :data:`KD_WORKERS`). That is the measured fast order (docs/photon.md):
    the query returns one Python list per query point, and turning 157 000
    lists (the photons of a 65 536-photon pass in ``cornell-caustic``) into
    an array costs 5 x more than building the tree over those photons
    (unbalanced, 55 ms), while 1 000-4 000 visible points' lists cost
    nothing. Queried by the visible points every point uses its own radius;
    queried by the photons the tree over the points takes the largest radius
    and the pairs beyond a point's own are dropped. A count pass
    (``return_length``) sizes the chunks, so memory stays bounded whatever
    the radius.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    photons = np.asarray(photons, dtype=np.float64).reshape(-1, 3)
    radii = np.asarray(radii, dtype=np.float64)
    if radii.shape != (points.shape[0],):
        raise ValueError(f"radii must have one value per point, shape ({points.shape[0]},); got {radii.shape}")
    if radii.size and not (np.all(np.isfinite(radii)) and radii.min() > 0):
        raise ValueError("radii must be finite and > 0")
    max_pairs = PAIRS_PER_CHUNK if max_pairs is None else check_count(max_pairs, "max_pairs")
    n, m = points.shape[0], photons.shape[0]
    if n == 0 or m == 0:
        return
    by_points = n <= m
    tree = cKDTree(photons if by_points else points, balanced_tree=False, compact_nodes=False)
    query = points if by_points else photons
    r = radii if by_points else float(radii.max())
    counts = tree.query_ball_point(query, r, workers=KD_WORKERS, return_length=True)
    ends = np.cumsum(counts)
    cuts = np.searchsorted(ends, np.arange(1, 1 + int(ends[-1]) // max_pairs) * max_pairs, side="right")
    bounds = np.unique(np.concatenate([[0], cuts, [query.shape[0]]]))
    for a, b in zip(bounds[:-1], bounds[1:]):
        if ends[b - 1] - (ends[a - 1] if a else 0) == 0:
            continue
        rq = r[a:b] if by_points else r
        lists = tree.query_ball_point(query[a:b], rq, workers=KD_WORKERS, return_sorted=False)
        other = _flatten(lists, counts[a:b])
        own = np.repeat(np.arange(a, b), counts[a:b])
        if by_points:
            yield own, other
        else:
            d2 = np.einsum("ij,ij->i", points[other] - photons[own], points[other] - photons[own])
            keep = d2 <= radii[other] ** 2
            yield other[keep], own[keep]


def _gather(scene: Scene, vp_rows, vp: VisiblePoints, photons: PhotonBatch, pairs_vp, pairs_ph):
    """``beta f(wo, wi_p) Phi_p`` of every (visible point, photon) pair, (pairs, 3)."""
    mat = vp.material[pairs_vp]
    f = _eval_bsdf(scene, mat, vp.normal[pairs_vp], vp.wo[pairs_vp], photons.direction[pairs_ph])
    return vp.beta[pairs_vp] * f * photons.power[pairs_ph]


def photon_map_radiance(scene: Scene, pm: PhotonMap, vp: VisiblePoints, *, k: int | None = None,
                        radius: float | None = None) -> np.ndarray:
    """Radiance at the visible points: emission on the way plus the photon density estimate.

    Parameters
    ----------
    scene : Scene
    pm : PhotonMap
    vp : VisiblePoints
    k : int, optional
        Use the ``k`` nearest photons; the disk radius is the distance to the
        k-th (Jensen's estimate).
    radius : float, optional
        Use every photon within ``radius`` (a box kernel of that radius).
        Exactly one of ``k`` and ``radius``.

    Returns
    -------
    ndarray, shape (n, 3)
        ``emitted + sum_p beta f(wo, wi_p) Phi_p / (pi r^2)``.
    """
    if (k is None) == (radius is None):
        raise ValueError("give exactly one of k (nearest photons) and radius (fixed gather radius)")
    if k is not None:
        k = check_count(k, "k")
    else:
        radius = check_positive(radius, "radius")
    out = vp.emitted.copy()
    rows = np.flatnonzero(vp.valid)
    if pm.tree is None or rows.size == 0:
        return out
    ph = pm.photons
    if k is not None:
        chunks = [rows[s:s + POINTS_PER_CHUNK] for s in range(0, rows.size, POINTS_PER_CHUNK)]
    else:
        # chunks of about PAIRS_PER_CHUNK pairs, from the number of photons around each point
        n_near = pm.tree.query_ball_point(vp.position[rows], radius, return_length=True)
        cuts = np.arange(1, 1 + n_near.sum() // PAIRS_PER_CHUNK) * PAIRS_PER_CHUNK
        chunks = [c for c in np.split(rows, np.unique(np.searchsorted(np.cumsum(n_near), cuts))) if c.size]
    for r in chunks:
        x = vp.position[r]
        if k is not None:
            kk = min(k, ph.n)
            dist, j = pm.tree.query(x, k=kk)
            dist, j = dist.reshape(r.size, kk), j.reshape(r.size, kk)
            r2 = dist[:, -1] ** 2
            pv = np.repeat(r, kk)
            contrib = _gather(scene, r, vp, ph, pv, j.ravel()).reshape(r.size, kk, 3).sum(axis=1)
        else:
            pairs = cKDTree(x).sparse_distance_matrix(pm.tree, radius, output_type="coo_matrix")
            contrib = np.zeros((r.size, 3))
            if pairs.nnz:
                c = _gather(scene, r, vp, ph, r[pairs.row], pairs.col)
                for ch in range(3):
                    contrib[:, ch] = np.bincount(pairs.row, c[:, ch], minlength=r.size)
            r2 = np.full(r.size, radius * radius)
        with np.errstate(divide="ignore", invalid="ignore"):
            out[r] += np.where(r2[:, None] > 0, contrib / (np.pi * r2[:, None]), 0.0)
    return out


# ---------------------------------------------------------------------------
# The registered method

#: Nearest photons gathered by ``photon`` when neither ``k`` nor ``radius`` is given.
DEFAULT_K = 100


def check_photon_options(options) -> None:
    """Options shared by ``photon`` and ``sppm``: clear errors for bad values,
    and counts whose memory cannot fit refused before anything is traced
    (``sppm``'s photons are per iteration: more than one photon map holds is
    refused too, since more iterations reach any photon count)."""
    photons = check_photon_budget(options["photons"], "photons")
    if options.get("radius") is not None:
        check_positive(options["radius"], "radius")
    if options.get("k") is not None:
        k = check_count(options["k"], "k")
        pairs = float(min(k, photons)) * POINTS_PER_CHUNK
        check_budget("k", k, pairs * BYTES_PER_PAIR, per_unit=POINTS_PER_CHUNK * BYTES_PER_PAIR,
                     what=f"the k nearest photons of {POINTS_PER_CHUNK} visible points at once")
        if options.get("radius") is not None:
            raise ValueError("give exactly one of k (nearest photons) and radius (fixed gather radius)")
    if "alpha" in options:
        alpha = options["alpha"]
        if isinstance(alpha, bool) or not isinstance(alpha, (int, float, np.floating, np.integer)):
            raise TypeError(f"alpha must be a real number in (0, 1); got {type(alpha).__name__}")
        if not 0.0 < float(alpha) < 1.0:
            raise ValueError(f"alpha must lie in (0, 1); got {alpha}")


def check_photon_method_scene(scene, options) -> None:
    """``check_scene`` of ``photon`` and ``sppm``: some emitter, no mixed
    delta/non-delta materials, valid options."""
    check_photon_options(options)
    check_photon_scene(scene)
    mixed = [f"{scene.material_names[m]!r} ({type(scene.materials[m]).__name__})"
             for m in np.unique(scene.prim_material)
             if getattr(scene.materials[m], "has_delta", False) and not getattr(scene.materials[m], "is_delta", False)]
    if mixed:
        raise ValueError(f"photon mapping here follows camera rays through pure delta BSDFs only; scene "
                         f"{scene.name!r} has material(s) with a delta and a non-delta lobe: {', '.join(mixed)}")


def _prepare_photon(scene, options, rng) -> PhotonMap:
    return build_photon_map(scene, options["photons"], rng=rng)


def run_photon_batch(job: BatchJob) -> BatchResult:
    """``run_batch`` of ``photon``: visible points of this batch's camera rays, density estimate."""
    _, o, d, _ = camera_rays(job)
    o = np.ascontiguousarray(o)
    vp = visible_points(job.scene, job.tracer, o, d, rng=job.rng)
    k, radius = job.options["k"], job.options["radius"]
    if k is None and radius is None:
        k = DEFAULT_K
    out = photon_map_radiance(job.scene, job.prepared, vp, k=k, radius=radius)
    return camera_result(job, out, vp.rays, "photon")


register(Method(
    "photon", "camera", run_photon_batch,
    "photon mapping (Jensen 1996): photons from the lights, density estimation at the first diffuse hit",
    options=dict(photons=1 << 17, k=None, radius=None),
    prepare=_prepare_photon, check_scene=check_photon_method_scene, uses_max_depth=False,
    lecture=("yes", "no"), chart_row="Photon Mapping",
    # the chart: more photons at a fixed gather radius (the blur stays)
    knob=scaled_knob("photons (x 2048, radius 40)", "photon", {"photons": (2048, 1)}, {"spp": 4, "radius": 40.0}),
    theory=("no", "no", "at a fixed radius the density estimate keeps its blur whatever the photon count: "
                        "photon mapping is consistent only progressively (sppm)"),
    stream_dims=2))
