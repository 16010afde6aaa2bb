"""The Lambertian kernel: :func:`mcvar.integrators.trace_paths`' loop written out
for scenes of Lambertian triangles lit by one quad light (the Cornell box).

The same estimator as the general loop of :mod:`mcvar.integrators.path`
(the same sample stream layout, MIS weights, Russian roulette and shadow
rays), with the BSDF written out: ``f = albedo / pi``, ``p = cos theta /
pi`` (so the sampling weight is ``albedo``), sampled by Malley's method
through :func:`mcvar.integrators.directions.sample_directions` (the seam
both loops share). Because no
material needs its own call, the rays are not sorted by material; the
:class:`~mcvar.integrators.state.PathState` block is kept in the ray
geometry's precision, so compaction is one ``np.take`` of half the bytes.
The shading frame is the triangle's unflipped frame with the normal's sign
``sgn = sign(wo . n_g)`` applied to the local ``y`` only (the
cosine-weighted density is symmetric in ``x`` and ``z``, so which of the
two tangent orientations is used does not change the distribution).

**Path regeneration.** A batch's camera paths go through a wavefront of at
most :data:`WAVEFRONT_PATHS` slots: whenever fewer than half are live, the
next camera paths take the free slots (appended after the older rows), so
the rows of one iteration are at different depths. Each row then reads its
own vertex's columns of the sample stream (:class:`_VertexColumns`) and plays
roulette by its own depth; the first segment's rules (the exact light image's
correction, emission seen directly) apply to the new rows. A batch then has
one tail of nearly empty iterations (each costing NumPy's fixed overhead)
however many paths it holds, so larger batches pay
(:func:`~mcvar.integrators.allocation.main_batch_paths`). A path is still a
pure function of its row of ``u`` when ``u`` holds every number it reads
(then the radiance of every path does not depend on the slots, tested
exactly); otherwise its iid numbers come from the batch's ``rng`` in another
order, a different but equally distributed image, the same for any number
of workers. Numbers drawn iid (not from the sampler) are warped to the
cosine hemisphere by the polar map, 3x cheaper than the concentric one that
stratified numbers keep (:func:`~mcvar.integrators.directions.sample_directions`'s
``stratified`` rows). Measured on the Cornell box, 128 x 128, 256 spp
(docs/performance.md, 'The Cornell cases'): the tail fell from 9% to 3% of
a render.
"""
from __future__ import annotations

import numpy as np

from .directions import Vertex, sample_directions
from .reuse import PathReuse
from .state import PathState, Transport, dot, shadow_rays
from .stream import BSDF, CAMERA_DIMS, LIGHT, ROULETTE, VERTEX_DIMS

__all__ = ["trace_lambertian", "triangle_tables"]


class _Tables:
    """Per-triangle albedo, ``albedo Le / pi`` and unflipped frames (9, T) in the
    tracer's precision (:func:`triangle_tables`), and the light's constants."""

    def __init__(self, tr: Transport):
        self.frame9, self.albedo, self.f_le, self.black = triangle_tables(tr.tables, tr.tracer.dtype)
        em = tr.emitters
        self.emits = tr.tables.emits                 # the light's triangles (no other emitter here)
        self.le = em.radiance_soa[:, 0].copy()
        self.n_l = [float(c) for c in em.normal_soa[:, 0]]
        self.pdf_area = float(em.pdf_area[0])
        #: exponent of the MIS heuristic (power 2, balance 1), written out below
        self.mis_beta = {"power": 2.0, "balance": 1.0}[tr.settings.heuristic]


def triangle_tables(tables, dtype) -> tuple:
    """The kernel's per-triangle tables of ``tables`` (a
    :class:`~mcvar.integrators.state.SceneTables`) in ``dtype``: ``(frame9 (9, T),
    albedo (3, T), f_le (3, T), black (T,))``, read-only.

    They depend only on the scene tables and the precision, so they are built
    once and kept on the scene tables (which are kept on the tracer), not per
    batch: at 100,922 triangles they cost 3.5 ms, and an adaptive render has
    ~20 batches.
    """
    dt = np.dtype(dtype)
    cache = tables.__dict__.setdefault("_lambertian_tables", {})
    arrays = cache.get(dt)
    if arrays is None:
        arrays = cache[dt] = _build_tables(tables, dt)
    return arrays


def _build_tables(tables, dt) -> tuple:
    scene = tables.scene
    frame9 = np.ascontiguousarray(np.concatenate(
        [tables.frame_s[:, 0::2], tables.frame_n[:, 0::2], tables.frame_t[:, 0::2]]), dtype=dt)
    albedo = np.array([m.albedo for m in scene.materials]).T          # (3, M)
    albedo = np.ascontiguousarray(albedo[:, scene.prim_material])      # (3, T)
    le = tables.emitters.radiance_soa[:, :1]
    f_le = np.ascontiguousarray(albedo / np.pi * le)                  # NEE's f Le per triangle
    black = ~np.any(albedo > 0.0, axis=0)
    for a in (frame9, albedo, f_le, black):
        a.setflags(write=False)                  # shared by every batch of the tracer
    return frame9, albedo, f_le, black


#: Live paths of the kernel's wavefront: a batch of more camera paths is traced
#: through this many slots, a finished path's slot taken by a new camera path
#: (path regeneration), so that one batch has one tail of nearly empty
#: iterations however many paths it holds (docs/performance.md, 'The Cornell cases:
#: path regeneration').
WAVEFRONT_PATHS = 1 << 16
#: The slots are refilled once fewer than this share of them is live (a refill
#: copies the live state; doing it every iteration cost more than it saved).
REFILL_BELOW = 0.5


class _VertexColumns:
    """The sample stream of a wavefront whose rows are at different depths.

    ``depth[i]`` is the vertex row ``i`` is at; rows ``fresh ..`` are new
    camera paths (vertex 1), the rows before them continue older paths.
    :meth:`vertex` has :meth:`SampleStream.vertex`'s signature (so that
    :func:`~mcvar.integrators.directions.sample_directions` reads the BSDF
    columns through it) but ignores ``k``: each row reads its own vertex's
    columns, from the sampler's matrix where it covers them, else from the
    stream's ``rng`` (iid), exactly as a wavefront of one depth would. A path is
    still a pure function of its row of ``u`` when ``u`` is wide enough.
    """

    __slots__ = ("stream", "depth", "fresh")

    def __init__(self, stream, depth, fresh):
        self.stream, self.depth, self.fresh = stream, depth, fresh

    def _cover(self, offset) -> int:
        """How many vertices (1, 2, ...) find column ``offset`` in the sampler's matrix."""
        first = CAMERA_DIMS + offset + self.stream.base        # column of vertex 1's ``offset`` in u
        return 0 if self.stream.width <= first else (self.stream.width - first - 1) // VERTEX_DIMS + 1

    def stratified(self, offset, m):
        """The rows (a slice) whose columns at ``offset`` come from the sampler,
        or None when those rows are not one slice (the sampler covers vertices
        past the first)."""
        cover = self._cover(offset)
        if cover == 0:
            return slice(0, 0)
        return slice(self.fresh, m) if cover == 1 else None

    def vertex(self, k, offset, count, idx, dtype=np.float64):
        stream, depth = self.stream, self.depth
        m = idx.shape[0]
        cover = self._cover(offset)
        if cover == 0:
            return stream.rng.random((count, m), dtype=dtype)
        fresh = self.fresh
        if cover == 1:
            # the common case (the adaptive renders' 6 columns): only the new
            # camera paths, a contiguous tail of rows (vertex 1), read u; the
            # older rows are at vertex 2 or later
            if fresh == 0:
                return stream.vertex(1, offset, count, idx, dtype)
            if fresh == m:
                return stream.rng.random((count, m), dtype=dtype)
            out = np.empty((count, m), dtype)
            for j in range(count):               # the same numbers as rng.random((count, fresh))
                stream.rng.random(dtype=dtype, out=out[j, :fresh])
            out[:, fresh:] = stream.vertex(1, offset, count, idx[fresh:], dtype)
            return out
        out = np.empty((count, m), dtype)
        rest = np.flatnonzero(depth > cover)
        if rest.size:
            out[:, rest] = stream.rng.random((count, rest.size), dtype=dtype)
        for kk in range(1, cover + 1):
            rows = np.flatnonzero(depth == kk)
            if rows.size:
                out[:, rows] = stream.vertex(kk, offset, count, np.take(idx, rows), dtype)
        return out


def _rows(state: PathState, a: int, b: int) -> PathState:
    """Rows ``a:b`` of ``state`` as a :class:`PathState` of views (no copy)."""
    view = PathState.__new__(PathState)
    view.geo, view.weights, view.idx = state.geo[:, a:b], state.weights[:, a:b], state.idx[a:b]
    view.tag = None if state.tag is None else state.tag[a:b]
    return view


def trace_lambertian(tr: Transport, o, d, *, slots: int | None = None) -> None:
    """Trace SoA camera rays ``o, d`` (3, n) into ``tr.radiance``.

    At most ``slots`` (default :data:`WAVEFRONT_PATHS`) paths are live at once:
    when fewer than :data:`REFILL_BELOW` of them are, the next camera paths
    (in order) take the free slots, so the paths of one wavefront are at
    different depths (``depth``, the vertex each row is at). New camera paths
    are appended after the older rows: rows ``fresh ..`` are at their first
    segment (the camera's light image, emission seen directly).
    """
    tracer, stream = tr.tracer, tr.stream
    lt = _Tables(tr)
    dt = tracer.dtype
    frame9 = lt.frame9
    total = d.shape[1]
    slots = WAVEFRONT_PATHS if slots is None else slots
    refill_below = max(1, int(REFILL_BELOW * slots))
    reuse = PathReuse.start(tr, total, slots)
    nxt = min(total, slots) if reuse is None else reuse.aligned(0, slots)
    state = PathState(o[:, :nxt], d[:, :nxt], dtype=dt)
    if reuse is not None:
        state.tag = state.idx.copy()        # where a row's radiance goes (its reuse column from x2 on)
    depth = np.ones(nxt, dtype=np.int32)
    fresh = 0                               # rows fresh.. are new camera paths
    limit = tr.limit
    while state.n:
        t, prim = tracer.closest_soa(state.o, state.d, t_dtype=dt)    # float32 t: no float64 round trip
        m = state.n
        if tr.visible and fresh < m:
            tr.camera_hits(_rows(state, fresh, m), t[fresh:].astype(np.float64), prim[fresh:])
        t = t.astype(dt, copy=False)
        tr.rays += m
        alive = None
        if prim.min() < 0:                 # drop the rays that left the scene (no environment)
            keep = np.flatnonzero(prim >= 0)
            fresh = int(np.searchsorted(keep, fresh))
            state.take(keep)
            t, prim, depth = np.take(t, keep), np.take(prim, keep), np.take(depth, keep)
            m = state.n
        if m:
            p = state.d * t
            p += state.o
            if fresh < m:
                tr.hit_emission(1, _rows(state, fresh, m), p[:, fresh:], prim[fresh:])
            if fresh:
                _hit_light(tr, lt, _rows(state, 0, fresh), t[:fresh], prim[:fresh])
            if depth.max() >= limit:       # paths of ``limit`` segments end here
                keep = np.flatnonzero(depth < limit)
                fresh = int(np.searchsorted(keep, fresh))
                state.take(keep)
                t, prim, depth, p = np.take(t, keep), np.take(prim, keep), np.take(depth, keep), np.take(p, keep, 1)
                m = state.n
        if m:
            cols = _VertexColumns(stream, depth, fresh)
            frame = np.take(frame9, prim, axis=1)
            fs, fn, ft = frame[0:3], frame[3:6], frame[6:9]
            sgn = np.sign(dot(state.d, fn))
            np.negative(sgn, out=sgn)          # sign(wo . n_g); 0 (grazing) gives f = 0
            if reuse is not None:
                if fresh < m:
                    reuse.first_vertices(state.idx[fresh:], p[:, fresh:], fn[:, fresh:] * sgn[fresh:],
                                         np.take(lt.albedo, prim[fresh:], axis=1),
                                         ~np.take(lt.black, prim[fresh:]) & (sgn[fresh:] != 0))
                second = np.flatnonzero(depth[:fresh] == 2)
                if second.size:
                    reuse.connect(tr, state, second, p, fn, sgn, prim)
            if tr.nee:                         # depth + 1 <= limit on every row here
                _next_event(tr, lt, state, cols, p, fn, sgn, prim)
            alive = np.ones(m, dtype=bool)
            if not tr.bsdf_hits:
                alive &= depth + 1 < limit     # the last segment's emission is NEE's
            # d is not needed any more: the new directions are written into it
            dirs = sample_directions(Vertex(None, state.idx, frame=(fs, fn, ft), sgn=sgn, albedo=lt.albedo,
                                            prim=prim, stratified=cols.stratified(BSDF, m)), cols, out=state.d)
            beta = state.beta
            beta *= dirs.weight                # in place (``state.beta[...] *=`` would copy the block onto itself)
            pdf = dirs.pdf
            del dirs                           # free the weights now (allocator reuse)
            _row_roulette(tr, state, cols, alive)
            # leave on wi's side of the surface: sign(wi . n_g) = sgn for a valid sample
            np.multiply(fn, sgn * tr.eps, out=state.o)
            state.o[...] += p
            state.prev_pdf[...] = pdf
            if not alive.all():
                keep = np.flatnonzero(alive)
                state.take(keep)
                depth = np.take(depth, keep)
        depth += 1
        fresh = state.n
        if fresh < refill_below and nxt < total:
            end = min(total, nxt + slots - fresh)
            nxt = _refill(state, o, d, nxt, end if reuse is None else reuse.aligned(nxt, end))
            depth = np.concatenate([depth, np.ones(state.n - fresh, dtype=np.int32)])
    if reuse is not None:
        reuse.finish(tr)


def _refill(state: PathState, o, d, a: int, b: int) -> int:
    """Append camera paths ``a:b`` (rays ``o, d``) to ``state``; returns ``b``."""
    n, add = state.n, b - a
    geo = np.empty((6, n + add), dtype=state.geo.dtype)
    geo[:, :n] = state.geo
    geo[0:3, n:] = o[:, a:b]
    geo[3:6, n:] = d[:, a:b]
    weights = np.empty((4, n + add), dtype=state.weights.dtype)
    weights[:, :n] = state.weights
    weights[0:3, n:] = 1.0
    weights[3, n:] = np.inf
    state.geo, state.weights = geo, weights
    state.idx = np.concatenate([state.idx, np.arange(a, b)])
    if state.tag is not None:
        state.tag = np.concatenate([state.tag, np.arange(a, b)])
    return b


def _row_roulette(tr: Transport, state: PathState, cols: _VertexColumns, alive) -> None:
    """:func:`mcvar.integrators.state.roulette` for rows at different depths:
    the rows at vertex ``>= rr_start`` survive with ``q = min(0.95, max(beta) /
    rr_threshold)`` and carry ``beta / q``; ``alive`` (m,) is updated in place.
    Once any row plays, every row draws its roulette number (a wavefront of
    one depth draws exactly as the general loop does)."""
    beta = state.beta
    bmax = beta.max(axis=0)
    alive &= bmax > 0.0
    if not tr.roulette:
        return
    depth = cols.depth
    play = depth >= tr.rr_start
    if not play[-1] and not play.any():           # new rows are appended last: usually decided at once
        return
    q = np.divide(bmax, tr.rr_threshold, out=bmax) if tr.rr_threshold != 1.0 else bmax
    np.minimum(q, 0.95, out=q)
    u = cols.vertex(None, ROULETTE, 1, state.idx, state.weights.dtype)[0]
    survive = u < q
    if not play.all():
        q[~play] = 1.0                             # rows not yet playing keep their weight ...
        survive |= ~play                           # ... and live
    beta /= np.where(survive, q, 1.0)
    alive &= survive


def _next_event(tr: Transport, lt: _Tables, state: PathState, cols, p, fn, sgn, prim) -> None:
    """NEE: ``beta (albedo / pi) Le cos_i w_light / p_light`` over unoccluded
    samples, with ``p_bsdf = cos_i / pi``."""
    idx = state.idx
    w, dist, _, pdf_l, _ = tr.emitters.sample_li(p, cols.vertex(None, LIGHT, 2, idx, p.dtype), None, radiance=False)
    cos_i = dot(w, fn)
    cos_i *= sgn                            # local wi.y in the flipped frame
    ok = cos_i > 0.0
    ok &= pdf_l > 0.0
    ok &= ~np.take(lt.black, prim)
    go = np.flatnonzero(ok)
    if go.size == 0:
        return
    cg, plg, pg = np.take(cos_i, go), np.take(pdf_l, go), np.take(prim, go)
    scale = cg / plg
    if tr.mis:
        scale *= _mis_weight(lt, plg, cg * (1.0 / np.pi))
    contrib = np.take(state.beta, go, 1)
    contrib *= np.take(lt.f_le, pg, 1)
    contrib *= scale
    side = np.take(sgn, go)
    origin, d_shadow, tmax = shadow_rays(np.take(p, go, 1), np.take(fn, go, 1), side, np.take(w, go, 1),
                                         np.take(dist, go), tr.eps)
    keys = tr.tracer.shadow_keys(pg, side, np.zeros(go.size, dtype=np.int64))
    blocked = tr.tracer.occluded_soa(origin, d_shadow, tmax, keys)
    vis = np.flatnonzero(~blocked)
    tr.add(np.take(idx if state.tag is None else state.tag, np.take(go, vis)), np.take(contrib, vis, 1))
    tr.rays += int(go.size)


def _mis_weight(lt: _Tables, p_this, p_other):
    """The power (or balance) heuristic for positive finite densities, written
    out: ``1 / (1 + (p_other / p_this)^beta)`` (the kernel's own densities need
    none of :func:`mcvar.estimators.power_heuristic`'s checks and special cases)."""
    r = p_other / p_this
    if lt.mis_beta == 2.0:
        r *= r
    r += 1.0
    return np.divide(1.0, r, out=r)


def _hit_light(tr: Transport, lt: _Tables, state: PathState, t, prim) -> None:
    """Emission found by BSDF sampling (segments ``k >= 2``) on the one quad
    light: ``beta Le w`` on its front, ``w`` the MIS weight against NEE's
    density ``p_A t^2 / cos_l`` (:meth:`Transport.emission_weight` written out
    for this kernel's scenes: no delta lobes, no emitter NEE cannot sample)."""
    if not tr.bsdf_hits:
        return                                     # NEE alone counts the light
    lit = np.flatnonzero(np.take(lt.emits, prim))
    if not lit.size:
        return
    d = np.take(state.d, lit, axis=1)
    n = lt.n_l
    cos_l = d[0] * -n[0]
    cos_l -= d[1] * n[1]
    cos_l -= d[2] * n[2]
    front = cos_l > 0.0
    if not front.all():
        lit, cos_l, d = lit[front], cos_l[front], None
        if not lit.size:
            return
    val = np.take(state.beta, lit, axis=1) * lt.le[:, None]
    if tr.nee and tr.mis:
        tl = np.take(t, lit)
        p_light = tl * tl
        p_light *= lt.pdf_area
        p_light /= cos_l
        val *= _mis_weight(lt, np.take(state.prev_pdf, lit), p_light)
    tr.add(np.take(state.idx if state.tag is None else state.tag, lit), val)
