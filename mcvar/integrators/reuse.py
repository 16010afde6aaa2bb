"""Path reuse among neighbouring pixels for the Lambertian kernel (Bekaert,
Sbert and Halton 2002, 'Accelerating Path Tracing by Re-Using Paths', EGWR).

A batch's camera samples are grouped in **tiles**: sample ``s`` of
``size`` consecutive pixels of the batch (rows ``pixel * spp + s`` of the
batch's path order; the batch's pixels are image rows for ``render``, an
adaptive stage's pixels of one level in 2 x 2 blocks). Camera path ``k``
reaches its first vertex ``x1_k`` and draws the second, ``x2_k``, with the
cosine density. In a scene of Lambertian surfaces what the rest of a path
estimates from ``x2`` on, the reflected radiance ``L_r(x2)`` (everything but
``x2``'s own emission, which stays with its own path and its MIS weight
against next-event estimation), does not depend on the direction ``x2`` is
seen from, only on the side of its surface. So every first vertex of a tile
can use every ``x2`` of the tile: pixel ``i`` estimates its indirect light
by the multi-sample balance heuristic over the tile's ``size`` sampling
techniques (Veach 1997, sec. 9.2.2, one sample per technique),

    ``I_i = sum_j  rho_i  p_i(x2_j) / sum_k p_k(x2_j)  L_r(x2_j)``,

where ``p_k(x) = cos_k cos_x V(x1_k, x) / (pi |x - x1_k|^2)`` is the area
density with which ``x1_k`` draws ``x`` (visibility by one shadow ray per
pair of the tile; the pair of a path with itself is its own bounce),
``rho_i`` the albedo at ``x1_i`` and the sums run over the techniques on
``x2_j``'s side of its surface. Given the first vertices the weights of
every ``x`` sum to one over the techniques that can draw it, so ``I_i`` is
unbiased; without reuse the tile is ``size`` independent single-sample
estimates (``I_i = rho_i L_r(x2_i)``).

**What it gives, what it costs.** ``size - 1`` shadow rays and a few
dozen array operations a camera path, and each pixel's indirect light is
the average of up to ``size`` paths instead of one: its variance falls up
to ``size``-fold where the tile's first vertices see alike (one surface),
less across edges. The noise of a tile is *correlated*: the tile's mean is
estimated about as well as without reuse (the weights of one ``x2_j`` over
the tile's pixels sum to about ``rho``), so the gain is per pixel, the
measure of every MSE in this project, not in the image averaged over tiles
(docs/performance.md, 'Path reuse').

Exactness. A tile is traced in one wavefront load (the kernel's refills
end on tile boundaries, :meth:`PathReuse.aligned`), so every technique of a
tile is known when its second vertices are connected and a path's radiance
is a pure function of the tile's rows of ``u`` (tested exactly). Reuse is
off where its densities would not be the sampled ones: paths of at most two
segments (nothing after ``x2``), roulette at the first vertex
(``rr_depth < 2``), tiles of one pixel, or a tile larger than the wavefront.
"""
from __future__ import annotations

import numpy as np

from .state import dot

__all__ = ["PathReuse", "REUSE_SIZE"]

#: Pixels per tile of the adaptive renders (``render_adaptive``'s ``reuse``): on the
#: 128 x 128 box 2.0x as efficient per pixel as no reuse (2: 1.3x, 8: 2.5x, with the
#: noise correlated over 4 x 2 pixels); docs/performance.md, 'Path reuse'.
REUSE_SIZE = 4


class PathReuse:
    """The tiles of one batch of the Lambertian kernel and what reuse keeps of them.

    Made by :meth:`start`; the kernel calls :meth:`first_vertices` for its
    new camera paths' first hits, :meth:`connect` for the rows at their
    second vertex (before next-event estimation there) and :meth:`finish`
    once the batch is traced. While it runs, paths from ``x2`` on add their
    radiance to columns ``total + row`` of ``tr.radiance`` (their ``state.tag``),
    which :meth:`finish` spreads over the tile's pixels.
    """

    __slots__ = ("size", "spp", "pixels", "total", "first", "pairs")

    def __init__(self, size: int, spp: int, pixels: int, total: int, dtype):
        self.size, self.spp, self.pixels, self.total = size, spp, pixels, total
        #: per camera path: x1 (0-2), the normal on the camera's side (3-5),
        #: the albedo (6-8), 1 where x1 draws a bounce (9); zeros until registered
        self.first = np.zeros((10, total), dtype)
        #: per connected second vertex: (pixel rows, subpath rows, balance weights)
        self.pairs = []

    @classmethod
    def start(cls, tr, total: int, slots: int) -> "PathReuse | None":
        """The batch's reuse, or None where it is off (module docstring);
        switches ``tr.radiance`` to the doubled layout."""
        size, layout = tr.settings.reuse, tr.layout
        if size <= 1 or layout is None or tr.limit <= 2 or tr.rr_start < 2:
            return None
        spp, pixels = layout
        if spp * pixels != total or pixels < 2 or size * spp > slots:
            return None
        tr.radiance = np.zeros((3, 2 * total))
        return cls(size, spp, pixels, total, tr.tracer.dtype)

    def aligned(self, start: int, end: int) -> int:
        """The end of a wavefront load from row ``start``: ``end`` moved back to a
        tile boundary (at least one tile), so no tile is split between loads."""
        if end >= self.total:
            return self.total
        block = self.size * self.spp
        return min(self.total, max(start - start % block + block, end - end % block))

    def first_vertices(self, rows, p, n_side, albedo, draws) -> None:
        """Record camera paths ``rows``' first vertices: points ``p``, normals
        on the camera's side ``n_side``, albedo (3, m), ``draws`` (m,) where
        the path samples a bounce there."""
        f = self.first
        f[0:3, rows] = p
        f[3:6, rows] = n_side
        f[6:9, rows] = albedo
        f[9, rows] = draws

    def connect(self, tr, state, at, p, fn, sgn, prim) -> None:
        """Connect the rows ``at`` of ``state`` (at their second vertex ``p``,
        unflipped normal ``fn``, side ``sgn``, triangle ``prim``) to every first
        vertex of their tile; their later radiance goes to their reuse column."""
        K, spp = self.size, self.spp
        row = np.take(state.idx, at)
        n = row.size
        x2, n2 = np.take(p, at, axis=1), np.take(fn, at, axis=1)
        s2 = np.take(sgn, at)
        pix = row // spp
        me = pix % K                                       # this path's technique in its tile
        mem_pix = (pix - me)[None, :] + np.arange(K)[:, None]
        valid = mem_pix < self.pixels
        mem = np.where(valid, mem_pix * spp + (row - pix * spp)[None, :], row[None, :])   # (K, n)
        xk = np.take(self.first, mem.ravel(), axis=1).reshape(10, K, n)
        v = xk[0:3] - x2[:, None, :]                       # x2 -> x1_k
        d2 = v[0] * v[0]
        d2 += v[1] * v[1]
        d2 += v[2] * v[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / np.sqrt(d2)
        n2s = n2 * s2                                      # x2's normal on its path's side
        cos2 = v[0] * n2s[0][None]
        cos2 += v[1] * n2s[1][None]
        cos2 += v[2] * n2s[2][None]
        cos2 *= inv
        cos1 = v[0] * xk[3]
        cos1 += v[1] * xk[4]
        cos1 += v[2] * xk[5]
        cos1 *= -inv
        good = valid & (xk[9] > 0) & (cos2 > 0) & (cos1 > 0) & (d2 > 0)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            dens = np.where(good, cos1 * cos2 / (np.pi * d2), 0.0)
        own = np.zeros((K, n), dtype=bool)
        own[me, np.arange(n)] = True
        need = good & ~own
        a, j = np.nonzero(need)
        if a.size:
            origin, d_sh, tmax = _to_points(np.take(x2, j, 1), np.take(n2s, j, 1), xk[0:3, a, j], tr.eps)
            keys = tr.tracer.shadow_keys(np.take(prim, np.take(at, j)), np.take(s2, j), np.full(j.size, -1))
            blocked = tr.tracer.occluded_soa(origin, d_sh, tmax, keys)
            dens[a[blocked], j[blocked]] = 0.0
            tr.rays += int(a.size)
        total = dens.sum(axis=0)
        mine = dens[me, np.arange(n)]
        ok = mine > 0
        frac = np.where(ok[None], dens / np.where(ok, total, 1.0)[None], own)
        keep = frac > 0
        kk, jj = np.nonzero(keep)
        self.pairs.append((mem[kk, jj], row[jj], frac[kk, jj].astype(np.float32)))
        state.tag[at] += self.total

    def finish(self, tr) -> None:
        """Spread every reused path's radiance over its tile: pixel ``i`` gets
        ``rho_i / rho_j`` times path ``j``'s (its throughput carried ``rho_j``)
        times the balance weight; ``tr.radiance`` back to (3, total)."""
        total = self.total
        ext = tr.radiance
        rad = np.ascontiguousarray(ext[:, :total])
        if self.pairs:
            to = np.concatenate([q[0] for q in self.pairs])
            sub = np.concatenate([q[1] for q in self.pairs])
            frac = np.concatenate([q[2] for q in self.pairs]).astype(np.float64)
            alb = self.first[6:9]
            for c in range(3):
                rho_j = np.take(alb[c], sub).astype(np.float64)
                g = np.divide(np.take(alb[c], to), rho_j, out=np.zeros(sub.size), where=rho_j > 0)
                g *= frac
                g *= np.take(ext[c], sub + total)
                rad[c] += np.bincount(to, weights=g, minlength=total)
        tr.radiance = rad


def _to_points(p, n_side, q, eps):
    """Shadow rays from ``p`` (offset ``eps`` along ``n_side``) to points ``q``,
    stopping ``2 eps`` short: (origin, unit direction, tmax), SoA (3, m)."""
    origin = n_side * eps
    origin += p
    d = q - origin
    length = np.sqrt(dot(d, d))
    d /= length
    length -= 2.0 * eps
    return origin, d, length
