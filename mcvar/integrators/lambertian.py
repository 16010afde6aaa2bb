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
"""
from __future__ import annotations

import numpy as np

from .directions import Vertex, sample_directions
from .state import PathState, Transport, dot, roulette, shadow_rays
from .stream import LIGHT

__all__ = ["trace_lambertian"]


class _Tables:
    """Per-triangle albedo, ``albedo Le / pi`` and unflipped frames (9, T)."""

    def __init__(self, tr: Transport):
        scene, tables = tr.scene, tr.tables
        self.frame9 = np.ascontiguousarray(np.concatenate(
            [tables.frame_s[:, 0::2], tables.frame_n[:, 0::2], tables.frame_t[:, 0::2]]))
        albedo = np.array([m.albedo for m in scene.materials]).T          # (3, M)
        self.albedo = np.ascontiguousarray(albedo[:, scene.prim_material])   # (3, T)
        le = tr.emitters.radiance_soa[:, :1]
        self.f_le = np.ascontiguousarray(self.albedo / np.pi * le)          # NEE's f Le per triangle
        self.black = ~np.any(self.albedo > 0.0, axis=0)
        em = tr.emitters
        self.emits = tr.tables.emits                 # the light's triangles (no other emitter here)
        self.le = em.radiance_soa[:, 0].copy()
        self.n_l = [float(c) for c in em.normal_soa[:, 0]]
        self.pdf_area = float(em.pdf_area[0])
        #: exponent of the MIS heuristic (power 2, balance 1), written out below
        self.mis_beta = {"power": 2.0, "balance": 1.0}[tr.settings.heuristic]


def trace_lambertian(tr: Transport, o, d) -> None:
    """Trace SoA camera rays ``o, d`` (3, n) into ``tr.radiance``."""
    tracer, stream = tr.tracer, tr.stream
    lt = _Tables(tr)
    dt = tracer.dtype
    frame9 = lt.frame9.astype(dt)
    state = PathState(o, d, dtype=dt)
    k = 0
    while state.n and k < tr.limit:
        k += 1
        t, prim = tracer.closest_soa(state.o, state.d)
        if k == 1 and tr.visible:
            tr.camera_hits(state, t, prim)
        t = t.astype(dt, copy=False)
        tr.rays += state.n
        if prim.min() < 0:                 # drop the rays that left the scene (no environment)
            keep = np.flatnonzero(prim >= 0)
            if keep.size == 0:
                break
            state.take(keep)
            t, prim = np.take(t, keep), np.take(prim, keep)
        m = state.n
        p = state.d * t
        p += state.o
        if k == 1:
            tr.hit_emission(k, state, p, prim)
        else:
            _hit_light(tr, lt, state, t, prim)
        if k >= tr.limit:
            break
        frame = np.take(frame9, prim, axis=1)
        fs, fn, ft = frame[0:3], frame[3:6], frame[6:9]
        sgn = np.sign(dot(state.d, fn))
        np.negative(sgn, out=sgn)          # sign(wo . n_g); 0 (grazing) gives f = 0
        if tr.nee and k + 1 <= tr.limit:
            _next_event(tr, lt, state, k, p, fn, sgn, prim)
        if k + 1 > tr.limit or (k + 1 == tr.limit and not tr.bsdf_hits):
            break
        # d is not needed any more: the new directions are written into it
        dirs = sample_directions(Vertex(k, state.idx, frame=(fs, fn, ft), sgn=sgn, albedo=lt.albedo, prim=prim),
                                 stream, out=state.d)
        beta = state.beta
        beta *= dirs.weight                # in place (``state.beta[...] *=`` would copy the block onto itself)
        pdf = dirs.pdf
        del dirs                           # free the weights now (allocator reuse)
        alive = roulette(tr, state, k, np.ones(m, dtype=bool))
        # leave on wi's side of the surface: sign(wi . n_g) = sgn for a valid sample
        np.multiply(fn, sgn * tr.eps, out=state.o)
        state.o[...] += p
        state.prev_pdf[...] = pdf
        if not alive.all():
            state.take(np.flatnonzero(alive))


def _next_event(tr: Transport, lt: _Tables, state: PathState, k, p, fn, sgn, prim) -> None:
    """NEE: ``beta (albedo / pi) Le cos_i w_light / p_light`` over unoccluded
    samples, with ``p_bsdf = cos_i / pi``."""
    idx = state.idx
    w, dist, _, pdf_l, _ = tr.emitters.sample_li(p, tr.stream.vertex(k, LIGHT, 2, idx, p.dtype), None)
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
    tr.add(np.take(idx, np.take(go, vis)), np.take(contrib, vis, 1))
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
    tr.add(np.take(state.idx, lit), val)
