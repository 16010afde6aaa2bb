"""Path tracing and one-bounce direct lighting: ``path``, ``path_bsdf``,
``direct``, ``direct_light``, ``direct_bsdf`` (lecture: 'Previous Methods',
'Direct vs Indirect Illumination', 'Multiple Importance Sampling').

=================  ==========================================================
``direct``         one-bounce direct lighting, light sampling and BSDF
                   sampling combined by MIS (``heuristic``: power or balance)
``direct_light``   one-bounce direct lighting by light sampling; what light
                   sampling cannot draw (emitters seen through a delta lobe,
                   emitting surfaces that are not lights) by BSDF sampling,
                   the only strategy that can (before issue 10 it was
                   missing, so on scenes with mirrors, glass, smooth plastic
                   or the furnace it disagreed with ``direct``)
``direct_bsdf``    one-bounce direct lighting by BSDF sampling only
``path``           path tracing with next-event estimation and MIS ('backward
                   path tracing + connect to light'); Russian roulette when
                   ``max_depth`` is None (unbiased), fixed depth otherwise
                   (biased: longer paths are missing)
``path_bsdf``      path tracing that finds emitters only by chance ('backward
                   path tracing': fails for point lights, noisy for small ones)
=================  ==========================================================

Depth convention (CORNELL.md): a path of ``k`` segments has depth ``k``;
``max_depth = 1`` shows emitters seen directly, ``2`` adds direct
illumination, ``3`` one indirect bounce, and so on. The ``direct*``
methods are depth 2.

Two loops run these estimators: the general one here (any material; rays in
path order, Lambertian materials written out on every row and the other
BSDFs called unchecked on their own rows; rays in the tracer's precision,
throughputs in float64) and the Lambertian kernel of
:mod:`mcvar.integrators.lambertian` (the same estimator written out for
scenes of Lambertian triangles and one quad light). The option
``kernel='auto'`` picks the Lambertian kernel where the scene allows it;
``'general'`` and ``'lambertian'`` force one (``'lambertian'`` on a scene
it cannot run is a ``ValueError`` naming what the scene lacks).
"""
from __future__ import annotations

from functools import partial

import numpy as np

from .._validation import as_rng
from ..tracer import Tracer
from ..warps import _INV_PI
from .directions import Vertex, sample_directions, unchecked, unit64
from .emitters import Emitters, VisibleLights
from .film import BatchJob, BatchResult, camera_result
from .lambertian import trace_lambertian, triangle_tables
from .registry import Method, pop_method_name, register
from .settings import HEURISTICS, KERNELS, PATH_OPTIONS, STRATEGIES, PathSettings
from .state import PathState, SceneTables, Transport, dot, roulette, shadow_rays
from .stream import CAMERA_DIMS, LIGHT, LIGHT_SELECT, SampleStream, camera_rays

__all__ = ["HEURISTICS", "KERNELS", "trace_paths", "trace_camera_paths"]


def _method_and_settings(options: dict, settings, where: str):
    """``(method name, PathSettings)`` from the keywords of :func:`trace_paths`."""
    options = dict(options)
    name = pop_method_name(options, options.pop("method", None), where)
    if name not in STRATEGIES:
        raise ValueError(f"method must be one of {tuple(STRATEGIES)}; got {name!r}")
    settings = PathSettings.from_keywords(options, settings=settings, where=where)
    if options:
        raise TypeError(f"{where}() got unexpected keyword argument(s) {', '.join(map(repr, options))}")
    return name, settings


def trace_paths(scene, origins, directions, u, *, rng=None, tracer: Tracer | None = None,
                settings: PathSettings | None = None, **options):
    """Radiance carried back along each camera ray: the wavefront core.

    Parameters
    ----------
    scene : Scene
    origins, directions : ndarray, shape (n, 3)
        Camera rays (unit directions).
    u : ndarray, shape (n, D), or None
        The paths' sample streams *after* the camera columns: column
        ``6 (k - 1) + j`` is dimension ``j`` of vertex ``k``
        (:mod:`mcvar.integrators.stream`: light point 0-1, BSDF 2-3,
        roulette 4, emitter choice 5). Columns beyond ``D`` come from
        ``rng``; with ``D >= 6 (max_depth - 1)`` a path uses no ``rng`` at
        all: it is a pure function of its row of ``u``.
    rng : None, int, SeedSequence or Generator
    tracer : Tracer, optional
        Reuse a tracer (its precision); default float32.
    settings : PathSettings, optional
        Depth, MIS heuristic, kernel, light sampling, Russian roulette and
        visible lights (:class:`~mcvar.integrators.settings.PathSettings`);
        or give its fields as keywords (``max_depth=3, kernel='general'``).
        With ``visible_lights='exact'`` the rays must be camera rays: the
        emission of the lights :class:`~mcvar.integrators.emitters.VisibleLights`
        handles, seen directly, is left out (``f - g``) and the caller adds
        ``VisibleLights(scene).image(res)[pixel]`` to each ray's radiance (as
        :func:`mcvar.integrators.render` does), a control variate that removes
        the variance of the light's edge in the image.
    **options
        ``method`` (alias ``integrator``): ``path`` (default), ``path_bsdf``,
        ``direct``, ``direct_light`` or ``direct_bsdf``; and the fields of
        :class:`PathSettings` when ``settings`` is not given.

    Returns
    -------
    radiance : ndarray, shape (n, 3), float64
    rays : int
        Rays traced (including the camera rays and shadow rays).

    Notes
    -----
    At vertex ``x_k`` (hit by segment ``k``) with throughput ``beta``:

    * emission ``Le(x_k -> x_{k-1})`` is added with weight 1 for ``k = 1``
      or after a delta lobe (decided *per sample* by the mask of
      ``sample(..., return_delta=True)``: a layered material such as a smooth
      :class:`mcvar.bsdf.Plastic` has both kinds), else with the MIS weight
      ``w(p_bsdf, p_light)`` (``direct_light``: 0 where NEE could have drawn
      it, else 1);
    * NEE (if ``k + 1 <= max_depth``): an emitter point drawn with density
      ``p_light`` (area density converted to solid angle,
      ``p_A r^2 / |cos theta_l|``), one shadow ray, adding
      ``beta f cos Le w(p_light, p_bsdf) / p_light`` (``f`` and ``p_bsdf``
      are the non-delta part: ``eval`` and ``pdf`` omit delta lobes);
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
    name, settings = _method_and_settings(options, settings, "trace_paths")
    rng = as_rng(rng)
    if settings.visible_lights == "exact" and not _all_at(origins, scene.camera.position):
        raise ValueError("visible_lights='exact' needs camera rays: every origin at scene.camera.position")
    tracer = tracer if tracer is not None else Tracer(scene)
    stream = SampleStream(None if u is None else np.asarray(u, dtype=np.float64), rng, camera=False)
    return _trace(scene, tracer, np.asarray(origins, dtype=np.float64).T,
                  np.asarray(directions, dtype=np.float64).T, stream, name, settings)


def trace_camera_paths(scene, res, pixel, u, *, rng=None, tracer: Tracer | None = None,
                       settings: PathSettings | None = None, **options):
    """Radiance of camera paths through ``pixel`` given their whole sample vectors ``u``.

    ``u`` (n, D): columns 0-1 the position inside the pixel, then the
    vertex columns of :func:`trace_paths`. With ``D >= stream_dim(max_depth)``
    (:func:`mcvar.integrators.stream.stream_dim`) each path is a pure
    function of ``(pixel, u)``: the primary sample space of Metropolis
    light transport. ``settings`` and ``**options`` (``method``, the fields
    of :class:`PathSettings`) as for :func:`trace_paths`. Where ``pixel``
    is runs of one length (a camera batch: each pixel's samples together),
    ``reuse`` (path reuse) makes its tiles of consecutive runs; otherwise
    there is no reuse. Returns ``(radiance (n, 3), rays)``.
    """
    name, settings = _method_and_settings(options, settings, "trace_camera_paths")
    u = np.asarray(u, dtype=np.float64)
    if u.ndim != 2 or u.shape[1] < CAMERA_DIMS:
        raise ValueError(f"u must have shape (n, D) with D >= {CAMERA_DIMS}; got {u.shape}")
    tracer = tracer if tracer is not None else Tracer(scene)
    d = scene.camera.ray_directions_soa(res, pixel, u[:, :CAMERA_DIMS])
    o = np.broadcast_to(scene.camera.position[:, None], d.shape)
    stream = SampleStream(u, as_rng(rng))
    return _trace(scene, tracer, o, d, stream, name, settings, _runs(pixel) if settings.reuse > 1 else None)


def _runs(pixel):
    """``(spp, pixels)`` when ``pixel`` is ``pixels`` runs of ``spp`` equal entries, else None."""
    pixel = np.asarray(pixel).reshape(-1)
    starts = np.flatnonzero(np.diff(pixel)) + 1
    spp = int(starts[0]) if starts.size else pixel.size
    if spp == 0 or pixel.size % spp or not np.all(np.diff(starts, prepend=0) == spp):
        return None
    return spp, pixel.size // spp


def _trace(scene, tracer, o, d, stream, name: str, settings: PathSettings, layout=None):
    """The loops' common entry: rays SoA (3, n), the method ``name``'s strategies;
    ``layout`` ``(spp, pixels)``: the rays are ``pixels`` pixels' ``spp`` samples in
    pixel-major order (a camera batch), which path reuse needs."""
    tables = SceneTables.of(scene, tracer, settings.light_sampling)
    if settings.kernel == "lambertian":
        missing = tables.lambertian_missing(tables.emitters)
        if missing:
            raise ValueError(f"kernel='lambertian' needs {missing}; scene {scene.name!r} does not have it")
    tr = Transport(scene, tracer, o.shape[1], strategies=STRATEGIES[name], settings=settings, stream=stream,
                   tables=tables)
    tr.layout = layout
    if tables.lambertian and settings.kernel != "general":
        trace_lambertian(tr, o, d)
    else:
        _trace_general(tr, o, d)
    return np.ascontiguousarray(tr.radiance.T), tr.rays


def _trace_general(tr: Transport, o, d) -> None:
    """The general wavefront loop (any material); see :func:`trace_paths`.

    The rows stay in path order: Lambertian materials are written out on
    every row at once (their albedo is a per-primitive table, 0 on other
    materials' primitives), and each other material's BSDF is called on its
    own rows (index arrays), so the path state is never sorted.
    """
    tracer, tables, stream = tr.tracer, tr.tables, tr.stream
    materials = tables.materials
    dt = tables.dtype
    state = PathState(o, d, dtype=dt, weight_dtype=np.float64)
    k = 0
    while state.n and k < tr.limit:
        k += 1
        n = state.n
        t, prim = tracer.closest_soa(state.o, state.d)
        tr.rays += n
        if k == 1 and tr.visible:
            tr.camera_hits(state, t, prim)
        # -- rays that left the scene: environment emission, then dropped
        if prim.min() < 0:
            if tr.emitters.env is not None:
                tr.miss_emission(k, state, np.flatnonzero(prim < 0))
            keep = np.flatnonzero(prim >= 0)
            if keep.size == 0:
                break
            state.take(keep)
            t, prim = np.take(t, keep), np.take(prim, keep)
        m = state.n
        t = t.astype(dt, copy=False)
        p = state.d * t
        p += state.o
        # -- emission at the hit
        tr.hit_emission(k, state, p, prim)
        if k >= tr.limit:
            break
        mat = np.take(tables.mat_code, prim)
        groups = tables.groups(mat)
        # -- shading frame: flip two-sided materials' normal towards wo
        ng = tables.geometric_normals(tracer, prim, p)
        wo = -state.d
        flip = np.take(tables.flips, mat) & (dot(ng, wo) < 0.0)
        frame = tables.frames(prim, ng, flip)
        fs, fn, ft = frame
        wo_l = np.stack([dot(wo, fs), dot(wo, fn), dot(wo, ft)])
        del wo
        # -- next-event estimation (adds paths of k + 1 segments)
        vertex = Vertex(k, state.idx, frame, wo_local=wo_l, groups=groups, materials=materials, prim=prim,
                        diffuse=tables.diffuse_albedo if tables.any_diffuse else None)
        if tr.nee and k + 1 <= tr.limit:
            _next_event(tr, state, vertex, p, ng, prim)
        # -- continue the path by BSDF sampling? (without bsdf_hits only
        # through delta lobes, whose emission light sampling cannot find)
        last = k + 1 == tr.limit and not tr.bsdf_hits
        if k + 1 > tr.limit or (last and not (tables.any_delta or tables.hidden_emitters)):
            break
        dirs = sample_directions(vertex, stream)
        if tr.caustic_light and k == 1:
            # vertex 1 non-specular: light arriving through a specular vertex is the light tracer's
            state.tag = ~np.take(tables.all_delta, mat)
        branch = _split_glass(tr, state, vertex, dirs, mat) if k <= tr.splits else None
        state.beta[...] *= dirs.weight
        wi, pdf = dirs.wi, dirs.pdf
        del dirs                           # free the weights now (allocator reuse)
        keep_all = not last or tables.hidden_emitters
        alive = roulette(tr, state, k, np.ones(m, dtype=bool) if keep_all else np.isinf(pdf))
        side = np.sign(dot(wi, ng))
        side *= tr.eps
        np.multiply(ng, side, out=state.o)
        state.o[...] += p
        state.d[...] = wi
        state.prev_pdf[...] = pdf
        if branch is not None:
            rb, wi_b, beta_b = branch
            ngb = np.take(ng, rb, axis=1)
            side = np.sign(dot(wi_b, ngb))
            side *= tr.eps
            ngb *= side
            ngb += np.take(p, rb, axis=1)
            state.append(rb, ngb, wi_b, beta_b)
            alive = np.concatenate([alive, beta_b.max(axis=0) > 0.0])
            tr.duplicates = True
        if not alive.all():
            state.take(np.flatnonzero(alive))


def _split_glass(tr: Transport, state: PathState, vertex: Vertex, dirs, mat):
    """Both lobes of Glass at vertex ``k`` of the camera paths whose vertices so far
    are all Glass (:attr:`~mcvar.integrators.settings.PathSettings.glass_splits`).

    The sampled direction of those rows is replaced by the lobe ``u0 = 0``
    chooses (reflection where ``F > 0``) with weight ``tint x P(lobe)``; where
    the other lobe has probability > 0 (``0 < F < 1``: not under total
    internal reflection) it is returned as a new branch ``(rows, wi (3, b),
    beta (3, b))`` with ``beta`` the throughput so far times ``tint x (1 - F)``.
    The sum of the branches has the expectation of the choice (its two terms).
    """
    tables = tr.tables
    on = np.take(tables.glass, mat)
    state.prefix = on if state.prefix is None else state.prefix & on
    rows = np.flatnonzero(state.prefix)
    if not rows.size:
        return None
    out_rows, out_wi, out_w = [], [], []
    mats = np.take(mat, rows)
    for mi in np.unique(mats):
        r = rows[mats == mi]
        material = tables.materials[mi]
        wo = unit64(np.take(vertex.wo_local, r, axis=1))
        wi_a, w_a, p_a, _ = material._sample(wo, np.zeros((r.size, 2)))
        wi_b, w_b, p_b, _ = material._sample(wo, np.ones((r.size, 2)))
        frame = tuple(np.take(f, r, axis=1) for f in vertex.frame)
        dirs.wi[:, r] = _to_world(frame, wi_a.T.astype(dirs.wi.dtype))
        dirs.weight[:, r] = (w_a * p_a[:, None]).T
        dirs.pdf[r] = np.inf
        two = np.flatnonzero(p_a < 1.0)           # 0 < F < 1: the other lobe exists
        if two.size:
            out_rows.append(r[two])
            out_wi.append(_to_world(tuple(f[:, two] for f in frame), wi_b[two].T.astype(dirs.wi.dtype)))
            out_w.append((w_b[two] * p_b[two, None]).T)
    if not out_rows:
        return None
    rb = np.concatenate(out_rows)
    beta_b = np.take(state.beta, rb, axis=1) * np.concatenate(out_w, axis=1)
    return rb, np.concatenate(out_wi, axis=1), beta_b


def _to_world(frame, v):
    """Local SoA directions ``v`` (3, m) to world: ``s x + n y + t z``."""
    fs, fn, ft = frame
    w = fs * v[0]
    w += fn * v[1]
    w += ft * v[2]
    return w


def _next_event(tr: Transport, state: PathState, vertex: Vertex, p, ng, prim) -> None:
    """Connect every shading point to an emitter; add the unoccluded contributions.

    SoA arrays (3, m) in path order; Lambertian materials written out on all
    rows, the others evaluated on their rows (``vertex.groups``: material, rows).
    """
    idx = state.idx
    k, frame, wo_l = vertex.k, vertex.frame, vertex.wo_local
    tables = tr.tables
    u = tr.stream.vertex(k, LIGHT, 2, idx, p.dtype)
    u_sel = tr.stream.vertex(k, LIGHT_SELECT, 1, idx)[0] if tr.emitters.n_emitters > 1 else None
    w, dist, le, pdf_l, light = tr.emitters.sample_li(p, u, u_sel)
    fs, fn, ft = frame
    wi_l = np.stack([dot(w, fs), dot(w, fn), dot(w, ft)])
    # Lambertian rows: f = albedo / pi and p = cos / pi, both where wo and wi lie above
    ok = wo_l[1] > 0.0
    ok &= wi_l[1] > 0.0
    f = np.take(tables.diffuse_f, prim, axis=1)
    f *= ok
    if tr.mis:
        ok &= np.take(tables.diffuse, prim)
        pdf_b = np.where(ok, wi_l[1] * _INV_PI, 0.0)
    materials = tables.materials
    for mi, rows in vertex.groups:
        if tables.all_delta[mi]:
            continue                       # f = 0 and p = 0 there already (no diffuse albedo)
        wo_g, wi_g = unit64(np.take(wo_l, rows, axis=1)), unit64(np.take(wi_l, rows, axis=1))
        f[:, rows] = unchecked(materials[mi], "eval")(wo_g, wi_g).T
        if tr.mis:
            pdf_b[rows] = unchecked(materials[mi], "pdf")(wo_g, wi_g)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.abs(wi_l[1]) / np.where(pdf_l > 0, pdf_l, np.inf)
    contrib = state.beta * f
    contrib *= le
    contrib *= scale
    go = np.flatnonzero(contrib.max(axis=0) > 0.0)
    if go.size == 0:
        return
    contrib = np.take(contrib, go, axis=1)
    if tr.mis:
        pb = np.take(pdf_b, go)
        if tr.emitters.n_points:
            pb[np.take(light, go) == -2] = 0.0   # a point light: BSDF sampling cannot hit it, weight 1
        # the heuristic written out: NEE's density is positive and finite on ``go``,
        # BSDF densities (non-delta parts) are finite
        r = pb / np.take(pdf_l, go)
        if tr.settings.heuristic == "power":
            r *= r
        r += 1.0
        contrib /= r
    ngo = np.take(ng, go, 1)
    wgo = np.take(w, go, 1)
    side = np.sign(dot(wgo, ngo))
    origin, d_shadow, tmax = shadow_rays(np.take(p, go, 1), ngo, side, wgo, np.take(dist, go), tr.eps)
    keys = tr.tracer.shadow_keys(np.take(prim, go), side, np.take(light, go))
    blocked = tr.tracer.occluded_soa(origin, d_shadow, tmax, keys)
    vis = np.flatnonzero(~blocked)
    tr.add(np.take(idx, np.take(go, vis)), np.take(contrib, vis, 1))
    tr.rays += int(go.size)


# ---------------------------------------------------------------------------
# The registered methods

def run_path_batch(name: str, job: BatchJob) -> BatchResult:
    """``run_batch`` of the path-tracing and direct-lighting methods (``partial(run_path_batch, name)``)."""
    pixel, o, d, stream = camera_rays(job, soa=True)
    radiance, rays = _trace(job.scene, job.tracer, o, d, stream, name, job.settings, (job.spp, job.n_pixels))
    if job.settings.visible_lights == "exact":
        radiance += VisibleLights(job.scene).image(job.res)[pixel]
    return camera_result(job, radiance, rays, name)


def _all_at(points, position) -> bool:
    """Every row of ``points`` (n, 3) equals ``position``; one row when they are
    a broadcast of it (stride 0), as the renderers' camera rays are."""
    a = np.asarray(points)
    if a.ndim == 2 and a.shape[0] and a.strides[0] == 0:
        a = a[:1]
    return bool(np.all(a == position))


def _check_kernel(scene, options) -> None:
    """``check_scene`` of the path methods: valid settings, and a scene the kernel and light sampling can run."""
    settings = PathSettings(**{k: options[k] for k in PATH_OPTIONS})
    Emitters(scene, settings.light_sampling)    # a non-rectangular light with solid_angle: ValueError
    if settings.kernel == "lambertian":
        emitters = Emitters(scene)
        missing = SceneTables(scene, Tracer(scene), emitters).lambertian_missing(emitters)
        if missing:
            raise ValueError(f"kernel='lambertian' needs {missing}; scene {scene.name!r} does not have it")


_SUMMARIES = {
    "path": "path tracing, next-event estimation + MIS; Russian roulette when max_depth is None",
    "path_bsdf": "path tracing that finds emitters only by BSDF sampling",
    "direct": "one-bounce direct lighting, light and BSDF sampling combined by MIS",
    "direct_light": "one-bounce direct lighting by light sampling",
    "direct_bsdf": "one-bounce direct lighting by BSDF sampling",
}

#: The lecture's 'Rendering Algorithm Chart' claim (consistent, unbiased); the
#: other modes have no row there. What mcvar measures is in `mcvar chart`.
_LECTURE = {"path": ("almost", "almost")}

def _warm(scene, tracer, settings: PathSettings) -> None:
    """:attr:`Method.warm` of the path methods: the scene tables every batch reads,
    and the Lambertian kernel's per-triangle tables where the kernel runs."""
    tables = SceneTables.of(scene, tracer, settings.light_sampling)
    if tables.lambertian and settings.kernel != "general":
        triangle_tables(tables, tracer.dtype)


_DEFAULTS = PathSettings()
for _name, _mode in STRATEGIES.items():
    register(Method(_name, "camera", partial(run_path_batch, _name), _SUMMARIES[_name],
                    options={key: getattr(_DEFAULTS, key) for key in PATH_OPTIONS},
                    check_scene=_check_kernel, warm=_warm,
                    lecture=_LECTURE.get(_name),
                    fixed_depth=_mode.depth,
                    **(dict(chart_row="Path Tracing",
                            theory=("yes", "yes", "with Russian roulette path tracing is unbiased (and so "
                                    "consistent), not 'almost': every path length is kept, its probability "
                                    "divided out"),
                            chart_depths={3: ("no", "no", "a fixed depth (3) drops the light of longer paths: "
                                              "biased, and the MSE levels off at that bias, so not consistent "
                                              "either")})
                       if _name == "path" else {})))
