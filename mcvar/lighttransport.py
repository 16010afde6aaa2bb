"""Light tracing and bidirectional path tracing as wavefront loops (layer 5).

The lecture's 'Previous Methods' slides: backward (camera) path tracing,
forward (light) tracing that connects every light-path vertex to the camera,
and bidirectional path tracing (BDPT) that builds a camera subpath
``z_0 .. z_{t-1}`` and a light subpath ``y_0 .. y_{s-1}`` and joins them in
every way, each join ``(s, t)`` weighted by multiple importance sampling.
Everything here is vectorised over the paths of a batch: subpath vertices are
arrays ``(depth, n)`` (:class:`Subpath`), and every strategy ``(s, t)`` is
evaluated for all paths that have the vertices it needs at once; the only
Python loops are over depths, strategies and materials.

Measures and conventions (Veach 1997, ch. 8 and 10; pbrt-v4, sec. 16.3 of the
3rd ed. / 'BDPT' of the 4th):

* ``pdf_fwd[i]`` is the density, per unit *area* at vertex ``i`` (per unit
  solid angle converted with ``|cos theta_i| / r^2``; no cosine at the
  pinhole or at a point light, which are not surfaces), with which the
  subpath's own sampling produced vertex ``i``; ``pdf_rev[i]`` the density
  with which the *other* direction would have produced it (the BSDF at
  ``i + 1`` sampled backwards).
* A vertex is ``delta`` when its BSDF sample came from a Dirac lobe (mirror,
  glass, a smooth plastic's coat: per sample, not per material). Densities
  next to a delta vertex are stored as 1 on both sides (pbrt's ``remap0``;
  the discrete lobe probabilities of our materials are the same in both
  directions), and no strategy may connect at a delta vertex.
* The light vertex ``y_0`` has ``beta = 1 / (p_select p_pos)`` and acts as a
  'BSDF' ``Le(y_0, w)`` (radiance of an area emitter, intensity of a point
  light); ``beta`` of ``y_1`` is then ``Le |cos| / (p_select p_pos p_dir)``.
* The camera vertex ``z_0`` has ``beta = 1``: a camera path estimates the
  pixel mean directly (box filter, the pixel position uniform in the pixel).
  Connections to the pinhole (``t = 1``) carry ``We / pdf`` of
  :meth:`mcvar.scene.Camera.sample_Wi` with the film-wide importance, so that
  their splat sum divided by the samples per pixel is the image (one light
  path per camera path).

References
----------
.. [1] E. Veach, L. J. Guibas, "Bidirectional Estimators for Light
   Transport", Eurographics Rendering Workshop 1994.
.. [2] E. Veach, L. J. Guibas, "Optimally Combining Sampling Techniques for
   Monte Carlo Rendering", SIGGRAPH 1995.
.. [3] E. Veach, "Robust Monte Carlo Methods for Light Transport
   Simulation", PhD thesis, Stanford 1997, ch. 10.
.. [4] E. P. Lafortune, Y. D. Willems, "Bi-directional Path Tracing",
   Compugraphics 1993.
.. [5] M. Pharr, W. Jakob, G. Humphreys, "Physically Based Rendering", 4th
   ed., MIT Press 2023 (``PerspectiveCamera::We``, ``BDPT``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .geometry import Frame
from .scene import Scene
from .tracer import Tracer
from .warps import (_square_to_cosine_hemisphere_unchecked, square_to_uniform_sphere,
                    square_to_uniform_triangle)

__all__ = ["Emitters", "Subpath", "camera_subpath", "light_subpath", "light_tracing_splats",
           "bdpt_contributions", "STRATEGY_DEPTH"]

#: Russian roulette starts once a subpath has this many segments (as in path tracing).
RR_START_DEPTH = 3
#: Safety cap on subpath vertices under Russian roulette (survival <= 0.95 per step).
RR_MAX_VERTICES = 1024
#: The ``--strategies`` figure shows the weighted contribution of every (s, t)
#: with s + t - 1 <= this depth (the lecture's figure: depth <= 4).
STRATEGY_DEPTH = 4
_INV_PI = 1.0 / math.pi
#: Paths per chunk inside a batch: bounds the subpath arrays (~110 bytes per
#: vertex: 65 536 paths x ~5 vertices x 2 subpaths ~ 70 MB on the Cornell box).
CHUNK_PATHS = 1 << 16


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _unit(v):
    r = np.sqrt(_dot(v, v))
    return v / np.maximum(r, 1e-300)[:, None], r


# ---------------------------------------------------------------------------
# Emitters as light-subpath origins

class Emitters:
    """Every emitter of a scene as a light-subpath origin (``sample_le`` / ``pdf_le``).

    Emitting primitives (triangles, spheres: any primitive with emission, so
    also the furnace's sphere and the checkerboard's plane) and point lights,
    one chosen in proportion to its power (mean of RGB): a primitive emits
    ``pi L A`` (one-sided) or ``2 pi L A`` (two-sided), a point light
    ``4 pi I``. A point is uniform on the chosen primitive's area; the
    direction is cosine-weighted about the emitting side's normal (a
    two-sided emitter picks its side with probability 1/2), a point light's
    uniform over the sphere. BDPT's ``s = 1`` strategy (next-event
    estimation) uses the same densities, so the MIS weights see one light
    sampling technique.
    """

    def __init__(self, scene: Scene, tracer: Tracer):
        self.scene = scene
        self.tracer = tracer
        n_tri = scene.n_triangles
        n_prim = n_tri + scene.n_spheres
        prims = np.flatnonzero(np.any(scene.prim_emission > 0.0, axis=1))
        self.prims = prims
        is_tri = prims < n_tri
        area = np.empty(prims.size)
        tri = scene.triangles[prims[is_tri]]
        area[is_tri] = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        area[~is_tri] = 4.0 * math.pi * scene.sphere_radii[prims[~is_tri] - n_tri] ** 2
        two = scene.prim_two_sided_emission[prims]
        power = np.concatenate([scene.prim_emission[prims].mean(axis=1) * area * math.pi * (1.0 + two),
                                4.0 * math.pi * scene.point_light_intensity.mean(axis=1)])
        total = power.sum()
        self.count = power.size
        self.pmf = power / total if total > 0 else power
        self.cdf = np.cumsum(self.pmf)
        #: selection probability / area of every primitive (0 if it does not emit)
        self.prim_select = np.zeros(n_prim)
        self.prim_select[prims] = self.pmf[:prims.size]
        self.prim_area = np.ones(n_prim)
        self.prim_area[prims] = area

    @property
    def empty(self) -> bool:
        return self.count == 0 or not self.cdf[-1] > 0

    def sample_le(self, u):
        """Origins of light subpaths from ``u`` (n, 5) in [0, 1)^5.

        Returns a dict: ``p`` (n, 3), ``n`` (n, 3) emitting-side unit normal
        (0 for point lights), ``w`` (n, 3) emitted direction, ``prim`` (n,)
        (-1 for point lights), ``point`` (n,) point-light index or -1,
        ``pdf_pos`` = selection x area density (selection alone for a point
        light), ``pdf_dir`` per solid angle, ``le`` (n, 3) radiance (or
        intensity) towards ``w`` and ``cos`` (1 for point lights).
        """
        scene = self.scene
        n = u.shape[0]
        k = np.minimum(np.searchsorted(self.cdf, u[:, 0] * self.cdf[-1], side="right"), self.count - 1)
        n_area = self.prims.size
        area = k < n_area
        p = np.zeros((n, 3))
        nrm = np.zeros((n, 3))
        prim = np.full(n, -1)
        point = np.full(n, -1)
        pdf_pos = np.take(self.pmf, k)
        le = np.zeros((n, 3))
        ia = np.flatnonzero(area)
        if ia.size:
            pr = self.prims[k[ia]]
            prim[ia] = pr
            n_tri = scene.n_triangles
            tri = pr < n_tri
            it, isph = ia[tri], ia[~tri]
            if it.size:
                v = scene.triangles[pr[tri]]
                b = square_to_uniform_triangle(u[it, 1:3])
                p[it] = v[:, 0] + b[:, 0:1] * (v[:, 1] - v[:, 0]) + b[:, 1:2] * (v[:, 2] - v[:, 0])
                nrm[it] = self.tracer.triangle_normal[pr[tri]]
            if isph.size:
                j = pr[~tri] - n_tri
                d = square_to_uniform_sphere(u[isph, 1:3])
                p[isph] = scene.sphere_centers[j] + scene.sphere_radii[j][:, None] * d
                nrm[isph] = d
            pdf_pos[ia] /= self.prim_area[pr]
        ip = np.flatnonzero(~area)
        if ip.size:
            j = k[ip] - n_area
            point[ip] = j
            p[ip] = scene.point_light_position[j]
            le[ip] = scene.point_light_intensity[j]
        # directions
        w = np.zeros((n, 3))
        pdf_dir = np.zeros(n)
        cos = np.ones(n)
        if ia.size:
            two = scene.prim_two_sided_emission[prim[ia]]
            u3 = u[ia, 3].copy()
            back = two & (u3 >= 0.5)
            u3 = np.where(two, np.where(back, 2.0 * u3 - 1.0, 2.0 * u3), u3)
            side = np.where(back, -1.0, 1.0)
            x, y, z = _square_to_cosine_hemisphere_unchecked(np.clip(u3, 0.0, 1.0), u[ia, 4])
            fr = Frame(nrm[ia] * side[:, None])
            w[ia] = fr.s * x[:, None] + fr.n * y[:, None] + fr.t * z[:, None]
            nrm[ia] = fr.n
            cos[ia] = y
            pdf_dir[ia] = y * _INV_PI * np.where(two, 0.5, 1.0)
            le[ia] = self.emission(prim[ia], p[ia], w[ia])
        if ip.size:
            w[ip] = square_to_uniform_sphere(u[ip, 3:5])
            pdf_dir[ip] = 0.25 * _INV_PI
        return dict(p=p, n=nrm, w=w, prim=prim, point=point, pdf_pos=pdf_pos, pdf_dir=pdf_dir, le=le, cos=cos)

    def emission(self, prim, p, w):
        """Radiance emitted by primitives ``prim`` at ``p`` towards unit ``w``, (n, 3)."""
        scene = self.scene
        le = np.take(scene.prim_emission, prim, axis=0)
        if prim.size == 0:
            return le
        ng = self.tracer.normals(prim, p)
        front = _dot(ng, w) > 0.0
        le = np.where((front | np.take(scene.prim_two_sided_emission, prim))[:, None], le, 0.0)
        if scene.checker_period is not None:
            c = (np.floor(p[:, 0] / scene.checker_period) + np.floor(p[:, 2] / scene.checker_period)) % 2.0
            le = le * c[:, None]
        return le

    def pdf_dir(self, prim, p, w):
        """Solid-angle density of emitting ``w`` from ``p`` on primitives ``prim`` (cosine-weighted)."""
        ng = self.tracer.normals(prim, p)
        c = _dot(ng, w)
        two = np.take(self.scene.prim_two_sided_emission, prim)
        return np.where(two, 0.5 * np.abs(c) * _INV_PI, np.maximum(c, 0.0) * _INV_PI)

    def pdf_pos(self, prim):
        """Density (selection x area) of choosing a point of primitive ``prim`` as ``y_0``."""
        return np.take(self.prim_select, prim) / np.take(self.prim_area, prim)

    def light_le(self, point, prim, p, w):
        """'BSDF' of light vertices ``y_0``: point-light intensity or emitted radiance towards ``w``."""
        out = np.zeros((point.shape[0], 3))
        pt = point >= 0
        if np.any(pt):
            out[pt] = self.scene.point_light_intensity[point[pt]]
        if not np.all(pt):
            out[~pt] = self.emission(prim[~pt], p[~pt], w[~pt])
        return out

    def light_pdf_dir(self, point, prim, p, w):
        """Solid-angle density with which ``y_0`` emits towards ``w``."""
        out = np.full(point.shape[0], 0.25 * _INV_PI)
        area = point < 0
        if np.any(area):
            out[area] = self.pdf_dir(prim[area], p[area], w[area])
        return out


# ---------------------------------------------------------------------------
# Subpaths

@dataclass
class Subpath:
    """Vertices of ``n`` subpaths as arrays ``(depth, n, ...)`` (vertex 0 first).

    Attributes
    ----------
    Every field is indexed ``[depth, paths]`` like an array ``(D, n, ...)``
    (stored as compact per-depth rows, :class:`_ByDepth`), for paths that
    reach that depth (``depth < length``).

    p, ng, beta : shape (D, n, 3)
        Position, geometric normal (0 at the pinhole and at point lights) and
        throughput ``beta`` (the subpath's contribution up to the vertex
        divided by its pdf).
    pdf_fwd, pdf_rev : ndarray, shape (D, n)
        Area densities in the sampling and the reverse direction (module notes).
    delta : ndarray of bool, shape (D, n)
        The vertex's BSDF sample came from a Dirac lobe.
    surface : ndarray of bool, shape (D, n)
        The vertex lies on a surface (cosines count in density conversions).
    mat, prim : ndarray of int, shape (D, n)
        Material and primitive (-1 at the pinhole and on lights ``y_0``).
    length : ndarray of int, shape (n,)
        Vertices of each subpath (vertex ``i`` exists where ``i < length``).
    point : ndarray of int, shape (n,)
        Light subpaths: point-light index of ``y_0`` or -1; camera: all -1.
    pixel : ndarray of int, shape (n,)
        Camera subpaths: the pixel; light subpaths: -1.
    rays : int
        Rays traced to build them.
    """

    p: np.ndarray
    ng: np.ndarray
    beta: np.ndarray
    pdf_fwd: np.ndarray
    pdf_rev: np.ndarray
    delta: np.ndarray
    surface: np.ndarray
    mat: np.ndarray
    prim: np.ndarray
    length: np.ndarray
    point: np.ndarray
    pixel: np.ndarray
    rays: int


class _Levels:
    """Per-depth vertex rows of the paths that reach each depth (compact), with
    a map from path to row; :meth:`stack` wraps them as a :class:`Subpath`."""

    def __init__(self, n):
        self.n = n
        self.levels = []
        self.pos = []

    def add(self, idx):
        """A new depth holding the paths ``idx`` (row ``r`` is path ``idx[r]``)."""
        m = idx.size
        lev = dict(p=np.zeros((m, 3)), ng=np.zeros((m, 3)), beta=np.zeros((m, 3)), pdf_fwd=np.zeros(m),
                   pdf_rev=np.zeros(m), delta=np.zeros(m, bool), surface=np.zeros(m, bool),
                   mat=np.full(m, -1), prim=np.full(m, -1))
        pos = np.full(self.n, -1, dtype=np.int64)
        pos[idx] = np.arange(m)
        self.levels.append(lev)
        self.pos.append(pos)
        return lev

    def stack(self, length, point, pixel, rays):
        keys = self.levels[0].keys()
        arrays = {k: _ByDepth([lev[k] for lev in self.levels], self.pos) for k in keys}
        return Subpath(length=length, point=point, pixel=pixel, rays=rays, **arrays)


class _ByDepth:
    """A ``(depth, n, ...)`` array stored as compact per-depth rows: ``a[i, idx]``
    is the depth-``i`` data of paths ``idx`` (which must reach depth ``i``).

    Under Russian roulette the deep levels hold few paths: full-width levels
    (or stacking them) cost memory and time in proportion to the longest
    path (measured: stacking alone was 35% of a batch), compact ones in
    proportion to the vertices that exist.
    """

    __slots__ = ("rows", "pos")

    def __init__(self, rows, pos):
        self.rows = rows
        self.pos = pos

    def __getitem__(self, key):
        i, idx = key
        return self.rows[i][self.pos[i][idx]]

    def __len__(self):
        return len(self.rows)


def _flips(scene):
    """Per material: the caller flips the normal towards ``wo`` (all but transmissive models)."""
    return np.array([not getattr(m, "transmissive", False) for m in scene.materials])


def _shading_normals(flips, mat, ng, wo):
    """Normals of the local frames: geometric, flipped towards ``wo`` for two-sided materials."""
    flip = np.take(flips, mat) & (_dot(ng, wo) < 0.0)
    return np.where(flip[:, None], -ng, ng)


def _bsdf_eval(scene, flips, mat, ng, wo, wi, need_pdf=True):
    """``f(wo, wi)``, ``pdf(wo -> wi)`` and ``pdf(wi -> wo)`` of mixed materials (world directions).

    Delta lobes are not part of ``eval``/``pdf`` (a connection never passes
    through them).
    """
    m = mat.shape[0]
    f = np.zeros((m, 3))
    pf = np.zeros(m)
    pr = np.zeros(m)
    if m == 0:
        return f, pf, pr
    fr = Frame(_shading_normals(flips, mat, ng, wo))
    wo_l = np.stack([_dot(wo, fr.s), _dot(wo, fr.n), _dot(wo, fr.t)], axis=-1)
    wi_l = np.stack([_dot(wi, fr.s), _dot(wi, fr.n), _dot(wi, fr.t)], axis=-1)
    for mi in np.unique(mat):
        material = scene.materials[mi]
        if getattr(material, "is_delta", False):
            continue
        sel = np.flatnonzero(mat == mi)
        a, b = wo_l[sel], wi_l[sel]
        # the models' unchecked kernels: a and b are unit vectors built here
        # (the public eval/pdf re-check them: a quarter of a BDPT batch, measured)
        f[sel] = material._eval(a, b)
        if need_pdf:
            pf[sel] = material._pdf(a, b)
            pr[sel] = material._pdf(b, a)
    return f, pf, pr


def _walk(scene, tracer, flips, lev, first, o, d, beta, pdf_dir, max_vertices, rng, roulette):
    """Extend subpaths from vertex ``first - 1`` by BSDF sampling (the random walk).

    ``o, d`` (m, 3): rays leaving vertex ``first - 1`` of the paths ``idx``
    with solid-angle density ``pdf_dir``; ``beta`` the throughput they carry.
    Fills levels ``first, first + 1, ...`` of ``lev`` and returns
    ``(length, rays)``.
    """
    n = lev.n
    eps = float(scene.ray_epsilon)
    idx = np.arange(n)
    length = np.full(n, first)
    prev_delta = np.zeros(n, dtype=bool)
    scale = np.maximum(beta.max(axis=1), 1e-300)      # roulette on beta relative to its start
    rays = 0
    i = first
    while idx.size and i < max_vertices:
        t, prim = tracer.closest_soa(np.ascontiguousarray(o.T), np.ascontiguousarray(d.T))
        rays += idx.size
        hit = np.flatnonzero(prim >= 0)
        if hit.size == 0:
            break
        if hit.size < idx.size:
            idx, o, d, beta, pdf_dir, prev_delta, scale = (a[hit] for a in (idx, o, d, beta, pdf_dir,
                                                                            prev_delta, scale))
            t, prim = t[hit], prim[hit]
        p = o + d * t[:, None]
        ng = tracer.normals(prim, p)
        mat = np.take(scene.prim_material, prim)
        cur = lev.add(idx)
        cur["p"][:] = p
        cur["ng"][:] = ng
        cur["beta"][:] = beta
        cur["surface"][:] = True
        cur["mat"][:] = mat
        cur["prim"][:] = prim
        cur["pdf_fwd"][:] = np.where(prev_delta, 1.0, pdf_dir * np.abs(_dot(ng, d)) / (t * t))
        length[idx] = i + 1
        if i + 1 >= max_vertices:
            break
        # scatter: sample the BSDF at vertex i
        wo = -d
        fr = Frame(_shading_normals(flips, mat, ng, wo))
        wo_l = np.stack([_dot(wo, fr.s), _dot(wo, fr.n), _dot(wo, fr.t)], axis=-1)
        m = idx.size
        u = rng.random((m, 2))
        wi_l = np.zeros((m, 3))
        weight = np.zeros((m, 3))
        pdf = np.zeros(m)
        pdf_back = np.zeros(m)
        dmask = np.zeros(m, dtype=bool)
        for mi in np.unique(mat):
            sel = np.flatnonzero(mat == mi)
            material = scene.materials[mi]
            wi_s, w_s, p_s, d_s = material.sample(wo_l[sel], u[sel], return_delta=True)
            wi_l[sel], weight[sel], pdf[sel], dmask[sel] = wi_s, w_s, p_s, d_s
            if not getattr(material, "is_delta", False):
                ok = ~d_s & (p_s > 0.0)
                if np.any(ok):
                    back = np.zeros(sel.size)
                    back[ok] = material.pdf(wi_s[ok], wo_l[sel][ok])
                    pdf_back[sel] = back
        wi = fr.s * wi_l[:, 0:1] + fr.n * wi_l[:, 1:2] + fr.t * wi_l[:, 2:3]
        prev, rows = lev.levels[i - 1], lev.pos[i - 1][idx]
        cos_prev = np.where(prev["surface"][rows], np.abs(_dot(prev["ng"][rows], d)), 1.0)
        prev["pdf_rev"][rows] = np.where(dmask, 1.0, pdf_back * cos_prev / (t * t))
        cur["delta"][:] = dmask
        beta = beta * weight
        alive = (beta.max(axis=1) > 0.0) & (pdf > 0.0)
        if roulette and i >= RR_START_DEPTH:
            q = np.minimum(beta.max(axis=1) / scale, 0.95)
            survive = rng.random(m) < q
            beta = beta / np.where(survive, q, 1.0)[:, None]
            alive &= survive
        side = np.sign(_dot(wi, ng))
        o = p + ng * (eps * side)[:, None]
        d = wi
        pdf_dir = pdf
        prev_delta = dmask
        keep = np.flatnonzero(alive)
        idx, o, d, beta, pdf_dir, prev_delta, scale = (a[keep] for a in (idx, o, d, beta, pdf_dir,
                                                                         prev_delta, scale))
        i += 1
    return length, rays


def camera_subpath(scene, tracer, res, pixel, offsets, max_vertices, rng, roulette=False) -> Subpath:
    """Camera subpaths ``z_0 .. z_{t-1}`` through pixels ``pixel`` at ``offsets`` (n, 2)."""
    n = pixel.shape[0]
    cam = scene.camera
    lev = _Levels(n)
    z0 = lev.add(np.arange(n))
    z0["p"][:] = cam.position
    z0["beta"][:] = 1.0
    z0["pdf_fwd"][:] = 1.0
    d = np.ascontiguousarray(cam.ray_directions_soa(res, pixel, offsets).T)
    pdf_dir = cam.pdf_We(d, res)[1]
    o = np.broadcast_to(cam.position, d.shape).copy()
    length, rays = _walk(scene, tracer, _flips(scene), lev, 1, o, d, np.ones((n, 3)), pdf_dir,
                         max_vertices, rng, roulette)
    return lev.stack(length, np.full(n, -1), np.asarray(pixel), rays)


def light_subpath(scene, tracer, emitters: Emitters, n, max_vertices, rng, roulette=False) -> Subpath:
    """Light subpaths ``y_0 .. y_{s-1}`` from :meth:`Emitters.sample_le`."""
    lev = _Levels(n)
    s = emitters.sample_le(rng.random((n, 5)))
    y0 = lev.add(np.arange(n))
    y0["p"][:] = s["p"]
    y0["ng"][:] = s["n"]
    y0["surface"][:] = s["point"] < 0
    y0["prim"][:] = s["prim"]
    y0["pdf_fwd"][:] = s["pdf_pos"]
    with np.errstate(divide="ignore", invalid="ignore"):
        y0["beta"][:] = np.where(s["pdf_pos"] > 0, 1.0 / s["pdf_pos"], 0.0)[:, None]
        beta = y0["beta"] * s["le"] * np.where(s["pdf_dir"] > 0, s["cos"] / s["pdf_dir"], 0.0)[:, None]
    length = np.ones(n, dtype=np.int64)
    rays = 0
    if max_vertices > 1:
        eps = float(scene.ray_epsilon)
        o = s["p"] + s["n"] * eps
        length, rays = _walk(scene, tracer, _flips(scene), lev, 1, o, s["w"], beta, s["pdf_dir"],
                             max_vertices, rng, roulette)
    return lev.stack(length, s["point"], np.full(n, -1), rays)


# ---------------------------------------------------------------------------
# Connections

def _unoccluded(tracer, eps, pa, na, pb, nb):
    """Mutual visibility of point pairs, each end moved ``eps`` off its surface
    towards the other (``n = 0``: a pinhole or point light, not moved)."""
    v = pb - pa
    oa = pa + na * (eps * np.sign(_dot(na, v)))[:, None]
    ob = pb - nb * (eps * np.sign(_dot(nb, v)))[:, None]
    d, r = _unit(ob - oa)
    occ = tracer.occluded_soa(np.ascontiguousarray(oa.T), np.ascontiguousarray(d.T), r - eps)
    return ~occ


def _cos(surface, ng, w):
    return np.where(surface, np.abs(_dot(ng, w)), 1.0)


class _Context:
    """Per-batch constants shared by the strategies."""

    def __init__(self, scene, tracer, emitters, res, heuristic, mis):
        self.scene, self.tracer, self.em, self.res = scene, tracer, emitters, res
        self.flips = _flips(scene)
        self.delta_mat = np.array([bool(getattr(m, "is_delta", False)) for m in scene.materials] + [False])
        self.eps = float(scene.ray_epsilon)
        self.power = {"balance": 1.0, "power": 2.0}[heuristic]
        self.mis = mis


def _mis_weight(ctx, L, C, s, t, il, ic, over):
    """Veach's MIS weight of strategy (s, t) for the paths ``il`` (light) / ``ic`` (camera).

    ``over``: replacement ``pdf_rev`` of the vertices next to the connection,
    keyed ``('L', i)`` / ``('C', i)`` (pbrt's scoped assignments). Returns
    ``1 / (1 + sum_i r_i^beta)`` over the strategies that can produce the
    path (no connection at a delta vertex, none to the pinhole or a point
    light by hitting it); with ``mis`` off, ``1 / (number of those strategies)``.
    """
    m = ic.size if ic is not None else il.size
    total = np.ones(m)

    def add(ri, valid):
        if ctx.mis:
            return np.where(valid, ri ** ctx.power, 0.0)
        return (valid & (ri > 0.0)).astype(float)

    ri = np.ones(m)
    for i in range(t - 1, 0, -1):
        rev = over.get(("C", i))
        rev = C.pdf_rev[i, ic] if rev is None else rev
        fwd = C.pdf_fwd[i, ic]
        ri = ri * np.divide(rev, fwd, out=np.zeros(m), where=fwd > 0)
        valid = ~C.delta[i - 1, ic]
        if i != t - 1:
            valid &= ~C.delta[i, ic]
        total += add(ri, valid)
    ri = np.ones(m)
    for i in range(s - 1, -1, -1):
        rev = over.get(("L", i))
        rev = L.pdf_rev[i, il] if rev is None else rev
        fwd = L.pdf_fwd[i, il]
        ri = ri * np.divide(rev, fwd, out=np.zeros(m), where=fwd > 0)
        valid = ~(L.delta[i - 1, il] if i > 0 else (L.point[il] >= 0))
        if i != s - 1:
            valid &= ~L.delta[i, il]
        total += add(ri, valid)
    return 1.0 / total


def _connect_camera(ctx, L, s, weighted=True):
    """Strategy (s, t = 1): light vertex ``y_{s-1}`` joined to the pinhole.

    Returns ``(paths, pixel, value, weight)`` for the unoccluded connections.
    """
    scene, em, cam = ctx.scene, ctx.em, ctx.scene.camera
    il = np.flatnonzero(L.length >= s)
    if s >= 2:
        il = il[~ctx.delta_mat[L.mat[s - 1, il]]]
    if il.size == 0:
        return il, il, np.zeros((0, 3)), np.zeros(0)
    q = s - 1
    pq, nq, surf = L.p[q, il], L.ng[q, il], L.surface[q, il]
    wi, dist, we, pdf, xy, visible = cam.sample_Wi(pq, ctx.res)
    cos_q = _cos(surf, nq, wi)
    over = {}
    if s == 1:
        f = em.light_le(L.point[il], L.prim[q, il], pq, wi)
    else:
        pm = L.p[q - 1, il]
        wo, r_m = _unit(pm - pq)
        f, _, pdf_back = _bsdf_eval(scene, ctx.flips, L.mat[q, il], nq, wo, wi, need_pdf=weighted)
        if weighted:
            over[("L", q - 1)] = pdf_back * _cos(L.surface[q - 1, il], L.ng[q - 1, il], wo) / (r_m * r_m)
    with np.errstate(divide="ignore", invalid="ignore"):
        value = L.beta[q, il] * f * np.where(visible, cos_q * we / pdf, 0.0)[:, None]
    go = np.flatnonzero(value.max(axis=1) > 0.0)
    il, xy, value, wi, dist, cos_q = il[go], xy[go], value[go], wi[go], dist[go], cos_q[go]
    over = {k: v[go] for k, v in over.items()}
    if il.size == 0:
        return il, il, value, np.zeros(0)
    ok = _unoccluded(ctx.tracer, ctx.eps, L.p[q, il], L.ng[q, il], np.broadcast_to(cam.position, (il.size, 3)),
                     np.zeros((il.size, 3)))
    il, xy, value, wi, dist, cos_q = il[ok], xy[ok], value[ok], wi[ok], dist[ok], cos_q[ok]
    over = {k: v[ok] for k, v in over.items()}
    pixel = cam.pixel_index(xy, ctx.res)
    if not weighted:
        return il, pixel, value, np.ones(il.size)
    over[("L", q)] = cam.pdf_We(-wi, ctx.res)[1] * cos_q / (dist * dist)
    weight = _mis_weight(ctx, L, None, s, 1, il, None, over)
    return il, pixel, value, weight


def _connect_emitter(ctx, C, t):
    """Strategy (s = 0, t): camera vertex ``z_{t-1}`` lies on an emitter."""
    em = ctx.em
    ic = np.flatnonzero(C.length >= t)
    ic = ic[np.take(em.prim_select, C.prim[t - 1, ic]) > 0.0]
    if ic.size == 0:
        return ic, np.zeros((0, 3)), np.zeros(0)
    k = t - 1
    pk, prim = C.p[k, ic], C.prim[k, ic]
    wo, r = _unit(C.p[k - 1, ic] - pk)
    value = C.beta[k, ic] * em.emission(prim, pk, wo)
    go = np.flatnonzero(value.max(axis=1) > 0.0)
    ic, value, pk, prim, wo, r = ic[go], value[go], pk[go], prim[go], wo[go], r[go]
    over = {("C", k): em.pdf_pos(prim)}
    if k - 1 >= 1:
        over[("C", k - 1)] = em.pdf_dir(prim, pk, wo) * _cos(C.surface[k - 1, ic], C.ng[k - 1, ic], wo) / (r * r)
    return ic, value, _mis_weight(ctx, None, C, 0, t, None, ic, over)


def _connect_inner(ctx, L, C, s, t):
    """Strategy (s >= 1, t >= 2): ``y_{s-1}`` joined to ``z_{t-1}`` by a shadow ray."""
    scene, em = ctx.scene, ctx.em
    idx = np.flatnonzero((L.length >= s) & (C.length >= t))
    mat_t = C.mat[t - 1, idx]
    ok = ~ctx.delta_mat[mat_t] & (mat_t >= 0)
    if s >= 2:
        ok &= ~ctx.delta_mat[L.mat[s - 1, idx]]
    idx = idx[ok]
    if idx.size == 0:
        return idx, np.zeros((0, 3)), np.zeros(0)
    q, k = s - 1, t - 1
    pq, nq, sq = L.p[q, idx], L.ng[q, idx], L.surface[q, idx]
    pk, nk = C.p[k, idx], C.ng[k, idx]
    w, dist = _unit(pk - pq)                                  # from y_q to z_k
    d2 = dist * dist
    wo_k, r_k = _unit(C.p[k - 1, idx] - pk)
    f_k, pdf_k_fwd, pdf_k_rev = _bsdf_eval(scene, ctx.flips, C.mat[k, idx], nk, wo_k, -w)
    if s == 1:
        f_q = em.light_le(L.point[idx], L.prim[q, idx], pq, w)
        pdf_q_fwd = em.light_pdf_dir(L.point[idx], L.prim[q, idx], pq, w)
        pdf_q_rev = None
    else:
        wo_q, r_q = _unit(L.p[q - 1, idx] - pq)
        f_q, pdf_q_fwd, pdf_q_rev = _bsdf_eval(scene, ctx.flips, L.mat[q, idx], nq, wo_q, w)
    cos_q = _cos(sq, nq, w)
    cos_k = np.abs(_dot(nk, w))
    value = L.beta[q, idx] * f_q * C.beta[k, idx] * f_k * (cos_q * cos_k / d2)[:, None]
    go = np.flatnonzero(value.max(axis=1) > 0.0)
    if go.size < idx.size:
        idx, value, pq, nq, pk, nk = idx[go], value[go], pq[go], nq[go], pk[go], nk[go]
        w, d2, wo_k, r_k, cos_q, cos_k = w[go], d2[go], wo_k[go], r_k[go], cos_q[go], cos_k[go]
        pdf_k_fwd, pdf_k_rev, pdf_q_fwd = pdf_k_fwd[go], pdf_k_rev[go], pdf_q_fwd[go]
        if s >= 2:
            pdf_q_rev, wo_q, r_q = pdf_q_rev[go], wo_q[go], r_q[go]
    if idx.size == 0:
        return idx, value, np.zeros(0)
    vis = _unoccluded(ctx.tracer, ctx.eps, pq, nq, pk, nk)
    sel = np.flatnonzero(vis)
    idx, value = idx[sel], value[sel]
    over = {("C", k): pdf_q_fwd[sel] * cos_k[sel] / d2[sel],
            ("L", q): pdf_k_fwd[sel] * cos_q[sel] / d2[sel]}
    if k - 1 >= 1:
        over[("C", k - 1)] = (pdf_k_rev[sel] * _cos(C.surface[k - 1, idx], C.ng[k - 1, idx], wo_k[sel])
                              / (r_k[sel] ** 2))
    if s >= 2:
        over[("L", q - 1)] = (pdf_q_rev[sel] * _cos(L.surface[q - 1, idx], L.ng[q - 1, idx], wo_q[sel])
                              / (r_q[sel] ** 2))
    return idx, value, _mis_weight(ctx, L, C, s, t, idx, idx, over)


# ---------------------------------------------------------------------------
# Whole batches

def _splat(image, pixel, value):
    n_pix = image.shape[0]
    for c in range(3):
        image[:, c] += np.bincount(pixel, value[:, c], minlength=n_pix)


def light_tracing_splats(scene, tracer, emitters, res, n_paths, rng, max_depth=None):
    """Light (particle) tracing: ``n_paths`` light subpaths, every vertex joined to the camera.

    Returns ``(sum, rays)``: ``sum`` (W H, 3) of the splats, so that the
    image is ``sum / spp`` when ``n_paths = W H spp``. Strategies ``(s, 1)``
    with weight 1; paths whose camera end is a delta vertex (a mirror seen by
    the camera) have probability zero: light tracing cannot render them.
    """
    w, h = res
    image = np.zeros((w * h, 3))
    max_v = RR_MAX_VERTICES if max_depth is None else max_depth
    ctx = _Context(scene, tracer, emitters, res, "balance", True)
    rays = 0
    for a in range(0, n_paths, CHUNK_PATHS):
        L = light_subpath(scene, tracer, emitters, min(CHUNK_PATHS, n_paths - a), max_v, rng,
                          roulette=max_depth is None)
        rays += L.rays
        for s in range(1, int(L.length.max()) + 1):
            il, pixel, value, _ = _connect_camera(ctx, L, s, weighted=False)
            rays += int((L.length >= s).sum())
            _splat(image, pixel, value)
    return image, rays


def bdpt_contributions(scene, tracer, emitters, res, pixel, offsets, rng, max_depth=None,
                       heuristic="power", mis=True, strategies=False):
    """Bidirectional path tracing of one camera path per ``pixel`` (and one light path each).

    Returns ``(camera_sum, camera_sq, splat_sum, rays, per_strategy)``:
    per-pixel sums of the camera-side estimates (t >= 2; ``camera_sq`` of
    their per-sample squares), the splat sum of the t = 1 strategies, the
    rays traced, and with ``strategies`` a dict ``(s, t) -> (W H, 3)`` of the
    weighted contributions of every strategy of depth ``s + t - 1 <=``
    :data:`STRATEGY_DEPTH` (camera-side ones per pixel, t = 1 splatted).
    """
    w, h = res
    n_pix = w * h
    out = [np.zeros((n_pix, 3)), np.zeros((n_pix, 3)), np.zeros((n_pix, 3)), 0, {} if strategies else None]
    for a in range(0, pixel.shape[0], CHUNK_PATHS):
        part = _bdpt_chunk(scene, tracer, emitters, res, pixel[a:a + CHUNK_PATHS], offsets[a:a + CHUNK_PATHS],
                           rng, max_depth, heuristic, mis, strategies)
        for j in range(4):
            out[j] += part[j]
        for key, img in (part[4] or {}).items():
            out[4][key] = out[4].get(key, 0.0) + img
    return tuple(out)


def _bdpt_chunk(scene, tracer, emitters, res, pixel, offsets, rng, max_depth, heuristic, mis, strategies):
    """:func:`bdpt_contributions` for at most :data:`CHUNK_PATHS` paths."""
    w, h = res
    n = pixel.shape[0]
    n_pix = w * h
    roulette = max_depth is None
    max_c = RR_MAX_VERTICES if roulette else max_depth + 1
    max_l = RR_MAX_VERTICES if roulette else max_depth
    C = camera_subpath(scene, tracer, res, pixel, offsets, max_c, rng, roulette)
    L = light_subpath(scene, tracer, emitters, n, max_l, rng, roulette)
    ctx = _Context(scene, tracer, emitters, res, heuristic, mis)
    rays = C.rays + L.rays
    per_path = np.zeros((n, 3))
    splats = np.zeros((n_pix, 3))
    per_strategy = {} if strategies else None
    t_max, s_max = int(C.length.max()), int(L.length.max())
    for t in range(1, t_max + 1):
        for s in range(0, s_max + 1):
            if s + t < 2 or (not roulette and s + t - 1 > max_depth):
                continue
            keep = strategies and s + t - 1 <= STRATEGY_DEPTH
            if t == 1:
                il, pix, value, weight = _connect_camera(ctx, L, s)
                rays += il.size
                contrib = value * weight[:, None]
                _splat(splats, pix, contrib)
                if keep:
                    img = per_strategy.setdefault((s, t), np.zeros((n_pix, 3)))
                    _splat(img, pix, contrib)
                continue
            if s == 0:
                ic, value, weight = _connect_emitter(ctx, C, t)
            else:
                ic, value, weight = _connect_inner(ctx, L, C, s, t)
                rays += ic.size
            contrib = value * weight[:, None]
            per_path[ic] += contrib                       # one contribution per path
            if keep:
                img = per_strategy.setdefault((s, t), np.zeros((n_pix, 3)))
                _splat(img, C.pixel[ic], contrib)
    cam_sum = np.zeros((n_pix, 3))
    cam_sq = np.zeros((n_pix, 3))
    _splat(cam_sum, C.pixel, per_path)
    _splat(cam_sq, C.pixel, per_path * per_path)
    return cam_sum, cam_sq, splats, rays, per_strategy


def render_staging(scene, integrator="bdpt", *, spp=4, res=16, rng=None, max_depth=None, heuristic="power",
                   mis=True, batches=4, strategies=False):
    """Temporary driver until the integrator registry lands: ``batches``
    independent batches of ``spp / batches`` samples per pixel; returns
    ``(image, standard_error, per_strategy, rays)`` (SE from the batches)."""
    from ._validation import as_rng

    res = (res, res) if isinstance(res, int) else tuple(res)
    w, h = res
    n_pix = w * h
    tracer = Tracer(scene)
    em = Emitters(scene, tracer)
    streams = as_rng(rng).spawn(batches)
    per = spp // batches
    images = []
    strat = {}
    rays = 0
    for st in streams:
        if integrator == "light":
            total, r = light_tracing_splats(scene, tracer, em, res, n_pix * per, st, max_depth)
        else:
            pixel = np.repeat(np.arange(n_pix), per)
            cam, _, spl, r, ps = bdpt_contributions(scene, tracer, em, res, pixel, st.random((pixel.size, 2)),
                                                    st, max_depth, heuristic, mis, strategies)
            total = cam + spl
            for k, v in (ps or {}).items():
                strat[k] = strat.get(k, 0) + v / (per * batches)
        rays += r
        images.append((total / per).reshape(h, w, 3))
    images = np.array(images)
    se = images.std(0, ddof=1) / np.sqrt(batches) if batches > 1 else None
    return images.mean(0), se, strat, rays


def strategy_grid(per_strategy, res, depth=STRATEGY_DEPTH, gap=2):
    """The lecture's figure: every strategy's weighted image in a grid (linear radiance).

    Row ``d - 1`` holds the strategies of depth ``d = s + t - 1`` (1 ..
    ``depth``), column ``s`` (light vertices, 0 .. ``d``) with ``t = d + 1 -
    s`` camera vertices; cells without a strategy and the ``gap``-pixel
    borders are 0. ``per_strategy`` maps ``(s, t)`` to images ``(H, W, 3)``
    or per-pixel arrays ``(W H, 3)``.
    """
    w, h = res
    grid = np.zeros((depth * (h + gap) - gap, (depth + 1) * (w + gap) - gap, 3))
    for (s, t), img in per_strategy.items():
        d = s + t - 1
        if 1 <= d <= depth and s <= d:
            y, x = (d - 1) * (h + gap), s * (w + gap)
            grid[y:y + h, x:x + w] = np.asarray(img).reshape(h, w, 3)
    return grid


def write_strategies(out_dir, per_strategy, res, depth=STRATEGY_DEPTH):
    """Write ``s{s}_t{t}.npy`` (linear (H, W, 3)) per strategy and ``strategies.png``
    (:func:`strategy_grid`, sRGB at exposure 4) into ``out_dir``; returns the paths written."""
    from pathlib import Path

    from .images import write_image

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    w, h = res
    paths = []
    for (s, t), img in sorted(per_strategy.items()):
        if s + t - 1 <= depth:
            paths.append(write_image(out / f"s{s}_t{t}.npy", np.asarray(img).reshape(h, w, 3)))
    # exposure 4: each panel holds only its weighted share of the image
    paths.append(write_image(out / "strategies.png", strategy_grid(per_strategy, res, depth), exposure=4.0))
    return paths


def check_scene(scene, options=None, method="light transport"):
    """Raise ``ValueError`` naming what light tracing / BDPT cannot handle in ``scene``.

    Light subpaths start on emitters: a scene needs an emitting primitive or
    a point light; an environment map (light from infinitely far away) is
    not sampled as a light-path origin here (pbrt samples a disk beyond the
    scene's bounds; not implemented).
    """
    if scene.environment is not None:
        raise ValueError(f"{method} cannot handle scene {scene.name!r}: it has an environment map, which "
                         "light subpaths cannot start from (only emitting surfaces and point lights)")
    has_emission = bool(np.any(scene.prim_emission > 0.0))
    has_points = bool(np.any(scene.point_light_intensity > 0.0))
    if not (has_emission or has_points):
        raise ValueError(f"{method} needs a light: scene {scene.name!r} has no emitting surface and no "
                         "point light")
