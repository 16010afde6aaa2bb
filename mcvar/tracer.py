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

from . import bvh as _bvh
from . import convex as _convex
from ._validation import as_array, check_bool, check_count, check_choice

__all__ = ["Hit", "Tracer", "BVH_MIN_TRIANGLES", "ACCELERATIONS"]

#: ``accel='auto'`` uses the BVH (:mod:`mcvar.bvh`) for scenes with more triangles
#: than this, brute force over triangle groups below. Measured (``benchmarks/bench_triangles.py``,
#: the subdivided Cornell box, path 64x64 at 32 spp, CPU time, load 4-5): brute force ahead at
#: 122 triangles (0.91 against 0.66 M paths/s), a tie at 272 (0.61 against 0.63; 0.60 against
#: 0.57 in a second run), the 4-wide BVH ahead at 482 (0.63 against 0.40) and 10x at 1,922.
BVH_MIN_TRIANGLES = 400
#: Intersection strategies of :class:`Tracer`.
ACCELERATIONS = ("auto", "bvh", "groups", "shells")


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


#: OpenBLAS runs a matrix product on one thread when ``rows x columns x inner``
#: is below ``SMP_THRESHOLD_MIN x GEMM_MULTITHREAD_THRESHOLD`` = 65536 x 4
#: (interface/gemm.c); above it, its threads fight the render's worker
#: processes for the two cores.
_BLAS_ONE_THREAD = 65536 * 4


def _one_thread_product(a, b):
    """``a @ b`` for a small ``a`` (r, c) and a wide ``b`` (c, m), in column
    chunks small enough that OpenBLAS computes each on one thread.

    The same numbers as ``a @ b`` (each entry is the same length-``c`` dot
    product, only the columns are split). Measured: the default render of the
    122-triangle box (64 x 64, 64 spp, two workers) took 2.4-2.5 s of CPU with
    OpenBLAS's threads on this product and 0.48 s with
    ``OPENBLAS_NUM_THREADS=1`` (docs/performance.md, 'Cost per path and
    image size'); chunking gives the one-thread figure whatever the
    environment says.
    """
    r, c = a.shape
    m = b.shape[1]
    step = max(1, (_BLAS_ONE_THREAD - 1) // (r * c))
    if m <= step:
        return a @ b
    # even chunks: no narrow last chunk (a one-column product goes to
    # another kernel, whose float32 rounding differs from the GEMM's)
    step = -(-m // -(-m // step))
    out = np.empty((r, m), dtype=np.result_type(a, b))
    for start in range(0, m, step):
        np.matmul(a, b[:, start:start + step], out=out[:, start:start + step])
    return out


def _plane_coordinates(mat_o, mat_d, o4, d, k):
    """``(t, b1, b2)``, each (k, m): the distance to each of ``k`` planes and the
    hit's two coordinates in its frame, from stacked affine maps (rows: b1 of
    all, b2 of all, -h of all; :meth:`Tracer._make_block`)."""
    ot = _one_thread_product(mat_o, o4)
    dt = _one_thread_product(mat_d, d)
    t = ot[2 * k:]
    t /= dt[2 * k:]
    b1 = dt[:k]
    b1 *= t
    b1 += ot[:k]
    b2 = dt[k:2 * k]
    b2 *= t
    b2 += ot[k:2 * k]
    return t, b1, b2


class _Block:
    """One triangle group's stacked maps (rows: b1 of all, b2 of all, h of all)."""

    __slots__ = ("idx", "k", "mat_o", "mat_d", "box", "col8")

    def __init__(self, idx, k, mat_o, mat_d, box):
        self.idx, self.k, self.mat_o, self.mat_d, self.box = idx, k, mat_o, mat_d, box
        # triangle index within the group, as a uint8 column (None for >= 256 triangles)
        self.col8 = np.arange(k, dtype=np.uint8)[:, None] if k < 256 else None


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
    accel : {'auto', 'bvh', 'groups', 'shells'}
        ``'groups'``: brute force over triangle groups; ``'shells'``: the
        same, except that every edge-connected set of a group's triangles that
        bounds a convex polyhedron (:func:`mcvar.convex.find_shell`: the
        Cornell room and its blocks) is intersected by its planes' half-spaces,
        and leftover triangle pairs that form a parallelogram (the Cornell
        light) by one parallelogram test (closest hits only; shadow rays use
        the groups); ``accel`` then reads ``'shells'`` if any was found, else
        ``'groups'``; ``'bvh'``: a binned-SAH bounding volume hierarchy, collapsed
        to 4-wide nodes and traversed as a wavefront of (ray, node) pairs
        (:mod:`mcvar.bvh`), whose cost grows
        with the logarithm of the triangle count and whose memory grows
        linearly; ``'auto'`` (default): the BVH above
        :data:`BVH_MIN_TRIANGLES` triangles, ``'shells'`` below.

    Notes
    -----
    The cost per chunk is ``O(n_rays * n_triangles)``: brute force over all
    triangles, which for the 32 triangles of the Cornell box beats any
    hierarchy written in NumPy (a BVH's per-node Python overhead costs more
    than the arithmetic it saves).

    Shadow rays (:meth:`occluded`) are *any-hit* queries: a ray stops being
    tested once one group occludes it, and every group is tested only for
    rays that cross its bounding box. Next-event estimation also passes each
    shadow ray's *key* (the shading triangle, the side of its surface the ray
    leaves from and the light it aims at, :meth:`shadow_keys`); a table built
    once per scene then drops the triangles that cannot lie between any such
    origin and light. Triangle ``j`` is dropped for a key when the shading
    triangle and the light parallelogram, both moved off the surface by the
    ray offset ``ray_epsilon``, lie on one side of ``j``'s plane, the light
    strictly (by a margin that covers float32 rounding of the hit point): a
    segment from a point of a closed half-space to a point of the open one
    meets the plane at most at its start, where hits closer than
    ``ray_epsilon`` are ignored anyway (half-spaces are convex). In the
    Cornell box this removes the walls, the floor and the ceiling from the
    shadow rays of every wall, floor and ceiling point: only the blocks and
    the light remain.
    """

    def __getstate__(self):
        """Pickled without the shading tables cached on it (``SceneTables.of``):
        a tracer crosses to every worker process (once per process for a render's
        own pool, inside every batch for other executors), and the tables, several
        MB at 100k triangles, are rebuilt once in the process that reads them."""
        state = dict(self.__dict__)
        state.pop("_scene_tables", None)
        return state

    def __init__(self, scene, *, dtype="float32", chunk: int = 2048, cull: bool = True, accel: str = "auto"):
        # duck-typed: mcvar.scene is the same layer, so it is not imported here
        if not all(hasattr(scene, a) for a in ("triangles", "sphere_centers", "prim_group", "ray_epsilon")):
            raise TypeError(f"scene must be a mcvar.scene.Scene; got {type(scene).__name__}")
        check_choice(str(np.dtype(dtype)) if not isinstance(dtype, str) else dtype, "dtype",
                     ("float32", "float64"))
        self.scene = scene
        self.dtype = np.dtype(dtype)
        self.chunk = check_count(chunk, "chunk")
        self._box_slice = 4 * self.chunk        # rays per call of the slab test
        self.cull = check_bool(cull, "cull")
        check_choice(accel, "accel", ACCELERATIONS)
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
        #: the same normals as structure-of-arrays (3, T), for the wavefront loop
        self.triangle_normal_soa = np.ascontiguousarray(self.triangle_normal.T)
        # Per triangle the inverse of [e1 e2 n]; rows give b1, b2 and the height.
        basis = np.stack([e1, e2, nrm], axis=2)  # (T, 3, 3), columns e1, e2, n
        inv = np.linalg.inv(basis) if n_tri else np.zeros((0, 3, 3))
        offset = -np.einsum("tij,tj->ti", inv, v0) if n_tri else np.zeros((0, 3))
        # For origins the height row is negated, so that t = -h_o / h_d is one division.
        self._inv_o = inv.copy()
        self._inv_o[:, 2] *= -1.0
        self._inv = inv
        self._offset = offset.copy()
        self._offset[:, 2] *= -1.0
        self._sph_c = scene.sphere_centers
        self._sph_r2 = scene.sphere_radii ** 2
        self._n_prims = n_tri + self.n_spheres
        use_bvh = n_tri > 0 and (accel == "bvh" or (accel == "auto" and n_tri > BVH_MIN_TRIANGLES))
        self.accel = "bvh" if use_bvh else "groups"
        if use_bvh:
            # no per-group blocks and no shadow table (its size grows with T^2)
            self._bvh = _bvh.build_bvh(tri, dtype=self.dtype)
            self._cand = None
            self._shadow_keep = self._build_class_table()
            # the per-triangle maps serve only the groups' blocks: not kept (nor
            # pickled into every batch: 14.7 MB of a 40 MB tracer at 87k triangles)
            del self._inv, self._inv_o, self._offset
            return
        groups = scene.prim_group[:n_tri]
        self._shells = []
        shell_tris = (self._find_shells(groups) if n_tri and accel in ("auto", "shells")
                      else np.zeros(n_tri, dtype=bool))
        if self._shells:
            self.accel = "shells"
        self._blocks = [self._make_block(np.flatnonzero((groups == g) & ~shell_tris), g > 0 and self.cull)
                        for g in (np.unique(groups[~shell_tris]) if n_tri else [])]
        # any-hit order: boxed groups first (they occlude most), then the rest, each boxed;
        # shadow rays test the shells' triangles too (with the groups' boxes, most
        # shadow rays skip the Cornell blocks at once: measured faster than the shells)
        whole = [self._make_block(np.flatnonzero(groups == g), g > 0 and self.cull)
                 for g in (np.unique(groups) if n_tri else [])]
        order = sorted(whole, key=lambda b: b.box is None)
        self._shadow_all = self._stack_boxes([self._make_block(b.idx, True) for b in order])
        self._boxed = self._stack_boxes([b for b in self._blocks if b.box is not None])
        self._shadow_cache = {}
        self._build_shadow_table()
        if self._shells:
            # closest hits: the leftover triangles that pair into parallelograms
            # (the Cornell light) by one parallelogram test each, the others as blocks
            rest = np.flatnonzero(~shell_tris)
            self._quads, single = self._pair_quads(rest)
            self._closest_blocks = [self._make_block(np.intersect1d(b.idx, single), False)
                                    for b in self._blocks if np.intersect1d(b.idx, single).size]

    # ------------------------------------------------------------------
    # Construction

    def _find_shells(self, groups):
        """Convex shells (:mod:`mcvar.convex`) among each group's edge-connected
        triangles: ``self._shells``, the face tables, and which triangles they hold."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components
        tri = self.scene.triangles
        n_tri = tri.shape[0]
        scale = max(1.0, float(np.abs(tri).max()))
        keys = np.round(tri / (1e-9 * scale)).astype(np.int64).reshape(-1, 3)
        _, vid = np.unique(keys, axis=0, return_inverse=True)                    # vertex ids
        vid = vid.reshape(n_tri, 3)
        nv = int(vid.max()) + 1
        edge = np.concatenate([np.minimum(vid[:, a], vid[:, b]) * nv + np.maximum(vid[:, a], vid[:, b])
                               for a, b in ((0, 1), (1, 2), (2, 0))])             # (3T,) edge ids
        owner = np.tile(np.arange(n_tri), 3)
        order = np.argsort(edge, kind="stable")
        same = edge[order][1:] == edge[order][:-1]
        a, b = owner[order][:-1][same], owner[order][1:][same]
        keep = groups[a] == groups[b]
        graph = coo_matrix((np.ones(int(keep.sum())), (a[keep], b[keep])), shape=(n_tri, n_tri))
        _, comp = connected_components(graph, directed=False)
        shells = []
        prims, diagonal = [np.full((1, 2), -1, dtype=np.int64)], [np.zeros((1, 4))]
        held = np.zeros(n_tri, dtype=bool)
        for k in np.unique(comp):
            idx = np.flatnonzero(comp == k)
            shell = _convex.find_shell(tri, idx, first_code=sum(p.shape[0] for p in prims), dtype=self.dtype)
            if shell is None:
                continue
            shells.append((shell, idx))
            real = shell.code[:, 0] > 0
            prims.append(shell.prims[real])
            diagonal.append(shell.diagonal[real])
            held[idx] = True
        # per face code: the diagonal's row and the triangles on its two sides
        # (one-triangle faces: a zero row, the triangle on both sides; code 0: -1)
        face_prims = np.concatenate(prims)
        face_prims[:, 1] = np.where(face_prims[:, 1] < 0, face_prims[:, 0], face_prims[:, 1])
        self._face_table = np.ascontiguousarray(np.concatenate(diagonal).T, dtype=self.dtype)   # (4, K + 1)
        self._face_prims = np.ascontiguousarray(face_prims.T)                                   # (2, K + 1)
        # A shell that holds most of the other triangles (a room) mostly sees rays from
        # inside, the others (solids) rays from outside: stacked apart, so that each
        # stack's rays take one kernel (mcvar.convex.shell_hits; correct either way)
        centres = tri.mean(axis=1)
        kinds = []
        for shell, idx in shells:
            other = np.ones(n_tri, dtype=bool)
            other[idx] = False
            pts = centres[other] if other.any() else self.scene.light_origin + 0.5 * (
                self.scene.light_edge1 + self.scene.light_edge2)
            inside = (np.concatenate([pts, np.ones((pts.shape[0], 1))], axis=1) @ shell.w_rows.T.astype(np.float64)
                      >= 0).all(axis=1)
            kinds.append((shell, bool(pts.shape[0]) and inside.mean() > 0.5))
        self._shells = self._stacks(kinds)
        return held

    @staticmethod
    def _stacks(shells):
        """``(shell, is_room)`` pairs as at most two :class:`mcvar.convex.ShellStack`."""
        return [_convex.ShellStack.of([sh for sh, room in shells if room == kind])
                for kind in (True, False) if any(room == kind for _, room in shells)]

    def _pair_quads(self, idx):
        """Parallelograms among the triangles ``idx`` (pairs sharing a diagonal):
        ``(quads, unpaired)``, ``quads`` None or ``(mat_o (3Q, 4), mat_d (3Q, 3), prims (2, Q))``.

        A pair ``(c, a, b)``, ``(a, b, e)`` with ``c + e = a + b`` is the
        parallelogram ``c + u (a - c) + v (b - c)``, ``u, v`` in [0, 1]: one affine
        map to ``(u, v, h)`` as for a triangle (:meth:`_make_block`), the first
        triangle where ``u + v <= 1``."""
        tri = self.scene.triangles
        scale = max(1.0, float(np.abs(tri).max()))
        keys = np.round(tri / (1e-9 * scale)).astype(np.int64)
        by_edge = {}                                   # edge (two vertex keys) -> triangles
        for x in idx:
            for a, b in ((0, 1), (1, 2), (2, 0)):
                by_edge.setdefault(frozenset((tuple(keys[x, a]), tuple(keys[x, b]))), []).append(x)
        used, rows_o, rows_d, prims = set(), [], [], []
        for x in idx:
            if x in used:
                continue
            near = {y for a, b in ((0, 1), (1, 2), (2, 0))
                    for y in by_edge[frozenset((tuple(keys[x, a]), tuple(keys[x, b])))]}
            for y in sorted(near):
                if y == x or y in used:
                    continue
                tx, ty = tri[x], tri[y]
                shared = [(i, j) for i in range(3) for j in range(3)
                          if np.abs(tx[i] - ty[j]).max() <= 1e-9 * scale]
                if len(shared) != 2:
                    continue
                c = tx[3 - shared[0][0] - shared[1][0]]
                e = ty[3 - shared[0][1] - shared[1][1]]
                a, b = tx[shared[0][0]], tx[shared[1][0]]
                if np.abs(c + e - a - b).max() > 1e-9 * scale:
                    continue
                e1, e2 = a - c, b - c
                nrm = np.cross(e1, e2)
                inv = np.linalg.inv(np.stack([e1, e2, nrm], axis=1))
                off = -inv @ c
                inv_o, off_o = inv.copy(), off.copy()
                inv_o[2] *= -1.0
                off_o[2] *= -1.0
                rows_o.append(np.concatenate([inv_o, off_o[:, None]], axis=1))
                rows_d.append(inv)
                prims.append((x, y))
                used.update((x, y))
                break
        unpaired = np.array([i for i in idx if i not in used], dtype=np.int64)
        if not prims:
            return None, unpaired
        q = len(prims)
        mat_o = np.stack(rows_o).transpose(1, 0, 2).reshape(3 * q, 4)
        mat_d = np.stack(rows_d).transpose(1, 0, 2).reshape(3 * q, 3)
        return (np.ascontiguousarray(mat_o, self.dtype), np.ascontiguousarray(mat_d, self.dtype),
                np.ascontiguousarray(np.array(prims, dtype=np.int64).T)), unpaired

    def _closest_quads(self, o4, d):
        """Nearest parallelogram hit of each ray: ``(t, prim)``, ``t`` inf where none."""
        mat_o, mat_d, prims = self._quads
        q = prims.shape[1]
        with np.errstate(divide="ignore", invalid="ignore"):
            t, u, v = _plane_coordinates(mat_o, mat_d, o4, d, q)
            ok = np.minimum(u, v) >= 0
            ok &= np.maximum(u, v) <= 1
            ok &= t > self.epsilon
            np.copyto(t, np.inf, where=~ok)
            u += v
            second = u > 1
        if q == 1:
            return t[0], np.where(second[0], prims[1, 0], prims[0, 0])
        best = t.min(axis=0)
        j = np.argmin(t, axis=0)
        s = np.take_along_axis(second, j[None], axis=0)[0]
        return best, np.where(s, np.take(prims[1], j), np.take(prims[0], j))

    def _face_prim(self, code, o4, d, t):
        """The triangle of each shell face hit (``code`` > 0; -1 for 0), by the side of the face's diagonal."""
        code = code.astype(np.intp)
        tab = self._face_table                                                   # (4, K + 1)
        with np.errstate(invalid="ignore"):              # misses: inf x 0
            side = np.take(tab[3], code)
            for i in range(3):
                x = d[i] * t
                x += o4[i]
                x *= np.take(tab[i], code)
                side += x
        return np.where(side >= 0, np.take(self._face_prims[0], code), np.take(self._face_prims[1], code))

    def _make_block(self, idx, with_box):
        """Stacked maps of the triangles ``idx``: ``(3k, 4)`` homogeneous for
        origins (offset in the last column) and ``(3k, 3)`` for directions."""
        idx = np.asarray(idx, dtype=np.int64)
        mat_o = self._inv_o[idx].transpose(1, 0, 2).reshape(-1, 3)
        off = self._offset[idx].T.reshape(-1, 1)
        mat_d = self._inv[idx].transpose(1, 0, 2).reshape(-1, 3)
        box = None
        if with_box:
            verts = self.scene.triangles[idx].reshape(-1, 3)
            # a relative pad keeps the float32 slab test conservative at the box's faces
            pad = 1e-6 * max(1.0, float(np.abs(verts).max()))
            box = ((verts.min(axis=0) - pad)[:, None].astype(self.dtype),
                   (verts.max(axis=0) + pad)[:, None].astype(self.dtype))
        return _Block(idx, idx.size, np.ascontiguousarray(np.concatenate([mat_o, off], axis=1), self.dtype),
                      np.ascontiguousarray(mat_d, self.dtype), box)

    def _build_shadow_table(self):
        """``_cand[key, j]``: may triangle ``j`` occlude a shadow ray of this key?

        Keys ``(light * n_prims + prim) * 3 + side + 1`` (side -1, 0, +1 of the
        shading primitive's normal); the last row (all True) serves rays
        without a key (environment samples, unknown origins). Spheres as
        shading primitives get all-True rows.
        """
        scene = self.scene
        n_tri, n_prim, n_light = self.n_triangles, self._n_prims, scene.n_lights
        cand = np.ones((n_light * n_prim * 3 + 1, n_tri), dtype=bool)
        if n_tri and n_light:
            tri = scene.triangles
            nrm, v0 = self.triangle_normal, tri[:, 0]
            scale = max(1.0, float(np.abs(tri).max()))
            margin = max(0.25 * self.epsilon, 4e-6 * scale)
            touch = 1e-9 * scale
            corners = np.stack([scene.light_origin, scene.light_origin + scene.light_edge1,
                                scene.light_origin + scene.light_edge1 + scene.light_edge2,
                                scene.light_origin + scene.light_edge2], axis=1)      # (L, 4, 3)
            for side in (-1, 0, 1):
                shift = side * self.epsilon * nrm                                     # (T_i, 3)
                hull_i = tri + shift[:, None, :]                                      # (T_i, 3, 3)
                # signed distances to every plane j: (T_i, 3, T_j)
                h_i = np.einsum("ivk,jk->ivj", hull_i, nrm) - np.einsum("jk,jk->j", v0, nrm)
                lo_i, hi_i = h_i.min(axis=1), h_i.max(axis=1)                         # (T_i, T_j)
                for light in range(n_light):
                    hull_l = corners[light][None, :, :] + shift[:, None, :]            # (T_i, 4, 3)
                    h_l = np.einsum("ivk,jk->ivj", hull_l, nrm) - np.einsum("jk,jk->j", v0, nrm)
                    lo_l, hi_l = h_l.min(axis=1), h_l.max(axis=1)
                    apart = ((lo_i >= -touch) & (lo_l >= margin)) | ((hi_i <= touch) & (hi_l <= -margin))
                    rows = (light * n_prim + np.arange(n_tri)) * 3 + side + 1
                    cand[rows] = ~apart
        self._cand = cand

    def _build_class_table(self):
        """The BVH's shadow-ray table: ``keep[key]``, the plane classes
        (:attr:`mcvar.bvh.BVH.tri_class`, as bits) that may occlude a shadow ray of this key.

        Keys ``(light * CLASSES + class) * 3 + side + 1``, ``class`` the shading
        triangle's; the last row (every bit) serves rays without a key. The
        rule of :meth:`_build_shadow_table`, for classes instead of triangles
        (its memory ``3 L CLASSES`` words, whatever the scene's size): class
        ``c`` (its triangles within ``w_c`` of one plane, ``w_c`` measured) is
        skipped for a key when every triangle of the shading class, moved off
        its surface by ``side * ray_epsilon``, lies on or beyond ``w_c - touch``
        on one side of the plane and the light, moved by any of those moves,
        beyond ``w_c + margin`` on the same side: the segment then meets the
        slab holding ``c``'s triangles only within ``ray_epsilon`` of its
        start. The last class (the scene's smaller planes) is never skipped
        and keys none. Cost ``O(T CLASSES)`` (0.04 s at 94k triangles).
        """
        scene, bvh = self.scene, self._bvh
        n_light, n_cls = scene.n_lights, _bvh.CLASSES
        keep = np.full(n_light * n_cls * 3 + 1, np.iinfo(np.uint64).max, dtype=np.uint64)
        cls = bvh.tri_class.astype(np.int64)
        # the triangles of the real classes (all but the last), sorted by class
        mine = np.flatnonzero(cls < n_cls - 1)
        if not n_light or not mine.size:
            return keep
        mine = mine[np.argsort(cls[mine], kind="stable")]
        c_of = cls[mine]
        starts = np.flatnonzero(np.r_[True, c_of[1:] != c_of[:-1]])
        real = c_of[starts]                                                  # (C,) class numbers
        row = np.repeat(np.arange(real.size), np.diff(np.r_[starts, mine.size]))
        tri, nrm = scene.triangles[mine], self.triangle_normal[mine]
        scale = max(1.0, float(np.abs(scene.triangles).max()))
        margin = max(0.25 * self.epsilon, 4e-6 * scale)
        touch = 1e-9 * scale
        # every class's plane: the area-weighted normal, the mean offset, the slab's half width
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])           # 2 area x normal
        planes = np.add.reduceat(cross, starts, axis=0)
        planes /= np.maximum(np.linalg.norm(planes, axis=1, keepdims=True), 1e-300)
        h = np.einsum("tvk,tk->tv", tri, planes[row])                           # (t, 3)
        off = np.add.reduceat(h.sum(axis=1), starts) / (3 * np.diff(np.r_[starts, mine.size]))
        width = np.maximum.reduceat(np.abs(h - off[row, None]).max(axis=1), starts)
        corners = np.stack([scene.light_origin, scene.light_origin + scene.light_edge1,
                            scene.light_origin + scene.light_edge1 + scene.light_edge2,
                            scene.light_origin + scene.light_edge2], axis=1)      # (L, 4, 3)
        hc = np.einsum("lvk,ck->lvc", corners, planes) - off                   # (L, 4, C)
        lo_c, hi_c = hc.min(axis=1), hc.max(axis=1)
        # per shading class b, side and plane class c: the extremes over b's triangles of their
        # distances to c's plane once moved off by side * eps (lo, hi) and of the move (s_lo, s_hi)
        n_c = real.size
        lo = np.full((3, n_c, n_c), np.inf)
        hi = np.full((3, n_c, n_c), -np.inf)
        s_lo, s_hi = np.full((3, n_c, n_c), np.inf), np.full((3, n_c, n_c), -np.inf)
        for s0 in range(0, mine.size, 8192):
            sl = slice(s0, s0 + 8192)
            b = row[sl]
            first = np.flatnonzero(np.r_[True, b[1:] != b[:-1]])
            rows = b[first]
            ht = tri[sl] @ planes.T                                             # (t, 3, C)
            lo_t = np.minimum(np.minimum(ht[:, 0], ht[:, 1]), ht[:, 2]) - off
            hi_t = np.maximum(np.maximum(ht[:, 0], ht[:, 1]), ht[:, 2]) - off
            nn = nrm[sl] @ planes.T                                             # (t, C)
            for side in (-1, 0, 1):
                shift = side * self.epsilon * nn
                k = side + 1
                lo[k, rows] = np.minimum(lo[k, rows], np.minimum.reduceat(lo_t + shift, first, axis=0))
                hi[k, rows] = np.maximum(hi[k, rows], np.maximum.reduceat(hi_t + shift, first, axis=0))
                s_lo[k, rows] = np.minimum(s_lo[k, rows], np.minimum.reduceat(shift, first, axis=0))
                s_hi[k, rows] = np.maximum(s_hi[k, rows], np.maximum.reduceat(shift, first, axis=0))
        # class c may be skipped when every moved triangle of b is on or beyond w_c - touch on
        # one side and the light, moved by any of their moves, beyond w_c + margin on that side
        # (the per-triangle rule needs this of each triangle; asking it of the extremes is
        # stricter, so it skips no more than the triangles' rule does)
        apart = ((lo >= width - touch) & (lo_c[:, None, None, :] + s_lo >= width + margin)) \
            | ((hi <= touch - width) & (hi_c[:, None, None, :] + s_hi <= -width - margin))   # (L, 3, C_b, C)
        bits = np.left_shift(np.uint64(1), real.astype(np.uint64))             # (C,)
        skip = np.bitwise_or.reduce(np.where(apart, bits, np.uint64(0)), axis=3)  # (L, 3, C_b)
        for light in range(n_light):
            for side in range(3):
                keep[(light * n_cls + real) * 3 + side] = ~skip[light, side]
        return keep

    def shadow_keys(self, prim, side, light=None) -> np.ndarray:
        """Keys of shadow rays for :meth:`occluded`.

        Parameters
        ----------
        prim : ndarray of int, shape (n,)
            Primitive the shadow ray starts on.
        side : ndarray, shape (n,)
            -1, 0 or +1: the ray origin is ``p + side * ray_epsilon * n_g``.
        light : ndarray of int, shape (n,), optional
            Light the ray aims at (default 0); -1 for none (e.g. the
            environment): every triangle stays a candidate.
        """
        prim = np.asarray(prim, dtype=np.int64)
        side = np.asarray(side).astype(np.int64)
        light = np.zeros_like(prim) if light is None else np.asarray(light, dtype=np.int64)
        if self.accel == "bvh":         # keys of plane classes (_build_class_table); spheres: the last class
            tri = (prim >= 0) & (prim < self.n_triangles)
            cls = np.where(tri, np.take(self._bvh.tri_class, np.clip(prim, 0, self.n_triangles - 1)),
                           _bvh.CLASSES - 1)
            keys = (light * _bvh.CLASSES + cls) * 3 + side + 1
            return np.where(light >= 0, keys, self._shadow_keep.shape[0] - 1)
        keys = (light * self._n_prims + prim) * 3 + side + 1
        return np.where(light >= 0, keys, self._cand.shape[0] - 1)

    def _stack_boxes(self, blocks):
        """``(blocks, lo, hi)`` with the boxes stacked as (B, 3, 1) arrays."""
        if not blocks:
            return blocks, None, None
        return (blocks, np.stack([b.box[0] for b in blocks]), np.stack([b.box[1] for b in blocks]))

    def _shadow_blocks(self, keys):
        if keys is None or self._cand.shape[1] == 0:
            return self._shadow_all
        present = np.zeros(self._cand.shape[0], dtype=bool)
        present[keys] = True
        cand = self._cand[present].any(axis=0)
        tag = cand.tobytes()
        blocks = self._shadow_cache.get(tag)
        if blocks is None:
            blocks = []
            for b in self._shadow_all[0]:
                sub = b.idx[cand[b.idx]]
                if sub.size:
                    blocks.append(self._make_block(sub, True))
            blocks = self._stack_boxes(blocks)
            self._shadow_cache[tag] = blocks
        return blocks

    # ------------------------------------------------------------------
    # Kernels (structure-of-arrays, chunks of rays)

    @staticmethod
    def _boxes_hit(lo, hi, o, d, tmax):
        """Slab test of rays (3, m) against B boxes ``lo, hi`` (B, 3, 1) at once: (B, m) bool."""
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            oi = o * inv
            t0 = lo * inv
            t0 -= oi
            t1 = hi * inv
            t1 -= oi
        tn = np.minimum(t0, t1)
        tf = np.maximum(t0, t1, out=t1)
        # NaN (0 * inf on a slab boundary) must count as 'maybe hit': fmax/fmin ignore NaN.
        near = np.fmax(np.fmax(tn[:, 0], tn[:, 1]), tn[:, 2])
        far = np.fmin(np.fmin(tf[:, 0], tf[:, 1]), tf[:, 2])
        ok = near <= far
        ok &= far > 0
        ok &= near < tmax
        return ok

    def _block_t(self, blk, o4, d):
        """Distance to every triangle of ``blk`` (inf where not hit beyond epsilon), (k, m)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return self._block_t_inner(blk, o4, d)

    def _block_t_inner(self, blk, o4, d):
        t, b1, b2 = _plane_coordinates(blk.mat_o, blk.mat_d, o4, d, blk.k)
        ok = np.minimum(b1, b2) >= 0
        b1 += b2
        ok &= b1 <= 1
        ok &= t > self.epsilon
        return t, ok

    def _closest_block(self, blk, o4, d):
        """Nearest hit of each ray in ``blk``: ``(t, prim)``, ``t`` inf where none.
        Not cut at the rays' ``tmax``: both callers keep a hit only where it is
        nearer than their best so far, which is at most ``tmax``."""
        t, ok = self._block_t(blk, o4, d)
        if blk.k == 1:
            best = np.where(ok[0], t[0], np.inf)
            prim = np.full(best.shape, blk.idx[0])
        elif self.dtype == np.float32 and blk.col8 is not None:
            # argmin over the short axis 0 is slow (NumPy copies to make it
            # the last axis). Instead: the row-wise minimum (a fast reduce),
            # then the triangle as max(j * (t == best)) in uint8, a quarter of
            # the memory traffic of packing (distance bits << b | j) into
            # int64 keys (measured: closest hits of 61k secondary rays 11.9 ->
            # 10.8 ms). Exact distances; among triangles hit at exactly the
            # same distance (a shared edge) the higher j wins, deterministically.
            np.copyto(t, np.inf, where=~ok)
            best = t.min(axis=0)
            eq = t == best
            eq = eq.view(np.uint8)
            eq *= blk.col8
            prim = np.take(blk.idx, eq.max(axis=0))
        else:
            t = np.where(ok, t, np.inf)
            j = np.argmin(t, axis=0)
            best = np.take_along_axis(t, j[None], axis=0)[0]
            prim = np.take(blk.idx, j)
        return best, prim

    def _as_rays(self, o, d, tmax):
        """Float ``(4, n)`` homogeneous origins, ``(3, n)`` directions and tmax in the kernel dtype."""
        n = o.shape[1]
        o4 = np.empty((4, n), dtype=self.dtype)
        o4[:3] = o
        o4[3] = 1.0
        d = np.asarray(d, dtype=self.dtype)
        tm = np.full(n, np.inf, self.dtype) if tmax is None else np.asarray(tmax, dtype=self.dtype)
        return o4, d, tm

    def _closest_triangles(self, o, d, tmax, t_dtype=np.float64):
        n = o.shape[1]
        if self.accel == "bvh":
            tm = np.full(n, np.inf) if tmax is None else tmax
            t, prim = _bvh.closest(self._bvh, o, d, tm, self.epsilon)
            return t.astype(t_dtype, copy=False), prim
        if self._shells and not self._boxed[0]:
            return self._closest_shells(o, d, tmax, t_dtype)
        o4, d, tm = self._as_rays(o, d, tmax)
        t_out = np.full(n, np.inf, dtype=self.dtype)
        p_out = np.full(n, -1, dtype=np.int64)
        open_blocks = [b for b in self._blocks if b.box is None]
        boxed, lo, hi = self._boxed
        in_box = np.empty((len(boxed), n), dtype=bool) if boxed else None
        shells = self._shells
        code = np.zeros(n, dtype=np.uint8) if shells else None
        for s in range(0, n, self.chunk):
            sl = slice(s, min(n, s + self.chunk))
            oc, dc = o4[:, sl], d[:, sl]
            tb, pb = t_out[sl], p_out[sl]            # views: written in place
            tb[:] = tm[sl]
            for blk in open_blocks:
                t, p = self._closest_block(blk, oc, dc)
                better = t < tb
                np.copyto(tb, t, where=better)
                np.copyto(pb, p, where=better)
        # the shells, in slices of SHELL_SLICE rays (a shell costs ~20 NumPy calls)
        for s in range(0, n, _convex.SHELL_SLICE) if shells else ():
            sl = slice(s, min(n, s + _convex.SHELL_SLICE))
            tb, cb = t_out[sl], code[sl]
            t, c = self._shell_hits(o4[:, sl], d[:, sl])
            better = t < tb
            np.copyto(tb, t, where=better)
            np.copyto(cb, c, where=better)
            np.copyto(p_out[sl], -1, where=better)
        # all boxes at once, against the closest hit so far (conservative), in
        # slices of 4 chunks: the slab test's temporaries are small and NumPy's
        # per-call overhead dominated at 2048 rays (measured: 65 536 rays
        # against the Cornell blocks' boxes 1.19 -> 0.59 ms); elementwise, so
        # the result does not depend on the slice length
        for s in range(0, n, self._box_slice) if boxed else ():
            sl = slice(s, min(n, s + self._box_slice))
            in_box[:, sl] = self._boxes_hit(lo, hi, o4[:3, sl], d[:, sl], t_out[sl])
        # Each boxed group on all the rays that cross its box, gathered once
        # and cut into full chunks: per chunk only a few hundred rays cross a
        # box, and NumPy's per-call overhead on such short arrays cost more
        # than the arithmetic (measured: closest hits of 61k secondary Cornell rays 10.6 -> 9.2 ms).
        for blk, mask in zip(boxed, in_box if boxed else ()):
            sel_all = np.flatnonzero(mask)
            for s in range(0, sel_all.size, self.chunk):
                sel = sel_all[s:s + self.chunk]
                tsel = np.take(t_out, sel)
                t, p = self._closest_block(blk, np.take(o4, sel, axis=1), np.take(d, sel, axis=1))
                better = t < tsel
                hit = sel[better]
                t_out[hit] = t[better]
                p_out[hit] = p[better]
                if shells:
                    code[hit] = 0
        if shells:
            face = np.flatnonzero(code)
            if face.size:
                p_out[face] = self._face_prim(np.take(code, face), np.take(o, face, axis=1),
                                              np.take(d, face, axis=1), np.take(t_out, face))
        if tmax is not None:                     # else a row without a hit kept tm = inf
            t_out[p_out < 0] = np.inf
        return t_out.astype(t_dtype, copy=False), p_out

    def _shell_hits(self, o4, d):
        """The nearest face crossing over all shell stacks: ``(t, code)`` (:func:`mcvar.convex.shell_hits`)."""
        t, c = _convex.shell_hits(self._shells[0], o4, d, self.epsilon)
        for stack in self._shells[1:]:
            t2, c2 = _convex.shell_hits(stack, o4, d, self.epsilon)
            better = t2 < t
            np.copyto(t, t2, where=better)
            np.copyto(c, c2, where=better)
        return t, c

    def _closest_shells(self, o, d, tmax, t_dtype):
        """:meth:`_closest_triangles` for scenes of convex shells and unboxed
        triangle groups (the Cornell box: its room and blocks, and the light),
        everything per slice of ``SHELL_SLICE`` rays (the temporaries stay in cache)."""
        n = o.shape[1]
        o4, d, tm = self._as_rays(o, d, tmax)
        t_out = np.empty(n, dtype=self.dtype)
        p_out = np.empty(n, dtype=np.int64)
        step = _convex.SHELL_SLICE
        for s in range(0, n, step):
            sl = slice(s, min(n, s + step))
            oc, dc = o4[:, sl], d[:, sl]
            t, c = self._shell_hits(oc, dc)
            if tmax is not None:
                beyond = t >= tm[sl]
                np.copyto(t, tm[sl], where=beyond)
                np.copyto(c, 0, where=beyond)
            prim = self._face_prim(c, oc, dc, t)
            if self._quads is not None:
                tq, pq = self._closest_quads(oc, dc)
                better = tq < t
                np.copyto(t, tq, where=better)
                np.copyto(prim, pq, where=better)
            for blk in self._closest_blocks:
                tb, pb = self._closest_block(blk, oc, dc)
                better = tb < t
                np.copyto(t, tb, where=better)
                np.copyto(prim, pb, where=better)
            t_out[sl], p_out[sl] = t, prim
        if tmax is not None:
            t_out[p_out < 0] = np.inf
        return t_out.astype(t_dtype, copy=False), p_out

    def _any_triangles(self, o, d, tmax, keys):
        n = o.shape[1]
        if self.accel == "bvh":
            keep = None if keys is None else np.take(self._shadow_keep, keys)
            return _bvh.occluded(self._bvh, o, d, tmax, self.epsilon, keep=keep)
        occ = np.zeros(n, dtype=bool)
        blocks, lo, hi = self._shadow_blocks(keys)
        if not blocks:
            return occ
        o4, d, tm = self._as_rays(o, d, tmax)
        in_box = np.empty((len(blocks), n), dtype=bool)
        for s in range(0, n, self._box_slice):
            sl = slice(s, min(n, s + self._box_slice))
            in_box[:, sl] = self._boxes_hit(lo, hi, o4[:3, sl], d[:, sl], tm[sl])
        # each group on all the rays that cross its box and are not yet
        # occluded (any-hit), gathered once and cut into full chunks
        for i, blk in enumerate(blocks):
            mask = in_box[i]
            if i:
                mask &= ~occ
            sel_all = np.flatnonzero(mask)
            for s in range(0, sel_all.size, self.chunk):
                sel = sel_all[s:s + self.chunk]
                t, ok = self._block_t(blk, np.take(o4, sel, axis=1), np.take(d, sel, axis=1))
                ok &= t < np.take(tm, sel)
                occ[sel[ok.any(axis=0)]] = True
        return occ

    def _spheres(self, o, d, tmax):
        """Closest sphere hits, SoA rays (3, n): solved in float64.

        One sphere at a time, written out (no ``(S, 3, n)`` temporaries). The
        discriminant is computed in the rays' own precision on every ray; rays
        whose line clearly misses the sphere (a float32 discriminant below
        ``-1e-5 (|o - c|^2 + r^2)``, a margin of ~170 float32 roundings of its
        terms) are dropped, and the others are solved in float64 from the same
        (exactly converted) numbers, so the hits are those of a float64 test
        of every ray. A nearer sphere replaces a hit only where it is strictly
        nearer (ties: the lower index, as ``argmin``).
        """
        n = o.shape[1]
        best = np.full(n, np.inf)
        prim = np.full(n, -1, dtype=np.int64)
        eps = self.epsilon
        tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (n,))
        single = o.dtype == np.float32 and d.dtype == np.float32
        for j in range(self.n_spheres):
            c64 = self._sph_c[j]
            r2 = float(self._sph_r2[j])
            if single:
                # o - c rounded once (computed in float64): its float32 error is relative to |o - c|
                ox, oy, oz = (np.subtract(o[i], c64[i], dtype=np.float64).astype(o.dtype) for i in range(3))
            else:
                ox, oy, oz = o[0] - c64[0], o[1] - c64[1], o[2] - c64[2]
            b = ox * d[0]
            b += oy * d[1]
            b += oz * d[2]
            c = ox * ox
            c += oy * oy
            c += oz * oz
            disc = b * b
            if single:
                # disc + 1e-5 (|oc|^2 + r^2) >= |oc|^2 - r^2  (conservative in float32)
                disc -= c * (1.0 - 1e-5)
                sel = np.flatnonzero(disc >= -(1.0 + 1e-5) * r2)
                if sel.size == 0:
                    continue
                os_ = np.take(o, sel, axis=1).astype(np.float64)     # exact
                ds = np.take(d, sel, axis=1).astype(np.float64)
                oc = os_ - c64[:, None]
                bs = oc[0] * ds[0]
                bs += oc[1] * ds[1]
                bs += oc[2] * ds[2]
                cs = oc[0] * oc[0]
                cs += oc[1] * oc[1]
                cs += oc[2] * oc[2]
                cs -= r2
                ds2 = bs * bs
                ds2 -= cs
                ok = ds2 >= 0
                sel, bs, ds2 = sel[ok], bs[ok], ds2[ok]
            else:
                c -= r2
                disc -= c
                sel = np.flatnonzero(disc >= 0)
                bs, ds2 = np.take(b, sel), np.take(disc, sel)
            if sel.size == 0:
                continue
            root = np.sqrt(ds2)
            t = -bs - root
            t = np.where(t > eps, t, -bs + root)
            ok = t > eps
            ok &= t < np.minimum(np.take(tmax, sel), np.take(best, sel))
            hit = sel[ok]
            best[hit] = t[ok]
            prim[hit] = self.n_triangles + j
        return best, prim

    # ------------------------------------------------------------------
    # Internal entry points for the wavefront loop: SoA (3, n) float64, no checks

    def closest_soa(self, o, d, tmax=None, *, t_dtype=np.float64):
        """Closest hits of SoA rays ``o, d`` of shape (3, n): ``(t, prim)``.

        Internal fast path of :meth:`intersect` for already-checked arrays
        (the integrators' wavefront loop); ``t`` is float64 (``t_dtype``:
        the triangle test's float32 distances without the round trip through
        float64, for a scene without spheres), inf on a miss.
        """
        n = o.shape[1]
        if self.n_triangles:
            t, prim = self._closest_triangles(o, d, tmax, t_dtype if not self.n_spheres else np.float64)
        else:
            t, prim = np.full(n, np.inf), np.full(n, -1, dtype=np.int64)
        if self.n_spheres:
            tm = t if tmax is None else np.minimum(np.asarray(tmax, dtype=np.float64), t)
            ts, ps = self._spheres(o, d, tm)
            closer = ts < t
            t = np.where(closer, ts, t)
            prim = np.where(closer, ps, prim)
        return t, prim

    def occluded_soa(self, o, d, tmax, keys=None) -> np.ndarray:
        """Any-hit shadow test of SoA rays (3, n); ``keys`` from :meth:`shadow_keys`."""
        n = o.shape[1]
        tm = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (n,))
        occ = self._any_triangles(o, d, tm, keys) if self.n_triangles else np.zeros(n, dtype=bool)
        if self.n_spheres:
            rest = np.flatnonzero(~occ)
            if rest.size:
                ts, _ = self._spheres(o[:, rest], d[:, rest], tm[rest])
                occ[rest] = np.isfinite(ts)
        return occ

    # ------------------------------------------------------------------
    # Public API: rays (n, 3)

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
        t, prim = self.closest_soa(o.T, d.T, tm)
        return Hit(t=t, prim=prim)

    def occluded(self, origins, directions, tmax, keys=None) -> np.ndarray:
        """True where anything lies between ``scene.ray_epsilon`` and ``tmax`` along the ray.

        Shadow rays: pass ``tmax = distance - scene.ray_epsilon`` so that the
        light's own surface does not occlude it. An any-hit query: the same
        answer as ``intersect(...).prim >= 0``, found with less work.
        ``keys`` (:meth:`shadow_keys`) lets it skip triangles that cannot lie
        between the rays' origins and their light.
        """
        o, d, tm = self._check(origins, directions, tmax)
        return self.occluded_soa(o.T, d.T, tm, keys)

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
