"""Caustics by light tracing: the paths path tracing finds worst, handed to the strategy that finds them best.

A caustic path ``E D S+ L`` (camera, one diffuse vertex, one or more
specular vertices, the light) reaches path tracing only when the BSDF
sample at ``D`` happens to enter the glass or mirror and the specular chain
happens to end on the light: next-event estimation cannot connect through a
delta lobe. On ``cornell-spheres`` (64 x 64, 256 spp, ``mcvar render``'s
default) these paths hold about half of the image's MSE while carrying 2.7%
of its light (docs/performance.md). Light tracing finds the same paths the
other way round: from the light, through the specular vertices, to ``D``,
which is joined to the pinhole (the ``(s, t = 1)`` strategy of
:mod:`mcvar.integrators.light`) and splatted.

``PathSettings(caustics='light')`` partitions the path space between the
two (no MIS, every path counted by exactly one strategy, so the sum stays
unbiased): path tracing leaves out the emission of paths whose first vertex
is non-specular and whose later vertices are all specular
(:attr:`~mcvar.integrators.state.Transport.caustic_light`), and
:func:`caustic_splats` adds exactly those, from light subpaths that pass
one or more specular vertices before their first non-specular one (the
others stop there: path tracing has them). The render adds the splatted
image to the camera estimator's (:mod:`mcvar.integrators.allocation`).

It applies where the two sides agree on what a caustic path is
(:func:`light_caustics_apply`): one quad light of constant one-sided
radiance and nothing else emitting (no point light, no environment: those
caustics path tracing cannot find at all, and adding them would change the
image), every material either purely specular or without a specular lobe
(so that "specular" is a property of the surface, not of the sampled lobe),
and at least one of each kind. Elsewhere ``caustics='light'`` renders what
``'path'`` renders.

References
----------
.. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
   Simulation", PhD thesis, Stanford 1997, sec. 10.2 (light tracing) and
   8.2 (the regular expressions of paths).
.. [2] H. W. Jensen, "Global illumination using photon maps", Rendering
   Techniques 1996 (caustics from the light's side).
"""
from __future__ import annotations

import numpy as np

from ..geometry import Frame
from .emitters import LightOrigins
from .film import BatchJob, BatchResult, splat
from .light import _Context, _bsdf_eval, _shading_normals, _unoccluded
from .registry import Method
from .state import light_caustics_apply

__all__ = ["CAUSTICS", "light_caustics_apply", "caustic_splats", "CAUSTIC_METHOD", "CAUSTIC_PATH_FRACTION",
           "MAX_SPECULAR"]

#: Values of the ``caustics`` setting: ``path`` (path tracing finds them) or ``light``.
CAUSTICS = ("path", "light")
#: Light subpaths per camera path of the render (``caustics='light'``).
CAUSTIC_PATH_FRACTION = 0.25
#: Specular vertices after which a light subpath stops (glass keeps weight 1 on
#: every bounce, so there is no roulette; 0.96^64 of a path stays inside a sphere
#: by total internal reflection that long, far below anything seen).
MAX_SPECULAR = 64
#: Light subpaths per chunk.
_CHUNK = 1 << 16


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def caustic_splats(scene, tracer, res, n_paths: int, rng, max_depth: int | None = None):
    """``n_paths`` light subpaths through one or more specular vertices, their first
    non-specular vertex joined to the pinhole.

    ``max_depth``: the camera paths' segment limit (None: unbounded); a path
    ``E D S^j L`` has ``j + 2`` segments, so only ``j <= max_depth - 2`` are joined.

    Returns ``(sum, rays)``: ``sum`` (W H, 3) of the splats, so that the
    image of these paths is ``sum W H / n_paths`` (the convention of
    :func:`mcvar.integrators.light.light_tracing_splats`).
    """
    w, h = res
    image = np.zeros((w * h, 3))
    origins = LightOrigins(scene)
    ctx = _Context(scene, tracer, origins, res)
    eps, flips, delta_mat = ctx.eps, ctx.flips, ctx.delta_mat
    prim_mat = np.asarray(scene.prim_material)
    rays = 0
    for a in range(0, n_paths, _CHUNK):
        m = min(_CHUNK, n_paths - a)
        u = rng.random((m, 4))
        s = origins.sample(u[:, 0:2], u[:, 2:4])
        with np.errstate(divide="ignore", invalid="ignore"):
            ok = (s["pdf_pos"] > 0) & (s["pdf_dir"] > 0)
            beta = s["le"] * np.where(ok, s["cos"] / np.where(ok, s["pdf_pos"] * s["pdf_dir"], 1.0), 0.0)[:, None]
        o = s["p"] + s["n"] * eps
        d = s["w"]
        through = np.zeros(m, dtype=bool)          # a specular vertex passed
        last = MAX_SPECULAR if max_depth is None else min(MAX_SPECULAR, max_depth - 2)
        for j in range(last + 1):                  # j specular vertices passed so far
            if not d.shape[0]:
                break
            t, prim = tracer.closest_soa(np.ascontiguousarray(o.T), np.ascontiguousarray(d.T))
            rays += d.shape[0]
            hit = np.flatnonzero(prim >= 0)
            o, d, beta, through, t, prim = o[hit], d[hit], beta[hit], through[hit], t[hit], prim[hit]
            p = o + d * t[:, None]
            ng = tracer.normals(prim, p)
            mat = np.take(prim_mat, prim)
            spec = np.take(delta_mat, mat)
            join = np.flatnonzero(~spec & through)
            if join.size:
                rays += _join_camera(ctx, image, p[join], ng[join], -d[join], mat[join], beta[join])
            # only specular vertices go on (a first non-specular vertex: path tracing's)
            if j == last:
                break
            go = np.flatnonzero(spec)
            o, d, beta, p, ng, mat = o[go], d[go], beta[go], p[go], ng[go], mat[go]
            wo = -d
            nrm = _shading_normals(flips, mat, ng, wo)
            fr = Frame(nrm)
            wo_l = np.stack([_dot(wo, fr.s), _dot(wo, fr.n), _dot(wo, fr.t)], axis=-1)
            ur = rng.random((go.size, 2))
            wi_l = np.zeros((go.size, 3))
            weight = np.zeros((go.size, 3))
            for mi in np.unique(mat):
                sel = np.flatnonzero(mat == mi)
                wi_s, w_s, _, _ = scene.materials[mi]._sample(wo_l[sel], ur[sel])
                wi_l[sel], weight[sel] = wi_s, w_s
            wi = fr.s * wi_l[:, 0:1] + fr.n * wi_l[:, 1:2] + fr.t * wi_l[:, 2:3]
            beta = beta * weight
            alive = np.flatnonzero(beta.max(axis=1) > 0.0)
            side = np.sign(_dot(wi, ng))
            o = (p + ng * (eps * side)[:, None])[alive]
            d, beta = wi[alive], beta[alive]
            through = np.ones(alive.size, dtype=bool)
    return image, rays


def _join_camera(ctx, image, p, ng, wo, mat, beta) -> int:
    """Join non-specular light vertices ``p`` (reached along ``-wo``) to the pinhole
    and splat ``beta f |cos| We / pdf`` (:func:`mcvar.integrators.light._connect_camera`
    for ``s >= 2``, weight 1). Returns the shadow rays traced."""
    scene, tracer, cam, res, eps = ctx.scene, ctx.tracer, ctx.scene.camera, ctx.res, ctx.eps
    wi, dist, we, pdf, xy, visible = cam.sample_Wi(p, res)
    cos_q = np.abs(_dot(ng, wi))
    f, _, _ = _bsdf_eval(scene, ctx.flips, mat, ng, wo, wi, need_pdf=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        value = beta * f * np.where(visible, cos_q * we / pdf, 0.0)[:, None]
    go = np.flatnonzero(value.max(axis=1) > 0.0)
    if go.size == 0:
        return 0
    ok = _unoccluded(tracer, eps, p[go], ng[go], np.broadcast_to(cam.position, (go.size, 3)),
                     np.zeros((go.size, 3)))
    go = go[ok]
    splat(image, cam.pixel_index(xy[go], res), value[go])
    return int(ok.size)


def run_caustic_batch(job: BatchJob) -> BatchResult:
    """One batch of the caustic stage: ``W H spp`` light subpaths, splats summed per pixel."""
    w, h = job.res
    total, rays = caustic_splats(job.scene, job.tracer, job.res, w * h * job.spp, job.rng,
                                 job.settings.max_depth)
    return BatchResult(total, None, int(rays))


#: The caustic stage's batches (not a method users choose: ``render`` runs it
#: for ``caustics='light'``).
CAUSTIC_METHOD = Method("caustic_light_paths", "splat", run_caustic_batch,
                        "light subpaths through specular vertices joined to the camera", stream_dims=0)
