"""Vectorised ray-scene intersection for wavefront path tracing (layer 4).

Rays come in as arrays ``(n, 3)``; every stage works on all of them at once
(no Python loop over rays). Inside, the hot loop uses the layouts measured to
pay on this project's machines: structure-of-arrays ``(3, n)``, ``float32``
ray geometry by default, chunks of ~2048 rays so temporaries stay in cache,
and bounding-box culling of triangle groups (the Cornell box's two blocks).
Hit distances come back as float64 and shading uses float64; radiance is
never accumulated in float32.

Triangles are intersected with a per-triangle affine map (Baldwin and Weber
2016): ``M (p - v0) = (b1, b2, h)`` with ``p - v0 = b1 e1 + b2 e2 + h n``, so
one small matrix product maps every ray of a chunk into every triangle's
barycentric frame at once; ``h(o + t d) = 0`` gives ``t``, and the hit is
inside when ``b1, b2 >= 0`` and ``b1 + b2 <= 1``. Spheres are solved in
float64 (the quadratic's cancellation is worse than the triangle test's).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._validation import as_array, check_count, check_choice

__all__ = ["Hit", "Tracer"]


@dataclass(frozen=True, eq=False)
class Hit:
    """Closest hits of a batch of rays.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Distance along the (unit) ray direction; ``inf`` where nothing is hit.
    prim : ndarray of int, shape (n,)
        Primitive index (triangles first, then spheres); -1 for a miss.
    """

    t: np.ndarray
    prim: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.prim >= 0


class Tracer:
    """Precomputed intersection data for one scene (:class:`mcvar.scene.Scene`).

    Parameters
    ----------
    scene : mcvar.scene.Scene
    dtype : {'float32', 'float64'}
        Precision of the triangle test (default float32: about 1.9x faster
        than float64 on this project's machines; tests show the Cornell image
        agrees with float64 geometry within its standard error).
    chunk : int
        Rays per chunk of the triangle test (default 2048).
    cull : bool
        Test a triangle group (``scene.prim_group > 0``) only for rays that
        hit its bounding box (default True).

    Notes
    -----
    The cost per chunk is ``O(n_rays * n_triangles)``: brute force over all
    triangles, which for the 32 triangles of the Cornell box beats any
    hierarchy written in NumPy (a BVH's per-node Python overhead costs more
    than the arithmetic it saves).
    """

    def __init__(self, scene, *, dtype="float32", chunk: int = 2048, cull: bool = True):
        # duck-typed: mcvar.scene is the same layer, so it is not imported here
        if not all(hasattr(scene, a) for a in ("triangles", "sphere_centers", "prim_group", "ray_epsilon")):
            raise TypeError(f"scene must be a mcvar.scene.Scene; got {type(scene).__name__}")
        check_choice(str(np.dtype(dtype)) if not isinstance(dtype, str) else dtype, "dtype",
                     ("float32", "float64"))
        self.scene = scene
        self.dtype = np.dtype(dtype)
        self.chunk = check_count(chunk, "chunk")
        self.epsilon = float(scene.ray_epsilon)
        tri = scene.triangles
        n_tri = tri.shape[0]
        self.n_triangles = n_tri
        self.n_spheres = scene.n_spheres
        v0 = tri[:, 0]
        e1 = tri[:, 1] - v0
        e2 = tri[:, 2] - v0
        nrm = np.cross(e1, e2)
        area2 = np.linalg.norm(nrm, axis=1)
        if n_tri and not np.all(area2 > 0):
            raise ValueError("scene has degenerate (zero-area) triangles")
        # Unit geometric normals of all primitives (spheres' are computed per hit).
        self.triangle_normal = nrm / area2[:, None] if n_tri else np.zeros((0, 3))
        # Per triangle the inverse of [e1 e2 n]; rows give b1, b2 and the height.
        basis = np.stack([e1, e2, nrm], axis=2)  # (T, 3, 3), columns e1, e2, n
        inv = np.linalg.inv(basis) if n_tri else np.zeros((0, 3, 3))
        offset = -np.einsum("tij,tj->ti", inv, v0) if n_tri else np.zeros((0, 3))
        # For origins the height row is negated, so that t = -h_o / h_d is one division.
        inv_o = inv.copy()
        inv_o[:, 2] *= -1.0
        offset[:, 2] *= -1.0
        groups = scene.prim_group[:n_tri]
        self._blocks = []
        for g in np.unique(groups) if n_tri else []:
            idx = np.flatnonzero(groups == g)
            # rows: b1 of all triangles, b2 of all, h of all
            mat_o = inv_o[idx].transpose(1, 0, 2).reshape(-1, 3)
            mat_d = inv[idx].transpose(1, 0, 2).reshape(-1, 3)
            off = offset[idx].T.reshape(-1)
            verts = tri[idx].reshape(-1, 3)
            box = (verts.min(axis=0), verts.max(axis=0)) if (g > 0 and cull) else None
            self._blocks.append((idx, np.ascontiguousarray(mat_o, self.dtype),
                                 np.ascontiguousarray(mat_d, self.dtype),
                                 np.ascontiguousarray(off[:, None], self.dtype), box))
        self._sph_c = scene.sphere_centers
        self._sph_r2 = scene.sphere_radii ** 2

    # ------------------------------------------------------------------
    def _tri_block(self, mat_o, mat_d, off, o, d, tmax, idx):
        """Closest hit among one block's triangles for SoA rays o, d (3, m)."""
        k = mat_o.shape[0] // 3
        ot = mat_o @ o
        ot += off
        dt = mat_d @ d
        with np.errstate(divide="ignore", invalid="ignore"):
            return self._tri_block_inner(ot, dt, k, tmax, idx)

    def _tri_block_inner(self, ot, dt, k, tmax, idx):
        t = ot[2 * k:] / dt[2 * k:]
        b1 = dt[:k]
        b1 *= t
        b1 += ot[:k]
        b2 = dt[k:2 * k]
        b2 *= t
        b2 += ot[k:2 * k]
        ok = b1 >= 0
        ok &= b2 >= 0
        b1 += b2
        ok &= b1 <= 1
        ok &= t > self.epsilon
        ok &= t < tmax
        t[~ok] = np.inf
        if k == 1:
            return t[0], np.where(ok[0], idx[0], -1)
        j = np.argmin(t, axis=0)
        best = np.take_along_axis(t, j[None], axis=0)[0]
        return best, np.where(np.isfinite(best), idx[j], -1)

    @staticmethod
    def _box_hit(box, o, d, tmax):
        lo, hi = box
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t0 = (lo[:, None] - o) * inv
            t1 = (hi[:, None] - o) * inv
        tn = np.minimum(t0, t1)
        tf = np.maximum(t0, t1)
        # NaN (0 * inf on a slab boundary) must count as 'maybe hit': fmax/fmin ignore NaN.
        near = np.fmax(np.fmax(tn[0], tn[1]), tn[2])
        far = np.fmin(np.fmin(tf[0], tf[1]), tf[2])
        return (near <= far) & (far > 0) & (near < tmax)

    def _triangles(self, o, d, tmax):
        """Closest triangle hits for SoA rays, processed in cache-sized chunks."""
        n = o.shape[1]
        t_out = np.full(n, np.inf, dtype=self.dtype)
        p_out = np.full(n, -1, dtype=np.int64)
        for s in range(0, n, self.chunk):
            sl = slice(s, min(n, s + self.chunk))
            oc, dc, tm = o[:, sl], d[:, sl], tmax[sl]
            tb = np.full(oc.shape[1], np.inf, dtype=self.dtype)
            pb = np.full(oc.shape[1], -1, dtype=np.int64)
            for idx, mat_o, mat_d, off, box in self._blocks:
                if box is None:
                    t, p = self._tri_block(mat_o, mat_d, off, oc, dc, np.minimum(tm, tb), idx)
                    better = t < tb
                    tb = np.where(better, t, tb)
                    pb = np.where(better, p, pb)
                    continue
                sel = np.flatnonzero(self._box_hit(box, oc, dc, np.minimum(tm, tb)))
                if sel.size == 0:
                    continue
                t, p = self._tri_block(mat_o, mat_d, off, np.take(oc, sel, axis=1), np.take(dc, sel, axis=1),
                                       np.minimum(np.take(tm, sel), np.take(tb, sel)), idx)
                better = t < np.take(tb, sel)
                tb[sel[better]] = t[better]
                pb[sel[better]] = p[better]
            t_out[sl] = tb
            p_out[sl] = pb
        return t_out, p_out

    def _spheres(self, o, d, tmax):
        """Closest sphere hits (float64), rays (n, 3)."""
        n = o.shape[0]
        if self.n_spheres == 0:
            return np.full(n, np.inf), np.full(n, -1, dtype=np.int64)
        oc = o[None, :, :] - self._sph_c[:, None, :]           # (S, n, 3)
        b = np.einsum("snk,nk->sn", oc, d)
        c = np.einsum("snk,snk->sn", oc, oc) - self._sph_r2[:, None]
        disc = b * b - c
        root = np.sqrt(np.maximum(disc, 0.0))
        t0 = -b - root
        t1 = -b + root
        eps = self.epsilon
        t = np.where(t0 > eps, t0, t1)
        ok = (disc >= 0) & (t > eps) & (t < tmax[None, :])
        t = np.where(ok, t, np.inf)
        j = np.argmin(t, axis=0)
        best = t[j, np.arange(n)]
        return best, np.where(np.isfinite(best), self.n_triangles + j, -1)

    def _check(self, origins, directions, tmax):
        o = as_array(origins, "origins", ndim=2, last=3)
        d = as_array(directions, "directions", ndim=2, last=3)
        if o.shape != d.shape:
            raise ValueError(f"origins and directions must have the same shape; got {o.shape} and {d.shape}")
        if tmax is None:
            tm = np.full(o.shape[0], np.inf)
        else:
            tm = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (o.shape[0],))
            if np.any(np.isnan(tm)):
                raise ValueError("tmax must not be NaN")
        return o, d, tm

    def intersect(self, origins, directions, tmax=None) -> Hit:
        """Closest hit of every ray.

        Parameters
        ----------
        origins, directions : array_like, shape (n, 3)
            Ray origins and **unit** directions.
        tmax : float or array_like, shape (n,), optional
            Ignore hits at distance >= tmax (default: no limit). Hits closer
            than ``scene.ray_epsilon`` are ignored (self-intersection).

        Returns
        -------
        Hit
            ``t`` (float64, inf on a miss) and ``prim`` (-1 on a miss).
        """
        o, d, tm = self._check(origins, directions, tmax)
        t_tri, p_tri = self._triangles(np.ascontiguousarray(o.T, self.dtype),
                                       np.ascontiguousarray(d.T, self.dtype),
                                       tm.astype(self.dtype))
        t = t_tri.astype(np.float64)
        prim = p_tri
        if self.n_spheres:
            ts, ps = self._spheres(o, d, np.minimum(tm, t))
            closer = ts < t
            t = np.where(closer, ts, t)
            prim = np.where(closer, ps, prim)
        return Hit(t=t, prim=prim)

    def occluded(self, origins, directions, tmax) -> np.ndarray:
        """True where anything lies between ``scene.ray_epsilon`` and ``tmax`` along the ray.

        Shadow rays: pass ``tmax = distance - scene.ray_epsilon`` so that the
        light's own surface does not occlude it.
        """
        hit = self.intersect(origins, directions, tmax)
        return hit.prim >= 0

    def normals(self, prim, points) -> np.ndarray:
        """Unit geometric normals ``(n, 3)`` of primitives ``prim`` at ``points``.

        Triangles: ``normalize(cross(v1 - v0, v2 - v0))``; spheres: outward.
        """
        prim = np.asarray(prim)
        points = np.asarray(points, dtype=np.float64)
        n = np.empty((prim.shape[0], 3))
        is_tri = prim < self.n_triangles
        if np.all(is_tri):
            return np.take(self.triangle_normal, prim, axis=0)
        n[is_tri] = np.take(self.triangle_normal, prim[is_tri], axis=0)
        s = prim[~is_tri] - self.n_triangles
        v = points[~is_tri] - np.take(self._sph_c, s, axis=0)
        n[~is_tri] = v / np.take(self.scene.sphere_radii, s)[:, None]
        return n
