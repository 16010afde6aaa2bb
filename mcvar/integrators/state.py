"""The wavefront: per-path state, per-scene shading tables, and what every loop shares.

* :class:`PathState`: the live paths of a wavefront as one structure-of-arrays
  block (origin, direction, throughput ``beta``, the previous bounce's pdf)
  plus the paths' indices, so that compaction is one ``np.take``.
* :class:`SceneTables`: per-scene constants of the shading loop (material
  codes, Lambertian albedo per primitive, shading frames of triangles, which
  materials flip).
* :class:`Transport`: one trace's strategies and
  :class:`~mcvar.integrators.settings.PathSettings`, and its radiance accumulator; adds emission found
  by rays with its MIS weight.
* :func:`shadow_rays`, :func:`roulette`.
"""
from __future__ import annotations

import numpy as np

from ..bsdf import Glass, Lambertian
from ..geometry import Frame
from .emitters import Emitters, VisibleLights
from .settings import HEURISTICS, PathSettings, Strategies
from .stream import ROULETTE, SampleStream

__all__ = ["PathState", "SceneTables", "Transport", "shadow_rays", "roulette", "dot", "light_caustics_apply",
           "lambertian_scene",
           "RR_START_DEPTH", "RR_MAX_DEPTH"]

#: Russian roulette starts once a path has this many segments.
RR_START_DEPTH = 3
#: Safety cap on the number of segments under Russian roulette: a path
#: survives each step with probability <= 0.95, so reaching it has
#: probability <= 0.95^1021 < 1e-22 (negligible bias).
RR_MAX_DEPTH = 1024


def dot(a, b):
    """Row-wise dot products of SoA vectors (3, n) -> (n,)."""
    return np.einsum("ij,ij->j", a, b)


class PathState:
    """The live paths of a wavefront, structure-of-arrays.

    Two blocks hold per path: the ray, origin (rows 0-2) and direction
    (3-5) of :attr:`geo`, and in :attr:`weights` the throughput ``beta``
    (rows 0-2) and the solid-angle pdf of the bounce that made the current
    ray (3; ``inf`` for a camera ray or a delta bounce, whose emission gets
    MIS weight 1); ``idx`` is each path's row in the output. Compaction
    (:meth:`take`) is one ``np.take`` per block.

    Parameters
    ----------
    origins, directions : array_like, shape (3, n)
    dtype : numpy dtype
        Precision of the rays: the tracer's (float32 by default).
    weight_dtype : numpy dtype, optional
        Precision of ``beta`` and the pdf (default ``dtype``): the general
        loop keeps them in float64, so that a throughput is the exact product
        of its BSDF weights (the furnace's geometric sums); the Lambertian
        kernel keeps everything in float32 (radiance is accumulated in float64).
    """

    __slots__ = ("geo", "weights", "idx", "tag", "prefix")

    def __init__(self, origins, directions, dtype=np.float64, weight_dtype=None):
        n = np.shape(origins)[1]
        self.geo = np.empty((6, n), dtype=dtype)
        self.geo[0:3] = origins
        self.geo[3:6] = directions
        self.weights = np.empty((4, n), dtype=dtype if weight_dtype is None else weight_dtype)
        self.weights[0:3] = 1.0
        self.weights[3] = np.inf
        self.idx = np.arange(n)
        #: optional per-path flags kept through compaction: the caustic prefix
        #: (vertex 1 non-specular), and every vertex so far glass (``glass_splits``)
        self.tag = None
        self.prefix = None

    @property
    def n(self) -> int:
        return self.idx.shape[0]

    @property
    def o(self):
        return self.geo[0:3]

    @property
    def d(self):
        return self.geo[3:6]

    @property
    def beta(self):
        return self.weights[0:3]

    @property
    def prev_pdf(self):
        return self.weights[3]

    def take(self, rows) -> None:
        """Keep (and reorder to) the paths at positions ``rows``."""
        self.geo = np.take(self.geo, rows, axis=1)
        self.weights = np.take(self.weights, rows, axis=1)
        self.idx = np.take(self.idx, rows)
        if self.tag is not None:
            self.tag = np.take(self.tag, rows)
        if self.prefix is not None:
            self.prefix = np.take(self.prefix, rows)

    def append(self, rows, origins, directions, beta) -> None:
        """Add a branch of the paths at positions ``rows``: new rays ``origins``,
        ``directions`` (3, b) with throughput ``beta`` (3, b) after a delta lobe
        (pdf inf), the same output rows and flags (a split, ``glass_splits``)."""
        geo = np.empty((6, rows.size), dtype=self.geo.dtype)
        geo[0:3] = origins
        geo[3:6] = directions
        w = np.empty((4, rows.size), dtype=self.weights.dtype)
        w[0:3] = beta
        w[3] = np.inf
        self.geo = np.concatenate([self.geo, geo], axis=1)
        self.weights = np.concatenate([self.weights, w], axis=1)
        self.idx = np.concatenate([self.idx, np.take(self.idx, rows)])
        if self.tag is not None:
            self.tag = np.concatenate([self.tag, np.take(self.tag, rows)])
        if self.prefix is not None:
            self.prefix = np.concatenate([self.prefix, np.take(self.prefix, rows)])


def _flips(material) -> bool:
    """Whether the caller flips the shading normal towards ``wo`` (two-sided):
    every material except those light may cross (``BSDF.transmissive``), which
    tell inside from outside by the sign of ``wo.y``."""
    return not getattr(material, "transmissive", False)


class SceneTables:
    """Per-scene constants of the shading loop (built once per trace).

    The rays stay in path order (no sort): Lambertian materials are a
    per-primitive albedo table (0 on other materials' primitives) applied to
    every row at once, and every other material is called once per bounce on
    its own rows (:meth:`groups`, index arrays). Triangles have
    constant normals: their shading frames, for both orientations, are a
    table indexed by ``2 prim + flipped``.

    Attributes
    ----------
    lambertian : bool
        Every material :class:`mcvar.bsdf.Lambertian`, triangles only, one
        quad light and no environment: the scenes the Lambertian kernel
        (:mod:`mcvar.integrators.lambertian`) handles.
    """

    def __init__(self, scene, tracer, emitters: Emitters):
        self.scene = scene
        self.emitters = emitters
        self.materials = scene.materials
        self.n_mat = len(scene.materials)
        n_prim = scene.n_triangles + scene.n_spheres
        code = np.empty(n_prim + 1, dtype=np.int16 if self.n_mat < 32000 else np.int64)
        code[:n_prim] = scene.prim_material
        code[n_prim] = self.n_mat                   # prim -1 (a miss) takes the last entry
        self.mat_code = code
        self.emits = np.append(np.any(scene.prim_emission > 0, axis=1), False)
        self.flips = np.array([_flips(m) for m in scene.materials])
        #: every lobe a Dirac delta: NEE skips the material (per-sample masks decide the rest)
        self.all_delta = np.array([bool(getattr(m, "is_delta", False)) for m in scene.materials])
        #: some emitting primitive is not a light NEE samples (the furnace, the checkerboard)
        self.hidden_emitters = bool(np.any(self.emits[:-1] & (scene.prim_light < 0)))
        #: per material code (and a last entry for a miss): the material is Glass (``glass_splits``)
        self.glass = np.array([type(m) is Glass for m in scene.materials] + [False])
        #: some material has a delta lobe (Mirror, Glass, smooth Plastic ...)
        self.any_delta = any(bool(getattr(m, "is_delta", False) or getattr(m, "has_delta", False))
                             for m in scene.materials)
        self.n_tri = scene.n_triangles
        self.spheres = scene.n_spheres > 0
        # Lambertian materials written out (every row of a bounce at once, no
        # method call): albedo and f = albedo / pi per primitive, 0 on the
        # primitives of other materials, whose rows their own BSDF overwrites
        lamb = np.array([type(m) is Lambertian for m in scene.materials], dtype=bool)
        #: materials called through their BSDF methods, on their rows (index arrays)
        self.others = tuple(int(mi) for mi in np.flatnonzero(~lamb))
        prim_mat = np.asarray(scene.prim_material, dtype=np.int64)
        albedo = np.zeros((3, n_prim + 1))
        f_diffuse = np.zeros((3, n_prim + 1))
        for mi in np.flatnonzero(lamb):
            rows = np.flatnonzero(prim_mat == mi)
            albedo[:, rows] = scene.materials[mi].albedo[:, None]
            f_diffuse[:, rows] = (scene.materials[mi].albedo / np.pi)[:, None]
        #: precision of the general loop's path state: the tracer's ray geometry
        self.dtype = dt = np.dtype(tracer.dtype)
        self.diffuse_albedo = albedo                # float64: the throughput's factors stay exact
        #: some material is Lambertian (its sampling written out)
        self.any_diffuse = bool(lamb.any())
        self.diffuse_f = f_diffuse
        #: per primitive (and a last entry for a miss): its material is Lambertian
        self.diffuse = np.append(lamb[prim_mat], False) if n_prim else np.zeros(1, dtype=bool)
        self.sphere_center_soa = np.ascontiguousarray(scene.sphere_centers.T)
        self.sphere_radius = np.asarray(scene.sphere_radii, dtype=np.float64)
        if self.n_tri:
            nrm = tracer.triangle_normal
            both = np.stack([nrm, -nrm], axis=1).reshape(-1, 3)
            fr = Frame(both)
            # sphere columns (2 per sphere) are placeholders: their frames are computed per hit
            pad = np.zeros((3, 2 * scene.n_spheres))
            self.frame_s = np.ascontiguousarray(np.concatenate([fr.s.T, pad], axis=1), dtype=dt)
            self.frame_n = np.ascontiguousarray(np.concatenate([fr.n.T, pad], axis=1), dtype=dt)
            self.frame_t = np.ascontiguousarray(np.concatenate([fr.t.T, pad], axis=1), dtype=dt)
            self.normal_soa = np.ascontiguousarray(np.concatenate([tracer.triangle_normal_soa,
                                                                   pad[:, :scene.n_spheres]], axis=1), dtype=dt)
        #: one quad light of constant radiance, one-sided, and no other emitter:
        #: emission found by rays written out (:meth:`Transport.hit_emission`)
        self.quad_emission = None
        if emitters.single_quad and not self.hidden_emitters and scene.checker_period is None:
            em_prims = np.flatnonzero(self.emits[:-1])
            if (not np.any(scene.prim_two_sided_emission[em_prims])
                    and np.all(scene.prim_emission[em_prims] == scene.light_radiance[0])):
                self.quad_emission = (scene.light_radiance[0].astype(np.float64),
                                      [float(c) for c in scene.light_normal[0]], float(emitters.pdf_area[0]))
        #: ``caustics='light'`` applies (:func:`~mcvar.integrators.caustics.light_caustics_apply`)
        self.light_caustics = self.quad_emission is not None and light_caustics_apply(scene)
        self.lambertian = lambertian_scene(scene, emitters)

    @classmethod
    def of(cls, scene, tracer, light_sampling: str) -> "SceneTables":
        """The tables of ``scene`` traced by ``tracer``, built once per tracer and light sampling.

        They depend only on the scene, the tracer's geometry and the light
        sampling, and are never modified, so every batch traced by one
        tracer reads the same tables (building them costs 7% of a render at
        94,082 triangles, where the shading-frame table is rebuilt per batch
        otherwise). Kept on the tracer object, not in a module cache.
        """
        cache = tracer.__dict__.setdefault("_scene_tables", {})
        key = (id(scene), light_sampling)
        hit = cache.get(key)
        if hit is None or hit.scene is not scene:
            hit = cache[key] = cls(scene, tracer, Emitters(scene, light_sampling))
        return hit

    def lambertian_missing(self, emitters: Emitters) -> str | None:
        """Why the Lambertian kernel cannot run this scene (None if it can)."""
        scene = self.scene
        if not emitters.single_quad:
            return "exactly one quad light and no environment"
        if self.spheres or not self.n_tri:
            return "triangles only"
        if self.hidden_emitters:
            return "no emitting surface other than the light"
        bad = [n for n, m in zip(scene.material_names, scene.materials) if type(m) is not Lambertian]
        if bad:
            return f"Lambertian materials only (not {', '.join(bad)})"
        return None

    def groups(self, mat):
        """``[(material, rows)]`` of the rows (codes ``mat``) whose material is not
        Lambertian, each material's rows an index array in path order."""
        if not self.others:
            return []
        if len(self.others) == 1:
            rows = np.flatnonzero(mat == self.others[0])
            return [(self.others[0], rows)] if rows.size else []
        counts = np.bincount(mat, minlength=self.n_mat + 1)
        return [(mi, np.flatnonzero(mat == mi)) for mi in self.others if counts[mi]]

    def geometric_normals(self, tracer, prim, p):
        """Unit geometric normals (3, m) of primitives ``prim`` at SoA points ``p``
        (spheres: outward, ``(p - c) / r``)."""
        if not self.spheres:
            return np.take(self.normal_soa, prim, axis=1)
        if not self.n_tri:
            ng = np.empty((3, prim.shape[0]), dtype=self.dtype)
            on = np.arange(prim.shape[0])
        else:
            ng = np.take(self.normal_soa, prim, axis=1)
            on = np.flatnonzero(prim >= self.n_tri)
        if on.size:
            j = np.take(prim, on) - self.n_tri
            v = np.take(p, on, axis=1) - np.take(self.sphere_center_soa, j, axis=1)
            v /= np.take(self.sphere_radius, j)
            ng[:, on] = v
        return ng

    def frames(self, prim, ng, flip):
        """Shading frames ``(s, n, t)``, SoA (3, m) each, normal flipped where ``flip``:
        the triangles' from the table, the spheres' built per hit (Duff et al.
        2017's basis, as :class:`mcvar.geometry.Frame`)."""
        if self.n_tri:
            key = 2 * prim + flip
            fs, fn, ft = (np.take(self.frame_s, key, axis=1), np.take(self.frame_n, key, axis=1),
                          np.take(self.frame_t, key, axis=1))
            if not self.spheres:
                return fs, fn, ft
            on = np.flatnonzero(prim >= self.n_tri)
        else:
            m = prim.shape[0]
            fs, fn, ft = (np.empty((3, m), dtype=self.dtype) for _ in range(3))
            on = np.arange(m)
        if on.size:
            n = np.take(ng, on, axis=1)
            n = np.where(np.take(flip, on), -n, n)
            n /= np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
            x, y, z = n
            sign = np.copysign(1.0, y)
            a = -1.0 / (sign + y)
            b = z * x * a
            fs[:, on] = (sign + x * x * a, -x, b)
            fn[:, on] = n
            ft[:, on] = (sign * b, -sign * z, 1.0 + sign * z * z * a)
        return fs, fn, ft


class Transport:
    """One trace: the strategies used, its settings, the output.

    Parameters
    ----------
    scene, tracer
        What the loop reads.
    n : int
        Number of paths (rows of :attr:`radiance`).
    strategies : Strategies
        Which estimators are combined (NEE, emission found by BSDF sampling,
        MIS); ``strategies.depth`` overrides ``settings.max_depth``.
    settings : PathSettings
        Depth (None: Russian roulette from ``rr_depth`` segments on, default
        :data:`RR_START_DEPTH`, survival ``min(0.95, max(beta) / rr_threshold)``),
        MIS heuristic, light sampling, visible lights.
    stream : SampleStream
    tables : SceneTables, optional
        Built from ``scene``, ``tracer`` and ``settings.light_sampling`` if not given.
    """

    def __init__(self, scene, tracer, n, *, strategies: Strategies, settings: PathSettings,
                 stream: SampleStream, tables: SceneTables | None = None):
        if tables is None:
            tables = SceneTables.of(scene, tracer, settings.light_sampling)
        emitters = tables.emitters
        self.scene, self.tracer, self.emitters, self.tables = scene, tracer, emitters, tables
        self.settings = settings
        self.nee = strategies.nee and emitters.n_emitters > 0
        self.bsdf_hits, self.mis = strategies.bsdf_hits, strategies.mis
        self.weight_fn = HEURISTICS[settings.heuristic]
        depth = strategies.depth if strategies.depth is not None else settings.max_depth
        self.limit = RR_MAX_DEPTH if depth is None else depth
        self.roulette = depth is None
        self.stream = stream
        self.rr_start = RR_START_DEPTH if settings.rr_depth is None else settings.rr_depth
        self.rr_threshold = settings.rr_threshold
        self.eps = float(scene.ray_epsilon)
        self.radiance = np.zeros((3, n))
        self.rays = 0
        #: camera-path vertices whose Glass takes both lobes (:attr:`PathSettings.glass_splits`)
        self.splits = settings.glass_splits if tables.glass.any() else 0
        #: a path was split: several rows of the state add to one output row
        self.duplicates = False
        #: ``(spp, pixels)`` of a camera batch in pixel-major order (path reuse's tiles), else None
        self.layout = None
        #: :class:`~mcvar.integrators.emitters.VisibleLights` whose direct view
        #: by camera rays is left to the caller's exact image (None: sampled)
        self.visible = VisibleLights(scene) if settings.visible_lights == "exact" else None
        #: caustic paths ``E D (D|S)* S L`` are light tracing's (:mod:`~mcvar.integrators.caustics`):
        #: their emission is left out here
        self.caustic_light = (settings.caustics == "light" and tables.light_caustics and self.bsdf_hits
                              and self.limit >= 3)

    def add(self, rows, value) -> None:
        """``radiance[:, rows] += value``, one channel at a time (1-D fancy indexing
        is several times faster than 2-D); ``rows`` repeat once a path was split
        (:attr:`duplicates`: unbuffered ``np.add.at``)."""
        for c in range(3):
            if self.duplicates:
                np.add.at(self.radiance[c], rows, value[c])
            else:
                self.radiance[c, rows] += value[c]

    def emission_weight(self, k, prev_pdf, light_pdf):
        """MIS weight of emission found by the ray of segment ``k`` (BSDF sampling).

        ``prev_pdf``: the pdf of the bounce that made the ray (inf: camera ray
        or a delta lobe, which light sampling cannot draw); ``light_pdf``: a
        callable giving the density NEE would have drawn the emitter with.
        """
        n = prev_pdf.shape[0]
        if k == 1:
            return np.ones(n)
        delta = np.isinf(prev_pdf)
        if not self.bsdf_hits:
            # Light sampling cannot draw emission seen through a delta lobe, nor
            # emission of surfaces that are not lights (NEE density 0): BSDF
            # sampling, the only strategy that can, counts it (weight 1); other
            # emission after a smooth bounce was already counted by NEE.
            unsampled = delta.copy()
            if self.tables.hidden_emitters:
                unsampled |= ~(light_pdf() > 0.0)
            return unsampled.astype(np.float64)
        if not (self.nee and self.mis):
            return np.ones(n)
        w = self.weight_fn(np.where(delta, 1.0, prev_pdf), light_pdf())
        return np.where(delta, 1.0, w)

    def camera_hits(self, state: PathState, t, prim) -> None:
        """First segment, with :attr:`visible` set: subtract ``g`` of the camera
        rays that cross a handled light behind their first hit (``t`` inf, ``prim``
        -1 for misses); see :class:`~mcvar.integrators.emitters.VisibleLights`."""
        if self.visible:
            g = self.visible.hidden(state.o, state.d, t, prim)
            rows = np.flatnonzero(g.max(axis=0) > 0.0)
            if rows.size:
                self.add(state.idx[rows], -np.take(g, rows, axis=1))

    def hit_emission(self, k, state: PathState, p, prim) -> None:
        """Add the emission found by the rays of segment ``k`` at their hits ``p`` (SoA)."""
        emits = self.tables.emits
        if k == 1 and self.visible:
            emits = emits & ~self.visible.prim_exact      # f - g = 0: the caller adds the exact image
        lit = np.flatnonzero(np.take(emits, prim))
        if not lit.size:
            return
        if self.tables.quad_emission is not None:
            self._quad_emission(k, state, p, lit)
            return
        pl, dl, ol = p[:, lit].T, state.d[:, lit].T, state.o[:, lit].T
        pl, dl, ol = (np.asarray(a, dtype=np.float64) for a in (pl, dl, ol))
        pr = prim[lit]
        le = self.scene.emission(pr, pl, self.tracer.normals(pr, pl), dl)
        w = self.emission_weight(k, np.asarray(state.prev_pdf[lit], dtype=np.float64),
                                 lambda: self.emitters.pdf_li(pr, ol, pl))
        self.add(state.idx[lit], state.beta[:, lit] * le.T * w)

    def _quad_emission(self, k, state: PathState, p, lit) -> None:
        """:meth:`hit_emission` written out for the one quad light of
        :attr:`SceneTables.quad_emission`: ``beta Le w`` on its front, ``w``
        from :meth:`emission_weight`'s rules with NEE's density ``p_A r^2 /
        cos_l`` (no emitter NEE cannot sample in such scenes)."""
        le, n, pdf_area = self.tables.quad_emission
        d = np.take(state.d, lit, axis=1)
        cos_l = d[0] * -n[0]
        cos_l -= d[1] * n[1]
        cos_l -= d[2] * n[2]
        front = cos_l > 0.0
        if not front.all():
            lit, cos_l = lit[front], cos_l[front]
            if not lit.size:
                return
        if self.caustic_light and k >= 3:
            # vertex 1 non-specular and the last bounce specular: the light tracer's
            keep = ~(np.take(state.tag, lit) & np.isinf(np.take(state.prev_pdf, lit)))
            lit, cos_l = lit[keep], cos_l[keep]
            if not lit.size:
                return
        val = np.take(state.beta, lit, axis=1) * le[:, None]
        if k > 1:
            prev = np.take(state.prev_pdf, lit)
            delta = np.isinf(prev)
            if not self.bsdf_hits:
                val *= delta                # light sampling counted the rest
            elif self.nee and self.mis:
                v = np.take(p, lit, axis=1) - np.take(state.o, lit, axis=1)
                r = dot(v, v)
                r *= pdf_area
                r /= cos_l                  # NEE's density of this point
                r /= np.where(delta, 1.0, prev)
                if self.settings.heuristic == "power":
                    r *= r
                r += 1.0
                val /= np.where(delta, 1.0, r)
        self.add(np.take(state.idx, lit), val)

    def miss_emission(self, k, state: PathState, miss) -> None:
        """Add the environment's radiance along the rays ``miss`` that left the scene."""
        if self.emitters.env is None or not miss.size:
            return
        dm = np.asarray(state.d[:, miss].T, dtype=np.float64)
        if state.d.dtype != np.float64:        # float32 rays: unit length in float64 for the map's checks
            dm /= np.sqrt(np.einsum("ij,ij->i", dm, dm))[:, None]
        le = self.emitters.env.radiance(dm)
        w = self.emission_weight(k, np.asarray(state.prev_pdf[miss], dtype=np.float64),
                                 lambda: self.emitters.environment_pdf(dm))
        self.add(state.idx[miss], state.beta[:, miss] * le.T * w)


def lambertian_scene(scene, emitters: Emitters | None = None) -> bool:
    """Whether the Lambertian kernel (:mod:`mcvar.integrators.lambertian`) traces
    ``scene``: Lambertian triangles only, exactly one quad light and no other
    emitting surface, no environment (:attr:`SceneTables.lambertian`)."""
    emitters = Emitters(scene) if emitters is None else emitters
    hidden = bool(np.any(np.any(scene.prim_emission > 0, axis=1) & (scene.prim_light < 0)))
    return (emitters.single_quad and scene.n_spheres == 0 and scene.n_triangles > 0 and not hidden
            and all(type(m) is Lambertian for m in scene.materials))


def light_caustics_apply(scene) -> bool:
    """Whether ``caustics='light'`` changes anything on ``scene``: one quad light of
    constant one-sided radiance and nothing else emitting, every material purely
    specular or without a specular lobe, and some of each (:mod:`mcvar.integrators.caustics`)."""
    em = Emitters(scene)
    if not em.single_quad or scene.checker_period is not None:
        return False
    emits = np.any(scene.prim_emission > 0, axis=1)
    if np.any(emits & (scene.prim_light < 0)) or np.any(scene.prim_two_sided_emission[emits]):
        return False
    if not np.all(scene.prim_emission[emits] == scene.light_radiance[0]):
        return False
    delta = [bool(getattr(m, "is_delta", False)) for m in scene.materials]
    mixed = [bool(getattr(m, "has_delta", False)) and not d for m, d in zip(scene.materials, delta)]
    used = np.unique(scene.prim_material)
    return (not any(mixed[i] for i in used) and any(delta[i] for i in used)
            and not all(delta[i] for i in used))


def roulette(tr: Transport, state: PathState, k: int, alive) -> np.ndarray:
    """Russian roulette after the bounce at vertex ``k``: survive with
    ``q = min(0.95, max(beta) / tr.rr_threshold)``, ``beta /= q`` (unbiased).
    Returns the new ``alive`` mask.

    With the default threshold 1 a path's survival is its throughput (pbrt's
    rule); a threshold ``w < 1`` is the lower bound of a *weight window*
    (Booth 1982; Vorba and Krivanek 2016): only paths whose throughput fell
    below ``w`` play, and a survivor carries ``beta = w``, so that no path
    is ever weighted up beyond the window (the classic rule gives a path of
    throughput 0.04 a 25x weight).
    """
    beta = state.beta
    bmax = beta.max(axis=0)
    alive &= bmax > 0.0
    if tr.roulette and k >= tr.rr_start:
        q = np.minimum(bmax / tr.rr_threshold if tr.rr_threshold != 1.0 else bmax, 0.95)
        u = tr.stream.vertex(k, ROULETTE, 1, state.idx, state.weights.dtype)[0]
        survive = u < q
        beta /= np.where(survive, q, 1.0)
        alive &= survive
    return alive


def shadow_rays(p, ng, side, w, dist, eps):
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
        length = np.sqrt(dot(to_light, to_light))
        to_light /= length
        length -= 2.0 * eps
        return origin, to_light, length
    far = ~np.isfinite(dist)  # environment samples: infinitely far, keep w
    to_light = w * np.where(far, 1.0, dist)
    to_light += p
    to_light -= origin
    length = np.sqrt(dot(to_light, to_light))
    direction = np.where(far, w, to_light / length)
    return origin, direction, np.where(far, np.inf, length - 2.0 * eps)
