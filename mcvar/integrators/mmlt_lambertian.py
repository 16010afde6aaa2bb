"""MMLT's states evaluated in one pass on Lambertian scenes (layer 5): the kernel of ``mmlt``.

:func:`mcvar.integrators.mmlt_states.evaluate_states` runs BDPT's own code
(:mod:`mcvar.integrators.bdpt`): one call of the strategy's connection per
``(s, t)`` group of states, each a few hundred NumPy passes, and the general
random walk with its material loop. A chain step at depth 5 has 20 such
groups; profiled, a state cost 4-6 path-tracing samples of time (docs/mcmc.md,
'MMLT': the cost breakdown). Where every material is :class:`~mcvar.bsdf.Lambertian`
and every light an area emitter (no environment map, no point light, so no
delta vertex, no vertex at infinity), :func:`evaluate_lambertian` computes the same
values with BDPT's formulas written out once for all strategies:

* the camera subpaths of all states in one random walk and the light
  subpaths in another, each path stopping at its strategy's length (the
  BSDF sample is Malley's cosine sampling in the same shading frame as the
  general walk, so a state's path is the same path);
* the three connections (``s = 0``: the camera path hits the light;
  ``t = 1``: a light vertex joined to the pinhole; ``s, t >= 1, 2``: a
  shadow ray between the subpaths) evaluated on the states of each kind at
  once, their shadow rays in one call;
* Veach's MIS weight (Veach 1997, sec. 10.2; pbrt-v4's ``MISWeight``) for
  all states at once: the ratio chain ``pdf_rev / pdf_fwd`` walked away from
  each state's own connection, with the two densities next to it on either
  side replaced by the connection's (pbrt's scoped assignments).

The values are :func:`~mcvar.integrators.mmlt_states.evaluate_states`' to rounding
(``tests/test_mmlt.py``: an exact identity on the door and the Cornell box),
so the kernel is a faster route to one target, not a second estimator.

References
----------
.. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
   Simulation", PhD thesis, Stanford 1997, ch. 10.
.. [2] M. Pharr, W. Jakob, G. Humphreys, "Physically Based Rendering", 4th
   ed., MIT Press 2023 (``BDPT``, ``MLTIntegrator``).
"""
from __future__ import annotations

import numpy as np

from ..bsdf import Lambertian
from ..geometry import Frame
from ..envmap import LUMINANCE_WEIGHTS
from ..warps import _square_to_cosine_hemisphere_unchecked

__all__ = ["lambertian_scene", "Workspace", "trace_lambertian", "connect_lambertian"]

_INV_PI = 1.0 / np.pi
_LUM = np.asarray(LUMINANCE_WEIGHTS)


def lambertian_scene(scene) -> bool:
    """The kernel applies: every material Lambertian, no environment map, no point light."""
    return (all(type(m) is Lambertian for m in scene.materials) and scene.environment is None
            and not np.any(np.asarray(scene.point_light_intensity) > 0.0))


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _unit(v):
    r = np.sqrt(_dot(v, v))
    return v / np.maximum(r, 1e-300)[:, None], r


class _Vertices:
    """Dense vertex arrays of one kind of subpath: ``p[i, j]`` is vertex ``i`` of path ``j``;
    :meth:`take` gathers rows for the connections. Entries of vertices a path does not have are
    left unset (reused memory): every read is guarded by ``length`` or masked."""

    def __init__(self, v, m):
        self.m = m
        self.p = np.empty((v, m, 3))
        self.ng = np.empty((v, m, 3))
        self.beta = np.empty((v, m, 3))
        self.pdf_fwd = np.empty((v, m))
        self.pdf_rev = np.empty((v, m))
        self.mat = np.empty((v, m), dtype=np.intp)
        self.prim = np.empty((v, m), dtype=np.intp)
        self.length = np.zeros(m, dtype=np.intp)

    def take(self, field, i, j):
        """Rows ``field[i[k], j[k]]``, shape (n, 3) (one flat ``take``: a fancy index on two axes costs
        about 3x as much)."""
        return np.take(field.reshape(-1, 3), i * self.m + j, axis=0)


class Workspace:
    """Vertex buffers kept from one call to the next (a chain step has the shape of the one before):
    fresh arrays of this size cost a page fault per 4 kB on first touch, measured at a fifth of the
    random walk's time."""

    def __init__(self):
        self._buffers = {}

    def vertices(self, kind: str, v: int, m: int) -> _Vertices:
        V = self._buffers.get(kind)
        if V is None or V.p.shape[0] < v or V.m != m:
            V = self._buffers[kind] = _Vertices(v, m)
        V.length[:] = 0
        return V


def _dot3(a, b):
    """Row-wise dot products of structure-of-arrays vectors ``(3, n)``."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _keep(ii, *arrays):
    """The entries ``ii`` (last axis) of each array (``np.take``: a boolean mask on the last axis of a
    (3, n) array costs about 6x as much)."""
    return [np.take(a, ii, axis=-1) for a in arrays]


def _normals(tracer, prim, p):
    """Unit geometric normals ``(3, n)`` of primitives ``prim`` at points ``p`` (3, n)."""
    if np.all(prim < tracer.n_triangles):
        return np.take(tracer.triangle_normal_soa, prim, axis=1)
    return np.ascontiguousarray(tracer.normals(prim, p.T).T)


def _walk(ctx, V, albedo, start, numbers):
    """Extend subpaths from vertex 0 by cosine sampling (the general walk's
    :func:`~mcvar.integrators.light._walk` for Lambertian surfaces), structure of arrays.

    ``start = (idx, o, d, beta, pdf_dir, ng_prev)``: the paths, the rays (3, n) leaving their
    vertex 0 with solid-angle density ``pdf_dir``, their throughput (3, n) and the normal (3, n) at
    vertex 0; ``numbers = (u, cap, surface0)``: the BSDF numbers per vertex (m, 2 k), the vertex
    cap per path (vertex ``i`` exists where ``i < cap``) and whether vertex 0 is a surface (a
    light) rather than the pinhole. ``albedo`` (3, M). Returns the rays traced."""
    scene, tracer, eps = ctx.scene, ctx.tracer, ctx.eps
    idx, o, d, beta, pdf_dir, ng_prev = start
    u, cap, surface0 = numbers
    go = np.flatnonzero(cap[idx] > 1)
    if go.size < idx.size:
        idx, o, d, beta, pdf_dir, ng_prev = _keep(go, idx, o, d, beta, pdf_dir, ng_prev)
    rays = 0
    i = 1
    while idx.size:
        t, prim = tracer.closest_soa(np.ascontiguousarray(o), np.ascontiguousarray(d))
        rays += idx.size
        hit = np.flatnonzero(prim >= 0)
        if hit.size < idx.size:
            idx, o, d, beta, pdf_dir, ng_prev, t, prim = _keep(hit, idx, o, d, beta, pdf_dir, ng_prev, t, prim)
            if idx.size == 0:
                break
        p = o + d * t
        ng = _normals(tracer, prim, p)
        mat = np.take(scene.prim_material, prim)
        dn = _dot3(ng, d)
        for field, value in ((V.p, p), (V.ng, ng), (V.beta, beta)):
            for c in range(3):                         # per column: a row scatter costs about 4x as much
                field[i, :, c][idx] = value[c]
        V.mat[i, idx], V.prim[i, idx] = mat, prim
        t2 = t * t
        V.pdf_fwd[i, idx] = pdf_dir * np.abs(dn) / t2
        V.length[idx] = i + 1
        if i > 1 or surface0:                          # the reverse density of the vertex left behind
            cos_prev = np.abs(_dot3(ng_prev, d))
        else:
            cos_prev = 1.0
        go = np.flatnonzero(cap[idx] > i + 1)
        if go.size < idx.size:
            idx, d, beta, t2, p, ng, mat, dn = _keep(go, idx, d, beta, t2, p, ng, mat, dn)
            cos_prev = np.take(cos_prev, go) if np.ndim(cos_prev) else cos_prev
            if idx.size == 0:
                break
        # Lambertian is two-sided: the shading normal faces wo = -d; Duff et al.'s frame around it
        # (mcvar.geometry.Frame, written out)
        ns = ng * np.where(dn > 0.0, -1.0, 1.0)
        ns = ns / np.sqrt(_dot3(ns, ns))
        x, y, z = ns
        sign = np.copysign(1.0, y)
        a = -1.0 / (sign + y)
        b = z * x * a
        wo_y = -_dot3(d, ns)
        lx, ly, lz = _square_to_cosine_hemisphere_unchecked(u[idx, 2 * i - 2], u[idx, 2 * i - 1])
        pdf = np.where(wo_y > 0.0, np.where(ly >= 0.0, ly * _INV_PI, 0.0), 0.0)
        ok = (pdf > 0.0) & (ly > 0.0)
        pdf = np.where(ok, pdf, 0.0)
        back = np.where(ok & (wo_y > 0.0), wo_y * _INV_PI, 0.0)
        V.pdf_rev[i - 1, idx] = back * cos_prev / t2
        wi = np.stack([(sign + x * x * a) * lx + x * ly + sign * b * lz,
                       -x * lx + y * ly - sign * z * lz,
                       b * lx + z * ly + (1.0 + sign * z * z * a) * lz])
        beta = beta * np.where(ok, np.take(albedo, mat, axis=1), 0.0)
        alive = np.flatnonzero((beta.max(axis=0) > 0.0) & (pdf > 0.0))
        o = p + ng * (eps * np.sign(_dot3(wi, ng)))
        idx, o, d, beta, pdf_dir, ng_prev = _keep(alive, idx, o, wi, beta, pdf, ng)
        i += 1
    return rays


def _bsdf(albedo, mat, ng, wo, wi):
    """Lambertian ``f(wo, wi)``, ``pdf(wo -> wi)``, ``pdf(wi -> wo)`` (world directions; the general
    :func:`~mcvar.integrators.light._bsdf_eval` for Lambertian surfaces: the shading normal is the
    unit geometric normal turned towards ``wo``, so only the two cosines with it are needed)."""
    dn = _dot(ng, wo)
    sgn = np.where(dn < 0.0, -1.0, 1.0)
    a, b = dn * sgn, _dot(wi, ng) * sgn
    ok = (a > 0.0) & (b > 0.0)
    f = np.where(ok[:, None], np.take(albedo, mat, axis=0) * _INV_PI, 0.0)
    return f, np.where(ok, b * _INV_PI, 0.0), np.where(ok, a * _INV_PI, 0.0)


def _area_light(ctx, prim, p, w):
    """``Le`` of light origins on triangles ``prim`` at ``p`` towards unit ``w`` and the density of
    emitting ``w`` (``LightOrigins.light_le`` and ``light_pdf_dir`` for area lights, written out)."""
    em, scene = ctx.em, ctx.scene
    if np.any(prim >= scene.n_triangles) or scene.checker_period is not None:
        none = np.full(prim.size, -1)
        return em.light_le(none, prim, p, w), em.light_pdf_dir(none, prim, p, w)
    c = _dot(np.take(em.triangle_normal, prim, axis=0), w)
    two = np.take(scene.prim_two_sided_emission, prim)
    le = np.where(((c > 0.0) | two)[:, None], np.take(scene.prim_emission, prim, axis=0), 0.0)
    return le, np.where(two, 0.5 * np.abs(c), np.maximum(c, 0.0)) / np.pi


def _max3(v):
    """Row maxima of (n, 3) values (``v.max(axis=1)`` reduces slowly over a length-3 axis)."""
    return np.maximum(np.maximum(v[:, 0], v[:, 1]), v[:, 2])


def _mis(ctx, C, L, j, s, t, over):
    """Veach's MIS weight ``1 / (1 + sum_i r_i^beta)`` of each state's strategy (``bdpt._mis_weight``):
    the camera side walks ``i = t - 1 .. 1``, the light side ``i = s - 1 .. 0``, on subpaths ``j``;
    ``over = (oc0, oc1, ol0, ol1)``: ``oc0, oc1`` replace ``pdf_rev`` at camera vertices ``t - 1,
    t - 2``, ``ol0, ol1`` at light vertices ``s - 1, s - 2`` (pbrt's scoped assignments). The sum
    runs in BDPT's order."""
    oc0, oc1, ol0, ol1 = over
    m = j.size
    total = np.ones(m)
    with np.errstate(all="ignore"):          # entries of states off a step are unset memory, masked
        for V, n_v, o0, o1, last in ((C, t, oc0, oc1, 1), (L, s, ol0, ol1, 0)):
            ri = np.ones(m)
            for step in range(int(n_v.max(initial=0))):
                i = n_v - 1 - step                               # the vertex of this step, per state
                on = i >= last
                if not np.any(on):
                    break
                ii = np.maximum(i, 0)
                rev = o0 if step == 0 else (o1 if step == 1 else V.pdf_rev[ii, j])
                fwd = V.pdf_fwd[ii, j]
                ri = np.where(on, ri * np.divide(rev, fwd, out=np.zeros(m), where=fwd > 0), ri)
                total += np.where(on, ri ** ctx.power, 0.0)
    return 1.0 / total


def _origins(ctx, u):
    """Light-subpath origins from the numbers ``u`` (n, 4) on triangle emitters: the general
    :meth:`~mcvar.integrators.emitters.LightOrigins.sample` written out for them (same formulas, so
    the same origins), in about a third of its time. Other emitters (spheres, textures): the general one."""
    em, scene = ctx.em, ctx.scene
    if np.any(em.prims >= scene.n_triangles) or scene.checker_period is not None or em.count != em.prims.size:
        return em.sample(u[:, 0:2], u[:, 2:4])
    n = u.shape[0]
    k = np.minimum(np.searchsorted(em.cdf, u[:, 0] * em.cdf[-1], side="right"), em.count - 1)
    lo = np.where(k > 0, np.take(em.cdf, k - 1), 0.0)
    pmf = np.take(em.pmf, k)
    u0 = np.clip(np.divide(u[:, 0] - lo, pmf, out=np.zeros(n), where=pmf > 0), 0.0, 1.0)
    pr = np.take(em.prims, k)
    v = np.take(scene.triangles, pr, axis=0)
    r = np.sqrt(u0)
    b0, b1 = r * (1.0 - u[:, 1]), r * u[:, 1]
    p = v[:, 0] + b0[:, None] * (v[:, 1] - v[:, 0]) + b1[:, None] * (v[:, 2] - v[:, 0])
    nrm = np.take(em.triangle_normal, pr, axis=0)
    two = np.take(scene.prim_two_sided_emission, pr)
    ud = u[:, 2]
    back = two & (ud >= 0.5)
    ud = np.clip(np.where(two, np.where(back, 2.0 * ud - 1.0, 2.0 * ud), ud), 0.0, 1.0)
    lx, ly, lz = _square_to_cosine_hemisphere_unchecked(ud, u[:, 3])
    fr = Frame(nrm * np.where(back, -1.0, 1.0)[:, None])
    w = fr.s * lx[:, None] + fr.n * ly[:, None] + fr.t * lz[:, None]
    le = np.take(scene.prim_emission, pr, axis=0)
    le = np.where(((_dot(nrm, -w) < 0.0) | two)[:, None], le, 0.0)
    return dict(p=p, n=fr.n, w=w, prim=pr, pdf_pos=pmf / np.take(em.prim_area, pr), le=le, cos=ly,
                pdf_dir=np.where(ly >= 0.0, ly * _INV_PI, 0.0) * np.where(two, 0.5, 1.0))


def trace_lambertian(ctx, layout, x, cam_cap, light_cap, work: Workspace | None = None):
    """The camera subpaths (``cam_cap`` vertices each; 1: the pinhole only) and light subpaths
    (``light_cap``; 0: none) of states ``x``: ``(C, L, pixel, rays)`` (dense :class:`_Vertices`,
    ``pixel`` the film pixel of each state)."""
    scene, em, cam, res = ctx.scene, ctx.em, ctx.scene.camera, ctx.res
    m = x.shape[0]
    albedo = np.ascontiguousarray(np.array([mt.albedo for mt in scene.materials]).T)     # (3, M)
    rays = 0
    width, height = res
    col = np.minimum((x[:, 0] * width).astype(np.intp), width - 1)
    row = np.minimum((x[:, 1] * height).astype(np.intp), height - 1)
    pixel = row * width + col
    work = Workspace() if work is None else work
    C = work.vertices("camera", max(int(cam_cap.max(initial=1)), 1), m)
    C.p[0], C.ng[0], C.beta[0], C.pdf_fwd[0], C.prim[0] = cam.position, 0.0, 1.0, 1.0, -1
    C.length[:] = 1
    cj = np.flatnonzero(cam_cap >= 2)
    if cj.size:
        offsets = np.stack([x[cj, 0] * width - col[cj], x[cj, 1] * height - row[cj]], axis=1)
        d = cam.ray_directions_soa(res, pixel[cj], offsets)
        pdf_dir = cam.pdf_We(np.ascontiguousarray(d.T), res)[1]
        o = np.repeat(np.asarray(cam.position, dtype=np.float64)[:, None], cj.size, axis=1)
        rays += _walk(ctx, C, albedo, (cj, o, d, np.ones((3, cj.size)), pdf_dir, np.zeros((3, cj.size))),
                      (x[:, layout.camera_vertices], cam_cap, False))
    L = work.vertices("light", max(int(light_cap.max(initial=1)), 1), m)
    lj = np.flatnonzero(light_cap >= 1)
    if lj.size:
        u = x[lj, layout.light_origin]
        org = _origins(ctx, u)
        L.p[0][lj], L.ng[0][lj], L.prim[0, lj] = org["p"], org["n"], org["prim"]
        L.pdf_fwd[0, lj] = org["pdf_pos"]
        L.length[lj] = 1
        with np.errstate(divide="ignore", invalid="ignore"):
            L.beta[0][lj] = np.where(org["pdf_pos"] > 0, 1.0 / org["pdf_pos"], 0.0)[:, None]
            beta1 = org["le"] * np.where((org["pdf_dir"] > 0) & (org["pdf_pos"] > 0),
                                         org["cos"] / (org["pdf_pos"] * org["pdf_dir"]), 0.0)[:, None]
        o = org["p"] + org["n"] * ctx.eps
        start = (lj, np.ascontiguousarray(o.T), np.ascontiguousarray(org["w"].T), np.ascontiguousarray(beta1.T),
                 org["pdf_dir"], np.ascontiguousarray(org["n"].T))
        rays += _walk(ctx, L, albedo, start, (x[:, layout.light_vertices], light_cap, True))
    return C, L, pixel, rays


def connect_lambertian(ctx, C, L, pixel_c, rows, s, t, depth):
    """BDPT's connection of strategy ``(s[j], t[j])`` at depth ``depth[j]`` for every ``j`` at once,
    on the subpaths ``rows[j]`` of ``C`` and ``L`` (:func:`trace_lambertian`), weighted by the MIS
    weight: ``(f, pixel, rgb, rays)`` with ``rgb = (d + 1) w_{s,t} C_{s,t}``, as
    :func:`~mcvar.integrators.mmlt_states.evaluate_states`."""
    em, cam, res = ctx.em, ctx.scene.camera, ctx.res
    albedo = np.array([mt.albedo for mt in ctx.scene.materials])
    n = rows.size
    k, q = t - 1, s - 1
    rays = 0
    empty = np.zeros(0)
    parts = []           # per kind: (j, value, pixel, oc0, oc1, ol0, ol1, shadow-ray ends or None)
    # s = 0: z_{t-1} on an emitter (bdpt._connect_emitter)
    j = np.flatnonzero((s == 0) & (C.length[rows] >= t))
    if j.size:
        prim = C.prim[k[j], rows[j]]
        j = j[prim >= 0]
        j = j[np.take(em.prim_select, C.prim[k[j], rows[j]]) > 0.0]
    if j.size:
        kj, rj = k[j], rows[j]
        prim, pk = C.prim[kj, rj], C.take(C.p, kj, rj)
        wo, r = _unit(C.take(C.p, kj - 1, rj) - pk)
        value = C.take(C.beta, kj, rj) * em.emission(prim, pk, wo)
        oc1 = em.pdf_dir(prim, pk, wo) * np.abs(_dot(C.take(C.ng, kj - 1, rj), wo)) / (r * r)   # used where k - 1 >= 1
        parts.append([j, value, pixel_c[rj], em.pdf_pos(prim), oc1, empty, empty, None])
    # t = 1: y_{s-1} joined to the pinhole (light._connect_camera)
    j = np.flatnonzero((t == 1) & (L.length[rows] >= s))
    if j.size:
        qj, rj = q[j], rows[j]
        pq, nq = L.take(L.p, qj, rj), L.take(L.ng, qj, rj)
        wi, dist, we, pdf, xy, visible = cam.sample_Wi(pq, res)
        cos_q = np.abs(_dot(nq, wi))
        f = np.zeros((j.size, 3))
        ol1 = np.zeros(j.size)
        one = qj == 0
        if np.any(one):
            a = np.flatnonzero(one)
            f[a] = _area_light(ctx, L.prim[0, rj[a]], pq[a], wi[a])[0]
        if not np.all(one):
            a = np.flatnonzero(~one)
            qa, ra = qj[a], rj[a]
            wo, r_m = _unit(L.take(L.p, qa - 1, ra) - pq[a])
            f[a], _, back = _bsdf(albedo, L.mat[qa, ra], nq[a], wo, wi[a])
            ol1[a] = back * np.abs(_dot(L.take(L.ng, qa - 1, ra), wo)) / (r_m * r_m)
        with np.errstate(divide="ignore", invalid="ignore"):
            value = L.take(L.beta, qj, rj) * f * np.where(visible, cos_q * we / pdf, 0.0)[:, None]
            ol0 = cam.pdf_We(-wi, res)[1] * cos_q / (dist * dist)
        ends = (pq, nq, np.broadcast_to(cam.position, pq.shape), np.zeros_like(pq))
        parts.append([j, value, cam.pixel_index(xy, res), empty, empty, ol0, ol1, ends])
    # s >= 1, t >= 2: y_{s-1} joined to z_{t-1} by a shadow ray (bdpt._connect_inner)
    j = np.flatnonzero((s >= 1) & (t >= 2) & (L.length[rows] >= s) & (C.length[rows] >= t))
    if j.size:
        qj, kj, rj = q[j], k[j], rows[j]
        pq, nq, pk, nk = L.take(L.p, qj, rj), L.take(L.ng, qj, rj), C.take(C.p, kj, rj), C.take(C.ng, kj, rj)
        w, dist = _unit(pk - pq)
        d2 = dist * dist
        wo_k, r_k = _unit(C.take(C.p, kj - 1, rj) - pk)
        f_k, pdf_k_fwd, pdf_k_rev = _bsdf(albedo, C.mat[kj, rj], nk, wo_k, -w)
        f_q = np.zeros((j.size, 3))
        pdf_q_fwd = np.zeros(j.size)
        ol1 = np.zeros(j.size)
        one = qj == 0
        if np.any(one):
            a = np.flatnonzero(one)
            f_q[a], pdf_q_fwd[a] = _area_light(ctx, L.prim[0, rj[a]], pq[a], w[a])
        if not np.all(one):
            a = np.flatnonzero(~one)
            qa, ra = qj[a], rj[a]
            wo_q, r_q = _unit(L.take(L.p, qa - 1, ra) - pq[a])
            f_q[a], pdf_q_fwd[a], rev = _bsdf(albedo, L.mat[qa, ra], nq[a], wo_q, w[a])
            ol1[a] = rev * np.abs(_dot(L.take(L.ng, qa - 1, ra), wo_q)) / (r_q * r_q)
        cos_q, cos_k = np.abs(_dot(nq, w)), np.abs(_dot(nk, w))
        value = L.take(L.beta, qj, rj) * f_q * C.take(C.beta, kj, rj) * f_k * (cos_q * cos_k / d2)[:, None]
        oc1 = pdf_k_rev * np.abs(_dot(C.take(C.ng, kj - 1, rj), wo_k)) / (r_k * r_k)          # used where k - 1 >= 1
        parts.append([j, value, pixel_c[rj], pdf_q_fwd * cos_k / d2, oc1, pdf_k_fwd * cos_q / d2, ol1,
                      (pq, nq, pk, nk)])
    # what carries no light is dropped; then every shadow ray in one call
    for part in parts:
        go = np.flatnonzero(_max3(part[1]) > 0.0)
        part[:7] = [a[go] if a.size else a for a in part[:7]]
        part[7] = None if part[7] is None else tuple(e[go] for e in part[7])
    shadow = [part for part in parts if part[7] is not None]
    if shadow:
        pa, na, pb, nb = (np.concatenate(c) for c in zip(*(part[7] for part in shadow)))
        if pa.shape[0]:
            v = pb - pa
            oa = pa + na * (ctx.eps * np.sign(_dot(na, v)))[:, None]
            ob = pb - nb * (ctx.eps * np.sign(_dot(nb, v)))[:, None]
            dd, rr = _unit(ob - oa)
            vis = ~ctx.tracer.occluded_soa(np.ascontiguousarray(oa.T), np.ascontiguousarray(dd.T), rr - ctx.eps)
            rays += pa.shape[0]
        at = 0
        for part in shadow:
            ok = np.flatnonzero(vis[at:at + part[0].size]) if part[0].size else part[0]
            at += part[0].size
            part[:7] = [a[ok] if a.size else a for a in part[:7]]
    rgb = np.zeros((n, 3))
    pixel = np.full(n, -1, dtype=np.intp)
    for j, value, pix, oc0, oc1, ol0, ol1, _ in parts:
        if j.size:
            weight = _mis(ctx, C, L, rows[j], s[j], t[j], (oc0, oc1, ol0, ol1))
            rgb[j] = value * (weight * (depth[j] + 1))[:, None]
            pixel[j] = pix
    f = rgb @ _LUM
    pixel[f <= 0.0] = -1
    return f, pixel, rgb, rays
