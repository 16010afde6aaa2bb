"""A bounding volume hierarchy over triangles, built and traversed in NumPy (layer 4).

Build: binned surface-area heuristic (Wald 2007, 'On fast Construction of
SAH-based Bounding Volume Hierarchies'; pbrt-v4's ``BVHAggregate``), one
*level* of the tree at a time: every node of a level is split in the same
handful of array operations (centroid bounds by ``reduceat`` over each node's
contiguous run of triangles, bin counts and bin boxes by ``bincount`` /
``ufunc.at``, prefix sweeps for the SAH cost of every candidate plane, a
stable sort to partition), so the build costs O(T) NumPy work per level and
O(T log T) in all, with no Python loop over nodes. While a node holds
triangles of several supporting planes it bins the planes' centroids (all
triangles of a plane on one side), so the tree's top is a tree over the
scene's planes and every node below it is flat (:func:`_planes`; the greedy
SAH alone cut rooms into octants whose boxes fill the room). The binary tree is then
collapsed into a ``WIDTH``-wide one (every wide node holds the boxes of the
binary nodes ``log2(WIDTH)`` levels below it; the MBVH / BVH8 of Dammertz et
al. 2008, 'Shallow Bounding Volume Hierarchies for Fast SIMD Ray Tracing of
Incoherent Rays', and Ylitie et al. 2017), and the triangles of every leaf
are stored next to each other, padded to ``WIDTH`` slots.

Traversal: a *wavefront of (ray, wide node) pairs*. One round tests every
pair against all ``WIDTH`` boxes of its node at once; the boxes that are hit
before the ray's closest hit so far become the next round's pairs, and the
leaves among them are intersected in the same round (all ``WIDTH`` triangle
slots of every (ray, leaf) pair at once), so a hit found at one level prunes
the boxes of the next. Any-hit queries (shadow rays) drop a ray's pairs as
soon as it is occluded, and, given per-ray masks of the plane classes that
may occlude it (:attr:`BVH.tri_class`, :meth:`mcvar.tracer.Tracer.shadow_keys`),
every slot none of whose classes is in the ray's mask (:attr:`BVH.wmask`).

Layout (measured on this project's 2-core machines, NumPy 2): gathers of
*runs* of ``WIDTH`` contiguous numbers (``np.take(a, idx, axis=1)`` on a
``(rows, N, WIDTH)`` array) cost about 0.16 ns a number against 0.9 ns for
gathers of single numbers, and elementwise operations on equal-shaped
contiguous ``(P, WIDTH)`` blocks about 0.13 ns; broadcasting a ``(P, 1)``
column costs five times that. So node boxes, leaf triangles and the rays
themselves (repeated ``WIDTH`` times once per chunk) are all stored as
``(rows, N, WIDTH)`` blocks, and every operation of a round is between
blocks of one shape. Empty slots hold NaN boxes and NaN triangles, which
fail every comparison.

Widths 2, 4, 8 and 16 are supported; 4 (leaves of 4 triangles) was measured
fastest on the subdivided Cornell box from 122 to 94,000 triangles. Float32
distances agree with float64 to ``2e-4`` relative plus the rounding of the
ray origin (about one ulp of the scene's size over ``|cos theta|``).

Memory: nodes and leaves ``O(T)`` (about 130 bytes a triangle); pairs bounded
by the chunk of rays.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._validation import check_count

__all__ = ["BVH", "build_bvh", "triangle_maps", "closest", "occluded", "WIDTH", "CLASSES"]

#: Candidate split planes per axis and node (Wald 2007 uses 16; 12 measured as good).
SAH_BINS = 12
#: Largest number of triangles kept in one leaf (at most :data:`WIDTH`).
LEAF_SIZE = 4
#: Children per wide node, and triangle slots per leaf (a power of two).
WIDTH = 4
#: Rays traversed together (pairs per round are a small multiple of it).
CHUNK = 8192
#: Direction components smaller than this are replaced by it (sign kept) in
#: the slab test, so ``1 / d`` is finite and ``(lo - o) / d`` never NaN; the
#: change moves the ray by less than ``|t| * TINY``, far inside the boxes' padding.
TINY = 1e-20
#: Plane classes of the shadow-ray masks (bits of a uint64): the ``CLASSES - 1``
#: planes holding the most triangles get a class each, every other triangle the
#: last class, which no shadow ray skips (:attr:`BVH.tri_class`).
CLASSES = 64


@dataclass(frozen=True, eq=False)
class BVH:
    """A BVH in flat arrays: the binary SAH tree and the wide tree traversed.

    Attributes
    ----------
    lo, hi : ndarray, shape (N, 3), float32
        Binary node bounds (padded outwards so the float32 slab test is conservative).
    child : ndarray of int64, shape (N,)
        Left child's index (the right child is ``child + 1``); -1 at a leaf.
    start, count : ndarray of int64, shape (N,)
        A node's triangles are ``order[start:start + count]``.
    order : ndarray of int64, shape (T,)
        Triangle indices, grouped by node.
    depth : int
        Levels of the binary tree below the root.
    width : int
        Slots per wide node and per leaf.
    wbox : ndarray, shape (6, W, width)
        Wide node ``w``'s slot boxes: rows ``lo_x, lo_y, lo_z, hi_x, hi_y, hi_z``; NaN in empty slots.
    wchild : ndarray of int64, shape (W, width)
        A slot's wide node (>= 0) or leaf ``~code`` (< 0); wide node 0 is the root.
    leaf_maps : ndarray, shape (12, L, width)
        The ray-test maps (:func:`triangle_maps`) of every leaf's triangles; NaN in empty slots.
    leaf_prim : ndarray of int64, shape (L, width)
        The triangle of every leaf slot (-1 in empty slots).
    tri_class : ndarray of uint8, shape (T,)
        Every triangle's plane class (0 ... :data:`CLASSES` - 1): one of the
        largest planes, or the last class for the rest.
    wmask : ndarray of uint64, shape (W, width)
        The plane classes under every slot of a wide node, as bits (0 in empty
        slots): an any-hit query given per-ray class masks (``occluded(...,
        keep=)``) skips the slots none of whose classes its ray may hit.
    """

    lo: np.ndarray
    hi: np.ndarray
    child: np.ndarray
    start: np.ndarray
    count: np.ndarray
    order: np.ndarray
    depth: int
    width: int
    wbox: np.ndarray
    wchild: np.ndarray
    leaf_maps: np.ndarray
    leaf_prim: np.ndarray
    tri_class: np.ndarray
    wmask: np.ndarray

    @property
    def n_nodes(self) -> int:
        """Nodes of the binary tree."""
        return self.child.shape[0]

    @property
    def dtype(self) -> np.dtype:
        """Precision of the traversal (of the boxes and triangle maps)."""
        return self.leaf_maps.dtype

    @property
    def nbytes(self) -> int:
        """Bytes of all arrays (binary tree, wide tree and leaves)."""
        return sum(a.nbytes for a in (self.lo, self.hi, self.child, self.start, self.count, self.order,
                                      self.wbox, self.wchild, self.leaf_maps, self.leaf_prim,
                                      self.tri_class, self.wmask))


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


def build_bvh(triangles, *, leaf_size: int = LEAF_SIZE, bins: int = SAH_BINS, width: int = WIDTH,
              dtype="float32") -> BVH:
    """Build a binned-SAH BVH over ``triangles`` (T, 3, 3), level by level, and its wide form.

    Parameters
    ----------
    triangles : ndarray, shape (T, 3, 3)
        Zero-area triangles are kept in the tree but never hit.
    leaf_size : int
        Nodes with at most this many triangles become leaves (``<= width``).
    bins : int
        SAH candidate planes per axis are the ``bins - 1`` bin boundaries
        between the node's centroid bounds.
    width : int
        Children per wide node and triangle slots per leaf: 2, 4, 8 or 16.
    dtype : {'float32', 'float64'}
        Precision of the traversal.

    Returns
    -------
    BVH
    """
    tri = np.asarray(triangles, dtype=np.float64)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3) or tri.shape[0] == 0:
        raise ValueError(f"triangles must have shape (T, 3, 3) with T >= 1; got {tri.shape}")
    if not np.all(np.isfinite(tri)):
        raise ValueError("triangles must be finite (no NaN or Inf coordinates)")
    leaf_size = check_count(leaf_size, "leaf_size")
    bins = check_count(bins, "bins")
    if bins < 2:
        raise ValueError(f"bins must be >= 2; got {bins}")
    width = check_count(width, "width")
    if width not in (2, 4, 8, 16):
        raise ValueError(f"width must be 2, 4, 8 or 16; got {width}")
    if leaf_size > width:
        raise ValueError(f"leaf_size must be <= width ({width}); got {leaf_size}")
    if str(np.dtype(dtype)) not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64'; got {dtype!r}")
    t_lo, t_hi = tri.min(axis=1), tri.max(axis=1)
    cent = 0.5 * (t_lo + t_hi)
    tri_plane, plane_cent = _planes(tri, t_lo, t_hi)
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
        # nodes holding more than one plane bin the planes' centroids, so that
        # a plane's triangles stay together until a node holds one plane
        pid = tri_plane[ids]
        off = np.cumsum(a_c) - a_c
        mixed = (_segment_reduce(np.minimum, pid, off, a_c, 0) != _segment_reduce(np.maximum, pid, off, a_c, 0))
        if mixed.any():
            cen = np.where(mixed[seg][:, None], plane_cent[pid], cen)
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
    lo = np.ascontiguousarray(lo - pad, np.float32)
    hi = np.ascontiguousarray(hi + pad, np.float32)
    child = np.concatenate(child)
    start, count = np.concatenate(starts), np.concatenate(counts)
    tri_class = _plane_classes(tri_plane)
    bits = np.left_shift(np.uint64(1), tri_class.astype(np.uint64))
    node_bits = _segment_reduce(np.bitwise_or, bits[order], start, count, 0)
    wbox, wchild, wmask = _collapse(lo, hi, child, width, np.dtype(dtype), node_bits)
    leaf_maps, leaf_prim = _leaves(child, start, count, order, width, triangle_maps(tri, dtype))
    return BVH(lo=lo, hi=hi, child=child, start=start, count=count, order=order, depth=depth, width=width,
               wbox=wbox, wchild=wchild, leaf_maps=leaf_maps, leaf_prim=leaf_prim, tri_class=tri_class,
               wmask=wmask)


def _plane_classes(label):
    """:attr:`BVH.tri_class` from the plane labels of :func:`_planes`: the
    ``CLASSES - 1`` planes with the most triangles (ties: the lower label)
    numbered by size, every other triangle in the last class."""
    sizes = np.bincount(label)
    top = np.lexsort((np.arange(sizes.size), -sizes))[:CLASSES - 1]
    of_plane = np.full(sizes.size, CLASSES - 1, np.uint8)
    of_plane[top] = np.arange(top.size, dtype=np.uint8)
    return of_plane[label]




def _planes(tri, t_lo, t_hi):
    """Each triangle's supporting plane (an integer label) and every plane's centroid.

    Triangles are coplanar when their unit normals (sign fixed) and offsets
    agree to ``1e-6`` (of the scene's size); zero-area triangles get planes
    of their own. Returns ``(label (T,), centre (P, 3))``, the centre of the
    plane's triangles' bounding box.
    """
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ln = np.linalg.norm(n, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = n / ln[:, None]
    # one sign per plane: the largest component positive
    big = np.take_along_axis(n, np.argmax(np.abs(n), axis=1)[:, None], axis=1)
    n *= np.where(big < 0, -1.0, 1.0)
    scale = max(1.0, float(np.abs(tri).max()))
    key = np.empty((tri.shape[0], 4), np.int64)
    good = ln > 0
    key[:, :3] = np.where(good[:, None], np.round(n * 1e6), 0)
    key[:, 3] = np.where(good, np.round(np.einsum("tk,tk->t", n, tri[:, 0]) / scale * 1e6), 0)
    key[~good, 0] = -(1 + np.arange(int((~good).sum())))          # a plane of its own
    _, label = np.unique(key, axis=0, return_inverse=True)
    label = label.ravel()
    m = int(label.max()) + 1
    lo = np.full((m, 3), np.inf)
    hi = np.full((m, 3), -np.inf)
    np.minimum.at(lo, label, t_lo)
    np.maximum.at(hi, label, t_hi)
    return label, 0.5 * (lo + hi)


def _collapse(lo, hi, child, width, dtype, node_bits):
    """The wide tree of a binary one, level by level in array operations.

    A wide node starts as its binary node and, while it has fewer than
    ``width`` slots, opens its inner slot of largest surface area into that
    node's two children (the greedy collapse of Wald et al. 2008, 'Getting
    rid of packets'; every wide node of a level at once). Returns
    :attr:`BVH.wbox`, :attr:`BVH.wchild` and :attr:`BVH.wmask` (the slots'
    ``node_bits``, the plane classes under every binary node).
    """
    leaf_of = np.full(child.size, -1, np.int64)
    is_leaf = child < 0
    leaf_of[is_leaf] = np.arange(int(is_leaf.sum()))
    area = _half_area(lo.astype(np.float64), hi.astype(np.float64))
    boxes, children, masks = [], [], []
    owners = np.zeros(1, np.int64)           # binary node of each wide node of this level
    n_wide = 1
    while owners.size:
        k = owners.size
        slots = np.full((k, width), -1, np.int64)
        slots[:, 0] = owners
        used = np.ones(k, np.int64)
        rows = np.arange(k)
        for _ in range(width - 1):
            inner = (slots >= 0) & (np.take(child, np.maximum(slots, 0)) >= 0)
            score = np.where(inner, np.take(area, np.maximum(slots, 0)), -1.0)
            pick = np.argmax(score, axis=1)
            go = (score[rows, pick] >= 0) & (used < width)
            if not go.any():
                break
            r, j = rows[go], pick[go]
            c = child[slots[r, j]]
            slots[r, j] = c
            slots[r, used[go]] = c + 1
            used[go] += 1
        own, slot = np.nonzero(slots >= 0)
        node = slots[own, slot]
        box = np.full((6, k, width), np.nan, dtype)
        box[:3, own, slot] = lo[node].T
        box[3:, own, slot] = hi[node].T
        inner = child[node] >= 0
        code = np.zeros((k, width), np.int64)
        code[own, slot] = np.where(inner, 0, ~leaf_of[node])
        mask = np.zeros((k, width), np.uint64)
        mask[own, slot] = node_bits[node]
        masks.append(mask)
        nxt = node[inner]
        code[own[inner], slot[inner]] = n_wide + np.arange(nxt.size)
        boxes.append(box)
        children.append(code)
        n_wide += nxt.size
        owners = nxt
    return (np.ascontiguousarray(np.concatenate(boxes, axis=1)), np.ascontiguousarray(np.concatenate(children)),
            np.ascontiguousarray(np.concatenate(masks)))


def _leaves(child, start, count, order, width, maps):
    """:attr:`BVH.leaf_maps` and :attr:`BVH.leaf_prim`: every leaf's triangle maps
    (``maps`` (12, T)) side by side in ``width`` slots, NaN in the empty ones,
    leaves numbered in node order (as :func:`_collapse` numbers them)."""
    leaves = np.flatnonzero(child < 0)
    pos, seg = _ranges(start[leaves], count[leaves])
    slot = np.arange(pos.size) - (np.cumsum(count[leaves]) - count[leaves])[seg]
    prim = np.full((leaves.size, width), -1, np.int64)
    prim[seg, slot] = order[pos]
    leaf_maps = np.full((12, leaves.size, width), np.nan, maps.dtype)
    leaf_maps[:, seg, slot] = maps[:, order[pos]]
    return leaf_maps, prim


def triangle_maps(triangles, dtype=np.float32) -> np.ndarray:
    """Per-triangle affine maps ``(12, T)`` of the ray test (Baldwin and Weber 2016).

    With ``n = e1 x e2`` the matrix ``[e1 e2 n]`` maps barycentric
    coordinates and height to ``p - v0``; its inverse has rows
    ``(e2 x n, n x e1, n) / |n|^2``. Rows 0-3, 4-7 and 8-11 hold these three
    rows with their offsets ``-r . v0``: ``b1(p), b2(p), h(p)`` are affine in
    ``p``. A ray ``o + t d`` meets the plane at ``t = -h(o) / (r_h . d)``
    and the triangle where ``b1, b2 >= 0`` and ``b1 + b2 <= 1`` there.
    Zero-area triangles get NaN maps (never hit).
    """
    tri = np.asarray(triangles, dtype=np.float64)
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.cross(e1, e2)
    nn = np.einsum("tk,tk->t", n, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        rows = np.stack([np.cross(e2, n), np.cross(n, e1), n], axis=1) / nn[:, None, None]   # (T, 3, 3)
    rows[~(nn > 0)] = np.nan
    off = -np.einsum("tij,tj->ti", rows, v0)
    return np.ascontiguousarray(np.concatenate([rows, off[:, :, None]], axis=2).reshape(-1, 12).T, dtype)


def _slab(box, r):
    """Slab test of ``(P, width)`` blocks: boxes ``box`` (6, P, w) and rays
    ``r`` (7, P, w) as ``(1/d, best, o)``, ``best`` the closest hit so far.

    Returns the hit mask and the entry distances ``max(t_near, 0)``. A box is
    hit where ``max(t_near, 0) <= min(t_far, best)``; NaN (an empty slot)
    fails the comparison. The three axes and both bounds go through each
    operation together (``(2, 3, P, w)``, the rays' rows broadcast over the
    leading axis, which costs nothing): 11 NumPy calls a round instead of 25,
    the same operations in the same order, so the same bits (the three axes
    are combined by two elementwise calls: a ``reduce`` over them cost 3.8 us
    a call on short rounds, three times an elementwise call)."""
    t = box.reshape((2, 3) + box.shape[1:]) - r[4:7]
    t *= r[0:3]
    near = np.minimum(t[0], t[1])
    far = np.maximum(t[0], t[1], out=t[1])
    tn = np.maximum(near[0], near[1])
    np.maximum(tn, near[2], out=tn)
    tf = np.minimum(far[0], far[1])
    np.minimum(tf, far[2], out=tf)
    np.maximum(tn, 0, out=tn)
    np.minimum(tf, r[3], out=tf)
    return tn <= tf, tn


def _leaf_t(maps, r, eps):
    """Distances ``(Q, w)`` of (ray, leaf) pairs to the leaf's slots and the hit mask.

    ``maps`` (12, Q, w) from :attr:`BVH.leaf_maps`; ``r`` (7, Q, w) as
    ``(best, o, d)``, ``best`` the closest hit so far. The three affine maps
    (``b1, b2, h``) are evaluated together as ``(3, 4, Q, w)`` blocks, term
    by term in the order ``m0 x + m1 y + m2 z + m3`` (the same bits as one
    map at a time)."""
    best, o, d = r[0], r[1:4], r[4:7]
    m = maps.reshape((3, 4) + maps.shape[1:])
    lin = m[:, :3] * o
    at_o = np.add(lin[:, 0], lin[:, 1])
    at_o += lin[:, 2]
    at_o += m[:, 3]                       # b1(o), b2(o), h(o)
    np.multiply(m[:, :3], d, out=lin)
    along = np.add(lin[:, 0], lin[:, 1])
    along += lin[:, 2]                    # their rates along d
    t = np.divide(at_o[2], along[2])
    np.negative(t, out=t)
    b = along[:2]
    b *= t
    b += at_o[:2]                         # b1, b2 at the plane's crossing
    ok = b[0] >= 0
    ok &= b[1] >= 0
    b1 = np.add(b[0], b[1], out=b[0])
    ok &= b1 <= 1
    ok &= t > eps
    ok &= t < best
    return t, ok


class _Chunk:
    """One chunk of rays in traversal: the rays and their closest hit so far,
    repeated over the slots, and the answer being built.

    ``rays`` (10, n, w) holds rows ``1/d, best, o, d``: the slab test gathers
    rows 0-6 and the triangle test rows 3-9 of a pair's ray in one ``take``
    each."""

    def __init__(self, bvh: BVH, o, d, tmax, eps, any_hit, keep=None):
        w, n, dt = bvh.width, o.shape[1], bvh.dtype
        self.bvh, self.w, self.eps, self.any_hit = bvh, w, dt.type(eps), any_hit
        self.shift = w.bit_length() - 1
        col = np.empty((10, n), dt)
        with np.errstate(divide="ignore", invalid="ignore"):
            safe = np.where(np.abs(d) < TINY, np.copysign(np.asarray(TINY, dt), d), d)
            np.divide(1.0, safe, out=col[0:3])
        self.best = np.array(tmax, dtype=dt, copy=True)
        col[3] = self.best
        col[4:7] = o
        col[7:10] = d
        # repeated over the slots by np.repeat (measured twice as fast as a broadcast assignment)
        rays = np.repeat(col, w, axis=1).reshape(10, n, w)
        self.rays = rays
        self.box_rays, self.leaf_rays = rays[0:7], rays[3:10]
        self.prim = np.full(n, -1, np.int64)
        self.occ = np.zeros(n, bool)
        self.fresh = False                      # any ray occluded since the last filter
        self.wchild, self.lprim = bvh.wchild.ravel(), bvh.leaf_prim.ravel()
        #: per-ray plane-class masks of an any-hit query (None: every slot may occlude)
        self.keep, self.wmask = keep, bvh.wmask.ravel()

    def boxes(self, ray, node):
        """Hit mask and entry distances (P, w) of the slots of (ray, node) pairs."""
        return _slab(self.bvh.wbox.take(node, axis=1), self.box_rays.take(ray, axis=1))

    def children(self, ray, node):
        """The (ray, child code) pairs of the slots of (ray, node) that are hit."""
        ok, _ = self.boxes(ray, node)
        # flat indices and shifts: a 2-D nonzero and a 2-D fancy index took 4.7x the time on large rounds
        f = ok.ravel().nonzero()[0]
        pair = f >> self.shift
        slot = node.take(pair)
        slot <<= self.shift
        f &= self.w - 1
        slot |= f
        ray = ray.take(pair)
        if self.keep is not None:
            # slots holding no plane class the ray's key may meet are skipped (exact: Tracer.shadow_keys)
            may = self.wmask.take(slot)
            may &= self.keep.take(ray)
            live = may != 0
            slot, ray = slot[live], ray[live]
        return ray, self.wchild.take(slot)

    def leaves(self, lr, lf):
        """Intersect (ray, leaf) pairs; closest hits or occlusion recorded."""
        t, hit = _leaf_t(self.bvh.leaf_maps.take(lf, axis=1), self.leaf_rays.take(lr, axis=1), self.eps)
        g = hit.ravel().nonzero()[0]
        if not g.size:
            return
        q = g >> self.shift
        hr = lr.take(q)
        if self.any_hit:
            self.occ[hr] = True
            self.fresh = True
            return
        tt = t.ravel().take(g)
        best = self.best
        np.minimum.at(best, hr, tt)
        nearest = best.take(hr)
        win = tt == nearest
        slot = lf.take(q[win])
        slot <<= self.shift
        g &= self.w - 1
        slot |= g[win]
        self.prim[hr[win]] = self.lprim.take(slot)
        self.rays[3, hr] = nearest[:, None]

    def split(self, ray, code):
        """Test the leaves among (ray, child code) pairs; return the inner pairs."""
        leaf = code < 0
        at = leaf.nonzero()[0]             # (ndarray.any() costs a reduce's set-up, 5 us)
        if not at.size:
            return ray, code
        self.leaves(ray.take(at), ~code.take(at))
        np.logical_not(leaf, out=leaf)
        return ray[leaf], code[leaf]


def _any_hit(c: _Chunk, n):
    """Breadth first: every hit slot becomes a pair of the next round; occluded rays drop out,
    and so do slots whose plane classes the ray's key excludes."""
    ray, node = np.arange(n), np.zeros(n, np.int64)
    if c.keep is not None:
        ray = np.flatnonzero(c.keep & np.bitwise_or.reduce(c.wmask[:c.w]))
        node = node[:ray.size]
    while ray.size:
        ray, node = c.split(*c.children(ray, node))
        if c.fresh and ray.size:
            live = ~np.take(c.occ, ray)
            ray, node = ray[live], node[live]
            c.fresh = False
    return c.occ


def _closest(c: _Chunk, n):
    """Breadth first: every hit slot becomes a pair of the next round, and the
    leaves met in a round are intersected in it, so a closer hit prunes the
    boxes of the next round. (A front-to-back variant, every pair descending
    into its nearest slot and deferring the others until the first hits were
    known, opened 11% fewer boxes on the subdivided box's path rays but took
    twice the time: twice the rounds, and the per-pair keys.)"""
    ray, node = np.arange(n), np.zeros(n, np.int64)
    while ray.size:
        ray, node = c.split(*c.children(ray, node))
    best, prim = c.best, c.prim
    best[prim < 0] = np.inf
    return best.astype(np.float64), prim


def _traverse(bvh: BVH, o, d, tmax, eps, any_hit, keep=None):
    """One chunk of SoA rays (3, n): closest ``(t, prim)`` or, with ``any_hit``, the occluded mask."""
    c = _Chunk(bvh, o, d, tmax, eps, any_hit, keep)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        return (_any_hit if any_hit else _closest)(c, o.shape[1])


def _check_rays(bvh, o, d, tmax):
    o = np.asarray(o, bvh.dtype)
    d = np.asarray(d, bvh.dtype)
    if o.ndim != 2 or o.shape[0] != 3 or d.shape != o.shape:
        raise ValueError(f"o and d must be SoA rays of shape (3, n); got {o.shape} and {d.shape}")
    n = o.shape[1]
    tmax = np.asarray(tmax, bvh.dtype)
    if tmax.shape != (n,):
        if tmax.size != 1:
            raise ValueError(f"tmax must be a scalar or of shape ({n},); got {tmax.shape}")
        tmax = np.full(n, tmax.reshape(()), bvh.dtype)
    return o, d, tmax, n


def closest(bvh: BVH, o, d, tmax, eps: float, chunk: int = CHUNK):
    """Closest triangle hits of SoA rays ``o, d`` (3, n) in ``(eps, tmax)``: ``(t, prim)``.

    ``t`` is float64 (``inf`` and ``prim = -1`` on a miss). Among triangles
    hit at exactly the same distance (a shared edge) either may be returned.
    """
    o, d, tmax, n = _check_rays(bvh, o, d, tmax)
    t_out, p_out = np.full(n, np.inf), np.full(n, -1, np.int64)
    for s in range(0, n, chunk):
        sl = slice(s, min(n, s + chunk))
        t_out[sl], p_out[sl] = _traverse(bvh, o[:, sl], d[:, sl], tmax[sl], eps, False)
    return t_out, p_out


def occluded(bvh: BVH, o, d, tmax, eps: float, chunk: int = CHUNK, keep=None) -> np.ndarray:
    """Any-hit test of SoA rays (3, n): True where a triangle lies in ``(eps, tmax)``.

    ``keep`` (n,) uint64, optional: per ray, the plane classes
    (:attr:`BVH.tri_class` as bits) whose triangles may occlude it; the
    others are not tested (the caller vouches that they cannot lie in
    ``(eps, tmax)``: :meth:`mcvar.tracer.Tracer.shadow_keys`).
    """
    o, d, tmax, n = _check_rays(bvh, o, d, tmax)
    if keep is not None:
        keep = np.asarray(keep)
        if keep.dtype != np.uint64 or keep.shape != (n,):
            raise ValueError(f"keep must be a uint64 array of shape ({n},); got {keep.dtype} {keep.shape}")
    occ = np.zeros(n, bool)
    for s in range(0, n, chunk):
        sl = slice(s, min(n, s + chunk))
        occ[sl] = _traverse(bvh, o[:, sl], d[:, sl], tmax[sl], eps, True, None if keep is None else keep[sl])
    return occ
