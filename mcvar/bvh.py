"""A bounding volume hierarchy over triangles, built and traversed in NumPy (layer 4).

Build: binned surface-area heuristic (Wald 2007, 'On fast Construction of
SAH-based Bounding Volume Hierarchies'; pbrt-v4's ``BVHAggregate``), one
*level* of the tree at a time: every node of a level is split in the same
handful of array operations (centroid bounds by ``reduceat`` over each node's
contiguous run of triangles, bin counts and bin boxes by ``bincount`` /
``ufunc.at``, prefix sweeps for the SAH cost of every candidate plane, a
stable sort to partition), so the build costs O(T) NumPy work per level and
O(T log T) in all, with no Python loop over nodes.

Traversal: a *wavefront of (ray, node) pairs*. All pairs of a chunk of rays
are tested against their node's box at once; pairs that reach a leaf expand
into (ray, triangle) pairs that are intersected at once and reduce into each
ray's closest hit (``np.minimum.at``); pairs at inner nodes expand into their
two children. A level of the tree is one iteration, so a chunk costs about
``depth`` rounds of array operations whose length is the number of live
pairs; a closer hit found at one level prunes the boxes of the next. Any-hit
queries (shadow rays) drop a ray's pairs as soon as it is occluded.

Memory: nodes ``O(T)``; pairs bounded by the chunk of rays.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._validation import check_count

__all__ = ["BVH", "build_bvh", "triangle_maps", "closest", "occluded"]

#: Candidate split planes per axis and node (Wald 2007 uses 16; 12 measured as good).
SAH_BINS = 12
#: Largest number of triangles kept in one leaf.
LEAF_SIZE = 4
#: Rays traversed together (pairs per round are a small multiple of it).
CHUNK = 16384


@dataclass(frozen=True, eq=False)
class BVH:
    """A binary BVH in flat arrays (node 0 is the root).

    Attributes
    ----------
    lo, hi : ndarray, shape (N, 3), float32
        Node bounds (padded outwards so the float32 slab test is conservative).
    child : ndarray of int64, shape (N,)
        Left child's index (the right child is ``child + 1``); -1 at a leaf.
    start, count : ndarray of int64, shape (N,)
        A node's triangles are ``order[start:start + count]``.
    order : ndarray of int64, shape (T,)
        Triangle indices, grouped by node.
    depth : int
        Levels below the root.
    """

    lo: np.ndarray
    hi: np.ndarray
    child: np.ndarray
    start: np.ndarray
    count: np.ndarray
    order: np.ndarray
    depth: int

    @property
    def boxes(self) -> np.ndarray:
        """Node boxes ``(N, 2, 3)``: ``[lo, hi]`` per node."""
        return self._boxes

    @property
    def sibling_boxes(self) -> np.ndarray:
        """Boxes of the children pairs as structure of arrays ``(12, N // 2)``:
        column ``p`` holds nodes ``2p + 1`` and ``2p + 2`` as (child, lo/hi, axis)."""
        return self._siblings

    def __post_init__(self):
        boxes = np.ascontiguousarray(np.stack([self.lo, self.hi], axis=1))
        object.__setattr__(self, "_boxes", boxes)
        # gathers along the last axis of a (12, P) array are ~3x faster than
        # gathering (P, 12) rows and transposing them (measured)
        object.__setattr__(self, "_siblings", np.ascontiguousarray(boxes[1:].reshape(-1, 12).T))

    @property
    def n_nodes(self) -> int:
        return self.child.shape[0]

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.lo, self.hi, self.child, self.start, self.count, self.order))


def _segment_reduce(op, values, start, count, fill):
    """``op.reduce`` of ``values[start_i : start_i + count_i]`` for disjoint, sorted segments."""
    out = np.full((start.size,) + values.shape[1:], fill, dtype=values.dtype)
    keep = count > 0
    if not keep.any():
        return out
    s, c = start[keep], count[keep]
    padded = np.concatenate([values, values[:1]])     # an end index may equal len(values)
    idx = np.empty(2 * s.size, dtype=np.int64)
    idx[0::2], idx[1::2] = s, s + c
    out[keep] = op.reduceat(padded, idx, axis=0)[0::2]
    return out


def _ranges(start, count):
    """Concatenated ``arange(start_i, start_i + count_i)`` and the segment of each element."""
    seg = np.repeat(np.arange(start.size), count)
    offsets = np.cumsum(count) - count
    return start[seg] + (np.arange(seg.size) - offsets[seg]), seg


def _half_area(lo, hi):
    e = np.maximum(hi - lo, 0.0)
    return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]


def build_bvh(triangles, *, leaf_size: int = LEAF_SIZE, bins: int = SAH_BINS) -> BVH:
    """Build a binned-SAH BVH over ``triangles`` (T, 3, 3), level by level.

    Parameters
    ----------
    triangles : ndarray, shape (T, 3, 3)
    leaf_size : int
        Nodes with at most this many triangles become leaves.
    bins : int
        SAH candidate planes per axis are the ``bins - 1`` bin boundaries
        between the node's centroid bounds.

    Returns
    -------
    BVH
    """
    tri = np.asarray(triangles, dtype=np.float64)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3) or tri.shape[0] == 0:
        raise ValueError(f"triangles must have shape (T, 3, 3) with T >= 1; got {tri.shape}")
    leaf_size = check_count(leaf_size, "leaf_size")
    bins = check_count(bins, "bins")
    if bins < 2:
        raise ValueError(f"bins must be >= 2; got {bins}")
    t_lo, t_hi = tri.min(axis=1), tri.max(axis=1)
    cent = 0.5 * (t_lo + t_hi)
    n_tri = tri.shape[0]
    order = np.arange(n_tri, dtype=np.int64)
    # node tables grow level by level
    starts, counts, los, his = [np.zeros(1, np.int64)], [np.array([n_tri], np.int64)], [], []
    node_start, node_count = np.zeros(1, np.int64), np.array([n_tri], np.int64)
    n_nodes, depth = 1, 0
    child = [np.full(1, -1, np.int64)]
    while True:
        s, c = node_start, node_count
        los.append(_segment_reduce(np.minimum, t_lo[order], s, c, np.inf))
        his.append(_segment_reduce(np.maximum, t_hi[order], s, c, -np.inf))
        split = c > leaf_size
        if not split.any() or depth >= 60:
            break
        a_idx = np.flatnonzero(split)            # active nodes of this level (local indices)
        a_s, a_c = s[a_idx], c[a_idx]
        pos, seg = _ranges(a_s, a_c)
        ids = order[pos]
        cen = cent[ids]
        # centroid bounds per active node: reduce over the gathered, contiguous runs
        off = np.cumsum(a_c) - a_c
        cmin = _segment_reduce(np.minimum, cen, off, a_c, np.inf)
        cmax = _segment_reduce(np.maximum, cen, off, a_c, -np.inf)
        # no more planes than a level's typical node has triangles (deep levels
        # hold many small nodes; 12 bins for 6 triangles only cost memory traffic)
        nb = int(min(bins, max(4, np.median(a_c))))
        ext = cmax - cmin
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(ext > 0, nb / ext, 0.0)
        b = np.minimum(((cen - cmin[seg]) * scale[seg]).astype(np.int64), nb - 1)   # (m, 3)
        k = a_idx.size
        cost = np.full((k, 3, nb - 1), np.inf)
        tlo_i, thi_i = t_lo[ids], t_hi[ids]
        for ax in range(3):
            key = seg * nb + b[:, ax]
            cnt = np.bincount(key, minlength=k * nb)
            # bin boxes: sort by bin (runs are already sorted by node, so the
            # stable sort is near linear), then one reduceat per bound
            perm = np.argsort(key, kind="stable")
            nz = np.flatnonzero(cnt)
            first = (np.cumsum(cnt) - cnt)[nz]
            blo = np.full((k * nb, 3), np.inf)
            bhi = np.full((k * nb, 3), -np.inf)
            blo[nz] = np.minimum.reduceat(tlo_i[perm], first, axis=0)
            bhi[nz] = np.maximum.reduceat(thi_i[perm], first, axis=0)
            blo, bhi, cnt = blo.reshape(k, nb, 3), bhi.reshape(k, nb, 3), cnt.reshape(k, nb)
            n_l = np.cumsum(cnt, axis=1)[:, :-1]
            a_l = _half_area(np.minimum.accumulate(blo, axis=1), np.maximum.accumulate(bhi, axis=1))[:, :-1]
            r_lo = np.minimum.accumulate(blo[:, ::-1], axis=1)[:, ::-1]
            r_hi = np.maximum.accumulate(bhi[:, ::-1], axis=1)[:, ::-1]
            a_r = _half_area(r_lo, r_hi)[:, 1:]
            n_r = a_c[:, None] - n_l
            with np.errstate(invalid="ignore"):
                cst = a_l * n_l + a_r * n_r
            cost[:, ax] = np.where((n_l > 0) & (n_r > 0), cst, np.inf)
        flat = cost.reshape(k, -1)
        best = np.argmin(flat, axis=1)
        ok = np.isfinite(flat[np.arange(k), best])
        axis, plane = best // (nb - 1), best % (nb - 1)
        right = b[np.arange(seg.size), axis[seg]] > plane[seg]
        # no usable plane (all centroids in one bin): split the run in half
        rank = np.arange(seg.size) - off[seg]
        right = np.where(ok[seg], right, rank >= a_c[seg] // 2)
        perm = np.argsort(seg * 2 + right, kind="stable")
        order[pos] = ids[perm]
        n_left = np.bincount(seg, weights=~right, minlength=k).astype(np.int64)
        # children of this level's active nodes
        first = n_nodes
        ch = np.full(s.size, -1, np.int64)
        ch[a_idx] = first + 2 * np.arange(k)
        child[-1] = ch
        new_s = np.empty(2 * k, np.int64)
        new_c = np.empty(2 * k, np.int64)
        new_s[0::2], new_c[0::2] = a_s, n_left
        new_s[1::2], new_c[1::2] = a_s + n_left, a_c - n_left
        starts.append(new_s)
        counts.append(new_c)
        child.append(np.full(2 * k, -1, np.int64))
        node_start, node_count = new_s, new_c
        n_nodes += 2 * k
        depth += 1
    lo = np.concatenate(los)
    hi = np.concatenate(his)
    scale = max(1.0, float(np.abs(tri).max()))
    pad = 4e-6 * scale + 1e-6 * (hi - lo)
    return BVH(lo=np.ascontiguousarray(lo - pad, np.float32), hi=np.ascontiguousarray(hi + pad, np.float32),
               child=np.concatenate(child), start=np.concatenate(starts), count=np.concatenate(counts),
               order=order, depth=depth)


def triangle_maps(triangles, dtype=np.float32) -> np.ndarray:
    """Per-triangle affine maps ``(21, T)`` of the ray test (Baldwin and Weber 2016).

    Rows 0-11: the 3x4 map of homogeneous origins, rows ``(b1, b2, -h)``;
    rows 12-20: the 3x3 map of directions, rows ``(b1, b2, h)``. A ray
    ``o + t d`` meets the plane at ``t = (-h_o) / h_d`` and the triangle
    where ``b1, b2 >= 0`` and ``b1 + b2 <= 1`` at that ``t``.
    """
    tri = np.asarray(triangles, dtype=np.float64)
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    inv = np.linalg.inv(np.stack([e1, e2, np.cross(e1, e2)], axis=2))      # (T, 3, 3)
    off = -np.einsum("tij,tj->ti", inv, v0)
    mo = np.concatenate([inv, off[:, :, None]], axis=2)                      # (T, 3, 4)
    mo[:, 2] *= -1.0
    return np.ascontiguousarray(np.concatenate([mo.reshape(-1, 12), inv.reshape(-1, 9)], axis=1).T, dtype)


def _pair_t(maps, tri, o, d, eps):
    """Distances of rays (3, m) to triangles ``tri`` (m,), inf where missed; ``maps`` (21, T)."""
    m = np.take(maps, tri, axis=1)                                          # (21, m)
    ox, oy, oz = o
    dx, dy, dz = d
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (m[8] * ox + m[9] * oy + m[10] * oz + m[11]) / (m[18] * dx + m[19] * dy + m[20] * dz)
        b1 = m[0] * ox + m[1] * oy + m[2] * oz + m[3] + t * (m[12] * dx + m[13] * dy + m[14] * dz)
        b2 = m[4] * ox + m[5] * oy + m[6] * oz + m[7] + t * (m[15] * dx + m[16] * dy + m[17] * dz)
    ok = (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (t > eps)
    return np.where(ok, t, np.inf)


def _slab(box, o, inv_d, tmax):
    """Slab test of rays ``o, inv_d`` (3, m) against boxes (k, 2, 3, m): hit mask (k, m).

    Rays and boxes are laid out with the ray index last, so every NumPy
    loop runs over ``m`` contiguous numbers.
    """
    with np.errstate(invalid="ignore"):
        t0 = box[:, 0] - o
        t0 *= inv_d
        t1 = box[:, 1] - o
        t1 *= inv_d
    tn = np.fmin(t0, t1)
    tf = np.fmax(t0, t1, out=t1)
    # fmax/fmin ignore NaN (0 * inf on a slab's plane): such a slab never rejects
    near = np.fmax(np.fmax(tn[:, 0], tn[:, 1]), tn[:, 2])
    far = np.fmin(np.fmin(tf[:, 0], tf[:, 1]), tf[:, 2])
    ok = near <= far
    ok &= far > 0
    ok &= near < tmax
    return ok


def _leaf_pairs(bvh, ray, node):
    """Expand (ray, leaf) pairs into (ray, triangle) pairs."""
    cnt = np.take(bvh.count, node)
    pos, seg = _ranges(np.take(bvh.start, node), cnt)
    return np.take(ray, seg), np.take(bvh.order, pos)


def _traverse(bvh, maps, o, d, tmax, eps, any_hit):
    """One chunk: closest ``(t, prim)`` or, with ``any_hit``, the occluded mask.

    Pairs are (ray, inner node): each round tests *both* children's boxes of
    every pair at once (the ray's data is gathered once for the two), sends
    the rays that reach a leaf to its triangles and the rest to the next round.
    """
    n = o.shape[1]
    with np.errstate(divide="ignore"):
        inv_d = 1.0 / d
    rays = np.concatenate([o, inv_d])                                       # (6, n): origin, 1/direction
    best = np.array(tmax, dtype=d.dtype, copy=True)
    prim = np.full(n, -1, np.int64)
    occ = np.zeros(n, bool)
    root = _slab(bvh.boxes[0][None, :, :, None], o, inv_d, best)[0]
    ray = np.flatnonzero(root)
    node = np.zeros(ray.size, np.int64)
    while ray.size:
        ch = np.take(bvh.child, node)
        leaf = ch < 0
        if leaf.any():
            lr, lt = _leaf_pairs(bvh, ray[leaf], node[leaf])
            t = _pair_t(maps, lt, np.take(o, lr, axis=1), np.take(d, lr, axis=1), eps)
            hit = t < np.take(best, lr)
            if any_hit:
                occ[lr[hit]] = True
            else:
                lr, lt, t = lr[hit], lt[hit], t[hit]
                np.minimum.at(best, lr, t)
                win = np.flatnonzero(t == np.take(best, lr))
                prim[lr[win]] = lt[win]
            inner = ~leaf
            ray, ch = ray[inner], ch[inner]
        if any_hit:
            live = ~np.take(occ, ray)
            ray, ch = ray[live], ch[live]
        m = ray.size
        rd = np.take(rays, ray, axis=1)                                         # (6, m)
        box = np.take(bvh.sibling_boxes, (ch - 1) >> 1, axis=1).reshape(2, 2, 3, m)   # child, lo/hi, axis
        both = _slab(box, rd[:3], rd[3:], np.take(best, ray))                  # (2, m)
        pick = np.flatnonzero(both.ravel())
        ray = np.take(ray, pick % m)
        node = np.take(ch, pick % m) + (pick >= m)
    if any_hit:
        return occ
    best[prim < 0] = np.inf
    return best.astype(np.float64), prim


def closest(bvh: BVH, maps, o, d, tmax, eps: float, chunk: int = CHUNK):
    """Closest triangle hits of SoA rays ``o, d`` (3, n) with ``tmax`` (n,): ``(t, prim)``."""
    o = np.asarray(o, maps.dtype)
    d = np.asarray(d, maps.dtype)
    n = o.shape[1]
    t_out, p_out = np.full(n, np.inf), np.full(n, -1, np.int64)
    tmax = np.broadcast_to(np.asarray(tmax, maps.dtype), (n,))
    for s in range(0, n, chunk):
        sl = slice(s, min(n, s + chunk))
        t_out[sl], p_out[sl] = _traverse(bvh, maps, o[:, sl], d[:, sl], tmax[sl], eps, False)
    return t_out, p_out


def occluded(bvh: BVH, maps, o, d, tmax, eps: float, chunk: int = CHUNK) -> np.ndarray:
    """Any-hit test of SoA rays (3, n): True where a triangle lies in ``(eps, tmax)``."""
    o = np.asarray(o, maps.dtype)
    d = np.asarray(d, maps.dtype)
    n = o.shape[1]
    occ = np.zeros(n, bool)
    tmax = np.broadcast_to(np.asarray(tmax, maps.dtype), (n,))
    for s in range(0, n, chunk):
        sl = slice(s, min(n, s + chunk))
        occ[sl] = _traverse(bvh, maps, o[:, sl], d[:, sl], tmax[sl], eps, True)
    return occ
