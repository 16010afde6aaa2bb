"""Light (particle) tracing, and the subpaths bidirectional methods share (layer 5).

The lecture's 'Previous Methods' slides: forward (light) tracing starts paths
on the lights, scatters them through the scene with the BSDFs' ``sample``,
and *connects every vertex to the pinhole* (a pinhole has no area: a light
path never hits it), splatting ``beta f |cos| We / pdf`` at the pixel the
vertex projects to (:meth:`mcvar.scene.Camera.sample_Wi`). The subpath
machinery here is also BDPT's (:mod:`mcvar.integrators.bdpt`): light and
camera subpaths as arrays ``(depth, n)`` (:class:`Subpath`) with the
densities of both directions per vertex, and the connection to the camera.
Everything is vectorised over the paths of a batch; the only Python loops
are over depths, strategies and materials.

Measures and conventions (Veach 1997, ch. 8 and 10; pbrt-v4's BDPT):

* ``pdf_fwd[i]`` is the density, per unit *area* at vertex ``i`` (per unit
  solid angle converted with ``|cos theta_i| / r^2``; no cosine at the
  pinhole or at a point light, which are not surfaces), with which the
  subpath's own sampling produced vertex ``i``; ``pdf_rev[i]`` the density
  with which the *other* direction would have produced it (the BSDF at
  ``i + 1`` sampled backwards).
* A vertex is ``delta`` when its BSDF sample came from a Dirac lobe (mirror,
  glass, a smooth plastic's coat: per sample, from ``sample(...,
  return_delta=True)``, not per material). Densities next to a delta vertex
  are stored as 1 on both sides (pbrt's ``remap0``; the discrete lobe
  probabilities of mcvar's materials are the same in both directions), and
  no strategy may connect at a delta vertex.
* The light vertex ``y_0`` has ``beta = 1 / (p_choice p_pos)`` and acts as a
  'BSDF' ``Le(y_0, w)`` (radiance of an area emitter, intensity of a point
  light); ``beta`` of ``y_1`` is then ``Le |cos| / (p_choice p_pos p_dir)``
  (:class:`~mcvar.integrators.emitters.LightOrigins`).
* The camera vertex ``z_0`` has ``beta = 1``: a camera path estimates the
  pixel mean directly (box filter, the pixel position uniform in the pixel).
  Connections to the pinhole (``t = 1``) carry ``We / pdf`` with the
  film-wide importance ``We = 1 / (A cos^4 theta)``, so that with one light
  path per camera path (``W H spp`` of them) the splat sum divided by spp
  is the image. The origin of a point-light path is not joined to the
  pinhole (strategy ``(1, 1)``): a point light has no radiance and the
  camera cannot see it, as in path tracing (issue 26).

Light tracing is unbiased for every path whose camera end can be connected
to: a path whose first camera vertex is a delta vertex (the camera sees a
mirror or glass) has probability zero, so ``light`` renders such surfaces
black (measured in the tests and notebook 07).

References
----------
.. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
   Simulation", PhD thesis, Stanford 1997, ch. 8 and 10.
.. [2] E. P. Lafortune, Y. D. Willems, "Bi-directional Path Tracing",
   Compugraphics 1993.
.. [3] M. Pharr, W. Jakob, G. Humphreys, "Physically Based Rendering", 4th
   ed., MIT Press 2023 (``PerspectiveCamera::We``/``SampleWi``, ``BDPT``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import Frame
from .emitters import LightOrigins
from .film import BatchJob, BatchResult, splat
from .registry import Method, register
from .state import RR_START_DEPTH, _flips as _material_flips

__all__ = ["Subpath", "PathNumbers", "camera_subpath", "light_subpath", "light_tracing_splats", "check_scene",
           "run_light_batch"]

#: Safety cap on subpath vertices under Russian roulette (survival <= 0.95 per step).
RR_MAX_VERTICES = 1024
#: Paths per chunk inside a batch: bounds the subpath arrays (~110 bytes per
#: vertex: 65 536 paths x ~5 vertices x 2 subpaths ~ 70 MB on the Cornell box).
CHUNK_PATHS = 1 << 16


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _unit(v):
    r = np.sqrt(_dot(v, v))
    return v / np.maximum(r, 1e-300)[:, None], r


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
    infinite : ndarray of bool, shape (D, n)
        The vertex is a direction, not a point: an environment map's light
        at infinity (a light subpath's ``y_0``, or the last vertex of a
        camera subpath that left the scene). Its ``ng`` is the unit
        direction from the scene towards it; densities of and from it have
        no ``1 / r^2`` and no cosine at it (pbrt-v4's infinite-light vertices).
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
    infinite: np.ndarray
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
                   infinite=np.zeros(m, bool), mat=np.full(m, -1), prim=np.full(m, -1))
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
    return np.array([_material_flips(m) for m in scene.materials])


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


class PathNumbers:
    """Given random numbers for a wavefront of subpaths, in place of a generator.

    Metropolis light transport (:mod:`mcvar.integrators.mmlt`) makes a subpath
    a pure function of its chain's state: :func:`camera_subpath` and
    :func:`light_subpath` take a ``PathNumbers`` as their ``rng`` (without
    Russian roulette, the only other use of the generator).

    Parameters
    ----------
    origin : ndarray, shape (n, 4), or None
        What :func:`light_subpath` draws for its origins (``random((n, 4))``).
    vertices : ndarray, shape (n, 2 k)
        Columns ``2 (i - 1), 2 (i - 1) + 1``: the BSDF sample of vertex ``i``
        (``i = 1 .. k``) of path ``j`` in row ``j``.
    cap : ndarray of int, shape (n,), optional
        The most vertices path ``j`` may have (at most the walk's
        ``max_vertices``): MMLT traces the subpaths of states with different
        strategies in one wavefront, each only as long as its strategy needs.
    """

    def __init__(self, origin, vertices, cap=None):
        self.origin = origin
        self.vertices = vertices
        self.cap = cap

    def random(self, shape):
        if self.origin is None or tuple(shape) != self.origin.shape:
            raise ValueError(f"PathNumbers holds origins of shape "
                             f"{None if self.origin is None else self.origin.shape}; asked for {shape}")
        return self.origin

    def vertex(self, idx, i):
        """The BSDF numbers (m, 2) of vertex ``i`` of the paths ``idx``."""
        return self.vertices[idx, 2 * (i - 1):2 * i]


@dataclass(frozen=True)
class _Walk:
    """What a random walk needs besides its rays: the scene, its tracer, the
    materials' normal flips, the vertex cap, Russian roulette, and whether
    rays that leave the scene become vertices at infinity (camera subpaths
    under an environment map: BDPT's ``s = 0`` strategy reads them)."""

    scene: object
    tracer: object
    flips: np.ndarray
    max_vertices: int
    roulette: bool = False
    escape: bool = False


def _walk(ws: _Walk, lev, first, o, d, beta, pdf_dir, rng):
    """Extend subpaths from vertex ``first - 1`` by BSDF sampling (the random walk).

    ``o, d`` (m, 3): rays leaving vertex ``first - 1`` of the paths ``idx``
    with solid-angle density ``pdf_dir``; ``beta`` the throughput they carry.
    Fills levels ``first, first + 1, ...`` of ``lev`` and returns
    ``(length, rays)``. With ``ws.escape`` a ray that hits nothing ends its
    path in a vertex at infinity (``infinite``, ``ng`` its direction,
    ``pdf_fwd`` the solid-angle density: pbrt-v4's escaped camera rays).
    """
    scene, tracer, flips, max_vertices, roulette = ws.scene, ws.tracer, ws.flips, ws.max_vertices, ws.roulette
    n = lev.n
    eps = float(scene.ray_epsilon)
    idx = np.arange(n)
    length = np.full(n, first)
    prev_delta = np.zeros(n, dtype=bool)
    scale = np.maximum(beta.max(axis=1), 1e-300)      # roulette on beta relative to its start
    rays = 0
    i = first
    if isinstance(rng, PathNumbers) and rng.cap is not None:      # paths already at their cap trace nothing
        go = np.flatnonzero(rng.cap > first)
        idx, o, d, beta, pdf_dir, prev_delta, scale = (a[go] for a in (idx, o, d, beta, pdf_dir, prev_delta, scale))
    while idx.size and i < max_vertices:
        t, prim = tracer.closest_soa(np.ascontiguousarray(o.T), np.ascontiguousarray(d.T))
        rays += idx.size
        keep = np.flatnonzero((prim >= 0) | ws.escape)      # escape: a miss is a vertex too
        if keep.size == 0:
            break
        if keep.size < idx.size:
            idx, o, d, beta, pdf_dir, prev_delta, scale = (a[keep] for a in (idx, o, d, beta, pdf_dir,
                                                                             prev_delta, scale))
            t, prim = t[keep], prim[keep]
        cur = lev.add(idx)
        length[idx] = i + 1
        rows = slice(None)
        if ws.escape and np.any(prim < 0):
            r = np.flatnonzero(prim < 0)
            cur["p"][r] = o[r] + d[r]
            cur["ng"][r] = d[r]
            cur["beta"][r] = beta[r]
            cur["infinite"][r] = True
            cur["pdf_fwd"][r] = np.where(prev_delta[r], 1.0, pdf_dir[r])
            rows = np.flatnonzero(prim >= 0)       # the rest walk on
            idx, o, d, beta, pdf_dir, prev_delta, scale = (a[rows] for a in (idx, o, d, beta, pdf_dir,
                                                                             prev_delta, scale))
            t, prim = t[rows], prim[rows]
            if idx.size == 0:
                break
        p = o + d * t[:, None]
        ng = tracer.normals(prim, p)
        mat = np.take(scene.prim_material, prim)
        cur["p"][rows] = p
        cur["ng"][rows] = ng
        cur["beta"][rows] = beta
        cur["surface"][rows] = True
        cur["mat"][rows] = mat
        cur["prim"][rows] = prim
        cur["pdf_fwd"][rows] = np.where(prev_delta, 1.0, pdf_dir * np.abs(_dot(ng, d)) / (t * t))
        if i + 1 >= max_vertices:
            break
        if isinstance(rng, PathNumbers) and rng.cap is not None:     # paths at their own cap end here
            go = np.flatnonzero(rng.cap[idx] > i + 1)
            if go.size < idx.size:
                idx, d, beta, pdf_dir, prev_delta, scale, t, p, ng, mat = (
                    a[go] for a in (idx, d, beta, pdf_dir, prev_delta, scale, t, p, ng, mat))
                rows = lev.pos[i][idx]
                if idx.size == 0:
                    break
        # scatter: sample the BSDF at vertex i
        wo = -d
        fr = Frame(_shading_normals(flips, mat, ng, wo))
        wo_l = np.stack([_dot(wo, fr.s), _dot(wo, fr.n), _dot(wo, fr.t)], axis=-1)
        m = idx.size
        u = rng.vertex(idx, i) if isinstance(rng, PathNumbers) else rng.random((m, 2))
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
        prev, prev_rows = lev.levels[i - 1], lev.pos[i - 1][idx]
        cos_prev = np.where(prev["surface"][prev_rows], np.abs(_dot(prev["ng"][prev_rows], d)), 1.0)
        prev["pdf_rev"][prev_rows] = np.where(dmask, 1.0, pdf_back * cos_prev / (t * t))
        cur["delta"][rows] = dmask
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
    ws = _Walk(scene, tracer, _flips(scene), max_vertices, roulette, escape=scene.environment is not None)
    length, rays = _walk(ws, lev, 1, o, d, np.ones((n, 3)), pdf_dir, rng)
    return lev.stack(length, np.full(n, -1), np.asarray(pixel), rays)


def light_subpath(scene, tracer, origins: LightOrigins, n, max_vertices, rng, roulette=False,
                  escape=False) -> Subpath:
    """Light subpaths ``y_0 .. y_{s-1}`` from :meth:`LightOrigins.sample`.

    With ``escape`` a ray that leaves the scene ends its subpath in a vertex
    at infinity (``infinite``, ``ng`` its direction), as camera subpaths do
    under an environment map: forward tracing without the camera connection
    (:func:`mcvar.experiments.slide_pairs.forward_pinhole_hits`) reads them.

    An environment origin is a vertex at infinity (``infinite``; pbrt-v4's
    infinite lights in BDPT): ``y_0`` stands for the direction ``w``
    towards the map, with ``pdf_fwd = p_choice p(w)`` (solid angle) and
    ``beta = 1 / pdf_fwd``; ``y_1`` is reached by parallel rays from the
    disk, so its ``pdf_fwd`` is ``|cos theta_1| / (pi r^2)``, and the
    reverse density of ``y_0`` is the BSDF's solid-angle density at ``y_1``
    (no ``1 / r^2``).
    """
    lev = _Levels(n)
    u = rng.random((n, 4))
    s = origins.sample(u[:, 0:2], u[:, 2:4])
    env = s["env"]
    y0 = lev.add(np.arange(n))
    y0["p"][:] = s["p"]
    y0["ng"][:] = np.where(env[:, None], -s["w"], s["n"])
    y0["surface"][:] = (s["point"] < 0) & ~env
    y0["infinite"][:] = env
    y0["prim"][:] = s["prim"]
    pdf_origin = s["pdf_pos"].copy()
    if np.any(env):
        pdf_origin[env] = origins.env_pdf_origin(-s["w"][env])
    y0["pdf_fwd"][:] = pdf_origin
    with np.errstate(divide="ignore", invalid="ignore"):
        beta0 = np.where(pdf_origin > 0, 1.0 / pdf_origin, 0.0)
        y0["beta"][:] = beta0[:, None]
        # the same beta for every origin: le cos / (pdf_pos pdf_dir) (pbrt-v4 SampleLe)
        beta = s["le"] * np.where((s["pdf_dir"] > 0) & (s["pdf_pos"] > 0),
                                  s["cos"] / (s["pdf_pos"] * s["pdf_dir"]), 0.0)[:, None]
    length = np.ones(n, dtype=np.int64)
    rays = 0
    if max_vertices > 1:
        eps = float(scene.ray_epsilon)
        o = s["p"] + s["n"] * eps
        ws = _Walk(scene, tracer, _flips(scene), max_vertices, roulette, escape)
        length, rays = _walk(ws, lev, 1, o, s["w"], beta, s["pdf_dir"], rng)
        if np.any(env) and len(lev.levels) > 1:
            _at_infinity(lev, np.flatnonzero(env), origins.env_pdf_pos, eps)
    return lev.stack(length, s["point"], np.full(n, -1), rays)


def _at_infinity(lev, paths, pdf_disk, eps):
    """Densities next to an environment origin ``y_0`` of ``paths`` (pbrt-v4's
    correction for infinite lights): ``pdf_fwd(y_1) = |cos theta_1| pdf_disk``
    (parallel rays, area density ``pdf_disk`` across them) and the reverse
    density of ``y_0`` in solid angle (the walk converted it with the distance
    to the disk, which is not part of the path: the ray started ``eps``
    beyond the disk point along its direction)."""
    y0, y1 = lev.levels[0], lev.levels[1]
    rows1 = lev.pos[1][paths]
    reached = rows1 >= 0
    paths, rows1 = paths[reached], rows1[reached]
    if paths.size == 0:
        return
    rows0 = lev.pos[0][paths]
    d = y1["p"][rows1] - y0["p"][rows0]
    r2 = (np.sqrt(np.einsum("ij,ij->i", d, d)) - eps) ** 2
    cos1 = np.abs(np.einsum("ij,ij->i", y1["ng"][rows1], y0["ng"][rows0]))
    y1["pdf_fwd"][rows1] = cos1 * pdf_disk
    # the walk stored pdf_back * 1 / r^2 (y_0 is no surface), or 1 next to a delta vertex
    y0["pdf_rev"][rows0] = np.where(y1["delta"][rows1], 1.0, y0["pdf_rev"][rows0] * r2)


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
    """Per-batch constants shared by the connections: scene, tracer, light
    origins, image size, MIS exponent (1 balance, 2 power) and whether MIS is on."""

    def __init__(self, scene, tracer, origins, res, heuristic="power", mis=True):
        self.scene, self.tracer, self.em, self.res = scene, tracer, origins, res
        self.flips = _flips(scene)
        self.delta_mat = np.array([bool(getattr(m, "is_delta", False)) for m in scene.materials] + [False])
        self.eps = float(scene.ray_epsilon)
        self.power = {"balance": 1.0, "power": 2.0}[heuristic]
        self.mis = mis


def _connect_camera(ctx, L, s, mis_weight=None):
    """Strategy (s, t = 1): light vertex ``y_{s-1}`` joined to the pinhole.

    ``mis_weight``: BDPT's weight function (called with the reverse
    densities this connection sets, pbrt's scoped assignments); None: weight
    1 (light tracing). Returns ``(paths, pixel, value, weight)`` for the
    unoccluded connections.
    """
    weighted = mis_weight is not None
    scene, em, cam = ctx.scene, ctx.em, ctx.scene.camera
    il = np.flatnonzero(L.length >= s)
    if s >= 2:
        il = il[~ctx.delta_mat[L.mat[s - 1, il]]]
    else:
        # a point light is not seen by the camera (no area, no radiance: a
        # camera ray hits it with probability zero, as in path tracing,
        # Mitsuba 3 and pbrt-v4); splatting I / r^2 at its pixel would add
        # an image that no other method renders (issue 26)
        il = il[L.point[il] < 0]
    if il.size == 0:
        return il, il, np.zeros((0, 3)), np.zeros(0)
    q = s - 1
    if s == 1 and np.any(L.infinite[0, il]):
        inf = L.infinite[0, il]
        parts = [_connect_camera_at_infinity(ctx, L, il[inf], mis_weight)]
        if not np.all(inf):
            parts.append(_connect_camera(ctx, _Only(L, il[~inf]), 1, mis_weight))
        return tuple(np.concatenate(a) for a in zip(*parts))
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
            # no distance to a vertex at infinity (an environment origin y_0)
            r2 = np.where(L.infinite[q - 1, il], 1.0, r_m * r_m)
            over[("L", q - 1)] = pdf_back * _cos(L.surface[q - 1, il], L.ng[q - 1, il], wo) / r2
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
    weight = mis_weight(ctx, L, None, s, 1, il, None, over)
    return il, pixel, value, weight


class _Only:
    """A light subpath seen through a mask: only the paths ``keep`` reach
    ``y_0`` (``length`` 0 elsewhere); every other field is the subpath's."""

    def __init__(self, L, keep):
        self._L = L
        self.length = np.zeros_like(L.length)
        self.length[keep] = L.length[keep]

    def __getattr__(self, name):
        return getattr(self._L, name)


def _connect_camera_at_infinity(ctx, L, il, mis_weight=None):
    """Strategy (1, 1) for environment origins: the camera ray along ``w``
    towards the map (``y_0`` is the direction ``w``, ``L.ng``).

    The measurement ``int We L cos theta_c d omega`` of the map seen directly,
    with ``w`` drawn by the origin's density ``p_choice p(w)``: the splat
    ``beta_0 L(w) We(w) cos theta_c`` (``beta_0 = 1 / (p_choice p(w))``) at
    the pixel of ``w``, if the camera ray along ``w`` leaves the scene (the
    particle tracer's 'visible emitters' of Mitsuba 3, made from the light
    path's own origin). With MIS its alternative is the camera ray that
    escapes (``s = 0``, density ``pdf_We(w)`` in the same measure).
    """
    cam = ctx.scene.camera
    towards = L.ng[0, il]
    xy, visible, cos_c = cam._raster(ctx.res, towards)
    we = cam.We(towards, ctx.res)
    value = L.beta[0, il] * ctx.em.light_le(L.point[il], L.prim[0, il], L.p[0, il], -towards) * \
        np.where(visible, we * cos_c, 0.0)[:, None]
    go = np.flatnonzero(value.max(axis=1) > 0.0)
    il, xy, value, towards = il[go], xy[go], value[go], towards[go]
    if il.size:
        o = np.ascontiguousarray(np.broadcast_to(cam.position, (il.size, 3)).T)
        ok = ~ctx.tracer.occluded_soa(o, np.ascontiguousarray(towards.T), np.full(il.size, np.inf))
        il, xy, value, towards = il[ok], xy[ok], value[ok], towards[ok]
    pixel = cam.pixel_index(xy, ctx.res)
    if mis_weight is None:
        return il, pixel, value, np.ones(il.size)
    over = {("L", 0): cam.pdf_We(towards, ctx.res)[1]}
    return il, pixel, value, mis_weight(ctx, L, None, 1, 1, il, None, over)


# ---------------------------------------------------------------------------
# Whole batches

def light_tracing_splats(scene, tracer, origins, res, n_paths, rng, max_depth=None):
    """Light (particle) tracing: ``n_paths`` light subpaths, every vertex joined to the camera.

    Returns ``(sum, rays)``: ``sum`` (W H, 3) of the splats, so that the
    image is ``sum / spp`` when ``n_paths = W H spp``. Strategies ``(s, 1)``
    with weight 1; paths whose camera end is a delta vertex (a mirror seen by
    the camera) have probability zero: light tracing cannot render them.
    """
    w, h = res
    image = np.zeros((w * h, 3))
    max_v = RR_MAX_VERTICES if max_depth is None else max_depth
    ctx = _Context(scene, tracer, origins, res)
    rays = 0
    for a in range(0, n_paths, CHUNK_PATHS):
        L = light_subpath(scene, tracer, origins, min(CHUNK_PATHS, n_paths - a), max_v, rng,
                          roulette=max_depth is None)
        rays += L.rays
        for s in range(1, int(L.length.max()) + 1):
            il, pixel, value, _ = _connect_camera(ctx, L, s)
            rays += il.size
            splat(image, pixel, value)
    return image, rays


def check_scene(scene, options=None, method="light transport"):
    """Raise ``ValueError`` naming what light tracing / BDPT cannot handle in ``scene``.

    Light subpaths start on emitters: a scene needs an emitting primitive, a
    point light or an environment map with some radiance (light from
    infinitely far away starts on a disk that covers the scene:
    :class:`~mcvar.integrators.emitters.LightOrigins`).
    """
    has_emission = bool(np.any(scene.prim_emission > 0.0))
    has_points = bool(np.any(scene.point_light_intensity > 0.0))
    has_env = scene.environment is not None and bool(np.any(scene.environment.image > 0.0))
    if not (has_emission or has_points or has_env):
        raise ValueError(f"{method} needs a light: scene {scene.name!r} has no emitting surface, no "
                         "point light and no environment map with radiance")


def run_light_batch(job: BatchJob) -> BatchResult:
    """One batch of ``light``: ``W H spp`` light paths, their splats summed per pixel.

    The sample stream ``job.u`` (pixel positions) does not apply: light paths
    draw from ``job.rng``. ``sum_sq`` is None: the film estimates the
    variance from independent batches.
    """
    w, h = job.res
    total, rays = light_tracing_splats(job.scene, job.tracer, LightOrigins(job.scene), job.res,
                                       w * h * job.spp, job.rng, job.max_depth)
    if not np.all(np.isfinite(total)):
        raise FloatingPointError("light produced non-finite radiance (a bug, please report)")
    return BatchResult(total, None, int(rays))


def _check_light(scene, options):
    check_scene(scene, options, "light")


register(Method(
    "light", "splat", run_light_batch,
    "light (particle) tracing: light paths, every vertex connected to the pinhole and splatted",
    check_scene=_check_light, chart_row="Path Tracing",
    theory=("yes", "yes", "light tracing is path tracing started at the lights: with Russian roulette unbiased "
                          "and consistent"),
    stream_dims=0))
