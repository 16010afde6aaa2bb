"""Caustics by light tracing: the paths path tracing finds worst, handed to the strategy that finds them best.

A caustic path is one whose light arrives through a specular vertex after a
non-specular first camera vertex, ``E D (D|S)* S L``: the floor's caustic
under a glass sphere (``E D S+ L``), a wall lit by that caustic or by the
light's reflection in a mirror sphere (``E D D S L``), and so on. Path
tracing finds one only when a BSDF sample happens to pass the glass or
mirror onto the light: next-event estimation cannot connect through a delta
lobe. On ``cornell-spheres`` (64 x 64, 256 spp, ``mcvar render``'s
default) these paths held 90% of the variance while carrying 5% of the
light (docs/performance.md). Light tracing finds the same paths the other
way round: from the light, through a specular first vertex, on by BSDF
sampling, every later non-specular vertex joined to the pinhole (the
``(s, t = 1)`` strategy of :mod:`mcvar.integrators.light`) and splatted.

``PathSettings(caustics='light')`` partitions the path space between the
two (no MIS, every path counted by exactly one strategy, so the sum stays
unbiased): path tracing leaves out the emission found through a delta lobe
by paths whose first vertex is non-specular
(:attr:`~mcvar.integrators.state.Transport.caustic_light`), and
:func:`caustic_splats` adds exactly those, from light subpaths whose first
vertex is specular (the others stop there: path tracing has them), aimed at
the specular spheres by :class:`AimedOrigins`. The render adds the splatted
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
.. [3] M. Pharr, W. Jakob, G. Humphreys, "Physically Based Rendering", 4th
   ed., MIT Press 2023 (``SampleUniformCone``, ``src/pbrt/util/sampling.h``).
"""
from __future__ import annotations

import numpy as np

from ..bsdf import Lambertian
from ..geometry import Frame
from ..warps import _square_to_cosine_hemisphere_unchecked
from .film import BatchJob, BatchResult, splat
from .light import RR_MAX_VERTICES, _Context, _bsdf_eval, _shading_normals, _unoccluded
from .registry import Method
from .state import RR_START_DEPTH, light_caustics_apply

__all__ = ["CAUSTICS", "AimedOrigins", "light_caustics_apply", "caustic_splats", "CAUSTIC_METHOD",
           "CAUSTIC_PATH_FRACTION"]

#: Values of the ``caustics`` setting: ``path`` (path tracing finds them) or ``light``.
CAUSTICS = ("path", "light")
#: Light subpaths per camera path of the render (``caustics='light'``).
CAUSTIC_PATH_FRACTION = 0.04
#: Light subpaths per chunk.
_CHUNK = 1 << 16


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


class AimedOrigins:
    """Origins of the caustic light subpaths: a point on the one quad light, a
    direction aimed at the specular spheres.

    The point is uniform on the quad (density ``1 / A``); the direction is
    drawn from the mixture ``p(w) = a cos(w) / pi + (1 - a) sum_j pi_j
    1[w in C_j] / Omega_j``, where ``C_j`` is the cone of directions from the
    point towards specular sphere ``j`` (half-angle ``asin(r / |c - p|)``,
    solid angle ``Omega_j = 2 pi (1 - cos theta_j)``, sampled uniformly,
    pbrt-v4's ``SampleUniformCone``) and ``pi_j`` is proportional to
    ``Omega_j`` times the cosine at the light of the cone's direction nearest
    the light's normal (0 when the whole cone lies behind the light, where it
    emits nothing). The subpath's weight is ``Le cos / (p_A p(w))``, with
    ``p(w)`` summed over every cone that contains ``w`` (they may overlap).

    Every direction whose first hit is a specular sphere lies in its cone, so
    ``p(w) > 0`` on every path the caustic stage counts, and without
    specular triangles ``a = 0``: every subpath is aimed (the cosine density
    sent 91.6% of them to a non-specular first vertex, where they stop).
    With a specular triangle, whose directions the cones do not cover,
    ``a = 1/2`` (with no specular sphere, ``a = 1``: the light's cosine density).
    """

    def __init__(self, scene):
        self.p0, self.e1, self.e2 = scene.light_origin[0], scene.light_edge1[0], scene.light_edge2[0]
        self.normal = scene.light_normal[0]
        self.area = float(scene.light_area[0])
        self.le = np.asarray(scene.light_radiance[0], dtype=np.float64)
        delta = np.array([bool(getattr(m, "is_delta", False)) for m in scene.materials])
        prim_mat = np.asarray(scene.prim_material, dtype=np.int64)
        n_tri = scene.n_triangles
        spec_sph = np.flatnonzero(delta[prim_mat[n_tri:]]) if scene.n_spheres else np.zeros(0, dtype=np.int64)
        self.centers = np.asarray(scene.sphere_centers, dtype=np.float64)[spec_sph]
        self.radii = np.asarray(scene.sphere_radii, dtype=np.float64)[spec_sph]
        spec_tri = bool(n_tri and np.any(delta[prim_mat[:n_tri]]))
        #: the cosine density's share of the mixture
        self.cosine = 1.0 if not spec_sph.size else (0.5 if spec_tri else 0.0)

    def _cones(self, p):
        """Axes (J, m, 3), cosines of the half-angles and solid angles (J, m), choice weights (J, m)."""
        v = self.centers[:, None, :] - p[None, :, :]
        dist = np.sqrt(np.einsum("jmi,jmi->jm", v, v))
        axis = v / dist[..., None]
        sin2 = np.minimum((self.radii[:, None] / dist) ** 2, 1.0)
        inside = dist <= self.radii[:, None]                    # the point inside a sphere: every direction
        cos_max = np.where(inside, -1.0, np.sqrt(1.0 - sin2))
        omega = 2.0 * np.pi * (1.0 - cos_max)
        # angle of the cone's nearest direction to the normal: max(gamma - theta, 0)
        gamma = np.arccos(np.clip(axis @ self.normal, -1.0, 1.0))
        near = np.maximum(gamma - np.arccos(np.clip(cos_max, -1.0, 1.0)), 0.0)
        weight = omega * np.maximum(np.cos(near), 0.0)
        return axis, cos_max, omega, weight

    def sample(self, u):
        """Origins from ``u`` (m, 5) in [0, 1)^5: ``(p, w, beta)``, each (m, 3);
        ``beta = Le cos / (p_A p(w))`` (0 where the light emits nothing along ``w``)."""
        m = u.shape[0]
        p = self.p0 + u[:, 0:1] * self.e1 + u[:, 1:2] * self.e2
        nrm = self.normal
        w = np.empty((m, 3))
        a = self.cosine
        use_cos = u[:, 2] < a
        pdf = np.zeros(m)
        ic = np.flatnonzero(use_cos)
        if ic.size:
            fr = Frame(np.broadcast_to(nrm, (ic.size, 3)))
            x, y, z = _square_to_cosine_hemisphere_unchecked(u[ic, 3], u[ic, 4], np.float64)
            w[ic] = fr.s * x[:, None] + fr.n * y[:, None] + fr.t * z[:, None]
        if a < 1.0:
            axis, cos_max, omega, weight = self._cones(p)
            total = weight.sum(axis=0)
            share = np.divide(weight, total, out=np.zeros_like(weight), where=total > 0)
            ia = np.flatnonzero(~use_cos)
            # the cone: u2 rescaled into [0, 1) picks j by the cumulative shares
            v = (u[ia, 2] - a) / (1.0 - a)
            cum = np.cumsum(share[:, ia], axis=0)
            j = np.minimum((v[None, :] >= cum).sum(axis=0), len(self.radii) - 1)
            ax, cm = axis[j, ia], cos_max[j, ia]
            cos_t = 1.0 - u[ia, 3] * (1.0 - cm)
            sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
            phi = 2.0 * np.pi * u[ia, 4]
            fr = Frame(ax)
            w[ia] = (fr.s * (sin_t * np.cos(phi))[:, None] + fr.n * cos_t[:, None]
                     + fr.t * (sin_t * np.sin(phi))[:, None])
            own = np.zeros((len(self.radii), m), dtype=bool)
            own[j, ia] = True
            dens = share / omega
            pdf_cones = np.where(own | (np.einsum("jmi,mi->jm", axis, w) >= cos_max), dens, 0.0).sum(axis=0)
            pdf += (1.0 - a) * pdf_cones
        cos = w @ nrm
        if a > 0.0:
            pdf += a * np.maximum(cos, 0.0) / np.pi
        ok = (cos > 0.0) & (pdf > 0.0)
        beta = self.le[None, :] * np.where(ok, cos * self.area / np.where(ok, pdf, 1.0), 0.0)[:, None]
        return p, w, beta


def caustic_splats(scene, tracer, res, n_paths: int, rng, max_depth: int | None = None, *,
                   rr_depth: int | None = None, rr_threshold: float = 1.0):
    """``n_paths`` light subpaths whose first vertex is specular, every later
    non-specular vertex joined to the pinhole.

    A subpath ``y_0 y_1 ...`` starts on the light; if ``y_1`` is not
    specular it stops there (path tracing has every path whose light arrives
    from a non-specular vertex). Otherwise it walks on by BSDF sampling
    through any material, and each non-specular vertex ``y_i`` (``i >= 2``)
    is joined to the pinhole (strategy ``(s, t = 1)``, weight 1): the path
    ``E y_i ... y_1 y_0``, whose first camera vertex is non-specular and
    whose last vertex before the light is specular, the paths
    :attr:`~mcvar.integrators.state.Transport.caustic_light` leaves out.

    ``max_depth``: the camera paths' segment limit (None: unbounded, with
    Russian roulette on the subpath's throughput relative to its start from
    ``rr_depth`` segments on, survival ``min(0.95, beta / rr_threshold)``, the
    rule of :func:`mcvar.integrators.state.roulette`); a join at ``y_i`` makes
    a path of ``i + 1`` segments, so only ``i <= max_depth - 1`` are joined.

    Returns ``(sum, rays)``: ``sum`` (W H, 3) of the splats, so that the
    image of these paths is ``sum W H / n_paths`` (the convention of
    :func:`mcvar.integrators.light.light_tracing_splats`).
    """
    w, h = res
    image = np.zeros((w * h, 3))
    aimed = AimedOrigins(scene)
    ctx = _Context(scene, tracer, None, res)
    ctx.lambertian_f = np.array([m.albedo / np.pi if type(m) is Lambertian else np.full(3, np.nan)
                                 for m in scene.materials])
    eps, flips, delta_mat = ctx.eps, ctx.flips, ctx.delta_mat
    prim_mat = np.asarray(scene.prim_material)
    materials = scene.materials
    roulette = max_depth is None
    rr_start = RR_START_DEPTH if rr_depth is None else rr_depth
    last = RR_MAX_VERTICES if max_depth is None else min(RR_MAX_VERTICES, max_depth - 1)
    rays = 0
    for a in range(0, n_paths, _CHUNK):
        m = min(_CHUNK, n_paths - a)
        p, d, beta = aimed.sample(rng.random((m, 5)))
        scale = np.maximum(beta.max(axis=1), 1e-300)       # roulette on beta relative to its start
        o = p + aimed.normal * eps
        i = 1                                              # the vertex the next rays reach
        while d.shape[0] and i <= last:
            t, prim = tracer.closest_soa(np.ascontiguousarray(o.T), np.ascontiguousarray(d.T))
            rays += d.shape[0]
            hit = np.flatnonzero(prim >= 0)
            d, beta, scale, t, prim = d[hit], beta[hit], scale[hit], t[hit], prim[hit]
            p = o[hit] + d * t[:, None]
            mat = np.take(prim_mat, prim)
            spec = np.take(delta_mat, mat)
            if i == 1:
                # a first non-specular vertex: path tracing's; only specular ones go on
                go = np.flatnonzero(spec)
                d, beta, scale, p, prim, mat = d[go], beta[go], scale[go], p[go], prim[go], mat[go]
                ng = tracer.normals(prim, p)
            else:
                ng = tracer.normals(prim, p)
                join = np.flatnonzero(~spec)
                if join.size:
                    rays += _join_camera(ctx, image, p[join], ng[join], -d[join], mat[join], beta[join])
            if i == last or not d.shape[0]:
                break
            # scatter by BSDF sampling (weight f |cos| / pdf; the materials here are symmetric)
            wo = -d
            fr = Frame(_shading_normals(flips, mat, ng, wo))
            wo_l = np.stack([_dot(wo, fr.s), _dot(wo, fr.n), _dot(wo, fr.t)], axis=-1)
            ur = rng.random((d.shape[0], 2))
            wi_l = np.zeros((d.shape[0], 3))
            weight = np.zeros((d.shape[0], 3))
            for mi in np.unique(mat):
                sel = np.flatnonzero(mat == mi)
                wi_s, w_s, _, _ = materials[mi]._sample(wo_l[sel], ur[sel])
                wi_l[sel], weight[sel] = wi_s, w_s
            wi = fr.s * wi_l[:, 0:1] + fr.n * wi_l[:, 1:2] + fr.t * wi_l[:, 2:3]
            beta = beta * weight
            bmax = beta.max(axis=1)
            alive = bmax > 0.0
            if roulette and i >= rr_start:
                q = np.minimum(bmax / (scale * rr_threshold), 0.95)
                survive = rng.random(d.shape[0]) < q
                beta /= np.where(survive, q, 1.0)[:, None]
                alive &= survive
            alive = np.flatnonzero(alive)
            side = np.sign(_dot(wi, ng))
            o = (p + ng * (eps * side)[:, None])[alive]
            d, beta, scale = wi[alive], beta[alive], scale[alive]
            i += 1
    return image, rays


def _join_camera(ctx, image, p, ng, wo, mat, beta) -> int:
    """Join non-specular light vertices ``p`` (reached along ``-wo``) to the pinhole
    and splat ``beta f |cos| We / pdf`` (:func:`mcvar.integrators.light._connect_camera`
    for ``s >= 2``, weight 1). Returns the shadow rays traced."""
    scene, tracer, cam, res, eps = ctx.scene, ctx.tracer, ctx.scene.camera, ctx.res, ctx.eps
    wi, dist, we, pdf, xy, visible = cam.sample_Wi(p, res)
    c_i = _dot(ng, wi)
    cos_q = np.abs(c_i)
    f = _lambertian_f(ctx.lambertian_f, mat, ng, wo, c_i)
    if f is None:
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


def _lambertian_f(table, mat, ng, wo, c_i):
    """``f(wo, wi)`` of vertices whose materials are all Lambertian, written out:
    ``albedo / pi`` where ``wo`` and ``wi`` lie on one side of the surface
    (``c_i = ng . wi``; the two-sided normal flipped towards ``wo``, as
    :func:`mcvar.integrators.light._bsdf_eval` and ``Lambertian.eval`` do),
    else 0; None when some material is not Lambertian (``table``: albedo / pi
    per material, NaN for the others)."""
    f = table[mat]
    if np.isnan(f[:, 0]).any():
        return None
    c_o = _dot(ng, wo)
    return f * (((c_o > 0.0) & (c_i > 0.0)) | ((c_o < 0.0) & (c_i < 0.0)))[:, None]


def run_caustic_batch(job: BatchJob) -> BatchResult:
    """One batch of the caustic stage: ``W H spp`` light subpaths, splats summed per pixel."""
    w, h = job.res
    st = job.settings
    total, rays = caustic_splats(job.scene, job.tracer, job.res, w * h * job.spp, job.rng, st.max_depth,
                                 rr_depth=st.rr_depth, rr_threshold=st.rr_threshold)
    return BatchResult(total, None, int(rays))


#: The caustic stage's batches (not a method users choose: ``render`` runs it
#: for ``caustics='light'``).
CAUSTIC_METHOD = Method("caustic_light_paths", "splat", run_caustic_batch,
                        "light subpaths through specular vertices joined to the camera", stream_dims=0)
