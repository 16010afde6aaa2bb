"""Integrators and the :func:`render` entry point (layer 5).

Every integrator is a wavefront loop over the *bounces* of all paths of a batch
at once: intersect every active ray, add emission, connect to a light, sample
the BSDF, compact the survivors (``np.take``), repeat. There is no Python loop
over rays or pixels; the only loops are over bounces, over the handful of
materials of a scene and over spp batches.

Integrators (the lecture's 'Previous Methods', 'Direct vs Indirect
Illumination' and 'Multiple Importance Sampling' slides):

=================  ==========================================================
``direct``         one-bounce direct lighting, light sampling and BSDF
                   sampling combined by MIS (``heuristic``: power or balance)
``direct_light``   one-bounce direct lighting by light sampling only
``direct_bsdf``    one-bounce direct lighting by BSDF sampling only
``path``           path tracing with next-event estimation and MIS ('backward
                   path tracing + connect to light'); Russian roulette when
                   ``max_depth`` is None (unbiased), fixed depth otherwise
                   (biased: longer paths are missing)
``path_bsdf``      path tracing that finds emitters only by chance ('backward
                   path tracing': fails for point lights, noisy for small ones)
``albedo``         first-hit albedo (AOV)
``normal``         first-hit world shading normal, facing the camera (AOV)
``depth``          first-hit distance from the camera (AOV; 0 on a miss)
``raster``         first hit shaded like a rasterizer: emission plus each area
                   light as an unshadowed point light at its centre ('Direct vs
                   Rasterization': one ray per sample, no shadows, no bounces)
=================  ==========================================================

Depth convention (CORNELL.md): a path of ``k`` segments has depth ``k``;
``max_depth = 1`` shows emitters seen directly, ``2`` adds direct
illumination, ``3`` one indirect bounce, and so on. The ``direct*``
integrators are depth 2.
"""
from __future__ import annotations

import math
import time
import uuid
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np

from ._validation import as_rng, check_choice, check_count
from .estimators import balance_heuristic, power_heuristic
from .geometry import Frame
from .samplers import SAMPLERS, pixel_samples
from .scene import Scene
from .tracer import Tracer
from .bsdf import Lambertian
from .warps import (_rectangle_soa_frame, _rectangle_solid_angle_soa, _spherical_rectangle_soa,
                    _square_to_cosine_hemisphere_unchecked, area_to_solid_angle_pdf,
                    square_to_uniform_parallelogram)

__all__ = ["INTEGRATORS", "HEURISTICS", "LIGHT_SAMPLING", "Render", "render", "trace_paths"]

#: Integrator names accepted by :func:`render`.
INTEGRATORS = ("path", "path_bsdf", "direct", "direct_light", "direct_bsdf",
               "albedo", "normal", "depth", "raster")
#: How next-event estimation samples a point on a quad light: uniformly by
#: area (then converted to solid angle, ``p_A r^2 / cos theta_l``), or
#: uniformly in the solid angle it subtends (Urena, Fajardo and King 2013;
#: rectangles only; density ``1 / S``, no ``r^2 / cos`` factor).
LIGHT_SAMPLING = ("area", "solid_angle")
#: MIS heuristics by name.
HEURISTICS = {"power": power_heuristic, "balance": balance_heuristic}
_AOVS = ("albedo", "normal", "depth", "raster")
#: Paths per spp batch when ``batch_spp`` is not given: big enough that per-bounce
#: overhead is small, small enough that two processes do not fight over the
#: shared cache and memory bandwidth (measured: 1.8x with 2 workers at 2^16, 1.4x at 2^18).
PATHS_PER_BATCH = 1 << 16
#: Russian roulette starts once a path has this many segments.
RR_START_DEPTH = 3
#: Safety cap on the number of segments under Russian roulette: a path
#: survives each step with probability <= 0.95, so reaching it has
#: probability <= 0.95^1021 < 1e-22 (negligible bias).
RR_MAX_DEPTH = 1024
#: Sampler dimensions per path: pixel position (2), then light (2) and BSDF
#: (2) samples of the first vertex; later vertices use iid random numbers.
SAMPLER_DIM = 6


@dataclass(frozen=True, eq=False)
class Render:
    """The result of :func:`render`.

    Attributes
    ----------
    image : ndarray, shape (H, W, 3), float64
        Mean linear radiance per pixel (row 0 at the top).
    spp : int
        Samples per pixel actually completed (fewer than asked if interrupted).
    seconds : float
        Wall-clock time.
    interrupted : bool
        True if Ctrl-C (``KeyboardInterrupt``) stopped the render early.
    variance : ndarray, shape (H, W, 3), or None
        Per-sample variance of each pixel's radiance (``ddof = 1``), None for
        fewer than 2 spp. Under iid pixel sampling ``variance / spp`` is the
        variance of the pixel mean; stratified and QMC samples are not
        independent, so there it is only an upper-bound-like indicator.
    rays : int
        Rays traced (camera, extension and shadow rays).
    scene, integrator, sampler, res, max_depth, heuristic, batch_spp, workers, precision
        The settings used (``res`` is ``(W, H)``).
    """

    image: np.ndarray
    spp: int
    seconds: float
    interrupted: bool
    variance: np.ndarray | None
    rays: int
    scene: str
    integrator: str
    sampler: str
    res: tuple
    max_depth: int | None
    heuristic: str
    batch_spp: int
    workers: int
    precision: str

    @property
    def standard_error(self) -> np.ndarray | None:
        """``sqrt(variance / spp)`` per pixel (iid model), or None."""
        if self.variance is None:
            return None
        return np.sqrt(self.variance / self.spp)

    @property
    def paths_per_second(self) -> float:
        """Camera paths (pixel samples) per second."""
        w, h = self.res
        return w * h * self.spp / self.seconds if self.seconds > 0 else float("nan")


# ---------------------------------------------------------------------------
# One wavefront of paths

@dataclass(frozen=True)
class _Mode:
    nee: bool           # connect to lights (next-event estimation)
    bsdf_hits: bool     # count emission found by BSDF sampling after the first segment
    mis: bool           # weight the two strategies by the heuristic (else weight 1)
    max_depth: int | None
    heuristic: str


_MODES = {
    "direct": (True, True, True),
    "direct_light": (True, False, False),
    "direct_bsdf": (False, True, False),
    "path": (True, True, True),
    "path_bsdf": (False, True, False),
}


class _Shading:
    """Per-scene constant tables used while shading (built once per batch)."""

    def __init__(self, scene: Scene, tracer: Tracer, light_sampling: str = "area"):
        self.scene = scene
        self.tracer = tracer
        self.light_sampling = check_choice(light_sampling, "light_sampling", LIGHT_SAMPLING)
        # per light (x, y, z, l1, l2) of solid-angle sampling (ValueError for a non-rectangle)
        self.rect = [] if light_sampling == "area" else \
            [_rectangle_soa_frame(e1, e2) for e1, e2 in zip(scene.light_edge1, scene.light_edge2)]
        self.eps = float(scene.ray_epsilon)
        self.materials = scene.materials
        # Glass-like materials know inside from outside by the sign of wo.y: never flip them.
        self.two_sided = np.array([_flips(m) for m in scene.materials])
        self.delta = np.array([bool(getattr(m, "is_delta", False)) for m in scene.materials])
        self.light_area = scene.light_area
        self.light_normal = scene.light_normal
        self.env = scene.environment
        self.n_emitters = scene.n_lights + (1 if self.env is not None else 0)
        self.select_pdf = 1.0 / self.n_emitters if self.n_emitters else 0.0

    def emission(self, prim, p, d):
        """Emitted radiance towards ``-d`` of the hit primitives, (n, 3)."""
        scene = self.scene
        le = np.take(scene.prim_emission, prim, axis=0)
        if not np.any(le):
            return le
        n_g = self.tracer.normals(prim, p)
        front = np.einsum("ij,ij->i", n_g, d) < 0.0
        le = np.where((front | np.take(scene.prim_two_sided_emission, prim))[:, None], le, 0.0)
        if scene.checker_period is not None:
            c = (np.floor(p[:, 0] / scene.checker_period) + np.floor(p[:, 2] / scene.checker_period)) % 2.0
            le = le * c[:, None]
        return le

    def light_pdf_hit(self, prim, origins, points):
        """Solid-angle density with which NEE would have drawn these emitter hits."""
        light = np.take(self.scene.prim_light, prim)
        pdf = np.zeros(prim.shape[0])
        is_light = light >= 0
        if np.any(is_light) and self.rect:
            for k in np.unique(light[is_light]):
                sel = np.flatnonzero(light == k)
                pdf[sel] = self.rect_pdf(int(k), np.ascontiguousarray(origins[sel].T))
        elif np.any(is_light):
            li = light[is_light]
            pdf_area = self.select_pdf / np.take(self.light_area, li)
            pdf[is_light] = area_to_solid_angle_pdf(pdf_area, origins[is_light], points[is_light],
                                                    np.take(self.light_normal, li, axis=0))
        return pdf

    def rect_pdf(self, k, p):
        """Solid-angle density ``select_pdf / S`` of solid-angle sampling light
        ``k`` from the SoA points ``p`` (3, m); 0 behind the light or edge-on."""
        scene = self.scene
        s = _rectangle_solid_angle_soa(p, scene.light_origin[k], *self.rect[k])
        n = scene.light_normal[k]
        d = p - scene.light_origin[k][:, None]
        front = (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]) > 0.0
        ok = front & (s > 0.0)
        return np.where(ok, self.select_pdf / np.where(ok, s, 1.0), 0.0)

    def rect_sample(self, k, p, u0, u1):
        """Solid-angle sample of light ``k`` from SoA points ``p``: ``(w (3, m), dist, pdf)``."""
        scene = self.scene
        w, dist, s = _spherical_rectangle_soa(u0, u1, p, scene.light_origin[k], *self.rect[k])
        n = scene.light_normal[k]
        d = p - scene.light_origin[k][:, None]
        front = (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]) > 0.0
        ok = front & (s > 0.0)
        return w, dist, np.where(ok, self.select_pdf / np.where(ok, s, 1.0), 0.0)

    def sample_emitters(self, p, u):
        """Next-event estimation: a point on an emitter for every shading point.

        Returns ``(wi, dist, le, pdf)``: unit world direction, distance (inf
        for the environment), emitted radiance towards ``p`` and the solid
        angle density (0 where the sample cannot contribute).
        """
        n = p.shape[0]
        n_em = self.n_emitters
        scene = self.scene
        u = np.array(u, dtype=np.float64)
        if n_em > 1:
            k = np.minimum((u[:, 0] * n_em).astype(np.int64), n_em - 1)
            u[:, 0] = np.clip(u[:, 0] * n_em - k, 0.0, 1.0)
        else:
            k = np.zeros(n, dtype=np.int64)
        wi = np.zeros((n, 3))
        wi[:, 1] = 1.0
        dist = np.full(n, np.inf)
        le = np.zeros((n, 3))
        pdf = np.zeros(n)
        on_light = k < scene.n_lights
        if np.any(on_light) and self.rect:
            for j in np.unique(k[on_light]):
                sel = np.flatnonzero(k == j)
                w, r, pdf_l = self.rect_sample(int(j), np.ascontiguousarray(p[sel].T), u[sel, 0], u[sel, 1])
                wi[sel] = w.T
                dist[sel] = r
                le[sel] = np.where((pdf_l > 0.0)[:, None], scene.light_radiance[j], 0.0)
                pdf[sel] = pdf_l
        elif np.any(on_light):
            li = k[on_light]
            x = square_to_uniform_parallelogram(u[on_light], np.take(scene.light_origin, li, axis=0),
                                                np.take(scene.light_edge1, li, axis=0),
                                                np.take(scene.light_edge2, li, axis=0))
            v = x - p[on_light]
            d2 = np.einsum("ij,ij->i", v, v)
            r = np.sqrt(d2)
            w = v / np.maximum(r, 1e-300)[:, None]
            cos_l = -np.einsum("ij,ij->i", np.take(self.light_normal, li, axis=0), w)
            front = cos_l > 0.0
            pa = self.select_pdf / np.take(self.light_area, li)
            pdf_l = np.where(front, area_to_solid_angle_pdf(pa, p[on_light], x, np.take(self.light_normal, li, axis=0)), 0.0)
            wi[on_light] = w
            dist[on_light] = r
            le[on_light] = np.where(front[:, None], np.take(scene.light_radiance, li, axis=0), 0.0)
            pdf[on_light] = pdf_l
        if self.env is not None and not np.all(on_light):
            sel = ~on_light
            w_env, pdf_env = self.env.sample(u[sel])
            wi[sel] = w_env
            le[sel] = self.env.radiance(w_env)
            pdf[sel] = self.select_pdf * pdf_env
        return wi, dist, le, pdf

    def chosen_light(self, u):
        """Light index that :meth:`sample_emitters` picks for each ``u`` (-1: the environment)."""
        n_em = self.n_emitters
        if n_em > 1:
            k = np.minimum((np.asarray(u)[:, 0] * n_em).astype(np.int64), n_em - 1)
        else:
            k = np.zeros(np.shape(u)[0], dtype=np.int64)
        return np.where(k < self.scene.n_lights, k, -1)

    def environment(self, d):
        return self.env.radiance(d)

    def environment_pdf(self, d):
        return self.select_pdf * self.env.pdf(d)


def _flips(material) -> bool:
    """Whether the caller flips the shading normal towards ``wo`` (two-sided):
    every material except those light may cross (``BSDF.transmissive``), which
    tell inside from outside by the sign of ``wo.y``."""
    return not getattr(material, "transmissive", False)


def _dot(a, b):
    """Row-wise dot products of SoA vectors (3, n) -> (n,)."""
    return np.einsum("ij,ij->j", a, b)


class _Wavefront:
    """Per-scene tables of the SoA wavefront loop (built once per :func:`trace_paths`).

    Rays, throughputs and shading frames are structure-of-arrays ``(3, n)``
    float64 (the layout measured to pay for per-component passes); the
    intersection kernel converts to its own precision. Materials are
    dispatched on contiguous slices: the rays are sorted by material once per
    bounce (a stable radix sort of small integer codes), so every material is
    called once per bounce on a slice, with no gather or scatter.
    """

    def __init__(self, scene: Scene, tracer: Tracer, sh: _Shading):
        self.n_mat = len(scene.materials)
        n_prim = scene.n_triangles + scene.n_spheres
        code = np.empty(n_prim + 1, dtype=np.int16 if self.n_mat < 32000 else np.int64)
        code[:n_prim] = scene.prim_material
        code[n_prim] = self.n_mat                   # prim -1 (a miss) takes the last entry
        self.mat_code = code
        self.emits = np.append(np.any(scene.prim_emission > 0, axis=1), False)
        self.flips = sh.two_sided
        self.delta = sh.delta
        self.n_tri = scene.n_triangles
        self.spheres = scene.n_spheres > 0
        if not self.spheres and self.n_tri:
            # Triangles have constant normals: their shading frames, for both
            # orientations, are a table indexed by 2 * prim + flipped.
            nrm = tracer.triangle_normal
            both = np.stack([nrm, -nrm], axis=1).reshape(-1, 3)
            fr = Frame(both)
            self.frame_s = np.ascontiguousarray(fr.s.T)
            self.frame_n = np.ascontiguousarray(fr.n.T)
            self.frame_t = np.ascontiguousarray(fr.t.T)
        # One parallelogram light and nothing else to sample: fused NEE.
        self.single_quad = scene.n_lights == 1 and scene.environment is None
        if self.single_quad:
            self.light_affine = np.stack([scene.light_origin[0], scene.light_edge1[0],
                                          scene.light_edge2[0]], axis=1)      # columns o, e1, e2
            self.light_n = scene.light_normal[0]
            self.light_pa = sh.select_pdf / float(scene.light_area[0])
            self.light_le = scene.light_radiance[0][:, None]
        # Every material Lambertian, triangles only, one quad light: the trusted
        # loop of _trace_lambertian (no material sort, no BSDF calls).
        self.lambertian = (self.single_quad and not self.spheres and self.n_tri > 0
                           and all(type(m) is Lambertian for m in scene.materials))
        if self.lambertian:
            # (s, n, t) of the unflipped frame of every triangle, stacked (9, T)
            self.frame9 = np.ascontiguousarray(np.concatenate(
                [self.frame_s[:, 0::2], self.frame_n[:, 0::2], self.frame_t[:, 0::2]]))
            albedo = np.array([m.albedo for m in scene.materials]).T          # (3, M)
            self.albedo = np.ascontiguousarray(albedo[:, scene.prim_material])   # (3, T)
            # albedo / pi * Le of the light, per triangle: NEE's f Le
            self.f_le = np.ascontiguousarray(self.albedo / np.pi * self.light_le)
            self.black = ~np.any(self.albedo > 0.0, axis=0)

    def geometric_normals(self, tracer, prim, p):
        if not self.spheres:
            return np.take(tracer.triangle_normal_soa, prim, axis=1)
        return np.ascontiguousarray(tracer.normals(prim, p.T).T)

    def frames(self, prim, ng, flip):
        """Shading frames ``(s, n, t)``, SoA (3, m) each, normal flipped where ``flip``."""
        if not self.spheres:
            key = 2 * prim + flip
            return (np.take(self.frame_s, key, axis=1), np.take(self.frame_n, key, axis=1),
                    np.take(self.frame_t, key, axis=1))
        fr = Frame(np.where(flip, -ng, ng).T)
        return fr.s.T, fr.n.T, fr.t.T

    def sample_light(self, sh, p, u):
        """NEE sample for every shading point: ``(w, dist, le, pdf, light)``, SoA."""
        m = p.shape[1]
        if self.single_quad and sh.rect:
            w, r, pdf = sh.rect_sample(0, p, u[0], u[1])
            return w, r, np.broadcast_to(self.light_le, (3, m)), pdf, np.zeros(m, dtype=np.int64)
        if self.single_quad:
            # uniform point on the parallelogram, o + u0 e1 + u1 e2, written
            # out: as a (3, 3) @ (3, m) product it is a dgemm that OpenBLAS
            # threads, which on a busy machine cost 12 ms per call instead
            # of 0.1 ms (half of a whole 256-spp Cornell render's time)
            a = self.light_affine
            v = a[:, 1:2] * u[0]
            v += a[:, 2:3] * u[1]
            v += a[:, 0:1]
            v -= p
            d2 = _dot(v, v)
            r = np.sqrt(d2)
            w = v / np.maximum(r, 1e-300)
            cos_l = -np.einsum("i,im->m", self.light_n, w)     # no BLAS (see above)
            # area density to solid angle: p_A r^2 / cos_l (0 behind or edge-on)
            with np.errstate(divide="ignore", invalid="ignore"):
                pdf = np.where(cos_l > 0.0, self.light_pa * d2 / cos_l, 0.0)
            le = np.broadcast_to(self.light_le, (3, m))
            return w, r, le, pdf, np.zeros(m, dtype=np.int64)
        wi, dist, le, pdf = sh.sample_emitters(p.T, u.T)
        light = sh.chosen_light(u.T)
        return wi.T, dist, le.T, pdf, light


def trace_paths(scene: Scene, origins, directions, u, *, integrator: str = "path",
                max_depth: int | None = None, heuristic: str = "power", rng=None,
                tracer: Tracer | None = None, light_sampling: str = "area", rr_depth: int | None = None):
    """Radiance carried back along each camera ray: the wavefront core of :func:`render`.

    Parameters
    ----------
    scene : Scene
    origins, directions : ndarray, shape (n, 3)
        Camera rays (unit directions).
    u : ndarray, shape (n, k), k >= 2
        Sample dimensions of the first vertex: ``u[:, 0:2]`` the light
        sample, ``u[:, 2:4]`` the BSDF sample (missing ones are drawn from
        ``rng``). Later vertices use ``rng``.
    integrator : str
        One of the light-transport integrators (not the AOVs).
    max_depth : int or None
        Maximum number of path segments; None: Russian roulette.
    heuristic : {'power', 'balance'}
    rng : Generator-like
    tracer : Tracer, optional
        Reuse a tracer (its precision); default float32.
    light_sampling : {'area', 'solid_angle'}
        How NEE samples quad lights (:data:`LIGHT_SAMPLING`); the MIS weight
        of a light hit by BSDF sampling uses the same density.
    rr_depth : int, optional
        Russian roulette starts once a path has this many segments (default
        :data:`RR_START_DEPTH`); any value is unbiased, later is more work
        and less variance.

    Returns
    -------
    radiance : ndarray, shape (n, 3), float64
    rays : int
        Rays traced (including the camera rays and shadow rays).

    Notes
    -----
    At vertex ``x_k`` (hit by segment ``k``) with throughput ``beta``:

    * emission ``Le(x_k -> x_{k-1})`` is added with weight 1 for ``k = 1``
      or after a delta bounce, else with the MIS weight
      ``w(p_bsdf, p_light)`` (0 for ``direct_light``);
    * NEE (if ``k + 1 <= max_depth``): an emitter point drawn with density
      ``p_light`` (area density converted to solid angle,
      ``p_A r^2 / |cos theta_l|``), one shadow ray, adding
      ``beta f cos Le w(p_light, p_bsdf) / p_light``;
    * the BSDF is sampled, ``beta *= f cos / p_bsdf``; with Russian roulette
      a path survives with ``q = min(0.95, max(beta))`` and ``beta /= q``.

    The shading normal of two-sided materials is flipped to face ``wo``
    before the BSDF is called (local frame: normal +y). This is the one-sample
    MIS estimator of Veach and Guibas [1]_ (eq. 8); with ``w = 1`` for one
    strategy and 0 for the other it reduces to that single strategy.

    References
    ----------
    .. [1] E. Veach, L. J. Guibas, "Optimally Combining Sampling Techniques for
       Monte Carlo Rendering", SIGGRAPH 1995.
    .. [2] M. Pharr, W. Jakob, G. Humphreys, "Physically Based Rendering:
       From Theory to Implementation", 4th ed., MIT Press 2023, ch. 13.
    """
    check_choice(integrator, "integrator", tuple(_MODES))
    check_choice(heuristic, "heuristic", tuple(HEURISTICS))
    rng = as_rng(rng)
    rr_start = RR_START_DEPTH if rr_depth is None else check_count(rr_depth, "rr_depth")
    nee, bsdf_hits, mis = _MODES[integrator]
    if integrator.startswith("direct"):
        max_depth = 2
    weight_fn = HEURISTICS[heuristic]
    tracer = tracer if tracer is not None else Tracer(scene)
    sh = _Shading(scene, tracer, light_sampling)
    wf = _Wavefront(scene, tracer, sh)
    nee = nee and sh.n_emitters > 0
    u = np.asarray(u, dtype=np.float64)
    limit = RR_MAX_DEPTH if max_depth is None else max_depth
    if wf.lambertian and _LAMBERTIAN_FAST:
        return _trace_lambertian(sh, wf, tracer, origins, directions, u, rng, limit,
                                 rr_start if max_depth is None else None,
                                 nee, bsdf_hits, mis, weight_fn)
    o = np.array(np.asarray(origins, dtype=np.float64).T, order="C")
    d = np.array(np.asarray(directions, dtype=np.float64).T, order="C")
    n_all = o.shape[1]
    radiance = np.zeros((3, n_all))
    idx = np.arange(n_all)
    beta = np.ones((3, n_all))
    prev_pdf = np.full(n_all, np.inf)          # inf: camera ray or delta bounce (MIS weight 1)
    rays = 0
    materials = sh.materials
    eps = sh.eps
    k = 0
    while idx.size and k < limit:
        k += 1
        n = idx.size
        t, prim = tracer.closest_soa(o, d)
        rays += n
        mat = np.take(wf.mat_code, prim)
        # -- rays that left the scene: environment emission
        if sh.env is not None:
            miss = np.flatnonzero(prim < 0)
            if miss.size:
                dm = d[:, miss].T
                le = sh.environment(dm)
                w = _emission_weight(k, prev_pdf[miss], lambda: sh.environment_pdf(dm),
                                     nee, bsdf_hits, mis, weight_fn)
                _accumulate(radiance, idx[miss], beta[:, miss] * le.T * w)
        # -- sort the hits by material (misses last) and drop the misses
        order = np.argsort(mat, kind="stable")
        counts = np.bincount(mat, minlength=wf.n_mat + 1)
        m = n - int(counts[-1])
        if m == 0:
            break
        order = order[:m]
        o, d, beta = np.take(o, order, 1), np.take(d, order, 1), np.take(beta, order, 1)
        idx, prev_pdf = np.take(idx, order), np.take(prev_pdf, order)
        t, prim, mat = np.take(t, order), np.take(prim, order), np.take(mat, order)
        ends = np.cumsum(counts[:-1])
        groups = [(mi, int(ends[mi] - counts[mi]), int(ends[mi])) for mi in range(wf.n_mat) if counts[mi]]
        p = d * t
        p += o
        # -- emission at the hit
        _add_hit_emission(wf, sh, k, o, d, p, prim, idx, beta, prev_pdf, radiance,
                          nee, bsdf_hits, mis, weight_fn)
        if k >= limit:
            break
        # -- shading frame: flip two-sided materials' normal towards wo
        ng = wf.geometric_normals(tracer, prim, p)
        wo = -d
        flip = np.take(wf.flips, mat) & (_dot(ng, wo) < 0.0)
        fs, fn, ft = wf.frames(prim, ng, flip)
        wo_l = np.stack([_dot(wo, fs), _dot(wo, fn), _dot(wo, ft)])
        if k == 1 and u.shape[1] >= 4:
            uu = np.ascontiguousarray(np.take(u, idx, axis=0)[:, :4].T)
        else:
            uu = rng.random((4, m))
        # -- next-event estimation (adds paths of k + 1 segments)
        if nee and k + 1 <= limit:
            rays += _next_event(sh, wf, tracer, groups, p, ng, (fs, fn, ft), wo_l, prim, beta,
                                uu[0:2], radiance, idx, mis, weight_fn)
        # -- continue the path by BSDF sampling?
        if k + 1 > limit or (k + 1 == limit and not bsdf_hits):
            break
        wi_l = np.empty((3, m))
        weight = np.empty((3, m))
        pdf = np.empty(m)
        for mi, a, b in groups:
            s = materials[mi].sample(wo_l[:, a:b].T, uu[2:4, a:b].T)
            wi_l[:, a:b] = s.wi.T
            weight[:, a:b] = s.weight.T
            pdf[a:b] = np.inf if wf.delta[mi] else s.pdf
        beta *= weight
        wi = fs * wi_l[0]
        wi += fn * wi_l[1]
        wi += ft * wi_l[2]
        bmax = beta.max(axis=0)
        alive = bmax > 0.0
        if max_depth is None and k >= rr_start:
            q = np.minimum(bmax, 0.95)
            survive = rng.random(m) < q
            beta /= np.where(survive, q, 1.0)
            alive &= survive
        side = np.sign(_dot(wi, ng))
        side *= eps
        o = ng * side
        o += p
        d = wi
        prev_pdf = pdf
        if not alive.all():
            keep = np.flatnonzero(alive)
            idx, o, d = np.take(idx, keep), np.take(o, keep, 1), np.take(d, keep, 1)
            beta, prev_pdf = np.take(beta, keep, 1), np.take(prev_pdf, keep)
    return np.ascontiguousarray(radiance.T), rays


#: Use :func:`_trace_lambertian` where it applies (tests switch it off to
#: compare it with the general loop).
_LAMBERTIAN_FAST = True


def _trace_lambertian(sh, wf, tracer, origins, directions, u, rng, limit, roulette, nee, bsdf_hits, mis,
                      weight_fn):
    """The loop of :func:`trace_paths` for scenes of Lambertian triangles lit by one quad light.

    The same estimator as the general loop (the same sample dimensions, the
    same random-number stream layout, the same MIS weights, Russian roulette
    and shadow rays), with the BSDF written out: ``f = albedo / pi``,
    ``p = cos theta / pi`` (so the sampling weight is ``albedo``), sampled by
    Malley's method through the warps' unchecked kernel on arrays built here.
    Because no material needs its own call, the rays are not sorted by
    material; the per-ray state (origin, direction, throughput, previous
    pdf) lives in one ``(10, n)`` array, so compaction is one ``np.take``.
    The shading frame is the triangle's unflipped frame with the normal's
    sign ``sgn = sign(wo . n_g)`` applied to the local ``y`` only (the
    cosine-weighted density is symmetric in ``x`` and ``z``, so which of the
    two tangent orientations is used does not change the distribution).
    """
    o = np.asarray(origins, dtype=np.float64).T
    d = np.asarray(directions, dtype=np.float64).T
    n_all = o.shape[1]
    radiance = np.zeros((3, n_all))
    idx = np.arange(n_all)
    # rows: origin (3), direction (3), beta (3), previous pdf; in the ray
    # geometry's precision (the tracer converts to it anyway), radiance float64
    dt = tracer.dtype
    frame9 = wf.frame9.astype(dt)
    state = np.empty((10, n_all), dtype=dt)
    state[0:3] = o
    state[3:6] = d
    state[6:9] = 1.0
    state[9] = np.inf                      # camera ray: MIS weight 1
    eps = sh.eps
    rays = 0
    k = 0
    while idx.size and k < limit:
        k += 1
        t, prim = tracer.closest_soa(state[0:3], state[3:6])
        t = t.astype(dt, copy=False)
        rays += idx.size
        if prim.min() < 0:                 # drop the rays that left the scene (no environment)
            keep = np.flatnonzero(prim >= 0)
            if keep.size == 0:
                break
            state, idx = np.take(state, keep, 1), np.take(idx, keep)
            t, prim = np.take(t, keep), np.take(prim, keep)
        m = idx.size
        o, d, beta, prev_pdf = state[0:3], state[3:6], state[6:9], state[9]
        p = d * t
        p += o
        _add_hit_emission(wf, sh, k, o, d, p, prim, idx, beta, prev_pdf, radiance,
                          nee, bsdf_hits, mis, weight_fn)
        if k >= limit:
            break
        frame = np.take(frame9, prim, axis=1)
        fs, fn, ft = frame[0:3], frame[3:6], frame[6:9]
        sgn = np.sign(_dot(d, fn))
        np.negative(sgn, out=sgn)          # sign(wo . n_g); 0 (grazing) gives f = 0
        if k == 1 and u.shape[1] >= 4:
            uu = np.ascontiguousarray(np.take(u, idx, axis=0)[:, :4].T)
        else:
            uu = rng.random((4, m))
        if nee and k + 1 <= limit:
            rays += _next_event_lambertian(sh, wf, tracer, p, fn, sgn, prim, beta, uu[0:2], radiance,
                                           idx, mis, weight_fn)
        if k + 1 > limit or (k + 1 == limit and not bsdf_hits):
            break
        x, y, z = _square_to_cosine_hemisphere_unchecked(uu[2], uu[3], np.float32)
        pdf = y * (1.0 / np.pi)
        ok = y > 0.0
        ok &= sgn != 0.0
        y *= sgn
        beta *= np.take(wf.albedo, prim, axis=1)
        beta *= ok
        wi = np.multiply(fs, x, out=state[3:6])        # d is not needed any more
        wi += fn * y
        wi += ft * z
        bmax = beta.max(axis=0)
        alive = bmax > 0.0
        if roulette is not None and k >= roulette:
            q = np.minimum(bmax, 0.95)
            survive = rng.random(m) < q
            beta /= np.where(survive, q, 1.0)
            alive &= survive
        # leave on wi's side of the surface: sign(wi . n_g) = sgn for a valid sample
        np.multiply(fn, sgn * eps, out=state[0:3])
        state[0:3] += p
        state[9] = pdf
        if not alive.all():
            keep = np.flatnonzero(alive)
            state, idx = np.take(state, keep, 1), np.take(idx, keep)
    return np.ascontiguousarray(radiance.T), rays


def _next_event_lambertian(sh, wf, tracer, p, fn, sgn, prim, beta, u_light, radiance, idx, mis, weight_fn):
    """NEE of :func:`_trace_lambertian`: ``beta (albedo / pi) Le cos_i w_light / p_light``
    over unoccluded samples, with ``p_bsdf = cos_i / pi``. Returns the shadow rays traced."""
    w, dist, _, pdf_l, _ = wf.sample_light(sh, p, u_light)
    cos_i = _dot(w, fn)
    cos_i *= sgn                            # local wi.y in the flipped frame
    ok = cos_i > 0.0
    ok &= pdf_l > 0.0
    ok &= ~np.take(wf.black, prim)
    go = np.flatnonzero(ok)
    if go.size == 0:
        return 0
    cg, plg, pg = np.take(cos_i, go), np.take(pdf_l, go), np.take(prim, go)
    scale = cg / plg
    if mis:
        scale *= weight_fn(plg, cg * (1.0 / np.pi))
    contrib = np.take(beta, go, 1)
    contrib *= np.take(wf.f_le, pg, 1)
    contrib *= scale
    side = np.take(sgn, go)
    origin, d_shadow, tmax = _shadow_rays(np.take(p, go, 1), np.take(fn, go, 1), side, np.take(w, go, 1),
                                          np.take(dist, go), sh.eps)
    keys = tracer.shadow_keys(pg, side, np.zeros(go.size, dtype=np.int64))
    blocked = tracer.occluded_soa(origin, d_shadow, tmax, keys)
    vis = np.flatnonzero(~blocked)
    _accumulate(radiance, np.take(idx, np.take(go, vis)), np.take(contrib, vis, 1))
    return int(go.size)


def _add_hit_emission(wf, sh, k, o, d, p, prim, idx, beta, prev_pdf, radiance, nee, bsdf_hits, mis,
                      weight_fn):
    """Add the emission found by the rays of segment ``k`` (SoA arrays) at their
    hits ``p``, weighted by throughput ``beta`` and its MIS weight."""
    lit = np.flatnonzero(np.take(wf.emits, prim))
    if lit.size:
        pl, dl, ol = p[:, lit].T, d[:, lit].T, o[:, lit].T
        le = sh.emission(prim[lit], pl, dl)
        w = _emission_weight(k, prev_pdf[lit], lambda: sh.light_pdf_hit(prim[lit], ol, pl),
                             nee, bsdf_hits, mis, weight_fn)
        _accumulate(radiance, idx[lit], beta[:, lit] * le.T * w)


def _emission_weight(k, prev_pdf, light_pdf, nee, bsdf_hits, mis, weight_fn):
    """MIS weight of emission found by the ray of segment ``k`` (BSDF sampling)."""
    n = prev_pdf.shape[0]
    if k == 1:
        return np.ones(n)
    delta = np.isinf(prev_pdf)
    if not bsdf_hits:
        # Light sampling alone cannot draw emission seen through a delta bounce;
        # emission after a smooth bounce was already counted by NEE.
        return np.zeros(n)
    if not (nee and mis):
        return np.ones(n)
    w = weight_fn(prev_pdf, light_pdf())
    return np.where(delta, 1.0, w)


def _next_event(sh, wf, tracer, groups, p, ng, frame, wo_l, prim, beta, u_light, radiance, idx, mis,
                weight_fn):
    """Connect every shading point to an emitter; add the unoccluded contributions.

    SoA arrays (3, m), rows sorted by material (``groups``: material,
    start, end). Returns the number of shadow rays traced.
    """
    m = p.shape[1]
    w, dist, le, pdf_l, light = wf.sample_light(sh, p, u_light)
    fs, fn, ft = frame
    wi_l = np.stack([_dot(w, fs), _dot(w, fn), _dot(w, ft)])
    f = np.zeros((3, m))
    pdf_b = np.zeros(m)
    for mi, a, b in groups:
        if wf.delta[mi]:
            continue
        wo_g, wi_g = wo_l[:, a:b].T, wi_l[:, a:b].T
        f[:, a:b] = sh.materials[mi].eval(wo_g, wi_g).T
        if mis:
            pdf_b[a:b] = sh.materials[mi].pdf(wo_g, wi_g)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.abs(wi_l[1]) / np.where(pdf_l > 0, pdf_l, np.inf)
    if mis:
        scale *= weight_fn(pdf_l, pdf_b)
    contrib = beta * f
    contrib *= le
    contrib *= scale
    go = np.flatnonzero(contrib.max(axis=0) > 0.0)
    if go.size == 0:
        return 0
    ngo = np.take(ng, go, 1)
    wgo = np.take(w, go, 1)
    side = np.sign(_dot(wgo, ngo))
    origin, d_shadow, tmax = _shadow_rays(np.take(p, go, 1), ngo, side, wgo, np.take(dist, go), sh.eps)
    keys = tracer.shadow_keys(np.take(prim, go), side, np.take(light, go))
    blocked = tracer.occluded_soa(origin, d_shadow, tmax, keys)
    vis = go[~blocked]
    _accumulate(radiance, np.take(idx, vis), np.take(contrib, vis, 1))
    return int(go.size)


def _shadow_rays(p, ng, side, w, dist, eps):
    """Shadow rays from shading points ``p`` to light samples ``p + dist * w``.

    SoA arrays ``(3, m)``. The origin is offset by ``eps`` along the geometric
    normal ``ng`` (on the side ``side`` of the surface) to avoid
    self-intersection, and the ray is aimed from that *offset* origin at the
    light sample, stopping ``2 eps`` short of it (samples at infinite
    ``dist``, from an environment, keep ``w`` and ``tmax = inf``). Aiming along ``w`` from the
    offset origin instead would end past the light's plane whenever the light
    is seen at a grazing angle (``cos theta_light < 1/2`` for a surface facing
    it), so the emitter would occlude its own shadow ray.

    Returns ``(origin, direction, tmax)``.
    """
    origin = ng * (eps * side)
    origin += p
    if np.isfinite(dist).all():   # area lights only (the common case): fewer passes
        to_light = w * dist
        to_light += p
        to_light -= origin
        length = np.sqrt(_dot(to_light, to_light))
        to_light /= length
        length -= 2.0 * eps
        return origin, to_light, length
    far = ~np.isfinite(dist)  # environment samples: infinitely far, keep w
    to_light = w * np.where(far, 1.0, dist)
    to_light += p
    to_light -= origin
    length = np.sqrt(_dot(to_light, to_light))
    direction = np.where(far, w, to_light / length)
    return origin, direction, np.where(far, np.inf, length - 2.0 * eps)


def _accumulate(radiance, rows, value):
    """``radiance[:, rows] += value`` for distinct ``rows``, one channel at a
    time (1-D fancy indexing is several times faster than 2-D)."""
    for c in range(radiance.shape[0]):
        radiance[c, rows] += value[c]


# ---------------------------------------------------------------------------
# First-hit modes (AOVs and the rasterization-like shading)

def _first_hit(scene: Scene, tracer: Tracer, o, d, mode: str):
    """One ray per sample: albedo, normal, depth or rasterizer-like shading."""
    n = o.shape[0]
    hit = tracer.intersect(o, d)
    out = np.zeros((n, 3))
    rows = np.flatnonzero(hit.prim >= 0)
    if mode == "raster" and scene.environment is not None and rows.size < n:
        miss = hit.prim < 0
        out[miss] = scene.environment.radiance(d[miss])
    if rows.size == 0:
        return out
    prim, t = hit.prim[rows], hit.t[rows]
    p = o[rows] + t[:, None] * d[rows]
    if mode == "depth":
        out[rows] = t[:, None]
        return out
    n_g = tracer.normals(prim, p)
    facing = np.einsum("ij,ij->i", n_g, d[rows]) < 0.0
    n_s = np.where(facing[:, None], n_g, -n_g)
    if mode == "normal":
        out[rows] = n_s
        return out
    mat = np.take(scene.prim_material, prim)
    albedo = np.array([_material_albedo(m) for m in scene.materials]).reshape(-1, 3)
    alb = np.take(albedo, mat, axis=0)
    if mode == "albedo":
        out[rows] = alb
        return out
    # raster: emission + unshadowed point-light approximation of each area light
    sh = _Shading(scene, tracer)
    value = sh.emission(prim, p, d[rows])
    for li in range(scene.n_lights):
        c = scene.light_origin[li] + 0.5 * (scene.light_edge1[li] + scene.light_edge2[li])
        v = c - p
        r2 = np.einsum("ij,ij->i", v, v)
        w = v / np.sqrt(r2)[:, None]
        cos_s = np.maximum(np.einsum("ij,ij->i", w, n_s), 0.0)
        cos_l = np.maximum(-w @ sh.light_normal[li], 0.0)
        e = scene.light_radiance[li] * sh.light_area[li]
        value += (alb / np.pi) * e[None, :] * (cos_s * cos_l / r2)[:, None]
    out[rows] = value
    return out


def _material_albedo(material) -> np.ndarray:
    """Albedo AOV of a material: Lambertian albedo, else its reflectance tint."""
    for attr in ("albedo", "reflectance"):
        if hasattr(material, attr):
            return np.broadcast_to(np.asarray(getattr(material, attr), dtype=np.float64), (3,))
    return np.ones(3)


# ---------------------------------------------------------------------------
# Batches and render()

@dataclass(frozen=True)
class _Job:
    scene: Scene
    integrator: str
    sampler: str
    res: tuple
    max_depth: int | None
    heuristic: str
    precision: str
    token: str = ""
    light_sampling: str = "area"
    rr_depth: int | None = None


#: The tracer of the render in progress, by job token: built once per render
#: (in the parent before worker processes fork, so they inherit it) instead of
#: once per batch. Holds at most one entry.
_TRACERS: dict = {}


def _job_tracer(job: _Job) -> Tracer:
    tracer = _TRACERS.get(job.token)
    if tracer is None:
        tracer = Tracer(job.scene, dtype=job.precision)
        _TRACERS.clear()
        _TRACERS[job.token] = tracer
    return tracer


def _pool_context():
    """``fork`` where the platform has it: workers start in milliseconds and
    inherit the tracer; elsewhere the platform default."""
    import multiprocessing

    if "fork" in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("fork")
    return None


#: The worker processes, kept from one render to the next as ``[executor,
#: workers]``: a fresh process spends its first batch at about half speed
#: touching new memory (measured: 0.2 s wall for 0.1 s of CPU on this
#: machine), a warm one does not. Closed on Ctrl-C or error; Python's exit
#: handler joins it.
_POOL: list = []


def _worker_pool(workers: int) -> ProcessPoolExecutor:
    if _POOL and _POOL[1] == workers:
        return _POOL[0]
    _close_pool()
    _POOL[:] = [ProcessPoolExecutor(max_workers=workers, mp_context=_pool_context()), workers]
    return _POOL[0]


def _close_pool(wait: bool = True) -> None:
    if _POOL:
        executor = _POOL[0]
        _POOL.clear()
        executor.shutdown(wait=wait, cancel_futures=True)


def _render_batch(job: _Job, spp: int, rng, u=None):
    """Render ``spp`` samples of every pixel; return (sum, sum of squares, rays).

    ``u`` (n_pix, spp, dim): this batch's slice of the pixels' sample sets;
    None draws an independent set for the batch from ``rng``.
    """
    w, h = job.res
    n_pix = w * h
    scene = job.scene
    tracer = _job_tracer(job)
    aov = job.integrator in _AOVS
    if u is None:
        u = pixel_samples(job.sampler, n_pix, spp, dim=2 if aov else SAMPLER_DIM, rng=rng)
    u = np.ascontiguousarray(u).reshape(n_pix * spp, -1)
    pixel = np.repeat(np.arange(n_pix), spp)
    # (3, n) directions, handed on as their (n, 3) transposed view: the
    # wavefront loop works in (3, n) and takes them without a copy
    d = scene.camera.ray_directions_soa(job.res, pixel, u[:, 0:2]).T
    o = np.broadcast_to(scene.camera.position, d.shape)
    if aov:
        radiance = _first_hit(scene, tracer, np.ascontiguousarray(o), np.ascontiguousarray(d), job.integrator)
        rays = n_pix * spp
    else:
        radiance, rays = trace_paths(scene, o, d, u[:, 2:], integrator=job.integrator,
                                     max_depth=job.max_depth, heuristic=job.heuristic,
                                     rng=rng, tracer=tracer, light_sampling=job.light_sampling,
                                     rr_depth=job.rr_depth)
    if not np.all(np.isfinite(radiance)):
        raise FloatingPointError(f"{job.integrator} produced non-finite radiance (a bug, please report)")
    per_pixel = radiance.reshape(n_pix, spp, 3)
    return per_pixel.sum(axis=1), np.einsum("psc,psc->pc", per_pixel, per_pixel), rays


def _as_res(res) -> tuple:
    if isinstance(res, (int, np.integer)) and not isinstance(res, (bool, np.bool_)):
        r = check_count(res, "res")
        return (r, r)
    if isinstance(res, (tuple, list)) and len(res) == 2:
        return (check_count(res[0], "res[0] (width)"), check_count(res[1], "res[1] (height)"))
    raise TypeError(f"res must be an int (square image) or a (width, height) pair; got {res!r}")


def _batch_sizes(spp: int, n_pix: int, batch_spp, sampler: str) -> list[int]:
    if batch_spp is None:
        if n_pix * spp <= PATHS_PER_BATCH:
            b = spp
        else:
            b = max(1, PATHS_PER_BATCH // n_pix)
            base = 4 if sampler in ("grid", "jittered") else 2   # keep squares / powers of two
            b = base ** int(math.log(b, base) + 1e-9)
    else:
        b = check_count(batch_spp, "batch_spp")
    b = min(b, spp)
    sizes = [b] * (spp // b)
    if spp % b:
        sizes.append(spp % b)
    return sizes


#: Largest pixel-sample set (paths) drawn whole: ~100 MB at SAMPLER_DIM = 6.
SAMPLES_PER_SET = 2 ** 21


def _sample_slices(sampler: str, n_pix: int, spp: int, sizes, dim: int, rng):
    """Per-batch pixel samples that keep the sampler's stratification over all spp.

    For a stratified or QMC sampler whose ``n_pix x spp`` pattern fits
    :data:`SAMPLES_PER_SET`, each pixel's whole ``spp``-point set is drawn once
    and the batches trace consecutive slices of it, so a 256-spp Sobol render
    is one 256-point net per pixel, not sixteen 16-point ones (measured at
    64 x 64: MSE 7.0e-5 -> 3.0e-5 for path tracing). Partial sets stay
    unbiased (each point is marginally uniform), so an interrupted render is
    too. Otherwise (``random``: iid has nothing to keep; or too many samples)
    returns None for every batch: each draws its own set.
    """
    if sampler == "random" or len(sizes) == 1 or n_pix * spp > SAMPLES_PER_SET:
        return [None] * len(sizes)
    u = pixel_samples(sampler, n_pix, spp, dim=dim, rng=rng)
    edges = np.cumsum([0] + list(sizes))
    return [u[:, a:b] for a, b in zip(edges[:-1], edges[1:])]


def render(scene: Scene, *, integrator: str = "path", spp: int = 16, res=64, sampler: str = "random",
           rng=None, max_depth: int | None = None, heuristic: str = "power", batch_spp: int | None = None,
           workers: int = 1, progress: bool | Callable[[int, int], None] = False,
           precision: Literal["float32", "float64"] = "float32", light_sampling: str = "area",
           rr_depth: int | None = None) -> Render:
    """Render ``scene`` with one integrator: the mean radiance of ``spp`` samples per pixel.

    Parameters
    ----------
    scene : Scene
        From :func:`mcvar.scene.load_scene`.
    integrator : str
        One of :data:`INTEGRATORS` (see the module docstring).
    spp : int
        Samples per pixel, >= 1.
    res : int or (int, int)
        Square side, or ``(width, height)``.
    sampler : str
        A sampler of :data:`mcvar.samplers.SAMPLERS`: pixel positions and the
        light and BSDF samples of the first vertex come from it (per pixel,
        dimension 6), later vertices use iid numbers.
    rng : None, int, SeedSequence or Generator
        The same seed gives the same image, for any ``workers``.
    max_depth : int or None
        Maximum path segments for ``path`` and ``path_bsdf`` (1 = emitters
        seen directly, 2 = + direct light, ...; fixed depth is biased); None:
        Russian roulette (unbiased). The ``direct*`` integrators are depth 2
        (None or 2 accepted).
    heuristic : {'power', 'balance'}
        MIS weights (Veach's power heuristic with beta = 2, or balance).
    batch_spp : int, optional
        Samples per pixel per batch; default: all of them if the batch holds at
        most :data:`PATHS_PER_BATCH` paths, else a power of two (of four for
        grid / jittered) that fits. Stratified and QMC samplers stratify
        within a batch; batches are independent randomizations.
    workers : int
        Processes that render batches in parallel (NumPy uses one core).
        The image is the same as with ``workers=1`` (batches do not depend on
        ``workers``), so it pays only for renders of two or more batches
        (e.g. ``batch_spp=spp // 2``). The processes (``fork`` where
        available) are kept for the next render with the same ``workers``:
        warm workers run about 10% faster than fresh ones.
    progress : bool or callable
        True: a tqdm progress bar; a callable is called as
        ``progress(spp_done, spp_total)`` after each batch.
    precision : {'float32', 'float64'}
        Ray-geometry precision of the intersection tests (radiance is always
        accumulated in float64).
    light_sampling : {'area', 'solid_angle'}
        How next-event estimation samples quad lights (:data:`LIGHT_SAMPLING`;
        'solid_angle' needs rectangular lights). Measured on the Cornell box
        (docs/performance.md): no lower MSE at 256 spp, 27% more time.
    rr_depth : int, optional
        Path segments before Russian roulette starts (default
        :data:`RR_START_DEPTH`; unbiased for any value).

    Returns
    -------
    Render
        The image (H, W, 3), float64 linear radiance, row 0 at the top, with
        spp completed, wall time, per-pixel sample variance and the settings.

    Notes
    -----
    Batch ``b`` draws from stream ``b`` of ``as_rng(rng).spawn(n_batches)``;
    batch results are summed in batch order, so the image does not depend on
    how batches are spread over processes. Ctrl-C (``KeyboardInterrupt``,
    also when raised by a ``progress`` callback) stops the render and returns
    the batches finished so far with ``interrupted=True``.

    Examples
    --------
    >>> from mcvar.scene import load_scene
    >>> r = render(load_scene("cornell"), spp=2, res=8, rng=1)
    >>> r.image.shape, r.spp
    ((8, 8, 3), 2)
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a mcvar.scene.Scene (see load_scene); got {type(scene).__name__}")
    integrator = check_choice(integrator, "integrator", INTEGRATORS)
    sampler = check_choice(sampler, "sampler", tuple(SAMPLERS))
    heuristic = check_choice(heuristic, "heuristic", tuple(HEURISTICS))
    precision = check_choice(precision, "precision", ("float32", "float64"))
    light_sampling = check_choice(light_sampling, "light_sampling", LIGHT_SAMPLING)
    if light_sampling != "area":
        for e1, e2 in zip(scene.light_edge1, scene.light_edge2):
            _rectangle_soa_frame(e1, e2)          # a ValueError for a non-rectangular light, before any work
    spp = check_count(spp, "spp")
    size = _as_res(res)
    workers = check_count(workers, "workers")
    if rr_depth is not None:
        rr_depth = check_count(rr_depth, "rr_depth")
    if max_depth is not None:
        max_depth = check_count(max_depth, "max_depth")
        if integrator.startswith("direct") and max_depth != 2:
            raise ValueError(f"max_depth must be None or 2 for {integrator!r} (one-bounce direct "
                             f"lighting); got {max_depth}")
        if integrator in _AOVS:
            raise ValueError(f"max_depth does not apply to the first-hit mode {integrator!r}; got {max_depth}")
    n_pix = size[0] * size[1]
    sizes = _batch_sizes(spp, n_pix, batch_spp, sampler)
    for b in set(sizes):  # a sampler that cannot make b points fails here, before any work
        pixel_samples(sampler, 1, b, dim=2, rng=0)
    streams = as_rng(rng).spawn(len(sizes) + 1)
    slices = _sample_slices(sampler, n_pix, spp, sizes, 2 if integrator in _AOVS else SAMPLER_DIM,
                            streams.pop())
    job = _Job(scene, integrator, sampler, size, max_depth, heuristic, precision, token=uuid.uuid4().hex,
               light_sampling=light_sampling, rr_depth=rr_depth)
    _job_tracer(job)

    total = np.zeros((n_pix, 3))
    total_sq = np.zeros((n_pix, 3))
    done = 0
    rays = 0
    interrupted = False
    bar = None
    if progress is True:
        from tqdm.auto import tqdm

        bar = tqdm(total=spp, unit="spp", desc=f"{scene.name} {integrator}", leave=False)
    callback = progress if callable(progress) else None
    start = time.perf_counter()

    def collect(result, k):
        nonlocal total, total_sq, done, rays
        s, sq, r = result
        total += s
        total_sq += sq
        rays += r
        done += sizes[k]
        if bar is not None:
            bar.update(sizes[k])
        if callback is not None:
            callback(done, spp)

    try:
        if workers == 1 or len(sizes) == 1:
            for k, (b, stream, u) in enumerate(zip(sizes, streams, slices)):
                collect(_render_batch(job, b, stream, u), k)
        else:
            pool = _worker_pool(workers)
            futures = [pool.submit(_render_batch, job, b, stream, u)
                       for b, stream, u in zip(sizes, streams, slices)]
            try:
                for k, fut in enumerate(futures):
                    collect(fut.result(), k)
            except BaseException:
                _close_pool(wait=False)       # never leave a render's batches running
                raise
    except KeyboardInterrupt:
        interrupted = True
    finally:
        _TRACERS.pop(job.token, None)
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - start
    w, h = size
    if done:
        image = (total / done).reshape(h, w, 3)
    else:
        image = np.zeros((h, w, 3))
    variance = None
    if done >= 2:
        var = (total_sq - total * total / done) / (done - 1)
        variance = np.maximum(var, 0.0).reshape(h, w, 3)
    return Render(image=image, spp=done, seconds=seconds, interrupted=interrupted, variance=variance,
                  rays=rays, scene=scene.name, integrator=integrator, sampler=sampler, res=size,
                  max_depth=max_depth, heuristic=heuristic, batch_spp=sizes[0], workers=workers,
                  precision=precision)
