"""Bidirectional path tracing: every (s, t) strategy, weighted by MIS (layer 5).

The lecture's 'Bidirectional Path Tracing' slides: trace a camera subpath
``z_0 .. z_{t-1}`` and a light subpath ``y_0 .. y_{s-1}``
(:mod:`mcvar.integrators.light`) and join them in every way. Strategy
``(s, t)`` uses ``s`` light and ``t`` camera vertices, a path of
``s + t - 1`` segments:

* ``s = 0``: the camera subpath hits an emitter (path tracing's BSDF-sampled
  emission);
* ``s = 1``: a camera vertex joined to the light subpath's origin ``y_0``
  (next-event estimation; point lights are reached only this way: ``(1,
  1)``, a point light seen by the camera, is left out as in path tracing);
* ``s, t >= 2``: ``y_{s-1}`` and ``z_{t-1}`` joined by a shadow ray;
* ``t = 1``: a light vertex joined to the pinhole and splatted (light
  tracing).

Each strategy is an unbiased estimator of the paths it can produce; BDPT adds
them with the balance or power heuristic of Veach and Guibas (1995),
``w_{s,t} = p_s^beta / sum_i p_i^beta``, computed from ratios of per-vertex
densities ``pdf_rev / pdf_fwd`` walking away from the connection (Veach 1997,
sec. 10.2; pbrt's ``MISWeight``). A strategy that would connect at a delta
vertex, hit a point light (``s = 0``) or hit the pinhole (``t = 0``) has
probability zero and weight 0. With ``mis=False`` every strategy that can
produce a path gets ``1 / (their number)``: still unbiased, noisier.

Vectorised over paths: for each (s, t) every path of the batch that has the
vertices is evaluated at once; loops run over strategies and depths only.

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
   ed., MIT Press 2023 (the ``BDPT`` integrator).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import check_bool
from .emitters import LightOrigins
from .film import BatchJob, BatchResult, splat
from .light import (CHUNK_PATHS, RR_MAX_VERTICES, _bsdf_eval, _connect_camera, _Context, _cos, _dot, _Only,
                    _unit, _unoccluded, camera_subpath, check_scene, light_subpath)
from .registry import Method, register

__all__ = ["STRATEGY_DEPTH", "BDPTSettings", "bdpt_contributions", "strategy_grid", "strategies_from_extra",
           "write_strategies", "run_bdpt_batch"]

#: The strategy images (``strategies=True``) cover every (s, t) with
#: ``s + t - 1 <=`` this depth: the lecture's figure.
STRATEGY_DEPTH = 4


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



def _connect_emitter(ctx, C, t):
    """Strategy (s = 0, t): camera vertex ``z_{t-1}`` lies on an emitter, or
    is the environment (the camera ray left the scene)."""
    em = ctx.em
    ic = np.flatnonzero(C.length >= t)
    inf = C.infinite[t - 1, ic]
    if np.any(inf):
        parts = [_connect_environment(ctx, C, t, ic[inf]), _connect_emitter(ctx, _Only(C, ic[~inf]), t)]
        return tuple(np.concatenate(a) for a in zip(*parts))
    ic = ic[(C.prim[t - 1, ic] >= 0) & (np.take(em.prim_select, np.maximum(C.prim[t - 1, ic], 0)) > 0.0)]
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


def _connect_environment(ctx, C, t, ic):
    """Strategy (s = 0, t) for camera paths ``ic`` whose vertex ``z_{t-1}`` is
    the environment: ``beta L(w)``, weighted against the light origin's
    density ``p_choice p(w)`` at ``z_{t-1}`` and the disk's
    ``|cos| / (pi r^2)`` at ``z_{t-2}`` (pbrt-v4's infinite-light vertex)."""
    em, k = ctx.em, t - 1
    towards = C.ng[k, ic]
    value = C.beta[k, ic] * em.env.radiance(towards)
    go = np.flatnonzero(value.max(axis=1) > 0.0)
    ic, value, towards = ic[go], value[go], towards[go]
    if ic.size == 0:
        return ic, value, np.zeros(0)
    over = {("C", k): em.env_pdf_origin(towards)}
    if k - 1 >= 1:
        over[("C", k - 1)] = em.env_pdf_pos * _cos(C.surface[k - 1, ic], C.ng[k - 1, ic], towards)
    return ic, value, _mis_weight(ctx, None, C, 0, t, None, ic, over)


def _escapes(tracer, eps, p, n, towards):
    """The rays from surface points ``p`` (normals ``n``) along ``towards`` leave the scene."""
    o = p + n * (eps * np.sign(_dot(n, towards)))[:, None]
    return ~tracer.occluded_soa(np.ascontiguousarray(o.T), np.ascontiguousarray(towards.T),
                                np.full(p.shape[0], np.inf))


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
    inf = L.infinite[q, idx] if s == 1 else np.zeros(idx.size, dtype=bool)
    if np.any(inf):      # y_0 at infinity: along -w towards z_k, G = |cos theta_k| (no distance)
        w[inf], dist[inf] = -nq[inf], 1.0
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
    inf = L.infinite[q, idx] if s == 1 else np.zeros(idx.size, dtype=bool)
    vis = np.zeros(idx.size, dtype=bool)
    fin = np.flatnonzero(~inf)
    vis[fin] = _unoccluded(ctx.tracer, ctx.eps, pq[fin], nq[fin], pk[fin], nk[fin])
    if np.any(inf):
        vis[inf] = _escapes(ctx.tracer, ctx.eps, pk[inf], nk[inf], nq[inf])
    sel = np.flatnonzero(vis)
    idx, value = idx[sel], value[sel]
    over = {("C", k): pdf_q_fwd[sel] * cos_k[sel] / d2[sel],
            ("L", q): pdf_k_fwd[sel] * cos_q[sel] / d2[sel]}
    if k - 1 >= 1:
        over[("C", k - 1)] = (pdf_k_rev[sel] * _cos(C.surface[k - 1, idx], C.ng[k - 1, idx], wo_k[sel])
                              / (r_k[sel] ** 2))
    if s >= 2:
        r2 = np.where(L.infinite[q - 1, idx], 1.0, r_q[sel] ** 2)       # none to an environment y_0
        over[("L", q - 1)] = pdf_q_rev[sel] * _cos(L.surface[q - 1, idx], L.ng[q - 1, idx], wo_q[sel]) / r2
    return idx, value, _mis_weight(ctx, L, C, s, t, idx, idx, over)



@dataclass(frozen=True)
class BDPTSettings:
    """How :func:`bdpt_contributions` traces: ``max_depth`` (None: Russian roulette), the MIS
    ``heuristic``, ``mis`` (False: uniform weights) and ``strategies`` (keep every strategy's image)."""

    max_depth: int | None = None
    heuristic: str = "power"
    mis: bool = True
    strategies: bool = False


def bdpt_contributions(scene, tracer, origins, res, pixel, offsets, rng, settings: BDPTSettings | None = None):
    """Bidirectional path tracing of one camera path per ``pixel`` (and one light path each).

    ``settings`` (:class:`BDPTSettings`) holds ``max_depth``, ``heuristic``,
    ``mis`` and ``strategies``, formerly four trailing arguments.

    Returns ``(camera_sum, camera_sq, splat_sum, rays, per_strategy)``:
    per-pixel sums of the camera-side estimates (t >= 2; ``camera_sq`` of
    their per-sample squares), the splat sum of the t = 1 strategies, the
    rays traced, and with ``strategies`` a dict ``(s, t) -> (W H, 3)`` of the
    weighted contributions of every strategy of depth ``s + t - 1 <=``
    :data:`STRATEGY_DEPTH` (camera-side ones per pixel, t = 1 splatted).
    """
    settings = BDPTSettings() if settings is None else settings
    if not isinstance(settings, BDPTSettings):
        raise TypeError(f"settings must be a BDPTSettings (max_depth, heuristic, mis, strategies); "
                        f"got {type(settings).__name__}")
    w, h = res
    n_pix = w * h
    ctx = _Context(scene, tracer, origins, res, settings.heuristic, settings.mis)
    out = [np.zeros((n_pix, 3)), np.zeros((n_pix, 3)), np.zeros((n_pix, 3)), 0,
           {} if settings.strategies else None]
    for a in range(0, pixel.shape[0], CHUNK_PATHS):
        part = _bdpt_chunk(ctx, pixel[a:a + CHUNK_PATHS], offsets[a:a + CHUNK_PATHS], rng, settings)
        for j in range(4):
            out[j] += part[j]
        for key, img in (part[4] or {}).items():
            out[4][key] = out[4].get(key, 0.0) + img
    return tuple(out)


def _bdpt_chunk(ctx, pixel, offsets, rng, settings: BDPTSettings):
    """:func:`bdpt_contributions` for at most :data:`CHUNK_PATHS` paths."""
    scene, tracer, origins, res = ctx.scene, ctx.tracer, ctx.em, ctx.res
    max_depth, strategies = settings.max_depth, settings.strategies
    w, h = res
    n = pixel.shape[0]
    n_pix = w * h
    roulette = max_depth is None
    max_c = RR_MAX_VERTICES if roulette else max_depth + 1
    max_l = RR_MAX_VERTICES if roulette else max_depth
    C = camera_subpath(scene, tracer, res, pixel, offsets, max_c, rng, roulette)
    L = light_subpath(scene, tracer, origins, n, max_l, rng, roulette)
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
                il, pix, value, weight = _connect_camera(ctx, L, s, _mis_weight)
                rays += il.size
                contrib = value * weight[:, None]
                splat(splats, pix, contrib)
                if keep:
                    img = per_strategy.setdefault((s, t), np.zeros((n_pix, 3)))
                    splat(img, pix, contrib)
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
                splat(img, C.pixel[ic], contrib)
    cam_sum = np.zeros((n_pix, 3))
    cam_sq = np.zeros((n_pix, 3))
    splat(cam_sum, C.pixel, per_path)
    splat(cam_sq, C.pixel, per_path * per_path)
    return cam_sum, cam_sq, splats, rays, per_strategy



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

    from ..images import write_image

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


def _strategy_key(s, t):
    return f"s{s}_t{t}"


def strategies_from_extra(extra, res):
    """``{(s, t): image (H, W, 3)}`` from a BDPT render's ``Render.extra`` (keys ``'s{s}_t{t}'``)."""
    w, h = res
    out = {}
    for key, value in extra.items():
        if key.startswith("s") and "_t" in key:
            s, t = key[1:].split("_t")
            out[(int(s), int(t))] = np.asarray(value).reshape(h, w, 3)
    return out


def run_bdpt_batch(job: BatchJob) -> BatchResult:
    """One batch of ``bdpt``: ``spp`` camera paths per pixel, one light path each.

    Pixel positions come from the sample stream (columns 0, 1) when the
    render's sampler gives one, the rest from ``job.rng``. With the option
    ``strategies=True`` the batch also returns every strategy's weighted
    image of depth <= :data:`STRATEGY_DEPTH` in ``extra`` (keys
    ``'s{s}_t{t}'``).
    """
    n_pix = job.n_pixels
    pixel = np.repeat(np.arange(n_pix), job.spp)
    offsets = job.u[:, 0:2] if job.u is not None else job.rng.random((pixel.size, 2))
    settings = BDPTSettings(job.max_depth, job.heuristic, bool(job.options.get("mis", True)),
                            bool(job.options.get("strategies", False)))
    cam, _, spl, rays, per = bdpt_contributions(job.scene, job.tracer, LightOrigins(job.scene), job.res, pixel,
                                                offsets, job.rng, settings)
    total = cam + spl
    if not np.all(np.isfinite(total)):
        raise FloatingPointError("bdpt produced non-finite radiance (a bug, please report)")
    extra = {_strategy_key(s, t): img for (s, t), img in (per or {}).items()}
    return BatchResult(total, None, int(rays), extra)


def _check_bdpt(scene, options):
    check_bool(options["mis"], "mis")
    check_bool(options["strategies"], "strategies")
    check_scene(scene, options, "bdpt")


register(Method(
    "bdpt", "splat", run_bdpt_batch,
    "bidirectional path tracing: every (s, t) strategy, weighted by MIS (heuristic=; mis=False: uniform)",
    options={"mis": True, "strategies": False}, check_scene=_check_bdpt, lecture=("yes", "yes"),
    chart_row="Bidirectional Path Tracing",
    theory=("yes", "yes", "every (s, t) connection strategy weighted by MIS: unbiased and consistent")))
